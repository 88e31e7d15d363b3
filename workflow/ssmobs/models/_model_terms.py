"""The model's two SymPy terms as the symmetry and propriety analyses use them (issue 60):
real symbols, NumPy functions of the terms, random points where both are finite, and the
block structure of Theta = (Omega, x_0, x_1..x_T).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import sympy as sp

from .base import StateSpaceModel

#: seed of every random point of the analyses: their results depend on the model only
SEARCH_SEED = 60


def split_blocks(model: StateSpaceModel, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    theta = np.asarray(theta, dtype=float)
    m, p = model.n_params, model.state_dim
    return theta[:, :m], theta[:, m:].reshape(theta.shape[0], -1, p)


def per_column(model: StateSpaceModel, n: int, per_block: Sequence[float]) -> np.ndarray:
    """Block values (m parameters, then p state coordinates) spread over Theta's n columns."""
    m, p = model.n_params, model.state_dim
    blocks = np.asarray(per_block, dtype=float)
    return np.concatenate([blocks[:m], np.tile(blocks[m:], (n - m) // p)])


def state_names(model: StateSpaceModel) -> list[str]:
    """Readable names of the state coordinates (all times): x, or x_1..x_p."""
    p = model.state_dim
    return ["x"] if p == 1 else [f"x_{j + 1}" for j in range(p)]


def x0_names(model: StateSpaceModel) -> list[str]:
    """Names of the components of x_0 as Theta names them."""
    p = model.state_dim
    return ["x0"] if p == 1 else [f"x0_{j + 1}" for j in range(p)]


@dataclass(frozen=True)
class ModelTerms:
    w: list[sp.Symbol]
    xp: list[sp.Symbol]
    x: list[sp.Symbol]
    z: list[sp.Symbol]
    obs: sp.Expr
    trans: sp.Expr
    obs_f: Callable
    trans_f: Callable


def model_symbols(model: StateSpaceModel) -> ModelTerms:
    """The model's two terms with real symbols, and their NumPy functions."""
    m, p, d = model.n_params, model.state_dim, model.obs_dim
    w = list(sp.symbols(f"w0:{m}", real=True))
    xp = list(sp.symbols(f"xp0:{p}", real=True))
    x = list(sp.symbols(f"x0:{p}", real=True))
    z = list(sp.symbols(f"z0:{d}", real=True))
    obs = sp.sympify(model.obs_term(w, x, z))
    trans = sp.sympify(model.trans_term(w, xp, x))
    return ModelTerms(
        w,
        xp,
        x,
        z,
        obs,
        trans,
        sp.lambdify(w + x + z, obs, modules="numpy"),
        sp.lambdify(w + xp + x, trans, modules="numpy"),
    )


def term_values(func: Callable, cols: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        out = func(*cols.T)
    return np.broadcast_to(np.asarray(out, dtype=float), (cols.shape[0],)).copy()


def random_points(
    model: StateSpaceModel, syms: ModelTerms, rng: np.random.Generator, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Up to n random (Omega, x_prev, x, z) where both terms are finite and real and the model
    constraints hold: parameters of either sign, magnitudes in (0.1, 0.9) or (0.1, 3); states
    and data normal with standard deviation 1.5.  Drawn in rounds of 40 n candidates, at
    most 10 rounds (fewer points where the model's domain is small)."""
    m, p, d = model.n_params, model.state_dim, model.obs_dim
    cons = model.support_constraints(syms.w)
    cf = sp.lambdify(syms.w, cons, modules="numpy") if cons else None
    kept: list[tuple[np.ndarray, ...]] = []
    found = 0
    for _ in range(10):
        size = 40 * n
        mag = np.where(
            rng.uniform(size=(size, 1)) < 0.5,
            rng.uniform(0.1, 0.9, (size, m)),
            rng.uniform(0.1, 3.0, (size, m)),
        )
        w = mag * rng.choice([-1.0, 1.0], size=(size, m))
        xp = rng.normal(0.0, 1.5, (size, p))
        x = rng.normal(0.0, 1.5, (size, p))
        z = rng.normal(0.0, 1.5, (size, d))
        ok = np.isfinite(term_values(syms.obs_f, np.hstack([w, x, z])))
        ok &= np.isfinite(term_values(syms.trans_f, np.hstack([w, xp, x])))
        if cf is not None:
            with np.errstate(all="ignore"):
                vals = [np.broadcast_to(np.asarray(c, dtype=float), (size,)) for c in cf(*w.T)]
            ok &= np.all(np.stack(vals, axis=1) > 0, axis=1)
        idx = np.flatnonzero(ok)[: n - found]
        kept.append((w[idx], xp[idx], x[idx], z[idx]))
        found += idx.size
        if found >= n:
            break
    w, xp, x, z = (np.concatenate(parts) for parts in zip(*kept))
    return w, xp, x, z
