"""The tables and figures of a study: what the stages' results become on paper.

Owns the figures (:mod:`~ssmobs.reports.figures`), the tables
(:mod:`~ssmobs.reports.tables`), the comparison with the paper's values
(:mod:`~ssmobs.reports.paper_comparison`), the observability study
(:mod:`~ssmobs.reports.observability_study`), the profile posterior
(:mod:`~ssmobs.reports.profile_posterior`) and the table of Stan variants
(:mod:`~ssmobs.reports.stan_variants`).

May import: the shared top-level modules, :mod:`ssmobs.models`, :mod:`ssmobs.config`,
:mod:`ssmobs.joint_map`, :mod:`ssmobs.nuts` and :mod:`ssmobs.cache_keys`.
"""
