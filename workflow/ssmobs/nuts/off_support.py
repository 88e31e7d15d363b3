"""Marginal MAPs and quantiles that are no estimate: off the prior support, or run off.

A KDE mode (Eq. (11)) of draws piled against the end of a prior support can lie a few
bandwidths beyond it, and draws that ran off along a ridge give modes and quantiles of
any size (b_map = -1.6e307 for a prior b > 0).  Such a value is kept in the per-trajectory
table as computed, and marked there (:func:`mark_off_support`), so that no reader of the
file takes it for an estimate; the tables built from it leave it out
(:mod:`ssmobs.reports.observability_study`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas

    from ..models.base import PriorBounds, StateSpaceModel

#: a marginal MAP, quantile or mean beyond this magnitude comes from draws that ran off
RUNOFF_MAGNITUDE = 1e100
#: the per-trajectory statistics checked, as column suffixes of the gathered table
CHECKED_STATS = ("map", "q5", "q95")


def unusable(value: float, support: tuple[float, float]) -> str:
    """Why ``value`` (an estimate of a component with prior support ``support``) is not an
    estimate: off the support or from draws that ran off ("" if usable; NaN means "not
    computed", which is no reason)."""
    if not np.isfinite(value):
        return ""
    if abs(value) > RUNOFF_MAGNITUDE:
        return f"from draws that ran off (|value| > {RUNOFF_MAGNITUDE:g})"
    lo, hi = support
    if not lo <= value <= hi:
        return f"off the support ({lo:g}, {hi:g})"
    return ""


def component_supports(
    model: StateSpaceModel, bounds: PriorBounds, T: int
) -> dict[str, tuple[float, float]]:
    """The prior support of every component of Theta (``model.theta_names(T)``): Omega's
    from ``bounds``, the whole line for x0 and the states (flat, Sec. IV)."""
    names = model.theta_names(T)
    m = model.n_params
    out = {n: (float(bounds.lower[i]), float(bounds.upper[i])) for i, n in enumerate(names[:m])}
    out.update({n: (-np.inf, np.inf) for n in names[m:]})
    return out


def off_support_reasons(
    frame: pandas.DataFrame, model: StateSpaceModel, bounds: PriorBounds, T: int
) -> list[str]:
    """Per row of ``frame`` (columns ``<name>_map``/``_q5``/``_q95``), every value that is
    no estimate, as ``"b_map -1.6e+307 from draws that ran off (...)"`` joined by "; "
    ("" for a row without any)."""
    reasons: list[list[str]] = [[] for _ in range(len(frame))]
    for name, support in component_supports(model, bounds, T).items():
        lo, hi = support
        for stat in CHECKED_STATS:
            col = f"{name}_{stat}"
            if col not in frame.columns:
                continue
            values = frame[col].to_numpy(dtype=float)
            with np.errstate(invalid="ignore"):
                bad = np.isfinite(values) & (
                    (np.abs(values) > RUNOFF_MAGNITUDE) | (values < lo) | (values > hi)
                )
            for i in np.flatnonzero(bad):
                reasons[i].append(f"{col} {values[i]:.3g} {unusable(float(values[i]), support)}")
    return ["; ".join(r) for r in reasons]


def mark_off_support(
    frame: pandas.DataFrame, model: StateSpaceModel, bounds: PriorBounds, T: int
) -> pandas.DataFrame:
    """``frame`` with the column ``off_support`` (:func:`off_support_reasons`; "" where every
    value is usable): the values themselves are kept as computed."""
    out = frame.copy()
    out["off_support"] = off_support_reasons(frame, model, bounds, T)
    return out
