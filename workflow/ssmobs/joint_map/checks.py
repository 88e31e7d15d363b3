"""Numerical checks of a found joint MAP Theta_hat (Sec. III.B), one status per k.

The checks are applied in this order (the first that applies wins):

``failed``
    value, gradient, Hessian or Theta_hat not finite (reason in ``reason``).
``unbounded``
    a run that did not converge (stopped by the iteration limit or the line search, or past
    ``divergence_limit``) still gains when followed (:func:`runoff_check`): -2 pi falls by
    more than ``ridge_value_tol (1 + |-2 pi|)`` in each of two continued segments while a
    magnitude grows by 10 % at least: the supremum is approached at infinity, and there is
    no maximum.  The reason names the direction (``b -> +inf``) and the two gains.  Passing
    ``divergence_limit`` alone is not enough: a run along a ridge passes it too (it is then
    ``ridge``, or ``boundary`` or ``gradient`` by what the continued run shows).
``boundary``
    the optimum lies on the boundary of the prior's support: a slack below
    ``boundary_tol``, or (for a converged run) a barrier multiplier mu / s_i above
    ``grad_tol`` (the barrier is what holds the point), or (for a run that did not
    converge) a slack below ``boundary_near_tol`` with -2 pi still decreasing towards that
    constraint faster than ``grad_tol``; or a run that did not converge ends on the
    boundary when followed (:func:`runoff_check`).
``not-positive-definite``
    the Hessian of -2 pi is not positive definite: its block Cholesky factorisation fails
    or its smallest eigenvalue is not above ``pd_tol``.
``gradient``
    largest absolute gradient component of -2 pi not below ``grad_tol`` (1e-5 in the paper).
    A run stopped by ``max_newton_iter`` or the line search is followed for up to two
    segments of ``runoff_iter`` more iterations (:func:`runoff_check`) to say why it did
    not converge:
    ``unbounded`` (with the direction) if -2 pi keeps decreasing while Theta moves outward,
    as at a supremum at infinity of any size;
    ``ridge`` if the continued run converges to a point whose checks find a ridge (a flat
    direction, e.g. an exact invariance of the density), or moves without changing -2 pi
    (by at most ``ridge_value_tol (1 + |-2 pi|) / runoff_margin``: a margin of 100 below
    the gain that counts, so that rounding moves no run between the two labels);
    ``boundary`` if it ends on the boundary; else it stays ``gradient`` (the reason says
    whether it converges with more iterations).
``ridge``
    eigenvalue ratio lambda_min / lambda_max below ``eig_ratio_min`` (r_0 = 1e-5) and a new
    optimisation started at Theta_hat + h v_min (v_min the unit eigenvector of the smallest
    eigenvalue, h = ``ridge_shift``, halved until the start is inside the support) ends more
    than ``ridge_move_tol`` away (sup norm), or ends non-finite or diverged.  If it returns
    to Theta_hat the trajectory is ``ok`` (the reason column records the check).
``ok``
    all checks passed: k belongs to K^max.

``STATUSES`` lists them; ``unbounded`` and the ``ridge`` of a run that did not converge
(issues 47, 60) replace what was ``boundary`` (ran off past ``divergence_limit``) and
``gradient`` (max-iter): neither is ever ``ok``, so K^max is the same.

Eigenvalues: lambda_max by Lanczos on H, lambda_min and v_min by Lanczos on H^{-1} (applied
through the factorisation), ``lanczos_steps`` steps with full reorthogonalisation;
``eigen_method="dense"`` uses LAPACK instead (O(n^3), for checks).

Local variances (Sec. II.B): LVar_j = -H_pi^{-1}(Theta_hat)_jj = 2 (H_{-2 pi}^{-1})_jj for
every component, by a selected inversion of the factorised arrow matrix, wherever the
Hessian is positive definite (NaN otherwise).

The ridge re-check records both how far the re-optimised point moved (sup norm) and how
much -2 pi changed; ``ridge_test`` says which decides (see
:class:`~ssmobs.joint_map.settings.JointMapSettings`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ..banded_linalg import ArrowFactor, arrow_extreme_eigenpairs
from ..models.base import StateSpaceModel
from ..models.log_posterior import neg2_log_posterior, neg2_log_posterior_blocks
from .barrier import LogBarrier, minimize_barrier
from .settings import JointMapSettings

#: the six statuses, in the order in which the checks assign them
STATUSES: tuple[str, ...] = (
    "ok",
    "not-positive-definite",
    "gradient",
    "ridge",
    "unbounded",
    "boundary",
    "failed",
)


def check_maxima(
    model: StateSpaceModel,
    z: np.ndarray,
    theta: np.ndarray,
    mu: np.ndarray,
    stop: np.ndarray,
    barrier: LogBarrier,
    settings: JointMapSettings,
    follow_runoff: bool = True,
) -> dict[str, np.ndarray]:
    """The checks of Sec. III.B at the results ``theta`` of one batch of trajectories.

    ``mu`` and ``stop`` are the final barrier parameter and the stop reason of
    :func:`~ssmobs.joint_map.barrier.minimize_barrier`.  Returns per-k arrays named as the
    fields of :class:`~ssmobs.joint_map.driver.JointMapResult` they fill: ``neg2_log_post``,
    ``local_variance``, ``eig_ratio``, ``grad_max``, ``status`` (the first check of the
    module docstring that applies), ``reason`` and ``ridge_value_change`` (the ridge
    re-optimisation, :func:`ridge_check`, is run where the eigenvalue ratio asks for it).
    """
    K, n = theta.shape
    m = model.n_params
    with np.errstate(all="ignore"):
        f, g, blk = neg2_log_posterior_blocks(model, theta, z)
    fin_h = np.ones(K, dtype=bool)
    for a in (blk.omega, blk.cross, blk.diag, blk.lower):
        fin_h &= np.all(np.isfinite(a.reshape(K, -1)), axis=1)
    finite = (
        np.isfinite(f) & np.all(np.isfinite(g), axis=1) & fin_h & np.all(np.isfinite(theta), axis=1)
    )
    fac = ArrowFactor(blk.omega, blk.cross, blk.diag, blk.lower)
    fac.ok &= finite
    lam_min, lam_max, v_min = arrow_extreme_eigenpairs(
        fac, settings.eigen_method, settings.lanczos_steps
    )
    with np.errstate(all="ignore"):
        ratio = lam_min / lam_max
        grad_max = np.abs(g).max(axis=1)
        s = barrier.slacks(theta[:, :m])
        s_min = s.min(axis=1) if s.shape[1] else np.full(K, np.inf)
        mult = np.where(stop == "converged", mu / s_min, 0.0)
        # rate of decrease of -2 pi when moving towards each constraint (unit normal)
        ds = barrier.slack_gradients(theta[:, :m])
        pull = np.einsum("ki,ksi->ks", g[:, :m], ds) / np.maximum(
            np.linalg.norm(ds, axis=2), 1e-300
        )
        pushed = np.any((s < settings.boundary_near_tol) & (pull > settings.grad_tol), axis=1)
        pushed &= stop != "converged"
        lvar = 2.0 * fac.diag_inverse()
    pd_ = fac.ok & (lam_min > settings.pd_tol)
    lvar[~pd_] = np.nan

    status = np.full(K, "ok", dtype=object)
    reason = np.full(K, "", dtype=object)
    undecided = np.ones(K, dtype=bool)

    def assign(mask: np.ndarray, st: str, why: str | Callable[[np.intp], str]) -> None:
        nonlocal undecided
        hit = mask & undecided
        status[hit] = st
        for k in np.flatnonzero(hit):
            reason[k] = why(k) if callable(why) else why
        undecided &= ~hit

    assign(
        ~finite,
        "failed",
        lambda k: f"non-finite value/gradient/Hessian at the result (optimiser stop: {stop[k]})",
    )
    assign(  # until the continued run (runoff_check) has measured a gain
        stop == "diverged",
        "unbounded",
        lambda k: (
            f"iterates passed divergence_limit (|Theta|_inf > {settings.divergence_limit:g}): "
            + beyond_limit(model, theta[k], settings.divergence_limit)
        ),
    )
    assign(
        s_min < settings.boundary_tol,
        "boundary",
        lambda k: f"optimum on the boundary of the prior support (min slack {s_min[k]:.3g})",
    )
    assign(
        mult > settings.grad_tol,
        "boundary",
        lambda k: f"barrier holds the optimum (mu/slack = {mult[k]:.3g})",
    )
    assign(
        pushed,
        "boundary",
        lambda k: (
            f"-2 pi still decreases towards the boundary (min slack {s_min[k]:.3g}, "
            f"optimiser stop: {stop[k]})"
        ),
    )
    assign(
        ~pd_,
        "not-positive-definite",
        lambda k: f"Hessian not positive definite (smallest eigenvalue about {lam_min[k]:.3g})",
    )
    assign(
        ~(grad_max < settings.grad_tol),
        "gradient",
        lambda k: (
            f"max |gradient| {grad_max[k]:.3g} >= {settings.grad_tol:g} (optimiser stop: {stop[k]})"
        ),
    )

    slow = np.flatnonzero(
        ((status == "gradient") & np.isin(stop, ("max-iter", "line-search")))
        | ((status == "unbounded") & (stop == "diverged"))
    )
    if follow_runoff and slow.size:
        new_status, new_reason = runoff_check(
            model, z[slow], theta[slow], f[slow], barrier, settings, stop[slow] == "diverged"
        )
        for j, k in enumerate(slow):
            status[k] = new_status[j]
            reason[k] = f"{reason[k]}; {new_reason[j]}"

    cand = np.flatnonzero(undecided & ~(ratio >= settings.eig_ratio_min))
    value_change = np.full(K, np.nan)
    if cand.size:
        ridge, dist, dval = ridge_check(
            model, z[cand], theta[cand], f[cand], v_min[cand], barrier, settings
        )
        value_change[cand] = dval
        for j, k in enumerate(cand):
            small = f"eigenvalue ratio {ratio[k]:.3g} < {settings.eig_ratio_min:g}"
            what = f"moved {dist[j]:.3g} (sup norm), -2 pi changed by {dval[j]:.3g}"
            if ridge[j]:
                status[k] = "ridge"
                reason[k] = f"{small}; after a shift along the ridge the re-optimisation {what}"
            else:
                reason[k] = (
                    f"{small} but the re-optimisation returned ({what}; "
                    f"test: {settings.ridge_test})"
                )
    return dict(
        neg2_log_post=f,
        local_variance=lvar,
        eig_ratio=ratio,
        grad_max=grad_max,
        status=status,
        reason=reason,
        ridge_value_change=value_change,
    )


def ridge_check(
    model: StateSpaceModel,
    z: np.ndarray,
    theta: np.ndarray,
    f_hat: np.ndarray,
    v: np.ndarray,
    barrier: LogBarrier,
    settings: JointMapSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Re-optimise from Theta_hat + h v (or - h v if that leaves the support).

    Returns (ridge, distance moved (sup norm), |change of -2 pi|); ``ridge`` by
    ``settings.ridge_test``.  A non-finite or diverged re-optimisation counts as a ridge.
    """
    m = model.n_params
    start = theta.copy()
    placed = np.zeros(theta.shape[0], dtype=bool)
    h = settings.ridge_shift
    for _ in range(30):
        for sign in (1.0, -1.0):
            trial = theta + sign * h * v
            inside = ~placed & np.isfinite(barrier.value(trial[:, :m]))
            start[inside] = trial[inside]
            placed |= inside
        if placed.all():
            break
        h *= 0.5
    new, _, _, stop = minimize_barrier(model, z, start, barrier, settings, settings.mu_min)
    with np.errstate(all="ignore"):
        dist = np.abs(new - theta).max(axis=1)
        (f_new,) = neg2_log_posterior(model, new, z, None, order=0)
        dval = np.abs(f_new - f_hat)
    if settings.ridge_test == "location":
        differs = ~(dist <= settings.ridge_move_tol)
    else:
        differs = ~(dval <= settings.ridge_value_tol * (1.0 + np.abs(f_hat)))
    ridge = differs | (stop == "non-finite") | (stop == "diverged")
    return ridge, dist, dval


