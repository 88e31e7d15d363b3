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

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache, lru_cache

import numpy as np
import scipy.sparse as sps
import sympy as sp

from ..banded_linalg import arrow_to_dense
from .base import PriorBounds, StateSpaceModel


@dataclass(frozen=True)
class _Term:
    """A lambdified per-step term: value, gradient and upper-triangle Hessian (``func``), and
    the value alone (``value_func``: the same statements as ``func`` pruned to those the value
    needs, so the same numbers, bit for bit)."""

    func: Callable
    value_func: Callable
    n_local: int
    triu: tuple[np.ndarray, np.ndarray]


def _needed_statements(
    statements: list[tuple[sp.Symbol, sp.Expr]], result: sp.Expr
) -> list[tuple[sp.Symbol, sp.Expr]]:
    """The common subexpressions ``result`` depends on, in their order."""
    wanted = set(result.free_symbols)
    kept = []
    for symbol, value in reversed(statements):
        if symbol in wanted:
            kept.append((symbol, value))
            wanted |= value.free_symbols
    return kept[::-1]


def _compile(args: list[sp.Symbol], n_local: int, expr: sp.Expr) -> _Term:
    local = args[:n_local]
    grad = [sp.diff(expr, v) for v in local]
    iu = np.triu_indices(n_local)
    hess = [sp.diff(grad[i], local[j]) for i, j in zip(*iu)]
    # one elimination of common subexpressions for both functions (what cse=True does)
    statements, reduced = sp.cse([expr, *grad, *hess], list=False)
    func = sp.lambdify(
        args, [expr, *grad, *hess], modules="numpy", cse=lambda _: (statements, reduced)
    )
    value_only = _needed_statements(statements, reduced[0])
    value_func = sp.lambdify(
        args, [expr], modules="numpy", cse=lambda _: (value_only, [reduced[0]])
    )
    return _Term(func=func, value_func=value_func, n_local=n_local, triu=iu)


