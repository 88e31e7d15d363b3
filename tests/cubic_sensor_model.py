"""A test model the paper does not treat (issue 47): the cubic sensor

    x_t = a x_{t-1} + eta_t,   z_t = b x_t^3 + eps_t,

unit noise variances.  Its states start at the cube root of z_t / b, which b = 0 excludes
(a start there is not finite).  With a flat prior on b over the whole line it has no joint
maximum: along (a, b / s^3, s x_0, s x) the observation term stays and the transition term
shrinks as s -> 0.
"""

from __future__ import annotations

import numpy as np
from ssmobs.models.base import StateSpaceModel


class CubicSensor(StateSpaceModel):
    """The cubic sensor above; b first, so that the Halton sequence's first point, 1/2 of
    b's box (-1, 1), is exactly b = 0."""

    slug = "test_cubic_sensor"
    title = "x_t = a x_{t-1} + eta_t, z_t = b x_t^3 + eps_t"
    obs_dim = 1
    state_dim = 1
    param_names = ("b", "a")
    default_prior = {"b": "unrestricted", "a": "restricted"}
    allowed_priors = {"b": ("unrestricted", "half_line"), "a": ("restricted",)}

    def obs_term(self, omega, x, z):
        (b, _), (xt,), (zt,) = omega, x, z
        return (zt - b * xt**3) ** 2

    def trans_term(self, omega, x_prev, x):
        (_, a), (xp,), (xt,) = omega, x_prev, x
        return (xt - a * xp) ** 2

    def initial_states(self, omega, z):
        """x_t = cbrt(z_t / b): not finite at b = 0."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.cbrt(np.asarray(z, dtype=float) / float(omega[0]))

    def simulate(self, omega, x0, eta, eps):
        b, a = omega
        K, T, _ = eta.shape
        x = np.empty((K, T, 1))
        prev = np.full(K, float(x0[0]))
        for t in range(T):
            prev = a * prev + eta[:, t, 0]
            x[:, t, 0] = prev
        return x, b * x**3 + eps
