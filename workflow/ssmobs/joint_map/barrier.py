"""The joint MAP's solver: a primal log-barrier Newton method, batched over k (Sec. III.B).

For every design observation trajectory z~(k) we minimise -2 pi(Theta | z~(k)) over
Theta = (Omega, x_0, x_1..x_T) with a primal log-barrier method ([26, Sec. 19.6]):

    P_mu(Theta) = -2 pi(Theta | z) - mu * sum_i log s_i(Omega),

where the slacks s_i > 0 are the finite prior bounds (Omega_j - lower_j, upper_j - Omega_j)
and the model constraints c(Omega) > 0 (e.g. 1 - a^2 - b^2 for (Sep, d=1, p=2)).  For each
mu the barrier problem is solved by Newton's method with the analytic Hessian and an
Armijo backtracking line search whose first trial step is cut to a fraction
(``fraction_to_boundary``) of the distance to the prior box and which rejects any trial
point with a non-positive slack, so every iterate stays strictly feasible (the halvings of
a trajectory's step are tried several in one evaluation once few trajectories are left,
:data:`LINE_SEARCH_VALUES`: the same steps, fewer calls).  mu starts at
mu_0 (below) and is multiplied by ``mu_factor`` each time the barrier gradient falls below
``max(inner_tol_factor * mu, newton_tol)``, down to ``mu_min``; the iteration stops at
``max |grad P| <= newton_tol`` with mu = mu_min.

The barrier start mu_0 (the paper gives none).  ``mu0_rule = "gradient_balance"`` (the
default) takes, per trajectory, the mu_0 at which the barrier and -2 pi pull equally hard
on Omega at the start Theta_0:

    mu_0 = || grad_Omega (-2 pi)(Theta_0) ||_2 / || grad_Omega B(Theta_0) ||_2,
    B = -sum log s_i,

i.e. the barrier term holds half of the Omega-gradient of P_mu at the start (floored at
``mu_min``; where there is no barrier the value does not matter).  A smaller mu_0 lets the
first Newton steps follow -2 pi alone, which in several models is unbounded below at the
edge of the support (in (Sep, d=p=1) it contains T log(1 - b^2), and x_t = z_t / b makes
the observation residuals vanish as b -> 1); a much larger one makes the first stages
ignore the data.  ``mu0_rule = "per_step"`` keeps the former rule mu_0 = max(mu0,
mu0_per_step * T) (mu_0 above about T bounds that singular term); the rule
``joint_map_mu0_sweep`` compares both over a range of mu_0.

All trajectories of a batch are optimised together: every Newton iteration evaluates the
per-step symbolic derivatives for the whole batch and solves the K Newton systems at once.
The Hessian is an "arrow" matrix (block-tridiagonal in the states plus m dense rows/columns
for Omega), so each system is solved in O(T (p^3 + p^2 m + m^2) + m^3) by a block
Cholesky of the state part and an m x m Schur complement, vectorised over k with a loop
over t (:mod:`ssmobs.banded_linalg`).  Where the Hessian is not positive definite a
multiple of the identity is added (modified Newton, [26, Sec. 3.4]).  A trajectory stops
early once it has run off to infinity (``divergence_limit``) or onto the boundary
(slack < ``boundary_stop_tol``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..banded_linalg import ArrowFactor
from ..models.base import PriorBounds, StateSpaceModel
from ..models.log_posterior import compile_model, neg2_log_posterior, neg2_log_posterior_blocks
from .settings import JointMapSettings


class LogBarrier:
    """Log barrier -sum log s_i(Omega) for the finite prior bounds and model constraints."""

    def __init__(self, model: StateSpaceModel, bounds: PriorBounds) -> None:
        self.model = model
        self.m = model.n_params
        self.lower = np.asarray(bounds.lower, dtype=float)
        self.upper = np.asarray(bounds.upper, dtype=float)
        self.lo_idx = np.flatnonzero(np.isfinite(self.lower))
        self.up_idx = np.flatnonzero(np.isfinite(self.upper))
        self.constraints = compile_model(model).constraints

    def slacks(self, omega: np.ndarray) -> np.ndarray:
        """(K, n_s) slacks (box lower, box upper, model constraints); all > 0 inside.

        Values only (no derivatives): this is what the line search evaluates.
        """
        parts = [
            omega[:, self.lo_idx] - self.lower[self.lo_idx],
            self.upper[self.up_idx] - omega[:, self.up_idx],
        ]
        if self.constraints.count:
            parts.append(self.constraints.values(omega))
        return np.concatenate(parts, axis=1)

    def slack_gradients(self, omega: np.ndarray) -> np.ndarray:
        """(K, n_s, m) gradients of the slacks, in the order of :meth:`slacks`."""
        K, m = omega.shape
        parts = [
            np.broadcast_to(np.eye(m)[self.lo_idx], (K, self.lo_idx.size, m)),
            np.broadcast_to(-np.eye(m)[self.up_idx], (K, self.up_idx.size, m)),
        ]
        if self.constraints.count:
            parts.append(self.constraints.derivatives(omega)[0])
        return np.concatenate(parts, axis=1)

    def value(self, omega: np.ndarray) -> np.ndarray:
        """(K,) -sum log s_i, +inf where a slack is not positive."""
        s = self.slacks(omega)
        with np.errstate(all="ignore"):
            phi = -np.sum(np.log(np.where(s > 0, s, 1.0)), axis=1)
        return np.where(np.all(s > 0, axis=1), phi, np.inf)

    def derivatives(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """value (K,), gradient (K, m) and Hessian (K, m, m) of -sum log s_i."""
        K, m = omega.shape
        grad = np.zeros((K, m))
        hess = np.zeros((K, m, m))
        phi = np.zeros(K)
        with np.errstate(all="ignore"):
            s_lo = omega[:, self.lo_idx] - self.lower[self.lo_idx]
            s_up = self.upper[self.up_idx] - omega[:, self.up_idx]
            phi -= np.log(s_lo).sum(axis=1) + np.log(s_up).sum(axis=1)
            grad[:, self.lo_idx] -= 1.0 / s_lo
            grad[:, self.up_idx] += 1.0 / s_up
            diag = np.zeros((K, m))
            diag[:, self.lo_idx] += 1.0 / s_lo**2
            diag[:, self.up_idx] += 1.0 / s_up**2
            hess += diag[:, :, None] * np.eye(m)
            if self.constraints.count:
                c = self.constraints.values(omega)
                dc, d2c = self.constraints.derivatives(omega)
                phi -= np.log(c).sum(axis=1)
                grad -= np.einsum("kj,kji->ki", 1.0 / c, dc)
                hess += np.einsum("kj,kji,kjl->kil", 1.0 / c**2, dc, dc) - np.einsum(
                    "kj,kjil->kil", 1.0 / c, d2c
                )
        return phi, grad, hess

    def max_step(self, omega: np.ndarray, d_omega: np.ndarray, tau: float) -> np.ndarray:
        """(K,) largest alpha <= 1 keeping a fraction (1 - tau) of every box slack."""
        alpha = np.ones(omega.shape[0])
        with np.errstate(all="ignore"):
            for idx, s, rate in (
                (
                    self.lo_idx,
                    omega[:, self.lo_idx] - self.lower[self.lo_idx],
                    -d_omega[:, self.lo_idx],
                ),
                (
                    self.up_idx,
                    self.upper[self.up_idx] - omega[:, self.up_idx],
                    d_omega[:, self.up_idx],
                ),
            ):
                if idx.size:
                    lim = np.where(rate > 0, tau * s / rate, np.inf)
                    alpha = np.minimum(alpha, lim.min(axis=1))
        return alpha


def _damped_newton_direction(
    A: np.ndarray,
    C: np.ndarray,
    Dd: np.ndarray,
    Dl: np.ndarray,
    g: np.ndarray,
    settings: JointMapSettings,
    tau_hint: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Newton direction d = -(H + tau I)^{-1} g with the smallest tried tau making H + tau I PD.

    Tries tau = 0 (or tau_hint / 10, the previous iteration's shift reduced, where that is
    above the first shift), then damping_init * (1 + max |H_jj|) times 10, 100, ...
    Returns d (K, n) and tau (K,); where no shift works, d is the scaled steepest-descent
    direction and tau is inf.
    """
    K = g.shape[0]
    scale = 1.0 + np.maximum(
        np.abs(np.diagonal(A, axis1=1, axis2=2)).max(axis=1),
        np.abs(np.diagonal(Dd, axis1=2, axis2=3)).max(axis=(1, 2)),
    )
    first = settings.damping_init * scale
    tau = np.zeros(K)
    if tau_hint is not None:
        hint = np.where(np.isfinite(tau_hint), tau_hint, 0.0) / 10.0
        tau = np.where(hint >= first, hint, 0.0)
    fac = ArrowFactor(A, C, Dd, Dl, tau=tau if tau.any() else None, rhs=-g)
    d = fac.solve_rhs()
    ok = fac.ok & np.all(np.isfinite(d), axis=1)
    if ok.all():
        return d, tau
    bad = np.flatnonzero(~ok)
    t_bad = np.maximum(first[bad], 10.0 * tau[bad])
    for _ in range(settings.max_damping_tries):
        fac = ArrowFactor(A[bad], C[bad], Dd[bad], Dl[bad], tau=t_bad, rhs=-g[bad])
        db = fac.solve_rhs()
        okb = fac.ok & np.all(np.isfinite(db), axis=1)
        d[bad[okb]] = db[okb]
        tau[bad[okb]] = t_bad[okb]
        bad, t_bad = bad[~okb], t_bad[~okb] * 10.0
        if bad.size == 0:
            return d, tau
    d[bad] = -g[bad] / scale[bad, None]
    tau[bad] = np.inf
    return d, tau


