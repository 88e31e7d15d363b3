"""A test model the paper does not treat (issue 60): an AR(1) state seen through the product
of two gains,

    x_t = a x_{t-1} + eta_t,   z_t = b c x_t + eps_t,

unit noise variances.  Only the product b c enters, so (b, c) -> (b e^s, c e^-s) leaves the
density unchanged for every s: a scaling ridge that moves no state.  With b and c flat on
(0, inf) its orbits carry infinite mass (improper); with both on (0, 1) they do not.
"""

from __future__ import annotations

import numpy as np
from ssmobs.models.base import StateSpaceModel


class TwoGains(StateSpaceModel):
    """The two-gain model above (a test model, not a paper model)."""

    slug = "test_two_gains"
    title = "x_t = a x_{t-1} + eta_t, z_t = b c x_t + eps_t"
    obs_dim = 1
    state_dim = 1
    param_names = ("a", "b", "c")
    default_prior = {"a": "restricted", "b": "half_line", "c": "half_line"}
    allowed_priors = {"a": ("restricted",), "b": ("half_line",), "c": ("half_line",)}

    def obs_term(self, omega, x, z):
        (_, b, c), (xt,), (zt,) = omega, x, z
        return (zt - b * c * xt) ** 2

    def trans_term(self, omega, x_prev, x):
        (a, _, _), (xp,), (xt,) = omega, x_prev, x
        return (xt - a * xp) ** 2

    def initial_states(self, omega, z):
        """x_t = z_t / (b c)."""
        return np.asarray(z, dtype=float) / float(omega[1] * omega[2])

    def simulate(self, omega, x0, eta, eps):
        a, b, c = omega
        x = np.empty(eta.shape)
        prev = np.full(eta.shape[0], float(x0[0]))
        for t in range(eta.shape[1]):
            prev = a * prev + eta[:, t, 0]
            x[:, t, 0] = prev
        return x, b * c * x + eps
