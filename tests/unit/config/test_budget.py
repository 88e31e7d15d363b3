"""The size budget's memory estimates bound the memory the stages really allocate."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from repo_paths import REPO_DIR
from ssmobs.config import budget
from ssmobs.config.scenario import Scenario
from ssmobs.design.disturbances import design_disturbances
from ssmobs.design.trajectories import make_trajectories
from ssmobs.joint_map.driver import joint_map
from ssmobs.joint_map.problem import JointMapProblem
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
            JointMapProblem(
                model, traj.z, bounds, traj.omega, traj.x0, JointMapSettings(max_newton_iter=2)
            )
        )
    )
    assert used <= budget.joint_map_bytes(model, T, K)


# ------------------------------------------------------------------------ time budget
def test_joint_map_time_estimate_bounds_the_measured_cpu():
    """K trajectories x 2 starts of the model measured slowest per Theta component
    ((Sep, d=1, p=2)): the CPU the multi-start really takes stays below the estimate."""
    import time

    from ssmobs.joint_map.multi_start import multi_start_joint_map

    slug, omega, x0, T, K = "sep_d1_p2", [0.6, 0.5, 0.9, 0.9], [8.0, 8.0], 60, 10
    model = get_model(slug)
    q = (model.obs_dim + model.state_dim) * T
    _, z = model.design_trajectories(omega, x0, np.random.default_rng(0).standard_normal((q, K)), T)
    bounds = model.prior_bounds(omega)
    start = time.process_time()
    multi_start_joint_map(
        JointMapProblem(
            model, z, bounds, np.asarray(omega), np.asarray(x0), JointMapSettings(n_starts=2)
        )
    )
    used = time.process_time() - start
    assert used <= K * 2 * budget.joint_map_start_seconds(model, T)


def n_starts_config(n_starts: int) -> dict:
    entry = {"name": "s", "model": "same", "omega": {"a": 0.9}, "x0": 8, "T": 20, "K": 100}
    return {"scenarios": [entry], "joint_map": {"n_starts": n_starts}}


def test_a_million_starts_are_refused_with_the_estimate_and_the_rule():
    from ssmobs.config import validation as cfg

    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(n_starts_config(1_000_000))
    lines = str(err.value).splitlines()
    assert len(lines) == 2, lines
    hours = 100 * 1_000_000 * budget.joint_map_start_seconds(get_model("same"), 20) / 3600
    assert lines[1].startswith(
        f"  - the joint-MAP starts of the run would take about {hours:.3g} CPU hours "
        f"(largest: scenario 's': {hours:.3g}), more than limits.joint_map_cpu_hours = 48; "
        f"the estimate is K x n_starts x 2 ms per component of Theta"
    )
    assert "reduce joint_map.n_starts (now 1000000)" in lines[1]
    assert hours > 500  # weeks of CPU
    # the scenario's own n_starts counts, the block's is overridden
    config = n_starts_config(1)
    config["scenarios"][0]["joint_map_n_starts"] = 1_000_000
    with pytest.raises(cfg.ConfigError, match="joint-MAP starts of the run would take"):
        cfg.validate(config)
    config["limits"] = {"joint_map_cpu_hours": 1e4}
    assert cfg.validate(config)["scenarios"][0]["joint_map_n_starts"] == 1_000_000


def test_a_map_counts_every_cell_and_a_scenario_without_joint_map_none():
    from ssmobs.config import validation as cfg

    config = cfg.validate(n_starts_config(8))
    config["scenarios"].append({**config["scenarios"][0], "name": "t", "joint_map": False})
    config["observability_maps"] = [
        {"name": "m", "base": {"model": "same"}, "values": [0.5, 0.9], "T": [4, 20], "K": 10}
    ]
    seconds = budget.joint_map_cpu_seconds(config)
    same = get_model("same")
    assert set(seconds) == {"scenario 's'", "observability map 'm'"}
    assert seconds["scenario 's'"] == 100 * 8 * budget.joint_map_start_seconds(same, 20)
    cells = 2 * (budget.joint_map_start_seconds(same, 4) + budget.joint_map_start_seconds(same, 20))
    assert seconds["observability map 'm'"] == pytest.approx(10 * 8 * cells)


def test_every_committed_profile_fits_the_time_budget():
    import yaml
    from ssmobs.config import validation as cfg

    profiles = [*(REPO_DIR / "config").glob("*.yaml"), *(REPO_DIR / "config").glob("*/*.yaml")]
    for path in sorted(profiles):
        raw = yaml.safe_load(path.read_text())
        if not isinstance(raw, dict) or "scenarios" not in raw:
            continue
        config = cfg.validate(raw)
        hours = sum(budget.joint_map_cpu_seconds(config).values()) / 3600
        assert hours <= 1.4, (path.name, hours)  # config/README.md says so
