"""The check of a model's Python module against its Stan program.

Owns the Stan source (:mod:`~ssmobs.model_check.stan_source`), the compiled program
(:mod:`~ssmobs.model_check.stan`), which generated program it runs and who writes it
(:mod:`~ssmobs.model_check.program`), the analytic gradients
(:mod:`~ssmobs.model_check.analytic`), the symmetry report
(:mod:`~ssmobs.model_check.symmetry_report`) and the run of them all
(:mod:`~ssmobs.model_check.check`); its command line ``python -m ssmobs.model_check``
(:mod:`~ssmobs.model_check.__main__`).  The cases and the Python module's check of itself
(step 1) belong to the models (:mod:`ssmobs.models.check_cases`,
:mod:`ssmobs.models.self_check`): the config's validation runs them too.

May import: the shared top-level modules, :mod:`ssmobs.models`, :mod:`ssmobs.stan_backends`,
:mod:`ssmobs.nuts` (the generated gradients) and :mod:`ssmobs.config` (the command line reads
a config's scenarios).
"""