def beyond_limit(model: StateSpaceModel, theta: np.ndarray, limit: float) -> str:
    """The components of one Theta beyond ``limit`` in magnitude, as ``b -> +inf`` (the
    states summarised as ``x -> +-inf``)."""
    names = model.theta_names((theta.size - model.n_params) // model.state_dim - 1)
    head = model.n_params + model.state_dim
    parts = [
        f"{names[j]} -> {'+' if theta[j] > 0 else '-'}inf"
        for j in range(head)
        if abs(theta[j]) > limit
    ]
    states = theta[head:]
    if states.size and np.any(np.abs(states) > limit):
        parts.append("x -> +-inf")
    return ", ".join(parts) or "no component"


#: a component "runs" (outward or towards 0) in a continued run when its magnitude changes
#: by at least this factor (:func:`runoff_direction`, :func:`runoff_check`)
RUNOFF_FACTOR = 1.1


def magnitude_changes(model: StateSpaceModel, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """log(|after| / |before|) of each component of Omega and x_0 and of the states' largest
    magnitude (last), 0 where not finite."""
    head = model.n_params + model.state_dim
    with np.errstate(all="ignore"):
        mags_before = np.append(np.abs(before[:head]), np.abs(before[head:]).max(initial=0.0))
        mags_after = np.append(np.abs(after[:head]), np.abs(after[head:]).max(initial=0.0))
        change = np.log(mags_after / mags_before)
    return np.where(np.isfinite(change), change, 0.0)


def runoff_direction(model: StateSpaceModel, before: np.ndarray, after: np.ndarray) -> str:
    """Where one Theta ran in a continued run: the components of Omega and x_0, and the
    states' largest magnitude (``x``), whose magnitude changed fastest (log ratio at least
    half the largest and above log ``RUNOFF_FACTOR``), as ``b -> +inf`` (growing),
    ``x -> inf`` or ``x0 -> 0`` (shrinking)."""
    head = model.n_params + model.state_dim
    names = [*model.theta_names(0), "x"]
    change = magnitude_changes(model, before, after)
    top = np.abs(change).max(initial=0.0)
    parts = []
    for j, c in enumerate(change):
        if abs(c) >= max(0.5 * top, np.log(RUNOFF_FACTOR)):
            sign = ("+" if after[j] > 0 else "-") if j < head else ""  # x: its magnitude
            parts.append(f"{names[j]} -> {sign + 'inf' if c > 0 else '0'}")
    return ", ".join(parts)


def _smallest_eigenpair(
    model: StateSpaceModel, z: np.ndarray, theta: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smallest and largest eigenvalue and the smallest's unit eigenvector of the dense
    Hessian of -2 pi at each row of ``theta`` (for the few points whose factorisation
    failed; O(|Theta|^3) each)."""
    with np.errstate(all="ignore"):
        _, _, hess = neg2_log_posterior(model, theta, z, None, order=2)
    K, n = theta.shape
    lam_min, lam_max, vec = np.full(K, np.nan), np.full(K, np.nan), np.zeros((K, n))
    for k in range(K):
        if np.all(np.isfinite(hess[k])):
            w, v = np.linalg.eigh(hess[k])
            lam_min[k], lam_max[k], vec[k] = w[0], w[-1], v[:, 0]
    return lam_min, lam_max, vec


def runoff_check(
    model: StateSpaceModel,
    z: np.ndarray,
    theta: np.ndarray,
    f_hat: np.ndarray,
    barrier: LogBarrier,
    settings: JointMapSettings,
    diverged: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Why a run did not converge (stopped by the iteration limit or the line search, or
    ``diverged``: past ``divergence_limit``): follow it for two segments of
    ``settings.runoff_iter`` Newton iterations at mu = mu_min, each allowed to run to
    ``runoff_reach`` times the |Theta|_inf it starts from (module docstring), and measure
    what -2 pi does.  With ``tol = ridge_value_tol (1 + |-2 pi(Theta_hat)|)``:

    - the continued run converges: the checks there decide; ``ok`` keeps ``gradient`` (it
      only needed more iterations), a ridge, or a Hessian that is singular along a flat
      direction (smallest eigenvalue below ``eig_ratio_min`` times the largest, and the
      re-optimisation from a shift along it moves, :func:`ridge_check`), gives ``ridge``,
      the boundary ``boundary``;
    - -2 pi fell by more than ``tol`` in *both* segments while Theta moved outward (the
      magnitude of a component of Omega or x_0, or the states' largest, grew by the factor
      ``RUNOFF_FACTOR`` (1.1) at least over the two segments): ``unbounded`` (a maximum
      attracts Newton's method quadratically, so a run that still gains after two segments
      is not approaching one).  Passing a divergence limit alone is no gain: a run along a
      ridge that runs off to infinity passes it too;
    - it moved in the second segment while -2 pi changed by at most ``tol /
      runoff_margin``: ``ridge`` (flat direction);
    - else the checks at the end of the second segment: a ridge there gives ``ridge``, the
      boundary ``boundary``, anything else ``gradient`` (a change of -2 pi between
      ``tol / runoff_margin`` and ``tol`` is neither a gain nor flat).

    Returns per trajectory the status (``unbounded``, ``ridge``, ``boundary`` or
    ``gradient``) and the reason (what the continued run did).  Theta_hat itself is not
    changed.
    """
    cont = dataclasses.replace(settings, max_newton_iter=settings.runoff_iter)
    K = theta.shape[0]
    diverged = np.zeros(K, dtype=bool) if diverged is None else np.asarray(diverged, dtype=bool)
    status = np.full(K, "gradient", dtype=object)
    reason = np.full(K, "", dtype=object)
    gain_tol = settings.ridge_value_tol * (1.0 + np.abs(f_hat))
    flat_tol = gain_tol / settings.runoff_margin
    points, values, stops, checks = [theta], [f_hat], [], []
    for _segment in range(2):
        with np.errstate(all="ignore"):
            reach = np.maximum(
                settings.divergence_limit, settings.runoff_reach * np.abs(points[-1]).max(axis=1)
            )
        new, _, mu, stop = minimize_barrier(
            model, z, points[-1], barrier, cont, settings.mu_min, divergence_limit=reach
        )
        with np.errstate(all="ignore"):
            (f_new,) = neg2_log_posterior(model, new, z, None, order=0)
        points.append(new)
        values.append(f_new)
        stops.append(stop)
        checks.append(check_maxima(model, z, new, mu, stop, barrier, cont, follow_runoff=False))
    n_it = settings.runoff_iter

    def singular_ridge(k: int, at: int) -> str:
        """The reason if the Hessian at points[at][k] is singular along a flat direction."""
        pt, fv = points[at][k : k + 1], values[at][k : k + 1]
        lo, hi, v = _smallest_eigenpair(model, z[k : k + 1], pt)
        if not abs(lo[0]) < settings.eig_ratio_min * abs(hi[0]):
            return ""
        ridge, dist, dval = ridge_check(model, z[k : k + 1], pt, fv, v, barrier, settings)
        if not ridge[0]:
            return ""
        return (
            f"the Hessian there is singular (eigenvalue ratio {lo[0] / hi[0]:.3g}) and a "
            f"shift along it moved {dist[0]:.3g} with -2 pi changed by {dval[0]:.3g}: "
            f"flat direction"
        )

    for k in range(K):
        first, second = checks[0]["status"][k], checks[1]["status"][k]
        drops = [values[i][k] - values[i + 1][k] for i in range(2)]
        where = runoff_direction(model, theta[k], points[2][k])
        # some magnitude grew by RUNOFF_FACTOR at least: not a move by rounding
        outward = magnitude_changes(model, theta[k], points[2][k]).max() >= np.log(RUNOFF_FACTOR)
        if stops[0][k] == "converged":
            flat = "" if first in ("ok", "ridge") else singular_ridge(k, 1)
            if first == "ok":
                reason[k] = f"passes the checks after up to {n_it} more iterations"
                reason[k] += ": raise " + ("divergence_limit" if diverged[k] else "max_newton_iter")
            elif first == "ridge" or flat:
                status[k] = "ridge"
                reason[k] = f"converges within {n_it} more iterations; "
                reason[k] += flat or f"a ridge there ({checks[0]['reason'][k]})"
            else:
                status[k] = "boundary" if first == "boundary" else "gradient"
                reason[k] = f"converges within {n_it} more iterations: {first}"
                reason[k] += f" ({checks[0]['reason'][k]})"
            continue
        if min(drops) > gain_tol[k] and outward and stops[1][k] != "converged":
            status[k] = "unbounded"
            reason[k] = (
                f"-2 pi still decreases ({drops[0]:.3g}, then {drops[1]:.3g} in two segments "
                f"of {n_it} more iterations) as Theta runs off: "
                + (where or beyond_limit(model, points[2][k], settings.divergence_limit))
            )
            continue
        moved = float(np.abs(points[2][k] - points[1][k]).max())
        if abs(drops[1]) <= flat_tol[k] and moved > settings.ridge_move_tol:
            status[k] = "ridge"
            reason[k] = (
                f"flat direction: {n_it} more iterations moved {moved:.3g} (sup norm) with "
                f"-2 pi changed by {drops[1]:.3g}" + (f" ({where})" if where else "")
            )
            continue
        flat = "" if second in ("ok", "ridge") else singular_ridge(k, 2)
        if second == "ridge" or flat:
            status[k] = "ridge"
            reason[k] = f"after {2 * n_it} more iterations, "
            reason[k] += flat or f"a ridge there ({checks[1]['reason'][k]})"
        else:
            status[k] = "boundary" if second == "boundary" else "gradient"
            reason[k] = f"after {2 * n_it} more iterations: {second} ({checks[1]['reason'][k]})"
            if diverged[k] or second == "unbounded":
                reason[k] += (
                    f"; -2 pi fell by {drops[0]:.3g}, then {drops[1]:.3g}: not a gain above "
                    f"{gain_tol[k]:.3g} in both segments"
                )
    return status, reason
