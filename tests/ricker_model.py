"""A test model the paper does not treat (issue 47): a Ricker model on the log scale with
abundance observed at an unknown detection rate c,

    x_t = x_{t-1} + a - b e^{x_{t-1}} + eta_t,   z_t = c e^{x_t} + eps_t,

unit noise variances, (a, b, c) flat on (0, inf).  It has an exact ridge: (a, b e^-d,
c e^-d, x_0 + d, x + d) leaves the density unchanged for every d, so no trajectory has a
joint maximum that passes the checks.
"""

from __future__ import annotations

import numpy as np
import sympy as sp
from ssmobs.models.base import StateSpaceModel


class Ricker(StateSpaceModel):
    """The Ricker model above (a test model, not a paper model)."""

    slug = "test_ricker"
    title = "x_t = x + a - b e^x + eta_t, z_t = c e^{x_t} + eps_t"
    obs_dim = 1
    state_dim = 1
    param_names = ("a", "b", "c")
    default_prior = {"a": "half_line", "b": "half_line", "c": "half_line"}
    allowed_priors = {"a": ("half_line",), "b": ("half_line",), "c": ("half_line",)}

    def obs_term(self, omega, x, z):
        (_, _, c), (xt,), (zt,) = omega, x, z
        return (zt - c * sp.exp(xt)) ** 2

    def trans_term(self, omega, x_prev, x):
        (a, b, _), (xp,), (xt,) = omega, x_prev, x
        return (xt - xp - a + b * sp.exp(xp)) ** 2

    def initial_states(self, omega, z):
        """x_t = log(max(z_t, 0.1) / c): the observation equation without noise."""
        z = np.asarray(z, dtype=float)
        return np.log(np.maximum(z, 0.1) / float(omega[2]))

    def simulate(self, omega, x0, eta, eps):
        a, b, c = omega
        K, T, _ = eta.shape
        x = np.empty((K, T, 1))
        prev = np.full(K, float(x0[0]))
        for t in range(T):
            prev = prev + a - b * np.exp(prev) + eta[:, t, 0]
            x[:, t, 0] = prev
        return x, c * np.exp(x) + eps
