"""Model (Same, d=p=1): same dynamics for observations and states (Sec. IV, model 1; Eq. (5)).

Z_t = a X_t + sqrt(1 - a^2) eps_t,   X_t = a X_{t-1} + sqrt(1 - a^2) eta_t.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sympy as sp

from .base import StateSpaceModel, ar1_states


class Same(StateSpaceModel):
    slug = "same"
    title = "(Same, d=p=1)"
    obs_dim = 1
    state_dim = 1
    param_names = ("a",)
    default_prior = {"a": "restricted"}
    allowed_priors = {"a": ("restricted", "unrestricted")}
    unit_interval_params = ("a",)
    linear_in_states = True

    def obs_term(
        self, omega: Sequence[sp.Symbol], x: Sequence[sp.Symbol], z: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (a,), (xt,), (zt,) = omega, x, z
        return (zt - a * xt) ** 2 / (1 - a**2) + sp.log(1 - a**2)

    def trans_term(
        self, omega: Sequence[sp.Symbol], x_prev: Sequence[sp.Symbol], x: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (a,), (xp,), (xt,) = omega, x_prev, x
        return (xt - a * xp) ** 2 / (1 - a**2) + sp.log(1 - a**2)

    def state_space_matrices(
        self, omega: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        a = np.asarray(omega, dtype=float)[..., 0]
        v = 1 - a**2
        return a[..., None, None], v[..., None], a[..., None, None], v[..., None]

    def simulate(
        self, omega: np.ndarray, x0: np.ndarray, eta: np.ndarray, eps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        a = omega[0]
        x = ar1_states(a, x0, eta)
        z = a * x + np.sqrt(1 - a**2) * eps
        return x, z
