"""Ridges of a model's joint density (issue 60): one-parameter flows of the generators
v = sum_b (alpha_b theta_b + beta_b) d/dtheta_b, which scale and/or translate each block of
Theta (each parameter; each state coordinate over x_0..x_T together).

The condition grad(-2 log pi) . v = 0 for every (Theta, z) is linear in (alpha, beta): it is
evaluated at many random (Theta, z) with T = :data:`RIDGE_T`, its null space taken by SVD
(singular values below :data:`RIDGE_TOLERANCE` times the largest, rows normalised), brought
to reduced row echelon form, and each basis generator confirmed by following its curve (the
density constant to rounding for |s| <= :data:`RIDGE_STRETCH`).
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from ._model_terms import ModelTerms, per_column, random_points, state_names, x0_names
from .base import StateSpaceModel
from .log_posterior import neg2_log_posterior

#: horizon, number of random (Theta, z) and relative singular-value tolerance of the search
RIDGE_T = 3
RIDGE_TOLERANCE = 1e-9
#: the stretch s in [-RIDGE_STRETCH, RIDGE_STRETCH] along which a ridge is followed
RIDGE_STRETCH = 1.0


@dataclass(frozen=True)
class Ridge:
    """theta_b(s) follows d theta_b / ds = scaling[b] theta_b + translation[b] for every block
    b (each parameter, then each state coordinate over all times)."""

    name: str
    scaling: tuple[float, ...]
    translation: tuple[float, ...]
    unbounded: tuple[str, ...]

    def follow(self, model: StateSpaceModel, theta: np.ndarray, s: float) -> np.ndarray:
        """The points at parameter s along the curves through the rows ``theta``."""
        theta = np.asarray(theta, dtype=float)
        alpha = per_column(model, theta.shape[1], self.scaling)
        beta = per_column(model, theta.shape[1], self.translation)
        scaled = np.abs(alpha) > 0
        safe = np.where(scaled, alpha, 1.0)
        grown = (theta + beta / safe) * np.exp(alpha * s) - beta / safe
        return np.where(scaled, grown, theta + beta * s)


def _random_theta(
    model: StateSpaceModel, syms: ModelTerms, rng: np.random.Generator, n: int, T: int
) -> tuple[np.ndarray, np.ndarray]:
    """n random Theta (T steps) and z (n, T, d) at which -2 log pi is finite."""
    m, p, d = model.n_params, model.state_dim, model.obs_dim
    w = random_points(model, syms, rng, 4 * n)[0]
    thetas, zs = [], []
    for omega in w:
        states = rng.normal(0.0, 1.0, ((T + 1) * p,))
        z = rng.normal(0.0, 1.5, (T, d))
        thetas.append(np.concatenate([omega, states]))
        zs.append(z)
    theta, z = np.array(thetas).reshape(-1, m + (T + 1) * p), np.array(zs).reshape(-1, T, d)
    (val,) = neg2_log_posterior(model, theta, z)
    ok = np.flatnonzero(np.isfinite(val))[:n]
    return theta[ok], z[ok]


def _rref(basis: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Reduced row echelon form of the rows of ``basis`` (pivots 1)."""
    a = basis.copy()
    rows, cols = a.shape
    r = 0
    for c in range(cols):
        if r == rows:
            break
        piv = r + int(np.argmax(np.abs(a[r:, c])))
        if abs(a[piv, c]) < tol:
            continue
        a[[r, piv]] = a[[piv, r]]
        a[r] /= a[r, c]
        for i in range(rows):
            if i != r:
                a[i] -= a[i, c] * a[r]
        r += 1
    a[np.abs(a) < tol] = 0.0
    return a[:r]


def _nice(value: float) -> float:
    frac = Fraction(value).limit_denominator(12)
    return float(frac) if abs(float(frac) - value) < 1e-7 else value


def _coef(value: float, unit: str) -> str:
    if value == 1:
        return unit
    if value == -1:
        return f"-{unit}"
    return f"{value:g} {unit}"


