"""Value, gradient and Hessian of -2 pi(Theta | z) for a batch of trajectories.

Theta = (Omega, x_0, x_1, ..., x_T) is laid out as one vector of length
n = m + p (T + 1): first the m parameters, then the states time-major
(x_{t,1}, ..., x_{t,p} for t = 0..T).  The log posterior (2) is a sum of per-step
terms (see :mod:`ssmobs.models.base`), so its Hessian is block-tridiagonal in the
states plus m dense rows and columns for Omega (Sec. III.B).  The derivatives of
each per-step term are taken symbolically once per model and evaluated in NumPy
over all trajectories k and steps t at once; a fixed sparse scatter matrix adds the
local pieces into the global gradient and Hessian.

Outside the prior support (or where a model constraint fails) the value is +inf:
the joint-MAP barrier method (Sec. III.B) never steps there.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np
import scipy.sparse as sps
import sympy as sp

from .base import PriorBounds, StateSpaceModel


@dataclass(frozen=True)
class _Term:
    """A lambdified per-step term: value, gradient and upper-triangle Hessian."""

    func: Callable
    n_local: int
    triu: tuple[np.ndarray, np.ndarray]


def _compile(args: list[sp.Symbol], n_local: int, expr: sp.Expr) -> _Term:
    local = args[:n_local]
    grad = [sp.diff(expr, v) for v in local]
    iu = np.triu_indices(n_local)
    hess = [sp.diff(grad[i], local[j]) for i, j in zip(*iu)]
    func = sp.lambdify(args, [expr, *grad, *hess], modules="numpy", cse=True)
    return _Term(func=func, n_local=n_local, triu=iu)


@dataclass(frozen=True)
class CompiledModel:
    """Symbolic derivatives of one model's per-step terms, ready for NumPy."""

    model: StateSpaceModel
    obs: _Term
    trans: _Term
    constraints: Callable | None
    n_constraints: int


@lru_cache(maxsize=None)
def compile_model(model: StateSpaceModel) -> CompiledModel:
    """Differentiate the model's per-step terms symbolically (cached per model)."""
    m, p, d = model.n_params, model.state_dim, model.obs_dim
    w = list(sp.symbols(f"w0:{m}", real=True))
    xp = list(sp.symbols(f"xp0:{p}", real=True))
    x = list(sp.symbols(f"x0:{p}", real=True))
    z = list(sp.symbols(f"z0:{d}", real=True))
    obs = _compile(w + x + z, m + p, model.obs_term(w, x, z))
    trans = _compile(w + xp + x, m + 2 * p, model.trans_term(w, xp, x))
    cons = model.support_constraints(w)
    cfunc = sp.lambdify(w, cons, modules="numpy") if cons else None
    return CompiledModel(model=model, obs=obs, trans=trans, constraints=cfunc,
                         n_constraints=len(cons))


def _evaluate(term: _Term, arrays: list[np.ndarray], shape: tuple[int, ...]) -> list[np.ndarray]:
    with np.errstate(all="ignore"):
        out = term.func(*arrays)
    return [np.broadcast_to(np.asarray(v, dtype=float), shape) for v in out]


@lru_cache(maxsize=64)
def _scatter(m: int, p: int, T: int) -> tuple[sps.csr_matrix, sps.csr_matrix]:
    """Sparse maps from stacked local gradients/Hessians to the global ones.

    Local vectors are ordered [obs terms t=1..T, trans terms t=1..T]; local Hessians are the
    full L x L blocks, in the same order.  Returns (G, H) with global = local @ G (resp. H).
    """
    n = m + p * (T + 1)
    om = np.arange(m)
    rows_g, cols_g, rows_h, cols_h = [], [], [], []
    offset_g = 0
    offset_h = 0
    blocks = []
    for t in range(1, T + 1):
        blocks.append(np.concatenate([om, m + t * p + np.arange(p)]))
    for t in range(1, T + 1):
        blocks.append(np.concatenate([om, m + (t - 1) * p + np.arange(p), m + t * p + np.arange(p)]))
    for idx in blocks:
        L = idx.size
        rows_g.append(offset_g + np.arange(L))
        cols_g.append(idx)
        ii, jj = np.meshgrid(idx, idx, indexing="ij")
        rows_h.append(offset_h + np.arange(L * L))
        cols_h.append((ii * n + jj).reshape(-1))
        offset_g += L
        offset_h += L * L
    G = sps.csr_matrix((np.ones(offset_g), (np.concatenate(rows_g), np.concatenate(cols_g))),
                       shape=(offset_g, n))
    H = sps.csr_matrix((np.ones(offset_h), (np.concatenate(rows_h), np.concatenate(cols_h))),
                       shape=(offset_h, n * n))
    return G, H


def split_theta(theta: np.ndarray, model: StateSpaceModel, T: int) -> tuple[np.ndarray, np.ndarray]:
    """(K, n) Theta -> Omega (K, m) and states (K, T+1, p) (x_0 first)."""
    theta = np.asarray(theta, dtype=float)
    K = theta.shape[0]
    m = model.n_params
    return theta[:, :m], theta[:, m:].reshape(K, T + 1, model.state_dim)


