"""A test model the paper does not treat (issue 60): two hidden AR(1) components seen
through their sum,

    x1_t = a1 x1_{t-1} + eta1_t,   x2_t = a2 x2_{t-1} + eta2_t,   z_t = x1_t + x2_t + eps_t,

unit noise variances, (a1, a2) flat on (-1, 1).  Swapping (a1, x_1) with (a2, x_2) leaves the
density unchanged; x0's first component drops out of the likelihood at a1 = 0 (and the second
at a2 = 0), inside the prior, so the posterior is improper there.
"""

from __future__ import annotations

import numpy as np
from ssmobs.models.base import StateSpaceModel


class TwoComponents(StateSpaceModel):
    """The two-component model above (a test model, not a paper model)."""

    slug = "test_two_components"
    title = "x_i,t = a_i x_i,t-1 + eta_i,t, z_t = x_1,t + x_2,t + eps_t"
    obs_dim = 1
    state_dim = 2
    param_names = ("a1", "a2")
    default_prior = {"a1": "unrestricted", "a2": "unrestricted"}
    allowed_priors = {"a1": ("unrestricted", "restricted"), "a2": ("unrestricted", "restricted")}
    unit_interval_params = ("a1", "a2")
    linear_in_states = True

    def obs_term(self, omega, x, z):
        (x1, x2), (zt,) = x, z
        return (zt - x1 - x2) ** 2

    def trans_term(self, omega, x_prev, x):
        (a1, a2), (p1, p2), (x1, x2) = omega, x_prev, x
        return (x1 - a1 * p1) ** 2 + (x2 - a2 * p2) ** 2

    def initial_states(self, omega, z):
        """Each component starts at half the observation."""
        return np.repeat(np.asarray(z, dtype=float) / 2, 2, axis=2)

    def state_space_matrices(self, omega):
        omega = np.asarray(omega, dtype=float)
        a1, a2 = omega[..., 0], omega[..., 1]
        zero, one = np.zeros_like(a1), np.ones_like(a1)
        F = np.stack([np.stack([a1, zero], -1), np.stack([zero, a2], -1)], axis=-2)
        Q = np.stack([one, one], axis=-1)
        H = np.stack([one, one], axis=-1)[..., None, :]
        return F, Q, H, one[..., None]

    def simulate(self, omega, x0, eta, eps):
        a1, a2 = omega
        K, T, _ = eta.shape
        x = np.empty((K, T, 2))
        prev = np.broadcast_to(np.asarray(x0, dtype=float), (K, 2)).copy()
        for t in range(T):
            prev = np.array([a1, a2]) * prev + eta[:, t, :]
            x[:, t, :] = prev
        return x, x.sum(axis=2, keepdims=True) + eps
