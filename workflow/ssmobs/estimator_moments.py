"""Empirical moments of a point estimator over the trajectories it is defined on.

One definition for the joint MAP over K^max (Sec. III.B), the marginal MAP over K^Stan
(Sec. III.C) and the exact marginal MAP: mean, variance (ddof = 1, as in Table II), bias and
mean squared error about the true value (Tables II and III), stored under
:func:`stat_key` in each stage's summary and read back by :class:`EstimatorSummary`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

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


def stat_key(component: str, stat: str) -> str:
    """The summary key of a component's statistic: ``a_mean``, ``x0_cover90``, ..."""
    return f"{component}_{stat}"


def moment_entries(component: str, estimates: npt.ArrayLike, truth: float) -> dict[str, float]:
    """:func:`estimator_moments` under the summary keys of ``component``."""
    return {stat_key(component, s): v for s, v in estimator_moments(estimates, truth).items()}


#: the key of each stage's summary that counts the trajectories its estimator is defined on:
#: |K^max| (Sec. III.B), |K^Stan| (Sec. III.C), unique interior maxima of the exact marginal
COUNT_KEYS = {"joint": "K_max", "stan": "n_stan", "exact": "n_exact"}


@dataclass(frozen=True)
class EstimatorSummary:
    """A stage's ``summary.json`` (joint MAP, Stan or exact) read back, typed: the count of
    trajectories its estimator is defined on out of K, and per component the statistics of
    :func:`estimator_moments` plus ``cover90`` (Stan and exact); an absent summary (stage
    not run) gives NaN everywhere."""

    stage: str
    values: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.stage not in COUNT_KEYS:
            raise ValueError(f"unknown stage {self.stage!r}; one of {sorted(COUNT_KEYS)}")

    @classmethod
    def read(cls, stage: str, values: Mapping[str, Any] | None) -> EstimatorSummary:
        return cls(stage, values or {})

    @property
    def present(self) -> bool:
        """True when the stage ran (its summary is not empty)."""
        return bool(self.values)

    @property
    def count(self) -> Any:
        """|K^max|, |K^Stan| or the exact stage's unique maxima, as stored; NaN if absent."""
        return self.values.get(COUNT_KEYS[self.stage], math.nan)

    def get(self, key: str, default: Any = None) -> Any:
        """Any other stored value (``K``, ``n_unique``, ...) as stored."""
        return self.values.get(key, default)

    def stat(self, component: str, stat: str) -> float:
        """``stat`` of ``component`` as a float (NaN where absent)."""
        return _float(self.values.get(stat_key(component, stat)))

    def states(self, stat: str) -> float:
        """Mean over the states x_1..x_T of ``cover90``, ``abs_bias`` or ``mse``."""
        return _float(self.values.get(f"x_{stat}_mean"))


def _float(value: Any) -> float:
    return float(value) if value is not None else math.nan
