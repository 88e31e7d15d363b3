"""Numerical checks of a found joint MAP Theta_hat (Sec. III.B), one status per k.

The checks are applied in this order (the first that applies wins):

``failed``
    value, gradient, Hessian or Theta_hat not finite (reason in ``reason``).
``boundary``
    the optimum lies on the boundary of the prior's support: a slack below
    ``boundary_tol``, or (for a converged run) a barrier multiplier mu / s_i above
    ``grad_tol`` (the barrier is what holds the point), or (for a run that did not
    converge) a slack below ``boundary_near_tol`` with -2 pi still decreasing towards that
    constraint faster than ``grad_tol``, or the iterates ran off to infinity
    (``|Theta|_inf`` above ``divergence_limit``; the supremum is approached at the edge of
    an unbounded support, as for a ridge of variable height).
``not-positive-definite``
    the Hessian of -2 pi is not positive definite: its block Cholesky factorisation fails
    or its smallest eigenvalue is not above ``pd_tol``.
``gradient``
    largest absolute gradient component of -2 pi not below ``grad_tol`` (1e-5 in the paper);
    typical for runs stopped by ``max_newton_iter`` while climbing a ridge.
``ridge``
    eigenvalue ratio lambda_min / lambda_max below ``eig_ratio_min`` (r_0 = 1e-5) and a new
    optimisation started at Theta_hat + h v_min (v_min the unit eigenvector of the smallest
    eigenvalue, h = ``ridge_shift``, halved until the start is inside the support) ends more
    than ``ridge_move_tol`` away (sup norm), or ends non-finite or diverged.  If it returns
    to Theta_hat the trajectory is ``ok`` (the reason column records the check).
``ok``
    all checks passed: k belongs to K^max.

Eigenvalues: lambda_max by Lanczos on H, lambda_min and v_min by Lanczos on H^{-1} (applied
through the factorisation), ``lanczos_steps`` steps with full reorthogonalisation;
``eigen_method="dense"`` uses LAPACK instead (O(n^3), for checks).

Local variances (Sec. II.B): LVar_j = -H_pi^{-1}(Theta_hat)_jj = 2 (H_{-2 pi}^{-1})_jj for
every component, by a selected inversion of the factorised arrow matrix, wherever the
Hessian is positive definite (NaN otherwise).

The ridge re-check records both how far the re-optimised point moved (sup norm) and how
much -2 pi changed; ``ridge_test`` says which decides (see
:class:`~ssmobs.joint_map_settings.JointMapSettings`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .banded_linalg import ArrowFactor, arrow_extreme_eigenpairs
from .joint_map_barrier import LogBarrier, minimize_barrier
from .joint_map_settings import JointMapSettings
from .models.base import StateSpaceModel
from .models.log_posterior import neg2_log_posterior, neg2_log_posterior_blocks

#: the six statuses, in the order in which the checks assign them
STATUSES: tuple[str, ...] = (
    "ok",
    "not-positive-definite",
    "gradient",
    "ridge",
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
) -> dict[str, np.ndarray]:
    """The checks of Sec. III.B at the results ``theta`` of one batch of trajectories.

    ``mu`` and ``stop`` are the final barrier parameter and the stop reason of
    :func:`~ssmobs.joint_map_barrier.minimize_barrier`.  Returns per-k arrays named as the
    fields of :class:`~ssmobs.joint_map.JointMapResult` they fill: ``neg2_log_post``,
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
    assign(
        stop == "diverged",
        "boundary",
        f"iterates ran off to infinity (|Theta|_inf > {settings.divergence_limit:g})",
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
