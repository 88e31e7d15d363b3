"""Issue 12: barrier start by gradient balance, the mu0 sweep table, the sign-consistent start."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from ssmobs.config import validation as cfg
from ssmobs.config.scenario import Scenario
from ssmobs.design.trajectories import make_trajectories, write_trajectories
from ssmobs.joint_map.barrier import LogBarrier, initial_mu_values
from ssmobs.joint_map.driver import initial_theta, joint_map
from ssmobs.joint_map.problem import JointMapProblem
from ssmobs.joint_map.settings import JointMapSettings
from ssmobs.models import get_model

pytestmark = pytest.mark.unit


def design(slug, omega, x0, T, K, seed=0):
    model = get_model(slug)
    rng = np.random.default_rng(seed)
    matrix = rng.standard_normal(((model.obs_dim + model.state_dim) * T, K))
    return model, matrix, *model.design_trajectories(omega, x0, matrix, T)


def test_gradient_balance_mu0_equals_the_hand_computed_ratio_for_sep():
    """(Sep, d=p=1) at the start (a, b, x0, x = z): the b-gradient of -2 pi is
    -2 S / (1 + b)^2 - 2 T b / (1 - b^2), S = sum z_t^2, and the barrier's is
    -1/b + 1/(1 - b); a's gradient is computed by the model.  mu_0 = |g_f| / |g_B|."""
    model, _, x, z = design("sep", [0.9, 0.9], [8.0], T=30, K=3, seed=1)
    bounds = model.prior_bounds([0.9, 0.9])
    theta0 = initial_theta(model, z, np.array([0.9, 0.9]), np.array([8.0]))
    mu0 = initial_mu_values(model, z, theta0, LogBarrier(model, bounds), JointMapSettings())
    from ssmobs.models.log_posterior import neg2_log_posterior

    g = neg2_log_posterior(model, theta0, z, None, order=1)[1]
    S = (z[:, :, 0] ** 2).sum(axis=1)
    b, T = 0.9, 30
    assert np.allclose(g[:, 1], -2 * S / (1 + b) ** 2 - 2 * T * b / (1 - b**2))
    gb = np.array([-1 / 0.9 + 1 / 0.1] * 2)  # a and b both restricted to (0, 1)
    expect = np.linalg.norm(g[:, :2], axis=1) / np.linalg.norm(gb)
    assert np.allclose(mu0, expect)
    assert np.all(mu0 > T)  # here the balance lands above the singular term's order T
    per_step = initial_mu_values(
        model, z, theta0, LogBarrier(model, bounds), JointMapSettings(mu0_rule="per_step")
    )
    assert np.all(per_step == 60.0)


def test_mu0_rule_changes_the_start_and_is_reported():
    model, _, x, z = design("sep", [0.9, 0.9], [8.0], T=40, K=6, seed=2)
    bounds = model.prior_bounds([0.9, 0.9])
    res = joint_map(JointMapProblem(model, z, bounds, [0.9, 0.9], [8.0]))
    frame = res.to_frame(model, 40)
    assert np.all(frame["mu0"] > 0) and frame["mu0"].nunique() == 6  # one per trajectory
    low = joint_map(
        JointMapProblem(
            model,
            z,
            bounds,
            [0.9, 0.9],
            [8.0],
            JointMapSettings(mu0_rule="per_step", mu0=0.1, mu0_per_step=0.0),
        )
    )
    assert np.all(low.mu_start == 0.1)
    # a start far below T lets the first Newton steps fall into the singular edge b -> 1
    assert (low.status == "ok").sum() <= (res.status == "ok").sum()
    with pytest.raises(ValueError, match="mu0_rule"):
        JointMapSettings(mu0_rule="guess")