@dataclass(frozen=True)
class ModelConstraints:
    """The model constraints c_j(Omega) > 0 besides the prior box (``support_constraints``).

    Values and derivatives are compiled apart, so that feasibility checks and barrier slacks
    (the line search) evaluate only c, and the Newton step alone pays for dc and d^2 c.
    ``count`` is n_c (0 when the model has none; then values are (K, 0) etc.).
    """

    n_params: int
    count: int
    _values: Callable | None
    _derivatives: Callable | None

    @classmethod
    def compile(cls, w: list[sp.Symbol], cons: list[sp.Expr]) -> ModelConstraints:
        """Lambdify the expressions ``cons`` (in the symbols ``w``) and their derivatives."""
        if not cons:
            return cls(n_params=len(w), count=0, _values=None, _derivatives=None)
        derivs: list[sp.Expr] = []
        for c in cons:
            derivs.extend(sp.diff(c, v) for v in w)
            derivs.extend(sp.diff(c, v, u) for v in w for u in w)
        return cls(
            n_params=len(w),
            count=len(cons),
            _values=sp.lambdify(w, cons, modules="numpy"),
            _derivatives=sp.lambdify(w, derivs, modules="numpy", cse=True),
        )

    def values(self, omega: np.ndarray) -> np.ndarray:
        """(..., n_c) c(Omega) for Omega (..., m)."""
        omega = np.asarray(omega, dtype=float)
        lead = omega.shape[:-1]
        if self._values is None:
            return np.zeros(lead + (0,))
        with np.errstate(all="ignore"):
            raw = self._values(*[omega[..., i] for i in range(self.n_params)])
        return np.stack([np.broadcast_to(np.asarray(c, dtype=float), lead) for c in raw], axis=-1)

    def satisfied(self, omega: np.ndarray) -> np.ndarray:
        """(...) True where every c_j(Omega) > 0 (False where a value is NaN)."""
        return np.all(self.values(omega) > 0, axis=-1)

    def derivatives(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gradients (K, n_c, m) and Hessians (K, n_c, m, m) of c, symbolic, for Omega (K, m)."""
        omega = np.asarray(omega, dtype=float)
        K, m = omega.shape
        grads = np.empty((K, self.count, m))
        hess = np.empty((K, self.count, m, m))
        if self._derivatives is None:
            return grads, hess
        with np.errstate(all="ignore"):
            raw = self._derivatives(*[omega[:, i] for i in range(m)])
        raw = [np.broadcast_to(np.asarray(v, dtype=float), (K,)) for v in raw]
        per = m + m * m
        for j in range(self.count):
            chunk = raw[j * per : (j + 1) * per]
            grads[:, j] = np.stack(chunk[:m], axis=1)
            hess[:, j] = np.stack(chunk[m:], axis=1).reshape(K, m, m)
        return grads, hess


@dataclass(frozen=True)
class CompiledModel:
    """Symbolic derivatives of one model's per-step terms and constraints, ready for NumPy."""

    model: StateSpaceModel
    obs: _Term
    trans: _Term
    constraints: ModelConstraints


@cache
def compile_constraints(model: StateSpaceModel) -> ModelConstraints:
    """The model constraints alone, lambdified (cached per model): what a support check
    needs, without the per-step terms' symbolic derivatives (about half a second per model
    and process, paid by every job that only asks whether Omega is inside)."""
    w = list(sp.symbols(f"w0:{model.n_params}", real=True))
    return ModelConstraints.compile(w, model.support_constraints(w))


@cache
def compile_model(model: StateSpaceModel) -> CompiledModel:
    """Differentiate the model's per-step terms and constraints symbolically (cached per model)."""
    m, p, d = model.n_params, model.state_dim, model.obs_dim
    w = list(sp.symbols(f"w0:{m}", real=True))
    xp = list(sp.symbols(f"xp0:{p}", real=True))
    x = list(sp.symbols(f"x0:{p}", real=True))
    z = list(sp.symbols(f"z0:{d}", real=True))
    obs = _compile(w + x + z, m + p, model.obs_term(w, x, z))
    trans = _compile(w + xp + x, m + 2 * p, model.trans_term(w, xp, x))
    return CompiledModel(
        model=model,
        obs=obs,
        trans=trans,
        constraints=compile_constraints(model),
    )


def _evaluate(func: Callable, arrays: list[np.ndarray], shape: tuple[int, ...]) -> list[np.ndarray]:
    """A term's lambdified ``func`` (:class:`_Term`) at ``arrays``, each result as a (K, T)
    float array; read-only views where a result is a constant.

    The per-call overhead matters: the joint MAP's line search calls this once per step of
    every backtrack, often for a handful of trajectories (T = 4 in the choice of K)."""
    with np.errstate(all="ignore"):
        out = func(*arrays)
    return [
        v
        if type(v) is np.ndarray and v.shape == shape and v.dtype == np.float64
        else np.broadcast_to(np.asarray(v, dtype=float), shape)
        for v in out
    ]


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
        blocks.append(
            np.concatenate([om, m + (t - 1) * p + np.arange(p), m + t * p + np.arange(p)])
        )
    for idx in blocks:
        L = idx.size
        rows_g.append(offset_g + np.arange(L))
        cols_g.append(idx)
        ii, jj = np.meshgrid(idx, idx, indexing="ij")
        rows_h.append(offset_h + np.arange(L * L))
        cols_h.append((ii * n + jj).reshape(-1))
        offset_g += L
        offset_h += L * L
    G = sps.csr_matrix(
        (np.ones(offset_g), (np.concatenate(rows_g), np.concatenate(cols_g))), shape=(offset_g, n)
    )
    H = sps.csr_matrix(
        (np.ones(offset_h), (np.concatenate(rows_h), np.concatenate(cols_h))),
        shape=(offset_h, n * n),
    )
    return G, H


def split_theta(theta: np.ndarray, model: StateSpaceModel, T: int) -> tuple[np.ndarray, np.ndarray]:
    """(K, n) Theta -> Omega (K, m) and states (K, T+1, p) (x_0 first)."""
    theta = np.asarray(theta, dtype=float)
    K = theta.shape[0]
    m = model.n_params
    return theta[:, :m], theta[:, m:].reshape(K, T + 1, model.state_dim)


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
    return bounds.contains(omega) & compile_constraints(model).satisfied(omega)


def neg2_log_posterior(
    model: StateSpaceModel,
    theta: np.ndarray,
    z: np.ndarray,
    bounds: PriorBounds | None = None,
    order: int = 0,
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
    om_cols = [omega[:, i : i + 1] for i in range(m)]
    shape = (K, T)
    obs_args = om_cols + [states[:, 1:, i] for i in range(p)] + [z[:, :, i] for i in range(d)]
    tr_args = om_cols + [states[:, :-1, i] for i in range(p)] + [states[:, 1:, i] for i in range(p)]
    if order == 0:  # the value alone (the line search)
        obs = _evaluate(cm.obs.value_func, obs_args, shape)
        tr = _evaluate(cm.trans.value_func, tr_args, shape)
    else:
        obs = _evaluate(cm.obs.func, obs_args, shape)
        tr = _evaluate(cm.trans.func, tr_args, shape)
    value = obs[0].sum(axis=1) + tr[0].sum(axis=1)
    if bounds is not None:
        value = np.where(in_support(model, omega, bounds), value, np.inf)
    out: list[np.ndarray] = [value]
    if order >= 1:
        G, H = _scatter(m, p, T)
        Lo, Lt = cm.obs.n_local, cm.trans.n_local
        gl = np.concatenate(
            [
                np.stack(obs[1 : 1 + Lo], axis=2).reshape(K, -1),
                np.stack(tr[1 : 1 + Lt], axis=2).reshape(K, -1),
            ],
            axis=1,
        )
        out.append(np.asarray((G.T @ gl.T).T))
    if order >= 2:
        ho = _full_from_triu(obs[1 + Lo :], cm.obs).reshape(K, -1)
        ht = _full_from_triu(tr[1 + Lt :], cm.trans).reshape(K, -1)
        hl = np.concatenate([ho, ht], axis=1)
        out.append(np.asarray((H.T @ hl.T).T).reshape(K, n, n))
    if single:
        out = [o[0] for o in out]
    return tuple(out)


def log_posterior(
    model: StateSpaceModel, theta: np.ndarray, z: np.ndarray, bounds: PriorBounds | None = None
) -> np.ndarray:
    """pi(Theta | z) of Eq. (2) up to an additive constant (-inf outside the support)."""
    (v,) = neg2_log_posterior(model, theta, z, bounds, order=0)
    return -0.5 * v


# --------------------------------------------------------------------------- structured Hessian
@dataclass(frozen=True)
class BlockHessian:
    """Hessian of -2 pi in its natural block structure (Sec. III.B), batched over k.

    With Theta = (Omega, x_0, ..., x_T) the Hessian is an "arrow" matrix: a dense m x m
    block for Omega, m dense columns coupling Omega with every state, and a
    block-tridiagonal state part (each step term couples only x_{t-1} and x_t).

    Attributes
    ----------
    omega : (K, m, m) d^2 / dOmega dOmega^T.
    cross : (K, T+1, p, m) d^2 / dx_t dOmega^T for t = 0..T.
    diag : (K, T+1, p, p) d^2 / dx_t dx_t^T.
    lower : (K, T, p, p) d^2 / dx_t dx_{t-1}^T for t = 1..T (entry t-1).
    """

    omega: np.ndarray
    cross: np.ndarray
    diag: np.ndarray
    lower: np.ndarray

    def to_dense(self) -> np.ndarray:
        """(K, n, n) dense Hessian (for checks)."""
        return arrow_to_dense(self.omega, self.cross, self.diag, self.lower)


def neg2_log_posterior_blocks(
    model: StateSpaceModel, theta: np.ndarray, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray, BlockHessian]:
    """Value, gradient and block-structured Hessian of -2 pi (smooth formula, no bounds).

    Same per-step symbolic derivatives as :func:`neg2_log_posterior`, but the Hessian is
    returned as a :class:`BlockHessian` (O(K T (m + p)^2) memory instead of O(K n^2)), which
    is what the batched Newton solver of :mod:`ssmobs.joint_map.barrier` factorizes
    (:class:`ssmobs.banded_linalg.ArrowFactor`).

    Parameters: ``theta`` (K, n), ``z`` (K, T, d).  Returns value (K,), grad (K, n), blocks.
    """
    theta = np.asarray(theta, dtype=float)
    z = np.asarray(z, dtype=float)
    K, T, d = z.shape
    m, p = model.n_params, model.state_dim
    n = model.n_theta(T)
    if theta.shape != (K, n):
        raise ValueError(f"theta must have shape ({K}, {n}) for T={T}, got {theta.shape}")
    cm = compile_model(model)
    omega, states = split_theta(theta, model, T)
    om_cols = [omega[:, i : i + 1] for i in range(m)]
    shape = (K, T)
    obs = _evaluate(
        cm.obs.func,
        om_cols + [states[:, 1:, i] for i in range(p)] + [z[:, :, i] for i in range(d)],
        shape,
    )
    tr = _evaluate(
        cm.trans.func,
        om_cols + [states[:, :-1, i] for i in range(p)] + [states[:, 1:, i] for i in range(p)],
        shape,
    )
    Lo, Lt = cm.obs.n_local, cm.trans.n_local
    value = obs[0].sum(axis=1) + tr[0].sum(axis=1)

    go = np.stack(obs[1 : 1 + Lo], axis=2)  # (K, T, m + p)
    gt = np.stack(tr[1 : 1 + Lt], axis=2)  # (K, T, m + 2p)
    grad_states = np.zeros((K, T + 1, p))
    grad_states[:, 1:] += go[:, :, m:] + gt[:, :, m + p :]
    grad_states[:, :-1] += gt[:, :, m : m + p]
    grad = np.concatenate(
        [go[:, :, :m].sum(axis=1) + gt[:, :, :m].sum(axis=1), grad_states.reshape(K, -1)], axis=1
    )

    h_omega = np.zeros((K, m, m))
    cross = np.zeros((K, T + 1, p, m))
    diag = np.zeros((K, T + 1, p, p))
    lower = np.zeros((K, T, p, p))
    # local variables: obs term [Omega, x_t], transition term [Omega, x_{t-1}, x_t];
    # role (shift, component) of a state variable: shift 0 = x_t, -1 = x_{t-1}
    obs_roles = [None] * m + [(0, c) for c in range(p)]
    tr_roles = [None] * m + [(-1, c) for c in range(p)] + [(0, c) for c in range(p)]
    steps = {0: slice(1, None), -1: slice(None, -1)}
    for vals, term, roles in (
        (obs[1 + Lo :], cm.obs, obs_roles),
        (tr[1 + Lt :], cm.trans, tr_roles),
    ):
        for v, i, j in zip(vals, *term.triu):
            ri, rj = roles[i], roles[j]
            if ri is None and rj is None:
                tot = v.sum(axis=1)
                h_omega[:, i, j] += tot
                if i != j:
                    h_omega[:, j, i] += tot
            elif ri is None or rj is None:
                (sh, c), w = (rj, i) if ri is None else (ri, j)
                cross[:, steps[sh], c, w] += v
            elif ri[0] == rj[0]:
                diag[:, steps[ri[0]], ri[1], rj[1]] += v
                if ri[1] != rj[1]:
                    diag[:, steps[ri[0]], rj[1], ri[1]] += v
            else:  # x_{t-1} with x_t: block (t, t-1)
                (_, c_prev), (_, c_now) = (ri, rj) if ri[0] == -1 else (rj, ri)
                lower[:, :, c_now, c_prev] += v
    return value, grad, BlockHessian(omega=h_omega, cross=cross, diag=diag, lower=lower)