def join_theta(omega: np.ndarray, states: np.ndarray) -> np.ndarray:
    """Omega (K, m) and states (K, T+1, p) -> Theta (K, n)."""
    K = omega.shape[0]
    return np.concatenate([omega, states.reshape(K, -1)], axis=1)


def _full_from_triu(vals: list[np.ndarray], term: _Term) -> np.ndarray:
    """Stack upper-triangle entries (each (K, T)) into full (K, T, L, L) blocks."""
    L = term.n_local
    K, T = vals[0].shape
    out = np.empty((K, T, L, L))
    for v, i, j in zip(vals, *term.triu):
        out[:, :, i, j] = v
        out[:, :, j, i] = v
    return out


def in_support(model: StateSpaceModel, omega: np.ndarray, bounds: PriorBounds) -> np.ndarray:
    """(K,) True where Omega is inside the prior box and the model constraints."""
    ok = bounds.contains(omega)
    cm = compile_model(model)
    if cm.constraints is not None:
        with np.errstate(all="ignore"):
            cons = cm.constraints(*[omega[:, i] for i in range(model.n_params)])
        for c in cons:
            ok &= np.asarray(c) > 0
    return ok


def constraint_values(model: StateSpaceModel, omega: np.ndarray) -> np.ndarray:
    """(K, n_c) values of the model constraints c(Omega) > 0 (empty when none)."""
    cm = compile_model(model)
    if cm.constraints is None:
        return np.zeros((omega.shape[0], 0))
    cons = cm.constraints(*[omega[:, i] for i in range(model.n_params)])
    return np.stack([np.broadcast_to(np.asarray(c, float), omega.shape[:1]) for c in cons], axis=1)


def neg2_log_posterior(model: StateSpaceModel, theta: np.ndarray, z: np.ndarray,
                       bounds: PriorBounds | None = None, order: int = 0
                       ) -> tuple[np.ndarray, ...]:
    """-2 pi(Theta | z) up to a constant, with derivatives up to ``order`` (0, 1 or 2).

    Parameters
    ----------
    theta : (K, n) or (n,) augmented states Theta = (Omega, x_0, ..., x_T).
    z : (K, T, d) or (T, d) observation trajectories (one per row of theta; a single
        trajectory is broadcast to all rows).
    bounds : prior support; outside it (and outside model constraints) the value is +inf.
        None skips the check (derivatives are then those of the smooth formula).
    order : 0 -> (value,), 1 -> (value, grad), 2 -> (value, grad, hess).

    Returns
    -------
    value (K,), grad (K, n), hess (K, n, n); for a 1-D ``theta`` the leading K axis is dropped.
    """
    theta = np.asarray(theta, dtype=float)
    single = theta.ndim == 1
    if single:
        theta = theta[None, :]
    z = np.asarray(z, dtype=float)
    if z.ndim == 2:
        z = np.broadcast_to(z, (theta.shape[0],) + z.shape)
    K, T, d = z.shape
    m, p = model.n_params, model.state_dim
    n = model.n_theta(T)
    if theta.shape != (K, n):
        raise ValueError(f"theta must have shape ({K}, {n}) for T={T}, got {theta.shape}")
    if d != model.obs_dim:
        raise ValueError(f"z must have {model.obs_dim} column(s) per step, got {d}")
    cm = compile_model(model)
    omega, states = split_theta(theta, model, T)
    om_cols = [omega[:, i:i + 1] for i in range(m)]
    shape = (K, T)
    obs_args = om_cols + [states[:, 1:, i] for i in range(p)] + [z[:, :, i] for i in range(d)]
    tr_args = om_cols + [states[:, :-1, i] for i in range(p)] + [states[:, 1:, i] for i in range(p)]
    obs = _evaluate(cm.obs, obs_args, shape)
    tr = _evaluate(cm.trans, tr_args, shape)
    value = obs[0].sum(axis=1) + tr[0].sum(axis=1)
    if bounds is not None:
        value = np.where(in_support(model, omega, bounds), value, np.inf)
    out: list[np.ndarray] = [value]
    if order >= 1:
        G, H = _scatter(m, p, T)
        Lo, Lt = cm.obs.n_local, cm.trans.n_local
        gl = np.concatenate([np.stack(obs[1:1 + Lo], axis=2).reshape(K, -1),
                             np.stack(tr[1:1 + Lt], axis=2).reshape(K, -1)], axis=1)
        out.append(np.asarray((G.T @ gl.T).T))
    if order >= 2:
        ho = _full_from_triu(obs[1 + Lo:], cm.obs).reshape(K, -1)
        ht = _full_from_triu(tr[1 + Lt:], cm.trans).reshape(K, -1)
        hl = np.concatenate([ho, ht], axis=1)
        out.append(np.asarray((H.T @ hl.T).T).reshape(K, n, n))
    if single:
        out = [o[0] for o in out]
    return tuple(out)


def log_posterior(model: StateSpaceModel, theta: np.ndarray, z: np.ndarray,
                  bounds: PriorBounds | None = None) -> np.ndarray:
    """pi(Theta | z) of Eq. (2) up to an additive constant (-inf outside the support)."""
    (v,) = neg2_log_posterior(model, theta, z, bounds, order=0)
    return -0.5 * v
