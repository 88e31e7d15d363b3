"""Model (Sep, d=p=1): separate dynamics for observations and states (Sec. IV, model 2).

Z_t = b X_t + sqrt(1 - b^2) eps_t,   X_t = a X_{t-1} + sqrt(1 - a^2) eta_t.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sympy as sp

from .base import StateSpaceModel, ar1_states


class Sep(StateSpaceModel):
    slug = "sep"
    title = "(Sep, d=p=1)"
    obs_dim = 1
    state_dim = 1
    param_names = ("a", "b")
    default_prior = {"a": "restricted", "b": "restricted"}
    allowed_priors = {"a": ("restricted", "unrestricted"), "b": ("restricted", "unrestricted")}
    unit_interval_params = ("a", "b")
    linear_in_states = True

    def obs_term(
        self, omega: Sequence[sp.Symbol], x: Sequence[sp.Symbol], z: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (_, b), (xt,), (zt,) = omega, x, z
        return (zt - b * xt) ** 2 / (1 - b**2) + sp.log(1 - b**2)

    def trans_term(
        self, omega: Sequence[sp.Symbol], x_prev: Sequence[sp.Symbol], x: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (a, _), (xp,), (xt,) = omega, x_prev, x
        return (xt - a * xp) ** 2 / (1 - a**2) + sp.log(1 - a**2)

    def state_space_matrices(
        self, omega: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        omega = np.asarray(omega, dtype=float)
        a, b = omega[..., 0], omega[..., 1]
        return a[..., None, None], (1 - a**2)[..., None], b[..., None, None], (1 - b**2)[..., None]

    def simulate(
        self, omega: np.ndarray, x0: np.ndarray, eta: np.ndarray, eps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        a, b = omega
        x = ar1_states(a, x0, eta)
        z = b * x + np.sqrt(1 - b**2) * eps
        return x, z
