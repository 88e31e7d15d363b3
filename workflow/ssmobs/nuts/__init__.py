"""NUTS on the design trajectories (Sec. III.C): sampling, records, convergence, metrics.

Owns a batch of trajectories sampled (:mod:`~ssmobs.nuts.batch`), the per-trajectory record
cache and its file format (:mod:`~ssmobs.nuts.record_cache`,
:mod:`~ssmobs.nuts.record_format`), the convergence checks and diagnostics
(:mod:`~ssmobs.nuts.convergence`, :mod:`~ssmobs.nuts.diagnostics`), the marginal MAP from
the draws (:mod:`~ssmobs.nuts.marginal_map`), the metrics of K^Stan
(:mod:`~ssmobs.nuts.stan_metrics`) and the generated analytic gradients
(:mod:`~ssmobs.nuts.analytic_gradients`).

May import: the shared top-level modules, :mod:`ssmobs.models` and :mod:`ssmobs.stan_backends`.
"""
