"""Model (Sep, d=p=1, Multiplicative): additive states, multiplicative observations
(Sec. IV, model 6).

    Z_t = sqrt(a) X_t eps_t,   X_t = a + X_{t-1} + eta_t,   a > 0.
"""

from __future__ import annotations

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

    def obs_term(self, omega, x, z):
        (a,), (xt,), (zt,) = omega, x, z
        return zt**2 / (a * xt**2) + sp.log(a) + sp.log(xt**2)

    def trans_term(self, omega, x_prev, x):
        (a,), (xp,), (xt,) = omega, x_prev, x
        return (xt - a - xp) ** 2

    def simulate(self, omega, x0, eta, eps):
        a = omega[0]
        K, T, _ = eta.shape
        steps = a + eta
        x = x0[0] + np.cumsum(steps, axis=1)
        z = np.sqrt(a) * x * eps
        return x, z
