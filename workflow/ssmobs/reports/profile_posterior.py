"""Profile log posterior over (Omega_i, x_0) for one trajectory (Sec. IV.E, Figure 4).

    pi_prof(omega_i, x_0 | z) = max over x_1..x_T of pi(Omega, x_0, x_1..x_T | z),

with the other components of Omega held fixed.  For fixed (Omega, x_0), -2 pi is a sum of
per-step terms that couple only x_{t-1} and x_t, so its Hessian in x_1..x_T is
block-tridiagonal; we minimise it by Newton's method batched over all grid points (block
Cholesky of the state Hessian, Armijo backtracking, a diagonal shift where the Hessian is
not positive definite).

For the models linear in the states with Gaussian disturbances, i.e. (Same), (Sep),
(Sep, d=2, p=1), (Sep, d=1, p=2) and (ranWalk), -2 pi is an exact quadratic in x_1..x_T
given (Omega, x_0) with a positive definite Hessian, so the first Newton step lands on the
exact maximiser from any start and the second iteration only confirms it (gradient at
rounding level).  For (Sep, d=p=1, Multiplicative) the states enter non-quadratically
(z_t^2 / (a x_t^2) + log x_t^2, singular at x_t = 0); the Newton iterations start from the
noise-free state path x_t = h(Omega, x_{t-1}, 0) of the grid point, which has the sign of
x_0, and find the maximum within that sign pattern.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..banded_linalg import BlockTridiagonalCholesky
from ..models.base import PriorBounds, StateSpaceModel
from ..models.log_posterior import in_support, neg2_log_posterior, neg2_log_posterior_blocks


def _state_newton(
    model: StateSpaceModel,
    z: np.ndarray,
    omega: np.ndarray,
    x0: np.ndarray,
    x_start: np.ndarray,
    max_iter: int,
    tol: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Minimise -2 pi over x_1..x_T for fixed (Omega, x_0), batched over rows.

    Returns the minimum value (K,) and a converged flag (K,).
    """
    K, T, p = x_start.shape
    m = model.n_params
    head = np.concatenate([omega, x0], axis=1)
    x = x_start.reshape(K, -1).copy()
    zz = np.broadcast_to(z, (K,) + z.shape)
    value = np.full(K, np.nan)
    conv = np.zeros(K, dtype=bool)
    active = np.ones(K, dtype=bool)
    eps = np.finfo(float).eps
    for _ in range(max_iter):
        act = np.flatnonzero(active)
        if act.size == 0:
            break
        theta = np.concatenate([head[act], x[act]], axis=1)
        with np.errstate(all="ignore"):
            f, g, blk = neg2_log_posterior_blocks(model, theta, zz[act])
        gx = g[:, m + p :]
        value[act] = f
        finite = np.isfinite(f) & np.all(np.isfinite(gx), axis=1)
        done = finite & (np.abs(gx).max(axis=1) <= tol * (1.0 + np.abs(f)))
        conv[act[done]] = True
        active[act[done | ~finite]] = False
        go = np.flatnonzero(finite & ~done)
        if go.size == 0:
            continue
        idx = act[go]
        diag, lower = blk.diag[go, 1:], blk.lower[go, 1:]
        g_go = gx[go].reshape(-1, T, p, 1)
        scale = 1.0 + np.abs(np.diagonal(diag, axis1=2, axis2=3)).max(axis=(1, 2))
        d = np.full((go.size, T * p), np.nan)
        tau = np.zeros(go.size)
        todo = np.arange(go.size)
        for _attempt in range(30):
            fac = BlockTridiagonalCholesky(
                diag[todo] + tau[todo, None, None, None] * np.eye(p), lower[todo]
            )
            step = -fac.solve(g_go[todo])[..., 0].reshape(todo.size, -1)
            ok = fac.ok & np.all(np.isfinite(step), axis=1)
            d[todo[ok]] = step[ok]
            todo = todo[~ok]
            if todo.size == 0:
                break
            tau[todo] = np.where(tau[todo] == 0, 1e-8 * scale[todo], 10.0 * tau[todo])
        if todo.size:
            d[todo] = -gx[go][todo] / scale[todo, None]
        slope = np.einsum("kj,kj->k", gx[go], d)
        alpha = np.ones(go.size)
        pending = np.ones(go.size, dtype=bool)
        for _ls in range(50):
            pi = np.flatnonzero(pending)
            if pi.size == 0:
                break
            trial = x[idx[pi]] + alpha[pi, None] * d[pi]
            (ft,) = neg2_log_posterior(
                model, np.concatenate([head[idx[pi]], trial], axis=1), zz[idx[pi]], None, order=0
            )
            ok = np.isfinite(ft) & (
                ft <= f[go][pi] + 1e-4 * alpha[pi] * slope[pi] + 16 * eps * np.abs(f[go][pi])
            )
            x[idx[pi[ok]]] = trial[ok]
            pending[pi[ok]] = False
            alpha[pi[~ok]] *= 0.5
        active[idx[pending]] = False  # line search failed: keep the value, not converged
    return value, conv