#: the machine epsilon of the float64 arithmetic (the line search's and the stop's round-off
#: allowances)
EPS = float(np.finfo(float).eps)

#: after the first trial step of every trajectory, the line search tries as many halvings
#: of the step in one evaluation as keep it at about this many per-step terms of -2 pi
#: (trial points x T); 0: one halving per evaluation.  One trajectory often backtracks tens
#: of times, and with one halving per evaluation the search was mostly per-call overhead
#: (3481 of 3517 evaluations for a single trajectory in the joint MAPs of a random set, q =
#: 8, K = 1000)
LINE_SEARCH_VALUES = 4096


@dataclass(frozen=True)
class _StepSearch:
    """The line search's rows: points ``th``, Newton directions ``d``, data ``z``, barrier
    weights ``mu``, P_mu at the points ``P0`` and its slope along ``d``."""

    th: np.ndarray
    d: np.ndarray
    z: np.ndarray
    mu: np.ndarray
    P0: np.ndarray
    slope: np.ndarray

    def rows(self, index: np.ndarray) -> _StepSearch:
        """The rows ``index`` of every array."""
        return _StepSearch(*(getattr(self, f.name)[index] for f in fields(self)))


def _armijo_backtracks(
    model: StateSpaceModel,
    barrier: LogBarrier,
    search: _StepSearch,
    alpha: np.ndarray,
    *,
    n_try: int,
    c1: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n_try`` successive halvings of the step ``alpha`` of every row, in one evaluation.

    Row i tries th_i + a d_i for a = alpha_i, alpha_i / 2, ... (each the half of the one
    before, as one halving per evaluation made them) against the Armijo test of P_mu.  Each
    row's numbers are those of its own evaluation (-2 pi and the barrier are computed row by
    row), so the first accepted step is the one the halvings one at a time accept.  Returns
    the index of the first accepted halving per row (-1: none), the (n_try, rows, n) trial
    points and the (n_try, rows) steps tried."""
    th, d, z, P0 = search.th, search.d, search.z, search.P0
    rows, n = th.shape
    alphas = np.empty((n_try, rows))
    alphas[0] = alpha
    for j in range(1, n_try):
        alphas[j] = alphas[j - 1] * 0.5
    steps = th[None] + alphas[:, :, None] * d[None]
    trial = steps.reshape(n_try * rows, n)
    zt = np.broadcast_to(z, (n_try,) + z.shape).reshape((n_try * rows,) + z.shape[1:])
    (ft,) = neg2_log_posterior(model, trial, zt, None, order=0)
    m = model.n_params
    P0t, at, st = np.tile(P0, n_try), alphas.reshape(-1), np.tile(search.slope, n_try)
    Pt = ft + np.tile(search.mu, n_try) * barrier.value(trial[:, :m])
    ok = np.isfinite(Pt) & (Pt <= P0t + c1 * at * st + 16 * EPS * np.abs(P0t))
    ok = ok.reshape(n_try, rows)
    first = np.where(ok.any(axis=0), ok.argmax(axis=0), -1)
    return first, steps, alphas


def minimize_barrier(
    model: StateSpaceModel,
    z: np.ndarray,
    theta0: np.ndarray,
    barrier: LogBarrier,
    settings: JointMapSettings,
    mu_start: float | np.ndarray,
    divergence_limit: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Batched primal barrier-Newton minimisation of -2 pi from ``theta0`` (module docstring).

    ``divergence_limit``: optional (K,) limit of |Theta|_inf per trajectory instead of
    ``settings.divergence_limit`` (the continued runs of
    :func:`ssmobs.joint_map.checks.runoff_check`).
    Returns theta (K, n), iterations (K,), final mu (K,) and the stop reason (K,) str:
    converged, max-iter, line-search, non-finite, diverged, at-boundary.
    """
    K, n = theta0.shape
    limit = np.broadcast_to(
        np.asarray(
            settings.divergence_limit if divergence_limit is None else divergence_limit, float
        ),
        (K,),
    )
    m = model.n_params
    theta = theta0.astype(float).copy()
    mu = np.broadcast_to(np.asarray(mu_start, dtype=float), (K,)).copy()
    iters = np.zeros(K, dtype=np.int64)
    reason = np.full(K, "max-iter", dtype=object)
    active = np.ones(K, dtype=bool)
    tau_last = np.zeros(K)

    def grad_p(g: np.ndarray, bg: np.ndarray, mu_a: np.ndarray) -> np.ndarray:
        gp = g.copy()
        gp[:, :m] += mu_a[:, None] * bg
        return gp

    for _ in range(settings.max_newton_iter):
        act = np.flatnonzero(active)
        if act.size == 0:
            break
        th, zz, mu_a = theta[act], z[act], mu[act]
        f, g, blk = neg2_log_posterior_blocks(model, th, zz)
        phi, bg, bh = barrier.derivatives(th[:, :m])
        finite = (
            np.isfinite(f)
            & np.isfinite(phi)
            & np.all(np.isfinite(g), axis=1)
            & np.all(np.isfinite(bg), axis=1)
        )
        gp = grad_p(g, bg, mu_a)
        gnorm = np.abs(gp).max(axis=1)
        # finish barrier stages whose inner problem is solved, possibly several at once
        while True:
            tol = np.maximum(settings.inner_tol_factor * mu_a, settings.newton_tol)
            lower_mu = finite & (gnorm <= tol) & (mu_a > settings.mu_min)
            if not lower_mu.any():
                break
            mu_a = np.where(lower_mu, np.maximum(mu_a * settings.mu_factor, settings.mu_min), mu_a)
            gp = grad_p(g, bg, mu_a)
            gnorm = np.abs(gp).max(axis=1)
        mu[act] = mu_a
        done = finite & (gnorm <= settings.newton_tol) & (mu_a <= settings.mu_min)
        reason[act[~finite]] = "non-finite"
        reason[act[done]] = "converged"
        active[act[~finite | done]] = False
        go = finite & ~done
        if not go.any():
            continue
        sel = np.flatnonzero(go)
        idx = act[sel]
        th, zz, mu_s, gps = th[sel], zz[sel], mu_a[sel], gp[sel]
        P0 = f[sel] + mu_s * phi[sel]
        A = blk.omega[sel] + mu_s[:, None, None] * bh[sel]
        d, tau_used = _damped_newton_direction(
            A, blk.cross[sel], blk.diag[sel], blk.lower[sel], gps, settings, tau_last[idx]
        )
        tau_last[idx] = tau_used
        slope = np.einsum("kj,kj->k", gps, d)
        uphill = ~(slope < 0)
        if uphill.any():  # safeguard: never search along an ascent direction
            d[uphill] = -gps[uphill]
            slope[uphill] = -np.einsum("kj,kj->k", gps[uphill], gps[uphill])
        # a full step smaller than rounding at mu_min: nothing left to gain
        tiny = (np.abs(d).max(axis=1) <= 4 * EPS * (1.0 + np.abs(th).max(axis=1))) & (
            mu_s <= settings.mu_min
        )
        if tiny.any():
            reason[idx[tiny]] = "converged"
            active[idx[tiny]] = False
        alpha = barrier.max_step(th[:, :m], d[:, :m], settings.fraction_to_boundary)
        accepted = np.zeros(sel.size, dtype=bool)
        pending = ~tiny
        search = _StepSearch(th, d, zz, mu_s, P0, slope)
        tries = 0  # trial steps so far of every pending trajectory (the same for all)
        while tries < settings.max_backtracks:
            pi = np.flatnonzero(pending)
            if pi.size == 0:
                break
            # the first trial step of all, then as many halvings as fit LINE_SEARCH_VALUES
            fit = LINE_SEARCH_VALUES // (pi.size * zz.shape[1]) if tries else 1
            n_try = min(settings.max_backtracks - tries, max(fit, 1))
            first, steps, alphas = _armijo_backtracks(
                model, barrier, search.rows(pi), alpha[pi], n_try=n_try, c1=settings.armijo_c1
            )
            hit = first >= 0
            good = pi[hit]
            theta[idx[good]] = steps[first[hit], np.flatnonzero(hit)]
            accepted[good] = True
            pending[good] = False
            alpha[pi[~hit]] = alphas[-1, ~hit] * 0.5
            tries += n_try
        stuck = pending  # never accepted
        reason[idx[stuck]] = "line-search"
        active[idx[stuck]] = False
        iters[idx[accepted]] += 1
        big = np.abs(theta[idx]).max(axis=1) > limit[idx]
        reason[idx[big]] = "diverged"
        active[idx[big]] = False
        s_now = barrier.slacks(theta[idx, :m])
        if s_now.shape[1]:
            edge = ~big & (s_now.min(axis=1) < settings.boundary_stop_tol)
            reason[idx[edge]] = "at-boundary"
            active[idx[edge]] = False
    return theta, iters, mu, reason


