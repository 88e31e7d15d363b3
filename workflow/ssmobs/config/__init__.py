"""The config and the scenario: what a study asks for, checked before any work.

Owns the JSON schema and its messages (:mod:`~ssmobs.config.schema`), the strict reading of
config files (:mod:`~ssmobs.config.files`), the checks a schema cannot express
(:mod:`~ssmobs.config.validation`), numbers written as text
(:mod:`~ssmobs.config.numbers`), the checks of ``outputs_dir``
(:mod:`~ssmobs.config.outputs_dir`), the scenario object (:mod:`~ssmobs.config.scenario`) and
its settings blocks merged once (:mod:`~ssmobs.config.blocks`), the cells of the
observability maps (:mod:`~ssmobs.config.maps`), the entry check before Snakemake
(:mod:`~ssmobs.config.preflight`) and the run lock it takes
(:mod:`~ssmobs.config.run_lock`), the size and time budget
(:mod:`~ssmobs.config.budget`), the smoke overlay (:mod:`~ssmobs.config.smoke`) and the
generated reference and profile tables (:mod:`~ssmobs.config.reference`,
:mod:`~ssmobs.config.profiles`).

May import: the shared top-level modules, :mod:`ssmobs.models` (a user's model is checked
against itself when its config is validated: :mod:`ssmobs.models.self_check`),
:mod:`ssmobs.stan_backends` and :mod:`ssmobs.nuts` (whether a Stan program can be generated
for a model without one).
"""
