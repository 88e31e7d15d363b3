"""Multi-start joint MAP: how many distinct maxima of pi(Theta | z~(k)) pass the checks.

The checks of Sec. III.B (gradient, Hessian, eigenvalue ratio with the ridge re-check) are
local: they pass at any strict local maximum, so one start per trajectory, as in the paper,
says that *a* maximum was found, not that it is the only one.  Here every design
trajectory is optimised from ``n_starts`` starts by the same barrier method with the same
checks (:func:`ssmobs.joint_map.driver.joint_map`, each start vectorised over k):

- start 0 is the paper's: (Omega_true, x0_true, the scenario's state start rule);
- starts 1 .. n_starts - 1 take (Omega, x_0) from a Halton sequence (bases 2, 3, 5, ...;
  its first point, the corner, skipped) scaled to the *start box*: Omega's prior box
  (Eq. (3), Eq. (14)), where a side without a finite bound (``half_line``) and both sides
  of x_0's (flat prior on R) lie ``start_box_span * max(1, |true value|)`` from the true
  value; points outside the model's constraints c(Omega) > 0 are skipped, and so are points
  where the start is excluded by the model (-2 pi or its gradient not finite at the start
  for some trajectory, e.g. b = 0 where the states start at z / b);
- the states of a Halton start come from one of two branches in turn, because a start
  covers Theta, not only Omega: the odd starts (1, 3, ...) take the model's own construction
  from the data, ``sign_consistent_states(Omega, x0, z)`` where the model defines one (the
  states take x_0's sign, and x_0 ranges over both signs), else ``initial_states(Omega,
  z)``; the even starts (2, 4, ...) take the model's noise-free path from x_0 at that Omega
  (``simulate`` with eta = eps = 0), which follows the branch the dynamics choose rather
  than the data's (where it is not finite, or excluded, the data's construction instead);
- *image starts* (:mod:`ssmobs.joint_map.images`): each distinct maximum found by the
  starts above is mapped by every symmetry of the model, those it declares
  (``mirror_images``, e.g. x -> -x) and the discrete ones found from its terms
  (:func:`ssmobs.models.symmetries.model_symmetries`: sign changes, swaps of blocks,
  translations by a period in both directions, reflections), and optimised again from
  every admissible image (inside the support, -2 pi finite) that is neither the maximum
  itself nor a maximum already found.  The image of a maximum is a maximum of the same
  height, so a symmetry never lets a trajectory count as having one maximum because no
  start happened to fall on the image's side (each start's states lie on one branch).

The starts are the same for every trajectory (the image starts per k) and need no seed.

Distinct maxima.  Among the starts of trajectory k whose result passes every check
(status ``ok``), two results are the same maximum when no component of Theta differs by
more than ``distinct_tol`` local standard deviations, |Theta_j - Theta'_j| <=
distinct_tol * sqrt(max(LVar_j, LVar'_j)) (Sec. II.B), i.e. the tolerance is stated in
parameters scaled by the posterior's local spread.  Greedy clustering from the highest
log posterior down gives the distinct maxima of k, each with the highest value reached in
it.  Per trajectory: their number, their log posterior values (pi up to the model's
constant, = -(-2 pi) / 2), whether the paper's start reached the highest (its value within
``ridge_value_tol * (1 + |-2 pi|)`` of the best, so exact ties count), and the gap in log
posterior from the highest to the second (0 up to rounding for a maximum and its image).

Verdict per trajectory (``maxima_verdict``): ``none`` (no maximum passes), ``several``
(two or more pass, or one whose image under a symmetry of the model is another admissible
point: ``symmetric_twin``, a maximum of the same height whether or not a run from it
passed; with a translation infinitely many), ``unique`` (one maximum found from the n
starts, the images under the model's symmetries included: reached by every start that
passes, no twin, and at least ``unique_min_share`` of the ``n_starts`` starts pass) or
``undetermined`` (one such maximum, but fewer starts pass: one passing start does not show
that the others would reach it).  K^max_unique: the trajectories with verdict ``unique``.
It is not a subset of K^max (which is the paper's start's result), since another start can
pass where the paper's does not.  ``starts_per_maximum`` counts, per maximum, the n starts
that reached it (0 for one only an image start reached).

A start that ends on the boundary, runs off or fails a check adds no maximum (its count is
reported), so K^max_unique can still hide a supremum above the interior maxima.  Two
columns say where one was measured: ``boundary_higher``, a start that ended with status
``boundary`` (on the boundary of the prior support) reached a higher log posterior than
every maximum that passes; ``edge_supremum``, a start ended ``unbounded`` (-2 pi still
fell in both continued segments as Theta ran off to infinity,
:func:`ssmobs.joint_map.checks.runoff_check`) at a higher log posterior than every maximum
that passes: the density rises towards an infinite end of the support (b -> inf on a
half-line prior, a flat x_0).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..models.base import PriorBounds, StateSpaceModel
from ..models.log_posterior import compile_constraints, neg2_log_posterior
from .driver import JointMapResult, ProgressLike, initial_theta, joint_map
from .images import image_runs, symmetric_twins
from .problem import JointMapProblem
from .settings import JointMapSettings

#: the verdicts of a trajectory's maxima (module docstring)
VERDICTS: tuple[str, ...] = ("unique", "several", "undetermined", "none")

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
    admissible: Callable[[np.ndarray, int], bool] | None = None,
) -> np.ndarray:
    """(n_starts, m + p) starts (Omega, x_0): row 0 the true values (the paper's start), the
    others Halton points of the start box that satisfy the model's constraints and, if
    given, ``admissible(point, index)`` (the start would be start ``index``)."""
    m = model.n_params
    points = [np.concatenate([omega_true, x0_true])]
    if n_starts == 1:
        return np.asarray(points)
    lower, upper = start_box(bounds, omega_true, x0_true, span)
    constraints = compile_constraints(model)
    skip = 1
    while len(points) < n_starts:
        batch = lower + halton(4 * n_starts, lower.size, skip) * (upper - lower)
        skip += 4 * n_starts
        inside = np.ones(batch.shape[0], dtype=bool)
        if constraints.count:
            inside = np.all(constraints.values(batch[:, :m]) > 0, axis=1)
        for point in batch[inside]:
            if len(points) == n_starts:
                break
            if admissible is None or admissible(point, len(points)):
                points.append(point)
        if len(points) < n_starts and skip > 1000 * n_starts:
            raise ValueError(
                f"model '{model.slug}': fewer than {n_starts} Halton points of the start box "
                f"({lower.tolist()}, {upper.tolist()}) satisfy the model's constraints"
                + ("" if admissible is None else " and give a finite -2 pi and gradient")
            )
    return np.asarray(points)


@dataclass
class MultiStartResult:
    """Results of every start and the distinct maxima per trajectory k.

    Attributes
    ----------
    starts : (S, m + p) start (Omega, x_0) of every Halton start; row 0 is the paper's.
    runs : the :class:`~ssmobs.joint_map.driver.JointMapResult` of every start, the S starts first
        (``runs[0]`` is the paper's start, the joint MAP of K^max), then the image starts
        (status ``not-run`` for the k an image start did not run).
    start_states : (S,) the state start rule of each of the S starts.
    n_starts_ok : (K,) of the S starts, those whose result passes every check.
    n_starts_boundary : (K,) of the S starts, those that ended with status ``boundary``.
    maxima_log_post : per k, the log posterior (pi up to the model's constant) of every
        distinct maximum that passes the checks, highest first.
    maxima_first_start : per k, the first start (index into ``runs``) reaching each of them.
    starts_per_maximum : per k, how many of the S starts reached each maximum (0 for one
        that only an image start reached), in the order of ``maxima_log_post``.
    paper_start_highest : (K,) the paper's start passed and reached the highest maximum.
    boundary_higher : (K,) one of the S starts ended with status ``boundary`` (on the
        boundary of the prior support) at a higher log posterior than every maximum that
        passes (or than -inf if none passes): the supremum lies on the boundary, above the
        interior maxima.
    edge_supremum : (K,) one of the S starts ended ``unbounded`` (still gaining as it ran
        off to infinity, :func:`ssmobs.joint_map.checks.runoff_check`) at a higher log
        posterior than every maximum that passes: the density rises towards an infinite end
        of the support (a half-line or line prior, or x_0's), above the interior maxima.
    symmetric_twin : (K,) a maximum that passes has an admissible image under a symmetry
        of the model (:mod:`ssmobs.joint_map.images`) that is another point: a maximum of
        the same height, whether or not a start reached it.
    unique_min_share : the share of the S starts that must pass for ``unique``.
    """

    starts: np.ndarray
    runs: list[JointMapResult]
    start_states: list[str]
    n_starts_ok: np.ndarray
    n_starts_boundary: np.ndarray
    maxima_log_post: list[np.ndarray]
    maxima_first_start: list[np.ndarray]
    starts_per_maximum: list[np.ndarray]
    paper_start_highest: np.ndarray
    boundary_higher: np.ndarray
    edge_supremum: np.ndarray
    symmetric_twin: np.ndarray
    unique_min_share: float = 0.5

    @property
    def n_maxima(self) -> np.ndarray:
        """(K,) number of distinct maxima that pass the checks."""
        return np.array([v.size for v in self.maxima_log_post], dtype=np.int64)

    @property
    def log_post_gap(self) -> np.ndarray:
        """(K,) log posterior of the highest maximum minus the second's (NaN if < 2)."""
        return np.array([v[0] - v[1] if v.size > 1 else np.nan for v in self.maxima_log_post])

    @property
    def verdict(self) -> np.ndarray:
        """(K,) one of :data:`VERDICTS` (module docstring)."""
        return maxima_verdict(
            self.n_maxima,
            self.n_starts_ok,
            self.starts.shape[0],
            self.unique_min_share,
            self.symmetric_twin,
        )

    def columns(self) -> pd.DataFrame:
        """Per-k columns beside the joint-MAP table (one row per k, in order of k)."""
        n_max = self.n_maxima
        verdict = self.verdict
        return pd.DataFrame(
            {
                "n_starts_ok": self.n_starts_ok.astype(np.int64),
                "n_starts_boundary": self.n_starts_boundary.astype(np.int64),
                "n_maxima": n_max,
                "maxima_verdict": pd.Series(verdict, dtype=object).astype(str),
                "unique_max": verdict == "unique",
                "paper_start_highest": self.paper_start_highest.astype(bool),
                "boundary_higher": self.boundary_higher.astype(bool),
                "edge_supremum": self.edge_supremum.astype(bool),
                "symmetric_twin": self.symmetric_twin.astype(bool),
                "log_post_best": [v[0] if v.size else np.nan for v in self.maxima_log_post],
                "log_post_gap": self.log_post_gap,
                "maxima_log_post": [v.astype(float) for v in self.maxima_log_post],
                "maxima_first_start": [v.astype(np.int64) for v in self.maxima_first_start],
                "starts_per_maximum": [v.astype(np.int64) for v in self.starts_per_maximum],
            }
        )


def maxima_verdict(
    n_maxima: np.ndarray,
    n_starts_ok: np.ndarray,
    n_starts: int,
    unique_min_share: float,
    symmetric_twin: np.ndarray | None = None,
) -> np.ndarray:
    """(K,) ``none``, ``several``, ``unique`` or ``undetermined`` (module docstring): one
    maximum is ``unique`` only when at least ceil(share * n_starts) of the starts pass and
    it has no ``symmetric_twin`` (an admissible image under a symmetry that is another
    point: then ``several``)."""
    needed = max(1, math.ceil(unique_min_share * n_starts - 1e-12))
    n_maxima, n_ok = np.asarray(n_maxima), np.asarray(n_starts_ok)
    twin = np.zeros(n_maxima.shape, dtype=bool) if symmetric_twin is None else symmetric_twin
    one = (n_maxima == 1) & ~np.asarray(twin, dtype=bool)
    out = np.where(n_maxima == 0, "none", "several").astype(object)
    out[one & (n_ok >= needed)] = "unique"
    out[one & (n_ok < needed)] = "undetermined"
    return out


def distinct_maxima(
    runs: list[JointMapResult], k: int, settings: JointMapSettings
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Distinct maxima of trajectory k over the starts whose result passes the checks.

    Returns the values -2 pi of the maxima (lowest, i.e. highest posterior, first), the
    first start reaching each, and whether start 0 reached the highest.
    """
    values, first, _, paper_highest = cluster_maxima(runs, k, settings)
    return values, first, paper_highest


def cluster_maxima(
    runs: list[JointMapResult], k: int, settings: JointMapSettings
) -> tuple[np.ndarray, np.ndarray, list[list[int]], bool]:
    """:func:`distinct_maxima` with the runs (indices into ``runs``) that reached each."""
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
    return np.asarray(values), np.asarray(first, dtype=np.int64), members, paper_highest


def data_states_rule(model: StateSpaceModel) -> str:
    """The data's construction of the states: ``sign_of_x0`` where defined, else
    ``observations``."""
    return "sign_of_x0" if model.has_sign_consistent_start else "observations"


def start_is_admissible(
    model: StateSpaceModel, z: np.ndarray, bounds: PriorBounds, theta: np.ndarray
) -> bool:
    """The start Theta (K, n) is finite and inside the support, and -2 pi and its gradient
    are finite there for every trajectory (the model does not exclude it)."""
    if not np.all(np.isfinite(theta)):
        return False
    with np.errstate(all="ignore"):
        value, grad = neg2_log_posterior(model, theta, z, bounds, order=1)
    return bool(np.all(np.isfinite(value)) and np.all(np.isfinite(grad)))


def halton_start_rule(
    model: StateSpaceModel, z: np.ndarray, bounds: PriorBounds, point: np.ndarray, index: int
) -> str | None:
    """State start rule of Halton start ``index`` at ``point`` = (Omega, x_0): ``simulate``
    for even indices, the data's construction for odd ones and where the simulated start is
    not admissible; None if no rule gives an admissible start."""
    m = model.n_params
    rules = [data_states_rule(model)]
    if index % 2 == 0:
        rules.insert(0, "simulate")
    for rule in rules:
        try:
            with np.errstate(all="ignore"):
                theta = initial_theta(model, z, point[:m], point[m:], rule)
        except (ArithmeticError, ValueError, NotImplementedError):
            if rule == "simulate":  # a simulator that fails here: the data's construction
                continue
            raise
        if start_is_admissible(model, z, bounds, theta):
            return rule
    return None


def _distinct_all(
    runs: list[JointMapResult], K: int, S: int, settings: JointMapSettings
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Per k: log pi of the distinct maxima, the first run reaching each, how many of the
    first S runs (the starts) reached each; and whether the paper's start reached the
    highest."""
    values, first, counts, highest = [], [], [], np.zeros(K, dtype=bool)
    for k in range(K):
        f, s, members, h = cluster_maxima(runs, k, settings)
        values.append(-0.5 * f)
        first.append(s)
        counts.append(np.array([sum(i < S for i in g) for g in members], dtype=np.int64))
        highest[k] = h
    return values, first, counts, highest


def higher_than_maxima(
    runs: list[JointMapResult], status: str, values: list[np.ndarray]
) -> np.ndarray:
    """(K,) one of ``runs`` ended with ``status`` at a higher log posterior than every
    maximum in ``values`` (log pi per k, highest first; -inf where there is none)."""
    edge = np.stack([np.where(r.status == status, r.neg2_log_post, np.inf) for r in runs]).min(
        axis=0
    )
    best = np.array([-2.0 * v[0] if v.size else np.inf for v in values])
    with np.errstate(invalid="ignore"):
        return np.isfinite(edge) & (edge < best)


def multi_start_joint_map(
    problem: JointMapProblem, progress: ProgressLike | None = None
) -> MultiStartResult:
    """Joint MAP of every trajectory from ``settings.n_starts`` starts and the images of
    the maxima they find (module docstring).

    Start 0 is :func:`ssmobs.joint_map.driver.joint_map` with the paper's start exactly (with one
    start nothing else runs); the others use the state start rule of
    :func:`halton_start_rule`.
    """
    model, bounds, settings = problem.model, problem.bounds, problem.settings
    omega = np.asarray(problem.omega_true, dtype=float)
    x0 = np.atleast_1d(np.asarray(problem.x0_true, dtype=float))
    z = np.asarray(problem.z, dtype=float)
    problem = problem.replace(z=z, omega_true=omega, x0_true=x0)
    m = model.n_params

    def admissible(point: np.ndarray, index: int) -> bool:
        return halton_start_rule(model, z, bounds, point, index) is not None

    starts = start_points(
        model, bounds, omega, x0, settings.n_starts, settings.start_box_span, admissible
    )
    runs = [joint_map(problem, progress=progress)]
    rules = [settings.start_states]
    for index, point in enumerate(starts[1:], start=1):
        rule = halton_start_rule(model, z, bounds, point, index)
        assert rule is not None  # start_points kept admissible points only
        rules.append(rule)
        spread = dataclasses.replace(settings, start_states=rule)
        start = problem.replace(omega_true=point[:m], x0_true=point[m:], settings=spread)
        runs.append(joint_map(start, progress=progress))
    S = len(runs)
    K = runs[0].status.shape[0]
    values, first, counts, highest = _distinct_all(runs, K, S, settings)
    twin = np.zeros(K, dtype=bool)
    if S > 1:
        extra = image_runs(problem, runs, first)
        if extra:
            runs.extend(extra)
            values, first, counts, highest = _distinct_all(runs, K, S, settings)
        twin = symmetric_twins(model, z, bounds, runs, first, settings)
    status = np.stack([r.status for r in runs[:S]])
    return MultiStartResult(
        starts=starts,
        runs=runs,
        start_states=rules,
        n_starts_ok=(status == "ok").sum(axis=0),
        n_starts_boundary=(status == "boundary").sum(axis=0),
        maxima_log_post=values,
        maxima_first_start=first,
        starts_per_maximum=counts,
        paper_start_highest=highest,
        boundary_higher=higher_than_maxima(runs[:S], "boundary", values),
        edge_supremum=higher_than_maxima(runs[:S], "unbounded", values),
        symmetric_twin=twin,
        unique_min_share=settings.unique_min_share,
    )
