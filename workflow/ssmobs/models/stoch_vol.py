"""Stochastic volatility model (not in the paper): AR(1) log-variance, returns z_t.

    X_t = mu + phi (X_{t-1} - mu) + sigma eta_t,   Z_t = exp(X_t / 2) eps_t,

with eta_t, eps_t ~ N(0, 1) iid, Omega = (phi, sigma) and the level mu fixed at 0.

mu is fixed, not estimated: it only sets the unit of z (replacing x_t by x_t - mu scales z
by exp(-mu / 2)), so mu = 0 means z is measured in units of its long-run volatility.  The
observability question is then about the dynamics (phi, sigma) alone, like the paper's
models whose Omega holds only dynamic coefficients.  The observation equation is nonlinear
and non-additive in the state, like the paper's Multiplicative model (Sec. IV.F).

Priors (Eq. (3), Eq. (14)): phi ~ U(0, 1) (``restricted``; stationary, positive persistence)
or U(-1, 1); sigma flat on (0, inf) (``half_line``) or U(0, 1).  x_0 has the flat prior of
Sec. IV.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sympy as sp

from .base import StateSpaceModel


class StochVol(StateSpaceModel):
    slug = "stoch_vol"
    title = "Stochastic volatility (d=p=1; not in the paper)"
    obs_dim = 1
    state_dim = 1
    param_names = ("phi", "sigma")
    default_prior = {"phi": "restricted", "sigma": "half_line"}
    allowed_priors = {"phi": ("restricted", "unrestricted"), "sigma": ("half_line", "restricted")}
    unit_interval_params = ("phi",)
    positive_params = ("sigma",)

    #: fixed level mu of the log-variance (see the module docstring)
    mu: float = 0.0

    def obs_term(
        self, omega: Sequence[sp.Symbol], x: Sequence[sp.Symbol], z: Sequence[sp.Symbol]
    ) -> sp.Expr:
        # z_t | x_t ~ N(0, exp(x_t)): -2 log f = z_t^2 exp(-x_t) + x_t + const
        (_, _), (xt,), (zt,) = omega, x, z
        return zt**2 * sp.exp(-xt) + xt

    def trans_term(
        self, omega: Sequence[sp.Symbol], x_prev: Sequence[sp.Symbol], x: Sequence[sp.Symbol]
    ) -> sp.Expr:
        # x_t | x_{t-1} ~ N(mu + phi (x_{t-1} - mu), sigma^2)
        (phi, sigma), (xp,), (xt,) = omega, x_prev, x
        mean = self.mu + phi * (xp - self.mu)
        return (xt - mean) ** 2 / sigma**2 + 2 * sp.log(sigma)

    def initial_states(self, omega: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Start of x_1..x_T for the joint MAP (Sec. III.B): here z_t is a return, not a
        noisy state, so the paper's start x_t = z_t does not apply.  Every state starts at
        x_t = log(mean_t z_t^2), the log-variance of the whole trajectory (data only, like
        the paper's start, and finite even where z_t = 0)."""
        z = np.asarray(z, dtype=float)
        level = np.log(np.mean(z**2, axis=1, keepdims=True))
        return np.broadcast_to(level, z.shape).copy()

    def simulate(
        self, omega: np.ndarray, x0: np.ndarray, eta: np.ndarray, eps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        phi, sigma = omega
        K, T, _ = eta.shape
        x = np.empty((K, T, 1))
        prev = np.full(K, float(x0[0]))
        for t in range(T):
            prev = self.mu + phi * (prev - self.mu) + sigma * eta[:, t, 0]
            x[:, t, 0] = prev
        z = np.exp(x / 2) * eps
        return x, z
