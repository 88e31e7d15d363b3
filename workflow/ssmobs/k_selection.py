"""Choice of the number K of design trajectories by relative differences (Sec. IV.A).

For K_i = i * step the scenario summary of the joint MAP estimator gives

    V_{K_i} = (|K^max| / K_i,  E^ of every Omega and x_0 component,
               Var^ of every component,  mean LVar of every component),

and K = K_i for the smallest i with RD(V_{K_i}, V_{K_j}) < (c_1, ..., c_2, ...) component-wise
for every computed j > i, where

    RD(x, y) = |x - y| / max(|x|, |y|),   RD(0, 0) = 0,

c_1 applies to the ratio and the means and c_2 to the variances and local variances.

Every K_i gets its own disturbance set.  The paper does not say whether the sets of
different K_i share points; we offer both (:func:`set_seed`): ``independent`` draws each
set from its own seed stream, ``nested`` uses one seed for every K_i, so a random set of
size K_i is the first K_i points of the set of size K_j > K_i (numpy draws row by row),
which correlates V_{K_i} and V_{K_j} and makes the RD rule stop earlier.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import seeds
from .models.base import StateSpaceModel

#: how the disturbance sets of the K_i relate (see the module docstring)
SET_VARIANTS = ("independent", "nested")


def set_seed(seed: int, K: int, sets: str) -> int:
    """Seed of the disturbance set of size K for a choice-of-K run with ``seed``.

    ``nested``: ``seed`` itself for every K (random sets of different K share their first
    points).  ``independent``: a seed drawn from the stream (seed, "disturbances",
    "k_selection", K), so the sets of different K are independent draws.
    """
    if sets == "nested":
        return int(seed)
    if sets == "independent":
        return seeds.int_seed(int(seed), "disturbances", "k_selection", int(K))
    raise ValueError(f"k_selection sets must be one of {SET_VARIANTS}, got {sets!r}")


def relative_difference(x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
    """Component-wise RD(x, y) = |x - y| / max(|x|, |y|) with RD(0, 0) = 0.

    NaN where either argument is NaN (e.g. a mean over an empty K^max), so such a
    component never counts as converged.  RD lies in [0, 2]; it is 1 when exactly one
    argument is 0 and 2 for opposite signs of equal size.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    num = np.abs(x - y)
    den = np.maximum(np.abs(x), np.abs(y))
    with np.errstate(invalid="ignore", divide="ignore"):
        rd = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return np.where(np.isnan(x) | np.isnan(y), np.nan, rd)


@dataclass(frozen=True)
class VVector:
    """V_{K_i} with a label and a threshold class ("c1" or "c2") per component."""

    values: np.ndarray
    labels: tuple[str, ...]
    kinds: tuple[str, ...]

    def thresholds(self, c1: float, c2: float) -> np.ndarray:
        """Per-component thresholds: c1 for the ratio and means, c2 for (local) variances."""
        return np.array([c1 if k == "c1" else c2 for k in self.kinds], dtype=float)


def v_vector(summary: Mapping[str, Any], model: StateSpaceModel) -> VVector:
    """V_{K_i} from :func:`ssmobs.joint_map.driver.joint_map_summary` (Sec. IV.A).

    Order (the paper's, generalised to any number of components): ``ratio``, ``c_mean`` for
    every component c of Omega and x_0, then ``c_var``, then ``c_lvar_mean``.  Kinds: c1
    for the ratio and the means, c2 for the variances and the mean local variances.
    """
    comps = model.theta_names(0)
    labels = (
        ["ratio"]
        + [f"{c}_mean" for c in comps]
        + [f"{c}_var" for c in comps]
        + [f"{c}_lvar_mean" for c in comps]
    )
    kinds = ["c1"] * (1 + len(comps)) + ["c2"] * (2 * len(comps))
    missing = [lab for lab in labels if lab not in summary]
    if missing:
        raise ValueError(f"joint-MAP summary lacks {missing} for model '{model.slug}'")
    values = np.array([float(summary[lab]) for lab in labels], dtype=float)
    return VVector(values=values, labels=tuple(labels), kinds=tuple(kinds))


