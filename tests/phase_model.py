"""A test model the paper does not treat (issue 60): phase tracking,

    x_t = x_{t-1} + mu + 0.3 eta_t,   z_t = b sin(x_t) + 0.3 eps_t,

mu flat on the line, b on (0, inf), x0 flat.  Shifting x0 and every state by 2 pi leaves the
density unchanged (so with x0 flat on the line the posterior is improper), and so does the
reflection (mu, x) -> (-mu, pi - x).
"""

from __future__ import annotations

import math

import numpy as np
import sympy as sp
from ssmobs.models.base import StateSpaceModel

#: standard deviation of both noises
NOISE_SD = 0.3


class PhaseTracking(StateSpaceModel):
    """The phase-tracking model above (a test model, not a paper model)."""

    slug = "test_phase"
    title = "x_t = x_{t-1} + mu + 0.3 eta_t, z_t = b sin(x_t) + 0.3 eps_t"
    obs_dim = 1
    state_dim = 1
    param_names = ("mu", "b")
    default_prior = {"mu": "unrestricted", "b": "half_line"}
    allowed_priors = {"mu": ("unrestricted",), "b": ("half_line",)}

    def obs_term(self, omega, x, z):
        (_, b), (xt,), (zt,) = omega, x, z
        return (zt - b * sp.sin(xt)) ** 2 / NOISE_SD**2

    def trans_term(self, omega, x_prev, x):
        (mu, _), (xp,), (xt,) = omega, x_prev, x
        return (xt - xp - mu) ** 2 / NOISE_SD**2

    def initial_states(self, omega, z):
        """x_t = arcsin of z_t / b, clipped to [-1, 1]."""
        ratio = np.clip(np.asarray(z, dtype=float) / float(omega[1]), -1.0, 1.0)
        return np.arcsin(ratio)

    def simulate(self, omega, x0, eta, eps):
        mu, b = omega
        x = float(x0[0]) + np.cumsum(mu + NOISE_SD * eta, axis=1)
        return x, b * np.sin(x) + NOISE_SD * eps


#: the period the search must find
PERIOD = 2 * math.pi
