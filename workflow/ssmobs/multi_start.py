"""Multi-start joint MAP: how many distinct maxima of pi(Theta | z~(k)) pass the checks.

The checks of Sec. III.B (gradient, Hessian, eigenvalue ratio with the ridge re-check) are
local: they pass at any strict local maximum, so one start per trajectory, as in the paper,
says that *a* maximum was found, not that it is the only one.  Here every design
trajectory is optimised from ``n_starts`` starts by the same barrier method with the same
checks (:func:`ssmobs.joint_map.joint_map`, each start vectorised over k):

- start 0 is the paper's: (Omega_true, x0_true, the scenario's state start rule);
- starts 1 .. n_starts - 1 take (Omega, x_0) from a Halton sequence (bases 2, 3, 5, ...;
  its first point, the corner, skipped) scaled to the *start box*: Omega's prior box
  (Eq. (3), Eq. (14)), where a side without a finite bound (``half_line``) and both sides
  of x_0's (flat prior on R) lie ``start_box_span * max(1, |true value|)`` from the true
  value; points outside the model's constraints c(Omega) > 0 are skipped.  The states
  start from the model's own construction at that point: ``sign_consistent_states(Omega,
  x0, z)`` where the model defines one (the states then take x_0's sign, and x_0 ranges
  over both signs), else ``initial_states(Omega, z)``.  The starts are the same for every
  trajectory and need no seed.

Distinct maxima.  Among the starts of trajectory k whose result passes every check
(status ``ok``), two results are the same maximum when no component of Theta differs by
more than ``distinct_tol`` local standard deviations, |Theta_j - Theta'_j| <=
distinct_tol * sqrt(max(LVar_j, LVar'_j)) (Sec. II.B), i.e. the tolerance is stated in
parameters scaled by the posterior's local spread.  Greedy clustering from the highest
log posterior down gives the distinct maxima of k, each with the highest value reached in
it.  Per trajectory: their number, their log posterior values (pi up to the model's
constant, = -(-2 pi) / 2), whether the paper's start reached the highest (its value within
``ridge_value_tol * (1 + |-2 pi|)`` of the best, so exact ties count), and the gap in log
posterior from the highest to the second.

K^max_unique: the trajectories with exactly one distinct maximum that passes the checks.
It is not a subset of K^max (which is the paper's start's result), since another start can
pass where the paper's does not.  A start that ends on the boundary or fails a check adds
no maximum (its count is reported), so K^max_unique can still hide a supremum at the edge
of the support; ``boundary_higher`` marks the trajectories where a start that ended on the
boundary reached a higher log posterior than every maximum that passes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .binomial import clopper_pearson
from .joint_map import JointMapResult, ProgressLike, joint_map
from .joint_map_settings import JointMapSettings
from .models.base import PriorBounds, StateSpaceModel
from .models.log_posterior import compile_model

#: the first primes: Halton bases of up to this many dimensions of (Omega, x_0)
_PRIMES: tuple[int, ...] = (2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53)


def halton(n: int, dim: int, skip: int = 1) -> np.ndarray:
    """(n, dim) points of the Halton sequence in (0, 1)^dim from index ``skip`` on.

    Index 0 is the corner 0 (skipped by default); every later point lies strictly inside.
    """
    if dim > len(_PRIMES):
        raise ValueError(f"Halton starts support up to {len(_PRIMES)} dimensions, got {dim}")
    out = np.empty((n, dim))
    for j, base in enumerate(_PRIMES[:dim]):
        for i in range(n):
            index, f, value = i + skip, 1.0, 0.0
            while index > 0:
                f /= base
                value += f * (index % base)
                index //= base
            out[i, j] = value
    return out


def start_box(
    bounds: PriorBounds, omega_true: np.ndarray, x0_true: np.ndarray, span: float
) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners of the box of (Omega, x_0) that the extra starts fill."""
    truth = np.concatenate([omega_true, x0_true])
    half = span * np.maximum(1.0, np.abs(truth))
    lower = np.concatenate([np.asarray(bounds.lower, float), np.full(x0_true.size, -np.inf)])
    upper = np.concatenate([np.asarray(bounds.upper, float), np.full(x0_true.size, np.inf)])
    lower = np.where(np.isfinite(lower), lower, truth - half)
    upper = np.where(np.isfinite(upper), upper, truth + half)
    return lower, upper


