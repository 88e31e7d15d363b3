"""The multi-start joint MAP of a scenario's design trajectories (Sec. III.B,
:mod:`ssmobs.joint_map.multi_start`) with its per-k table and its summary: |K^max_unique|
and the other counts of distinct maxima.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from ..binomial import clopper_pearson
from .driver import JointMapResult, ProgressLike, joint_map_summary
from .multi_start import multi_start_joint_map
from .problem import JointMapProblem
from .settings import JointMapSettings


def multi_start_of(
    problem: JointMapProblem, progress: ProgressLike | None = None
) -> tuple[JointMapResult, pd.DataFrame, dict[str, Any]]:
    """:func:`ssmobs.joint_map.driver.joint_map_of` from ``settings.n_starts`` starts: the
    paper's start's result, its table with the per-k columns of the distinct maxima beside,
    and its summary with |K^max_unique| and the other multi-start counts."""
    multi = multi_start_joint_map(problem, progress=progress)
    result = multi.runs[0]
    columns = multi.columns()
    frame = result.to_frame(problem.model, problem.T).join(columns)
    summary = joint_map_summary(frame, problem.model, problem.omega_true, problem.x0_true)
    summary.update(multi_start_summary(columns, problem.settings))
    return result, frame, summary


def multi_start_summary(columns: pd.DataFrame, settings: JointMapSettings) -> dict[str, object]:
    """Scenario summary of the multi-start columns (:meth:`MultiStartResult.columns`).

    ``K_max_unique`` (= |K^max_unique|, verdict ``unique``), ``K_max_undetermined`` (one
    maximum, too few starts passed), ``K_max_any`` (one or more maxima pass),
    ``K_max_several``, ``K_paper_start_highest``, ``K_max_unique_lo95`` / ``_hi95`` (exact
    binomial 95 % interval of |K^max_unique| / K), ``K_max_unique_boundary_higher`` (of
    K^max_unique, those where a start on the boundary went higher), ``K_edge_supremum`` and
    ``K_max_unique_edge_supremum`` (all, and of K^max_unique, those where a start that ran
    off went higher), ``K_symmetric_twin`` (a maximum with a twin), ``log_post_gap_median``
    (over the trajectories with several maxima) and the settings ``n_starts``,
    ``distinct_tol``, ``unique_min_share``.
    """
    K = int(len(columns))
    n_max = columns["n_maxima"].to_numpy()
    verdict = columns["maxima_verdict"].to_numpy(dtype=object)
    unique_k = verdict == "unique"
    unique = int(unique_k.sum())
    lo, hi = clopper_pearson(unique, K)
    gaps = columns["log_post_gap"].to_numpy(dtype=float)
    several = n_max > 1
    none = np.zeros(K, dtype=bool)  # tables written before these columns
    edge = columns["edge_supremum"].to_numpy(bool) if "edge_supremum" in columns else none
    twin = columns["symmetric_twin"].to_numpy(bool) if "symmetric_twin" in columns else none
    return {
        "n_starts": settings.n_starts,
        "distinct_tol": settings.distinct_tol,
        "unique_min_share": settings.unique_min_share,
        "K_max_unique": unique,
        "K_max_unique_lo95": lo,
        "K_max_unique_hi95": hi,
        "K_max_undetermined": int((verdict == "undetermined").sum()),
        "K_max_any": int((n_max >= 1).sum()),
        "K_max_several": int(several.sum()),
        "K_paper_start_highest": int(columns["paper_start_highest"].sum()),
        "K_max_unique_boundary_higher": int(
            (unique_k & columns["boundary_higher"].to_numpy(dtype=bool)).sum()
        ),
        "K_edge_supremum": int(edge.sum()),
        "K_max_unique_edge_supremum": int((unique_k & edge).sum()),
        "K_symmetric_twin": int(twin.sum()),
        "log_post_gap_median": float(np.median(gaps[several])) if several.any() else np.nan,
    }