def initial_mu_values(
    model: StateSpaceModel,
    z: np.ndarray,
    theta0: np.ndarray,
    barrier: LogBarrier,
    settings: JointMapSettings,
) -> np.ndarray:
    """(K,) barrier start mu_0 of every trajectory (``settings.mu0_rule``).

    ``gradient_balance``: mu_0 = ||grad_Omega(-2 pi)(Theta_0)||_2 / ||grad_Omega B(Theta_0)||_2,
    the mu at which the barrier holds half of P_mu's Omega-gradient at the start, floored
    at ``mu_min`` (and ``mu_min`` where there is no barrier or the ratio is not finite).
    ``per_step``: max(mu0, mu0_per_step * T) for every k.
    """
    K, T = z.shape[0], z.shape[1]
    if settings.mu0_rule == "per_step":
        return np.full(K, settings.initial_mu(T))
    m = model.n_params
    with np.errstate(all="ignore"):
        _, g = neg2_log_posterior(model, theta0, z, None, order=1)[:2]
        _, bg, _ = barrier.derivatives(theta0[:, :m])
        mu0 = np.linalg.norm(g[:, :m], axis=1) / np.linalg.norm(bg, axis=1)
    return np.where(np.isfinite(mu0), np.maximum(mu0, settings.mu_min), settings.mu_min)
