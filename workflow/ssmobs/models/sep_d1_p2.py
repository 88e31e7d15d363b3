"""Model (Sep, d=1, p=2): one observation of two independent AR(1) states (Sec. IV, model 4).

    Z_t = a X_{t,1} + b X_{t,2} + sqrt(1 - a^2 - b^2) eps_t,
    X_{t,1} = c X_{t-1,1} + sqrt(1 - c^2) eta_{t,1},
    X_{t,2} = d X_{t-1,2} + sqrt(1 - d^2) eta_{t,2}.

The paper gives no true values for this model; the configs choose a^2 + b^2 < 1.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sympy as sp

from .base import StateSpaceModel, ar1_states


class SepD1P2(StateSpaceModel):
    slug = "sep_d1_p2"
    title = "(Sep, d=1, p=2)"
    obs_dim = 1
    state_dim = 2
    param_names = ("a", "b", "c", "d")
    default_prior = {n: "restricted" for n in ("a", "b", "c", "d")}
    allowed_priors = {n: ("restricted", "unrestricted") for n in ("a", "b", "c", "d")}
    unit_interval_params = ("a", "b", "c", "d")
    constraint_text = ("a^2 + b^2 < 1",)
    linear_in_states = True

    def support_constraints(self, omega: Sequence[sp.Symbol]) -> list[sp.Expr]:
        a, b = omega[0], omega[1]
        return [1 - a**2 - b**2]

    def obs_term(
        self, omega: Sequence[sp.Symbol], x: Sequence[sp.Symbol], z: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (a, b, _, _), (x1, x2), (zt,) = omega, x, z
        s2 = 1 - a**2 - b**2
        return (zt - a * x1 - b * x2) ** 2 / s2 + sp.log(s2)

    def trans_term(
        self, omega: Sequence[sp.Symbol], x_prev: Sequence[sp.Symbol], x: Sequence[sp.Symbol]
    ) -> sp.Expr:
        (_, _, c, d), (p1, p2), (x1, x2) = omega, x_prev, x
        return (
            (x1 - c * p1) ** 2 / (1 - c**2)
            + sp.log(1 - c**2)
            + (x2 - d * p2) ** 2 / (1 - d**2)
            + sp.log(1 - d**2)
        )

    def initial_states(self, omega: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Start of x_1..x_T for the joint MAP (Sec. III.B) when d = 1 < p = 2.

        The paper's start "x_t = z_t" needs d == p; here both state components start at the
        observation, x_{t,1} = x_{t,2} = z_t.  Like the paper's start it uses only the data;
        for states of similar size (equal true x0 components and c, d, as in our configs)
        z_t ~ (a + b) x_t is as close to each state as the paper's z_t ~ a x_t is for d = p.
        """
        z = np.asarray(z, dtype=float)
        return np.repeat(z, 2, axis=2)

    def state_space_matrices(
        self, omega: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        omega = np.asarray(omega, dtype=float)
        a, b, c, d = (omega[..., i] for i in range(4))
        zero = np.zeros_like(c)
        F = np.stack([np.stack([c, zero], -1), np.stack([zero, d], -1)], axis=-2)
        Q = np.stack([1 - c**2, 1 - d**2], axis=-1)
        H = np.stack([a, b], axis=-1)[..., None, :]
        return F, Q, H, (1 - a**2 - b**2)[..., None]

    def simulate(
        self, omega: np.ndarray, x0: np.ndarray, eta: np.ndarray, eps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        a, b, c, d = omega
        x = ar1_states([c, d], x0, eta)
        z = (a * x[:, :, :1] + b * x[:, :, 1:]) + np.sqrt(1 - a**2 - b**2) * eps
        return x, z
