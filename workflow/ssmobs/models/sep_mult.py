"""Model (Sep, d=p=1, Multiplicative): additive states, multiplicative observations
(Sec. IV, model 6).

    Z_t = sqrt(a) X_t eps_t,   X_t = a + X_{t-1} + eta_t,   a > 0.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sympy as sp

from .base import StateSpaceModel


class SepMult(StateSpaceModel):
    slug = "sep_mult"
    title = "(Sep, d=p=1, Multiplicative)"
    obs_dim = 1
    state_dim = 1
    param_names = ("a",)
    default_prior = {"a": "half_line"}
    allowed_priors = {"a": ("half_line", "restricted")}
    positive_params = ("a",)
    #: multiplicative observation noise: not linear-Gaussian in the states
    linear_in_states = False

    def obs_term(
        self, omega: Sequence[sp.Symbol], x: Sequence[sp.Symbol], z: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (a,), (xt,), (zt,) = omega, x, z
        return zt**2 / (a * xt**2) + sp.log(a) + sp.log(xt**2)

    def trans_term(
        self, omega: Sequence[sp.Symbol], x_prev: Sequence[sp.Symbol], x: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (a,), (xp,), (xt,) = omega, x_prev, x
        return (xt - a - xp) ** 2

    has_sign_consistent_start = True

    def sign_consistent_states(
        self, omega: np.ndarray, x0: np.ndarray, z: np.ndarray
    ) -> np.ndarray:
        """|z_t| / sqrt(a) with the sign of x0: Z_t = sqrt(a) X_t eps_t leaves the sign of X_t
        unidentified by z_t, so the paper's start x = z gives states of random sign; this
        start puts them on x0's side of zero (the side X_t stays on for X_0 = 8, a = 0.9)."""
        a = float(np.asarray(omega, dtype=float).ravel()[0])
        sign = 1.0 if float(np.asarray(x0, dtype=float).ravel()[0]) >= 0 else -1.0
        return sign * np.abs(np.asarray(z, dtype=float)) / np.sqrt(a)

    def simulate(
        self, omega: np.ndarray, x0: np.ndarray, eta: np.ndarray, eps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        a = omega[0]
        K, T, _ = eta.shape
        steps = a + eta
        x = x0[0] + np.cumsum(steps, axis=1)
        z = np.sqrt(a) * x * eps
        return x, z
