"""The check of a model's Python module against its Stan program.

Owns the cases (:mod:`~ssmobs.model_check.cases`), the Python stage
(:mod:`~ssmobs.model_check.python`), the Stan source (:mod:`~ssmobs.model_check.stan_source`),
the compiled program (:mod:`~ssmobs.model_check.stan`), the analytic gradients
(:mod:`~ssmobs.model_check.analytic`) and the run of them all
(:mod:`~ssmobs.model_check.check`).

May import: the shared top-level modules, :mod:`ssmobs.models`, :mod:`ssmobs.stan_backends`
and :mod:`ssmobs.nuts` (the generated gradients).
"""
