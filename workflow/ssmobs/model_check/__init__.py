"""The check of a model's Python module against its Stan program.

Owns the cases (:mod:`~ssmobs.model_check.cases`), the Python stage
(:mod:`~ssmobs.model_check.python`), the Stan source (:mod:`~ssmobs.model_check.stan_source`),
the compiled program (:mod:`~ssmobs.model_check.stan`), the analytic gradients
(:mod:`~ssmobs.model_check.analytic`) and the run of them all
(:mod:`~ssmobs.model_check.check`); its command line ``python -m ssmobs.model_check``
(:mod:`~ssmobs.model_check.__main__`).

May import: the shared top-level modules, :mod:`ssmobs.models`, :mod:`ssmobs.stan_backends`
and :mod:`ssmobs.nuts` (the generated gradients); the command line also :mod:`ssmobs.config`
(the config validates a user's model by this package's Python stage, so no other module of
it may import the config).
"""