def _ridge_name(names: list[str], alpha: np.ndarray, beta: np.ndarray) -> str:
    moved, images = [], []
    for name, a, b in zip(names, alpha, beta):
        if a == 0 and b == 0:
            continue
        moved.append(name)
        if a == 0:
            images.append(f"{name} {'-' if b < 0 else '+'} {_coef(abs(b), 's')}")
        elif b == 0:
            power = "s" if a == 1 else "-s" if a == -1 else f"({_coef(a, 's')})"
            images.append(f"{name} e^{power}")
        else:
            images.append(f"({name} + {b / a:g}) e^({_coef(a, 's')}) - {b / a:g}")
    if len(moved) == 1:
        return f"{moved[0]} -> {images[0]}"
    return f"({', '.join(moved)}) -> ({', '.join(images)})"


def ridges(model: StateSpaceModel, syms: ModelTerms, rng: np.random.Generator) -> list[Ridge]:
    """The confirmed ridges of the scale-and-translate family (see the module docstring)."""
    m, p, T = model.n_params, model.state_dim, RIDGE_T
    n_blocks = m + p
    theta, z = _random_theta(model, syms, rng, 8 * 2 * n_blocks + 20, T)
    if theta.shape[0] < 4 * n_blocks:
        return []
    _, grad = neg2_log_posterior(model, theta, z, order=1)
    g_states = grad[:, m:].reshape(-1, T + 1, p)
    x_states = theta[:, m:].reshape(-1, T + 1, p)
    rows = np.concatenate(
        [
            grad[:, :m] * theta[:, :m],
            np.sum(g_states * x_states, axis=1),
            grad[:, :m],
            np.sum(g_states, axis=1),
        ],
        axis=1,
    )
    rows = rows[np.all(np.isfinite(rows), axis=1)]
    norms = np.linalg.norm(rows, axis=1)
    rows = rows[norms > 0] / norms[norms > 0, None]
    if rows.shape[0] < 2 * n_blocks:
        return []
    _, sing, vt = np.linalg.svd(rows)
    sing_full = np.zeros(vt.shape[0])
    sing_full[: sing.size] = sing
    null = vt[sing_full <= RIDGE_TOLERANCE * max(sing_full[0], 1e-300)]
    if null.shape[0] == 0:
        return []
    names = list(model.param_names) + state_names(model)
    check_theta, check_z = theta[:4], z[:4]
    (base,) = neg2_log_posterior(model, check_theta, check_z)
    found = []
    for vec in _rref(null):
        vec = np.array([_nice(v) for v in vec])
        alpha, beta = vec[:n_blocks], vec[n_blocks:]
        first_shift = next((b for b in beta[m:] if b != 0), None)
        lead = first_shift if first_shift is not None else next(v for v in vec if v != 0)
        if lead < 0:
            alpha, beta = -alpha, -beta
        ridge = Ridge(
            name=_ridge_name(names, alpha + 0.0, beta + 0.0),
            scaling=tuple(float(a) + 0.0 for a in alpha),
            translation=tuple(float(b) + 0.0 for b in beta),
            unbounded=tuple(
                x0 for j, x0 in enumerate(x0_names(model)) if alpha[m + j] != 0 or beta[m + j] != 0
            ),
        )
        if _constant_along(model, ridge, check_theta, check_z, base):
            found.append(ridge)
    return found


def _constant_along(
    model: StateSpaceModel, ridge: Ridge, theta: np.ndarray, z: np.ndarray, base: np.ndarray
) -> bool:
    """The density at s in [-RIDGE_STRETCH, RIDGE_STRETCH] equals its value at s = 0 (to
    rounding) wherever it is finite, at 9 of 11 stretches or more."""
    finite = 0
    for s in np.linspace(-RIDGE_STRETCH, RIDGE_STRETCH, 11):
        (val,) = neg2_log_posterior(model, ridge.follow(model, theta, s), z)
        ok = np.isfinite(val)
        if not np.all(np.abs(val[ok] - base[ok]) <= 1e-7 * (1.0 + np.abs(base[ok]))):
            return False
        finite += int(np.all(ok))
    return finite >= 9
