"""A test model the paper does not treat (issue 36): the univariate growth model

    x_t = a x_{t-1} + b x_{t-1} / (1 + x_{t-1}^2) + eta_t,   z_t = x_t^2 / 20 + eps_t,

whose joint posterior is symmetric under x -> -x (the transition mean is odd in x_{t-1},
z_t sees only x_t^2): every maximum has a mirror image of the same height.  One file, used
by the unit tests and, copied into a workflow's ``models/`` folder (with a planted
mistake), by the own-model tests.
"""

from __future__ import annotations

import numpy as np
from ssmobs.models.base import StateSpaceModel


class Growth(StateSpaceModel):
    """The growth model above, unit noise variances (a test model, not a paper model)."""

    slug = "test_growth"
    title = "x_t = a x + b x / (1 + x^2) + eta_t, z_t = x_t^2 / 20 + eps_t"
    obs_dim = 1
    state_dim = 1
    param_names = ("a", "b")
    default_prior = {"a": "restricted", "b": "half_line"}
    allowed_priors = {"a": ("restricted",), "b": ("half_line",)}
    has_sign_consistent_start = True

    def obs_term(self, omega, x, z):
        (xt,), (zt,) = x, z
        return (zt - xt**2 / 20) ** 2

    def trans_term(self, omega, x_prev, x):
        (a, b), (xp,), (xt,) = omega, x_prev, x
        return (xt - a * xp - b * xp / (1 + xp**2)) ** 2

    def initial_states(self, omega, z):
        """x_t = sqrt(20 max(z_t, 0)): the positive root of z_t = x_t^2 / 20."""
        return np.sqrt(20 * np.maximum(np.asarray(z, dtype=float), 0.0))

    def sign_consistent_states(self, omega, x0, z):
        sign = 1.0 if float(np.ravel(x0)[0]) >= 0 else -1.0
        return sign * self.initial_states(omega, z)

    def mirror_images(self, theta):
        """x_0, x_1..x_T -> their negatives, Omega unchanged: -2 pi stays the same."""
        theta = np.asarray(theta, dtype=float)
        return [np.concatenate([theta[:, :2], -theta[:, 2:]], axis=1)]

    def simulate(self, omega, x0, eta, eps):
        a, b = omega
        K, T, _ = eta.shape
        x = np.empty((K, T, 1))
        prev = np.full(K, float(x0[0]))
        for t in range(T):
            prev = a * prev + b * prev / (1 + prev**2) + eta[:, t, 0]
            x[:, t, 0] = prev
        return x, x**2 / 20 + eps