def profile_posterior(
    model: StateSpaceModel,
    z: np.ndarray,
    bounds: PriorBounds,
    omega_grid_name: str,
    omega_values: Sequence[float] | np.ndarray,
    x0_values: Sequence[float] | np.ndarray,
    *,
    omega_fixed: Mapping[str, float] | None = None,
    max_iter: int = 100,
    tol: float = 1e-10,
    chunk_size: int = 4096,
) -> np.ndarray:
    """Profile log posterior pi(omega_i, x_0 | z) = max_{x_1..x_T} pi (Figure 4).

    Parameters
    ----------
    model : the state space model.
    z : (T, d) one observation trajectory.
    bounds : prior support of Omega; grid points outside it (or outside the model
        constraints) get -inf.
    omega_grid_name : the component of Omega on the first grid axis (e.g. ``"a"``).
    omega_values : (n_omega,) values of that component.
    x0_values : (n_x0,) values of x_0 for p = 1, or (n_x0, p) rows of x_0.
    omega_fixed : values of the other components of Omega (required when m > 1).
    max_iter, tol : Newton iterations and relative gradient tolerance
        (max |grad| <= tol (1 + |-2 pi|)).
    chunk_size : grid points per vectorised batch.

    Returns
    -------
    (n_omega, n_x0) array of pi at the profile maximum, up to the model's additive
    constant (the same constant as :func:`ssmobs.models.log_posterior.log_posterior`);
    -inf outside the support; NaN where the inner maximisation did not converge.
    """
    z = np.asarray(z, dtype=float)
    if z.ndim != 2 or z.shape[1] != model.obs_dim:
        raise ValueError(
            f"z must have shape (T, {model.obs_dim}) for model '{model.slug}', got {z.shape}"
        )
    T = z.shape[0]
    p = model.state_dim
    if omega_grid_name not in model.param_names:
        raise ValueError(
            f"model '{model.slug}' has no parameter '{omega_grid_name}'; "
            f"its parameters are {list(model.param_names)}"
        )
    fixed = dict(omega_fixed or {})
    others = [nm for nm in model.param_names if nm != omega_grid_name]
    missing = [nm for nm in others if nm not in fixed]
    unknown = sorted(set(fixed) - set(others))
    if missing or unknown:
        raise ValueError(
            f"omega_fixed must give exactly {others} for model '{model.slug}' "
            f"(grid over '{omega_grid_name}'); missing {missing}, unknown {unknown}"
        )
    w_vals = np.asarray(omega_values, dtype=float).reshape(-1)
    x0_arr = np.asarray(x0_values, dtype=float)
    if p == 1 and x0_arr.ndim == 1:
        x0_arr = x0_arr[:, None]
    if x0_arr.ndim != 2 or x0_arr.shape[1] != p:
        raise ValueError(f"x0_values must have shape (n,) or (n, {p}), got {x0_arr.shape}")
    nw, nx = w_vals.size, x0_arr.shape[0]
    j = model.param_names.index(omega_grid_name)
    base = np.array([fixed.get(nm, 0.0) for nm in model.param_names], dtype=float)
    omega = np.tile(base, (nw * nx, 1))
    omega[:, j] = np.repeat(w_vals, nx)
    x0 = np.tile(x0_arr, (nw, 1))
    out = np.full(nw * nx, -np.inf)
    inside = np.flatnonzero(in_support(model, omega, bounds))
    zeros = np.zeros((1, T, p)), np.zeros((1, T, model.obs_dim))
    for s in range(0, inside.size, chunk_size):
        idx = inside[s : s + chunk_size]
        x_start = np.empty((idx.size, T, p))
        for r, k in enumerate(idx):  # noise-free state path of each grid point
            with np.errstate(all="ignore"):
                x_start[r] = model.simulate(omega[k], x0[k], *zeros)[0][0]
        bad = ~np.all(np.isfinite(x_start), axis=(1, 2))
        x_start[bad] = np.broadcast_to(x0[idx][bad][:, None, :], (int(bad.sum()), T, p))
        value, conv = _state_newton(model, z, omega[idx], x0[idx], x_start, max_iter, tol)
        out[idx] = np.where(conv, -0.5 * value, np.nan)
    return out.reshape(nw, nx)