def start_points(
    model: StateSpaceModel,
    bounds: PriorBounds,
    omega_true: np.ndarray,
    x0_true: np.ndarray,
    n_starts: int,
    span: float,
) -> np.ndarray:
    """(n_starts, m + p) starts (Omega, x_0): row 0 the true values (the paper's start), the
    others Halton points of the start box that satisfy the model's constraints."""
    m = model.n_params
    points = [np.concatenate([omega_true, x0_true])]
    if n_starts == 1:
        return np.asarray(points)
    lower, upper = start_box(bounds, omega_true, x0_true, span)
    constraints = compile_model(model).constraints
    skip = 1
    while len(points) < n_starts:
        batch = lower + halton(4 * n_starts, lower.size, skip) * (upper - lower)
        skip += 4 * n_starts
        inside = np.ones(batch.shape[0], dtype=bool)
        if constraints.count:
            inside = np.all(constraints.values(batch[:, :m]) > 0, axis=1)
        points.extend(batch[inside][: n_starts - len(points)])
        if skip > 1000 * n_starts:
            raise ValueError(
                f"model '{model.slug}': fewer than {n_starts} Halton points of the start box "
                f"({lower.tolist()}, {upper.tolist()}) satisfy the model's constraints"
            )
    return np.asarray(points)


@dataclass
class MultiStartResult:
    """Results of every start and the distinct maxima per trajectory k.

    Attributes
    ----------
    starts : (S, m + p) start (Omega, x_0) of every start; row 0 is the paper's.
    runs : the :class:`~ssmobs.joint_map.JointMapResult` of every start; ``runs[0]`` is the
        paper's start (the joint MAP of K^max).
    n_starts_ok : (K,) starts whose result passes every check.
    n_starts_boundary : (K,) starts that ended with status ``boundary``.
    maxima_log_post : per k, the log posterior (pi up to the model's constant) of every
        distinct maximum that passes the checks, highest first.
    maxima_first_start : per k, the first start that reached each of those maxima.
    paper_start_highest : (K,) the paper's start passed and reached the highest maximum.
    boundary_higher : (K,) a start that ended with status ``boundary`` has a higher log
        posterior there than every maximum that passes (or than -inf if none passes): the
        supremum lies at the edge of the support, above the interior maxima.
    """

    starts: np.ndarray
    runs: list[JointMapResult]
    n_starts_ok: np.ndarray
    n_starts_boundary: np.ndarray
    maxima_log_post: list[np.ndarray]
    maxima_first_start: list[np.ndarray]
    paper_start_highest: np.ndarray
    boundary_higher: np.ndarray

    @property
    def n_maxima(self) -> np.ndarray:
        """(K,) number of distinct maxima that pass the checks."""
        return np.array([v.size for v in self.maxima_log_post], dtype=np.int64)

    @property
    def log_post_gap(self) -> np.ndarray:
        """(K,) log posterior of the highest maximum minus the second's (NaN if < 2)."""
        return np.array([v[0] - v[1] if v.size > 1 else np.nan for v in self.maxima_log_post])

    def columns(self) -> pd.DataFrame:
        """Per-k columns beside the joint-MAP table (one row per k, in order of k)."""
        n_max = self.n_maxima
        return pd.DataFrame(
            {
                "n_starts_ok": self.n_starts_ok.astype(np.int64),
                "n_starts_boundary": self.n_starts_boundary.astype(np.int64),
                "n_maxima": n_max,
                "unique_max": n_max == 1,
                "paper_start_highest": self.paper_start_highest.astype(bool),
                "boundary_higher": self.boundary_higher.astype(bool),
                "log_post_best": [v[0] if v.size else np.nan for v in self.maxima_log_post],
                "log_post_gap": self.log_post_gap,
                "maxima_log_post": [v.astype(float) for v in self.maxima_log_post],
                "maxima_first_start": [v.astype(np.int64) for v in self.maxima_first_start],
            }
        )


