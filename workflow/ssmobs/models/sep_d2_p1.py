"""Model (Sep, d=2, p=1): bivariate observations driven by one state (Sec. IV, model 3).

Z_{t,1} = a X_t + sqrt(1 - a^2) eps_{t,1},   Z_{t,2} = b X_t + sqrt(1 - b^2) eps_{t,2},
X_t = c X_{t-1} + sqrt(1 - c^2) eta_t.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sympy as sp

from .base import StateSpaceModel, ar1_states


class SepD2P1(StateSpaceModel):
    slug = "sep_d2_p1"
    title = "(Sep, d=2, p=1)"
    obs_dim = 2
    state_dim = 1
    param_names = ("a", "b", "c")
    default_prior = {"a": "restricted", "b": "restricted", "c": "restricted"}
    allowed_priors = {n: ("restricted", "unrestricted") for n in ("a", "b", "c")}
    unit_interval_params = ("a", "b", "c")
    linear_in_states = True

    def obs_term(
        self, omega: Sequence[sp.Symbol], x: Sequence[sp.Symbol], z: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (a, b, _), (xt,), (z1, z2) = omega, x, z
        return (
            (z1 - a * xt) ** 2 / (1 - a**2)
            + sp.log(1 - a**2)
            + (z2 - b * xt) ** 2 / (1 - b**2)
            + sp.log(1 - b**2)
        )

    def trans_term(
        self, omega: Sequence[sp.Symbol], x_prev: Sequence[sp.Symbol], x: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (_, _, c), (xp,), (xt,) = omega, x_prev, x
        return (xt - c * xp) ** 2 / (1 - c**2) + sp.log(1 - c**2)

    def initial_states(self, omega: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Start of x_1..x_T for the joint MAP (Sec. III.B) when d = 2 > p = 1.

        The paper's start "x_t = z_t" needs d == p; here each state starts at the mean of
        its two observations, x_t = (z_{t,1} + z_{t,2}) / 2.  Like the paper's start it uses
        only the data (no inversion of the observation equation with Omega), and for
        a = b it is exactly the paper's rule applied to either observation's expectation.
        """
        z = np.asarray(z, dtype=float)
        return z.mean(axis=2, keepdims=True)

    def state_space_matrices(
        self, omega: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        omega = np.asarray(omega, dtype=float)
        a, b, c = omega[..., 0], omega[..., 1], omega[..., 2]
        H = np.stack([a, b], axis=-1)[..., None]
        R = np.stack([1 - a**2, 1 - b**2], axis=-1)
        return c[..., None, None], (1 - c**2)[..., None], H, R

    def simulate(
        self, omega: np.ndarray, x0: np.ndarray, eta: np.ndarray, eps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        a, b, c = omega
        x = ar1_states(c, x0, eta)
        z = np.concatenate(
            [a * x + np.sqrt(1 - a**2) * eps[:, :, :1], b * x + np.sqrt(1 - b**2) * eps[:, :, 1:]],
            axis=2,
        )
        return x, z
