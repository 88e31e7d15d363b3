"""Model (Sep, d=p=1, ranWalk): random-walk states (Sec. IV, model 5; Eq. (8), (13)).

Z_t = a X_t + eps_t,   X_t = X_{t-1} + eta_t.
"""

from __future__ import annotations

import numpy as np

from .base import StateSpaceModel


class SepRanWalk(StateSpaceModel):
    slug = "sep_ranwalk"
    title = "(Sep, d=p=1, ranWalk)"
    obs_dim = 1
    state_dim = 1
    param_names = ("a",)
    default_prior = {"a": "half_line"}
    allowed_priors = {"a": ("half_line", "restricted", "unrestricted")}
    linear_in_states = True

    def obs_term(self, omega, x, z):
        (a,), (xt,), (zt,) = omega, x, z
        return (zt - a * xt) ** 2

    def trans_term(self, omega, x_prev, x):
        (xp,), (xt,) = x_prev, x
        return (xt - xp) ** 2

    def state_space_matrices(self, omega):
        a = np.asarray(omega, dtype=float)[..., 0]
        one = np.ones_like(a)
        return one[..., None, None], one[..., None], a[..., None, None], one[..., None]

    def simulate(self, omega, x0, eta, eps):
        a = omega[0]
        x = x0[0] + np.cumsum(eta, axis=1)
        z = a * x + eps
        return x, z
