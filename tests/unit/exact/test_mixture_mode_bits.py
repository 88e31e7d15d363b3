"""The mixture mode's Newton steps skip the trajectories at a fixed point and give the
numbers of all twelve steps on every trajectory to the bit (issue 48)."""

from __future__ import annotations

import numpy as np
import pytest
from ssmobs.exact.state_mixtures import _mixture_mode

pytestmark = pytest.mark.unit


def _reference_mode(w, mean, sdm, S, lo_m, hi_m, n_iter):
    """The loop as it was: every step on every trajectory."""
    x = mean[:, 0].copy()
    for _ in range(n_iter):
        u = (x[:, None] - mean) / sdm
        phi = w * np.exp(-0.5 * u * u) / sdm
        f = phi.sum(1)
        f1 = -(phi * u / sdm).sum(1)
        f2 = (phi * (u * u - 1) / sdm**2).sum(1)
        with np.errstate(all="ignore"):
            g = f1 / f
            gp = f2 / f - g * g
            step = np.where(gp < 0, -g / gp, np.sign(g) * S / 4)
        step = np.where(np.isfinite(step), step, 0.0)
        x = np.clip(x + np.clip(step, -S / 2, S / 2), lo_m, hi_m)
    return x


@pytest.mark.parametrize("n_states", [2, 51])
def test_mixture_mode_equals_all_steps_on_all_trajectories(n_states):
    rng = np.random.default_rng(n_states)
    K, G = 9, 40
    w = rng.uniform(0, 1, (K, G, n_states)) ** 4
    w[:, 0] = 1.0  # the heaviest first
    w /= w.sum(1, keepdims=True)
    mean = rng.normal(0, 1, (K, G, n_states))
    mean[:3] = mean[:3, :1] + 1e-3 * mean[:3]  # narrow mixtures: a fixed point after a few steps
    mean[3:5] *= 40  # far-apart components: steps cut to S / 2, a bimodal density
    sdm = rng.uniform(0.3, 2.0, (K, G, n_states))
    S = np.sqrt((w * (sdm**2 + mean**2)).sum(1) - (w * mean).sum(1) ** 2)
    lo_m, hi_m = mean.min(1), mean.max(1)
    ref = _reference_mode(w, mean, sdm, S, lo_m, hi_m, 12)
    got = _mixture_mode(w, mean, sdm, S, lo_m, hi_m, 12)
    assert np.array_equal(got.view(np.uint64), ref.view(np.uint64))
    # the fixture has trajectories that stop early and some that take all twelve steps
    early = _reference_mode(w, mean, sdm, S, lo_m, hi_m, 6)
    assert (early == ref).all(1).any() and not (early == ref).all()