def test_mu0_sweep_table_is_made_by_the_stage(tmp_path):
    from ssmobs.stages.outputs.mu0_sweep import run_joint_map_mu0_sweep

    sc = Scenario.from_config(
        {
            "name": "sep_small",
            "model": "sep",
            "omega": {"a": 0.9, "b": 0.9},
            "x0": 8.0,
            "T": 30,
            "K": 5,
            "prior": "restricted",
            "paper_ref": "sep_ab_T75",
        }
    )
    model, matrix, _, _ = design("sep", [0.9, 0.9], [8.0], T=30, K=5, seed=3)
    traj = make_trajectories(sc, matrix)
    write_trajectories(tmp_path / "t.nc", traj)
    frame = run_joint_map_mu0_sweep(
        {"sep_small": tmp_path / "t.nc"},
        {"sep_small": sc},
        {},
        [0.5, 2.0],
        "config/paper_values.yaml",
        [tmp_path / "sweep.csv", tmp_path / "sweep.md"],
    )
    assert frame["mu0"].tolist() == ["gradient balance", "0.5 T", "2 T", "paper"]
    col = "sep_small K^max/K"
    assert frame[col].iloc[:3].between(0, 1).all()
    assert np.isclose(frame[col].iloc[3], 1956 / 4000)
    # every fraction with its exact binomial 95 % interval (the paper's too, at its K)
    lo, hi = frame[f"{col} lo95"], frame[f"{col} hi95"]
    assert ((lo <= frame[col]) & (frame[col] <= hi)).all()
    assert hi.iloc[3] - lo.iloc[3] < 0.035 < (hi.iloc[:3] - lo.iloc[:3]).min()  # K 4000 vs 5
    assert (tmp_path / "sweep.md").read_text().count("lo95") == 1
    # the row "2 T" is the former default rule, recomputed here by hand
    direct = joint_map(
        JointMapProblem(
            model,
            traj.z,
            model.prior_bounds([0.9, 0.9], "restricted"),
            [0.9, 0.9],
            [8.0],
            JointMapSettings(mu0_rule="per_step"),
        )
    )
    assert np.isclose(frame[col].iloc[2], (direct.status == "ok").mean())
    text = (tmp_path / "sweep.md").read_text()
    assert "gradient balance" in text and "paper" in text
    back = pd.read_csv(tmp_path / "sweep.csv")
    assert back.shape[0] == 4 and f"{'sep_small'} mu0/T" in back.columns


def test_sign_consistent_start_for_sep_mult():
    model, _, x, z = design("sep_mult", [0.9], [8.0], T=20, K=4, seed=5)
    theta0 = initial_theta(model, z, np.array([0.9]), np.array([8.0]), "sign_of_x0")
    assert np.all(theta0[:, 2:] >= 0)
    assert np.allclose(theta0[:, 2:], np.abs(z[:, :, 0]) / np.sqrt(0.9))
    paper = initial_theta(model, z, np.array([0.9]), np.array([8.0]))
    assert np.allclose(paper[:, 2:], z[:, :, 0]) and (paper[:, 2:] < 0).any()
    with pytest.raises(NotImplementedError):
        get_model("same").sign_consistent_states(np.array([0.9]), np.array([8.0]), z)


def test_config_accepts_joint_map_start_only_where_defined_and_the_mu0_settings():
    base = {
        "name": "m",
        "model": "sep_mult",
        "omega": {"a": 0.9},
        "x0": 8,
        "T": 5,
        "K": 4,
        "joint_map_start": "sign_of_x0",
    }
    c = cfg.validate(
        {
            "scenarios": [base],
            "joint_map": {"mu0_rule": "per_step", "mu0_per_step": 2.0, "mu0": 1.0},
        }
    )
    assert JointMapSettings.from_mapping(c["joint_map"]).initial_mu(50) == 100.0
    with pytest.raises(cfg.ConfigError, match="joint_map_start"):
        cfg.validate({"scenarios": [{**base, "model": "same"}]})
    with pytest.raises(cfg.ConfigError, match="mu0_rule"):
        cfg.validate({"scenarios": [base], "joint_map": {"mu0_rule": "tuned"}})
