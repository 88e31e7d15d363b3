"""Empirical moments of a point estimator over the trajectories it is defined on.

One definition for the joint MAP over K^max (Sec. III.B), the marginal MAP over K^Stan
(Sec. III.C) and the exact marginal MAP: mean, variance (ddof = 1, as in Table II), bias and
mean squared error about the true value (Tables II and III).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

#: the statistics :func:`estimator_moments` returns, in this order
MOMENTS = ("mean", "var", "bias", "mse")


def estimator_moments(estimates: npt.ArrayLike, truth: float) -> dict[str, float]:
    """``mean``, ``var`` (ddof = 1), ``bias`` (mean - truth) and ``mse`` (mean of
    (estimate - truth)^2) of the estimates; NaN where undefined (no estimate, or one for
    the variance)."""
    est = np.asarray(estimates, dtype=float).ravel()
    mean = float(np.mean(est)) if est.size else math.nan
    return {
        "mean": mean,
        "var": float(np.var(est, ddof=1)) if est.size > 1 else math.nan,
        "bias": mean - float(truth),
        "mse": float(np.mean((est - truth) ** 2)) if est.size else math.nan,
    }
