"""The size budget's memory estimates bound the memory the stages really allocate."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from ssmobs.config import budget
from ssmobs.config.scenario import Scenario
from ssmobs.design.disturbances import design_disturbances
from ssmobs.design.trajectories import make_trajectories
from ssmobs.joint_map.driver import joint_map
from ssmobs.joint_map.settings import JointMapSettings
from ssmobs.models import get_model

pytestmark = pytest.mark.unit


def peak_bytes(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("method", ["design", "random", "antithetic"])
def test_disturbance_estimate_bounds_the_measured_peak(method):
    q, K = 200, 2000
    used = peak_bytes(lambda: design_disturbances(q, K, method, seed=1, max_iter=3))
    assert used <= budget.disturbance_bytes(q, K, method)
    # and the estimate is not absurdly loose where the arrays dominate
    if method == "design":
        assert budget.disturbance_bytes(q, K, method) < 5 * used


@pytest.mark.parametrize(
    "slug,omega,x0",
    [
        ("same", {"a": 0.9}, 8.0),
        ("sep_d1_p2", {"a": 0.6, "b": 0.5, "c": 0.9, "d": 0.9}, [8.0, 8.0]),
    ],
)
def test_joint_map_estimate_bounds_the_measured_peak(slug, omega, x0):
    model = get_model(slug)
    T, K = 60, 1500
    q = (model.obs_dim + model.state_dim) * T
    matrix = np.random.default_rng(0).standard_normal((q, K))
    traj = make_trajectories(
        Scenario.from_config(
            {"name": "x", "model": slug, "omega": omega, "x0": x0, "T": T, "K": K}
        ),
        matrix,
    )
    bounds = model.prior_bounds(traj.omega, "restricted")
    used = peak_bytes(
        lambda: joint_map(
            model, traj.z, bounds, traj.omega, traj.x0, JointMapSettings(max_newton_iter=2)
        )
    )
    assert used <= budget.joint_map_bytes(model, T, K)
