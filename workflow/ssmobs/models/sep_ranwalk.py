"""Model (Sep, d=p=1, ranWalk): random-walk states (Sec. IV, model 5; Eq. (8), (13)).

Z_t = a X_t + eps_t,   X_t = X_{t-1} + eta_t.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sympy as sp

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

    def obs_term(
        self, omega: Sequence[sp.Symbol], x: Sequence[sp.Symbol], z: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (a,), (xt,), (zt,) = omega, x, z
        return (zt - a * xt) ** 2

    def trans_term(
        self, omega: Sequence[sp.Symbol], x_prev: Sequence[sp.Symbol], x: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (xp,), (xt,) = x_prev, x
        return (xt - xp) ** 2

    def state_space_matrices(
        self, omega: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        a = np.asarray(omega, dtype=float)[..., 0]
        one = np.ones_like(a)
        return one[..., None, None], one[..., None], a[..., None, None], one[..., None]

    def simulate(
        self, omega: np.ndarray, x0: np.ndarray, eta: np.ndarray, eps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        a = omega[0]
        x = x0[0] + np.cumsum(eta, axis=1)
        z = a * x + eps
        return x, z
