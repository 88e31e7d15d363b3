"""The exact marginal posterior of Omega for the linear-Gaussian models (issue 11).

Owns the Kalman filter (:mod:`~ssmobs.exact.kalman_filter`), the grid over Omega
(:mod:`~ssmobs.exact.omega_grid`), the state mixtures (:mod:`~ssmobs.exact.state_mixtures`),
the boundaries (:mod:`~ssmobs.exact.boundaries`), the interior singularities
(:mod:`~ssmobs.exact.interior_singularities`), the settings
(:mod:`~ssmobs.exact.settings`) and the driver (:mod:`~ssmobs.exact.marginal`).

May import: the shared top-level modules and :mod:`ssmobs.models`.
"""