def select_k(
    k_values: Sequence[int],
    vectors: np.ndarray | Sequence[Sequence[float]],
    thresholds: np.ndarray | Sequence[float],
) -> int | None:
    """Index i of the chosen K = K_i by the RD rule of Sec. IV.A, or None.

    Parameters
    ----------
    k_values : (I,) strictly increasing K_i (e.g. i * step).
    vectors : (I, q) V_{K_i}, one row per K_i.
    thresholds : (q,) per-component thresholds (c1 / c2, see :meth:`VVector.thresholds`).

    Returns
    -------
    The smallest index i < I - 1 with RD(V_{K_i}, V_{K_j}) < thresholds component-wise for
    every j > i; None if there is none.  The last K_i is never chosen: with no computed
    K_j beyond it the condition would hold vacuously, which says nothing about
    convergence, so a sequence that only "converges" at its end returns None (compute
    more K_i).  A NaN component (e.g. |K^max| = 0 or 1) never satisfies the condition.
    """
    k = np.asarray(k_values)
    V = np.asarray(vectors, dtype=float)
    thr = np.asarray(thresholds, dtype=float)
    if k.ndim != 1 or V.ndim != 2 or V.shape[0] != k.size:
        raise ValueError(
            f"need one V row per K_i: got {k.size} K values and vectors of shape {V.shape}"
        )
    if thr.shape != (V.shape[1],):
        raise ValueError(f"thresholds must have shape ({V.shape[1]},), got {thr.shape}")
    if k.size > 1 and not np.all(np.diff(k) > 0):
        raise ValueError(f"K values must be strictly increasing, got {k.tolist()}")
    for i in range(k.size - 1):
        rd = relative_difference(V[i][None, :], V[i + 1 :])
        if np.all(rd < thr):  # NaN compares False
            return i
    return None


def choose_k(
    summaries: Sequence[Mapping[str, Any]],
    model: StateSpaceModel,
    ksel: Mapping[str, Any],
    scenario: str,
    paper: Mapping[str, Any],
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The RD rule (:func:`select_k`) for every (method, set variant, seed) of one
    ``k_selection`` entry, from the joint-MAP summaries of its K_i (Sec. IV.A).

    Parameters
    ----------
    summaries : one :func:`ssmobs.joint_map.driver.joint_map_summary` per run and K_i, with the
        keys ``K_i``, ``method``, ``seed`` and ``sets`` (``nested`` when absent).
    model : the scenario's model (names of the V components).
    ksel : the config's ``k_selection`` entry (``name``, ``c1``, ``c2``).
    scenario : the scenario's name (copied into every choice).
    paper : the scenario's entry of ``paper_values.yaml`` (its ``k_selection`` per method:
        ``K``, and the thresholds ``c1``/``c2`` and range ``K_min``/``K_max`` where stated).

    Returns
    -------
    ``long_rows`` (one per run, K_i and V component: ``K``, ``method``, ``sets``, ``seed``,
    ``component``, ``value``) and ``choices`` (one per run: the chosen ``K_chosen``, None
    when the rule chooses none, the grid, and the paper's K where it is comparable: the
    paper's K of other thresholds is left out).
    """
    long_rows: list[dict[str, Any]] = []
    choices: list[dict[str, Any]] = []
    runs = sorted({(s["method"], s.get("sets", "nested"), int(s["seed"])) for s in summaries})
    for method, sets, seed in runs:
        sel = sorted(
            (
                s
                for s in summaries
                if s["method"] == method
                and s.get("sets", "nested") == sets
                and int(s["seed"]) == seed
            ),
            key=lambda s: s["K_i"],
        )
        ks = [int(s["K_i"]) for s in sel]
        vecs = [v_vector(s, model) for s in sel]
        V = np.array([v.values for v in vecs])
        thresholds = vecs[0].thresholds(ksel["c1"], ksel["c2"])
        idx = select_k(ks, V, thresholds)
        ref = (paper.get("k_selection") or {}).get(method) or {}
        if "c1" in ref and (ref["c1"], ref["c2"]) != (ksel["c1"], ksel["c2"]):
            ref = {"K": None}  # the paper's K belongs to other thresholds: not comparable
        choices.append(
            {
                "name": ksel["name"],
                "scenario": scenario,
                "method": method,
                "sets": sets,
                "seed": seed,
                "c1": ksel["c1"],
                "c2": ksel["c2"],
                "K_chosen": ks[idx] if idx is not None else None,
                "K_grid": f"{ks[0]}-{ks[-1]}"
                + (f" step {ks[1] - ks[0]}" if len(set(np.diff(ks))) == 1 else " (uneven)"),
                "K_max_grid": ks[-1],
                "K_paper": ref.get("K"),
                "c_paper": f"({ref['c1']}, {ref['c2']})" if "c1" in ref else "",
                "K_paper_range": (f"{ref['K_min']}-{ref['K_max']}" if "K_min" in ref else ""),
            }
        )
        for K, v in zip(ks, vecs):
            for label, value in zip(v.labels, v.values):
                long_rows.append(
                    {
                        "K": K,
                        "method": method,
                        "sets": sets,
                        "seed": seed,
                        "component": label,
                        "value": float(value),
                    }
                )
    return long_rows, choices