def distinct_maxima(
    runs: list[JointMapResult], k: int, settings: JointMapSettings
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Distinct maxima of trajectory k over the starts whose result passes the checks.

    Returns the values -2 pi of the maxima (lowest, i.e. highest posterior, first), the
    first start reaching each, and whether start 0 reached the highest.
    """
    passed = [s for s, r in enumerate(runs) if r.status[k] == "ok"]
    order = sorted(passed, key=lambda s: (runs[s].neg2_log_post[k], s))
    values: list[float] = []
    first: list[int] = []
    members: list[list[int]] = []
    for s in order:
        theta, lvar = runs[s].theta_hat[k], runs[s].local_variance[k]
        for j, group in enumerate(members):
            rep = group[0]
            sd = np.sqrt(np.maximum(lvar, runs[rep].local_variance[k]))
            if np.all(np.abs(theta - runs[rep].theta_hat[k]) <= settings.distinct_tol * sd):
                group.append(s)
                first[j] = min(first[j], s)
                break
        else:
            members.append([s])
            values.append(float(runs[s].neg2_log_post[k]))
            first.append(s)
    paper_highest = False
    if values and runs[0].status[k] == "ok":
        f0, best = float(runs[0].neg2_log_post[k]), values[0]
        paper_highest = f0 <= best + settings.ridge_value_tol * (1.0 + abs(best))
    return np.asarray(values), np.asarray(first, dtype=np.int64), paper_highest


def multi_start_joint_map(
    model: StateSpaceModel,
    z: np.ndarray,
    bounds: PriorBounds,
    omega_true: np.ndarray,
    x0_true: np.ndarray,
    settings: JointMapSettings,
    progress: ProgressLike | None = None,
) -> MultiStartResult:
    """Joint MAP of every trajectory from ``settings.n_starts`` starts (module docstring).

    Start 0 is :func:`ssmobs.joint_map.joint_map` with the paper's start exactly; the others
    use ``start_states = "sign_of_x0"`` where the model defines it, else ``observations``.
    """
    omega = np.asarray(omega_true, dtype=float)
    x0 = np.atleast_1d(np.asarray(x0_true, dtype=float))
    m = model.n_params
    starts = start_points(model, bounds, omega, x0, settings.n_starts, settings.start_box_span)
    spread_states = "sign_of_x0" if model.has_sign_consistent_start else "observations"
    spread = dataclasses.replace(settings, start_states=spread_states)
    runs = [joint_map(model, z, bounds, omega, x0, settings, progress=progress)]
    for point in starts[1:]:
        runs.append(joint_map(model, z, bounds, point[:m], point[m:], spread, progress=progress))
    K = runs[0].status.shape[0]
    status = np.stack([r.status for r in runs])
    values, first, highest = [], [], np.zeros(K, dtype=bool)
    for k in range(K):
        f, s, h = distinct_maxima(runs, k, settings)
        values.append(-0.5 * f)
        first.append(s)
        highest[k] = h
    edge = np.stack([np.where(r.status == "boundary", r.neg2_log_post, np.inf) for r in runs]).min(
        axis=0
    )
    best = np.array([-2.0 * v[0] if v.size else np.inf for v in values])
    with np.errstate(invalid="ignore"):
        boundary_higher = np.isfinite(edge) & (edge < best)
    return MultiStartResult(
        starts=starts,
        runs=runs,
        n_starts_ok=(status == "ok").sum(axis=0),
        n_starts_boundary=(status == "boundary").sum(axis=0),
        maxima_log_post=values,
        maxima_first_start=first,
        paper_start_highest=highest,
        boundary_higher=boundary_higher,
    )


def multi_start_summary(columns: pd.DataFrame, settings: JointMapSettings) -> dict[str, object]:
    """Scenario summary of the multi-start columns (:meth:`MultiStartResult.columns`).

    ``K_max_unique`` (= |K^max_unique|), ``K_max_any`` (one or more maxima pass),
    ``K_max_several``, ``K_paper_start_highest``, ``K_max_unique_lo95`` / ``_hi95`` (exact
    binomial 95 % interval of |K^max_unique| / K), ``K_max_unique_boundary_higher`` (of
    K^max_unique, those where a start on the boundary went higher), ``log_post_gap_median``
    (over the trajectories with several maxima) and the settings ``n_starts``,
    ``distinct_tol``.
    """
    K = int(len(columns))
    n_max = columns["n_maxima"].to_numpy()
    unique = int((n_max == 1).sum())
    lo, hi = clopper_pearson(unique, K)
    gaps = columns["log_post_gap"].to_numpy(dtype=float)
    several = n_max > 1
    return {
        "n_starts": settings.n_starts,
        "distinct_tol": settings.distinct_tol,
        "K_max_unique": unique,
        "K_max_unique_lo95": lo,
        "K_max_unique_hi95": hi,
        "K_max_any": int((n_max >= 1).sum()),
        "K_max_several": int(several.sum()),
        "K_paper_start_highest": int(columns["paper_start_highest"].sum()),
        "K_max_unique_boundary_higher": int(
            ((n_max == 1) & columns["boundary_higher"].to_numpy(dtype=bool)).sum()
        ),
        "log_post_gap_median": float(np.median(gaps[several])) if several.any() else np.nan,
    }
