"""Joint MAPs that do not converge (issue 47): ``unbounded`` (the density keeps rising as
Theta runs off, with the direction), ``ridge`` (a flat direction), or ``gradient`` (only
slow), told apart by following the run (:func:`ssmobs.joint_map.checks.runoff_check`)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from cubic_sensor_model import CubicSensor
from ricker_model import Ricker
from ssmobs.joint_map.checks import STATUSES, runoff_direction
from ssmobs.joint_map.driver import joint_map
from ssmobs.joint_map.problem import JointMapProblem
from ssmobs.joint_map.settings import JointMapSettings
from ssmobs.models import get_model

pytestmark = pytest.mark.unit


def trajectories(model, omega, x0, T, K, seed):
    rng = np.random.default_rng(seed)
    q = (model.obs_dim + model.state_dim) * T
    return model.design_trajectories(omega, x0, rng.standard_normal((q, K)), T)[1]


@pytest.mark.parametrize("limit", [1e6, 1e8])
def test_cubic_sensor_has_no_maximum_and_says_it_runs_off(limit):
    """Flat priors on b (0, inf) and x0: along (a, b / s^3, s x0, s x) -2 pi falls as s -> 0,
    so every run is unbounded, in the direction b -> +inf, whatever divergence_limit."""
    model = CubicSensor()
    omega, x0 = np.array([0.5, 0.8]), np.array([1.0])
    z = trajectories(model, omega, x0, T=20, K=12, seed=0)
    bounds = model.prior_bounds(omega, {"b": "half_line"})
    res = joint_map(
        JointMapProblem(model, z, bounds, omega, x0, JointMapSettings(divergence_limit=limit))
    )
    assert Counter(res.status) == {"unbounded": 12}
    assert all("b -> +inf" in r for r in res.reason)
    assert "unbounded" in STATUSES


def test_ricker_with_unknown_detection_rate_is_a_ridge():
    """(a, b e^-d, c e^-d, x0 + d, x + d) leaves the density unchanged: a flat direction,
    reported as ridge, never as unbounded or gradient, and never ok."""
    model = Ricker()
    omega, x0 = np.array([1.0, 0.1, 1.0]), np.array([2.0])
    z = trajectories(model, omega, x0, T=50, K=10, seed=0)
    res = joint_map(
        JointMapProblem(model, z, model.prior_bounds(omega), omega, x0, JointMapSettings())
    )
    assert Counter(res.status) == {"ridge": 10}
    assert all("flat direction" in r or "ridge" in r for r in res.reason)


def test_a_run_that_only_needed_more_iterations_stays_gradient():
    """(Same, a = 0.9), 3 Newton iterations: not converged, but the continued run passes
    the checks: the status stays ``gradient`` and the reason says so."""
    model = get_model("same")
    z = trajectories(model, [0.9], [8.0], T=10, K=6, seed=4)
    bounds = model.prior_bounds([0.9], "restricted")
    full = joint_map(JointMapProblem(model, z, bounds, [0.9], [8.0]))
    short = joint_map(
        JointMapProblem(model, z, bounds, [0.9], [8.0], JointMapSettings(max_newton_iter=3))
    )
    assert full.ok.all()
    slow = short.status == "gradient"
    assert slow.sum() >= 4
    assert all("raise max_newton_iter" in r for r in short.reason[slow])
    assert not np.isin(short.status, ["unbounded", "ridge"]).any()


def test_runoff_direction_names_the_fastest_changing_components():
    model = CubicSensor()  # Theta = (b, a, x0, x1, x2)
    before = np.array([1e3, 0.5, 0.1, 0.2, -0.2])
    after = np.array([8e3, 0.55, 0.05, 0.1, -0.1])  # log ratios 2.1, 0.1, -0.7, -0.7
    assert runoff_direction(model, before, after) == "b -> +inf"
    after[2:] = [0.01, 0.02, -0.02]  # log ratios -2.3 for x0 and x
    assert runoff_direction(model, before, after) == "b -> +inf, x0 -> 0, x -> 0"
    assert runoff_direction(model, before, before) == ""


@pytest.mark.parametrize("limit", [1e4, 1e6])
def test_a_ridge_that_passes_the_divergence_limit_is_a_ridge_wherever_the_limit_cuts(limit):
    """Issue 60: passing |Theta| > divergence_limit is no gain.  Along the Ricker model's
    exact ridge runs pass any limit (c -> +inf, x -> -inf) without the density rising; the
    continued run measures -2 pi and finds the flat direction.  Before, trajectory 13 of
    this set said ``unbounded`` at the default limit, and which ones did depended on where
    the limit cut the run."""
    model = Ricker()
    omega, x0 = np.array([1.0, 0.1, 1.0]), np.array([2.0])
    z = trajectories(model, omega, x0, T=50, K=20, seed=1)
    res = joint_map(
        JointMapProblem(
            model, z, model.prior_bounds(omega), omega, x0, JointMapSettings(divergence_limit=limit)
        )
    )
    assert Counter(res.status) == {"ridge": 20}
    passed = [k for k in range(20) if "passed divergence_limit" in res.reason[k]]
    assert 13 in passed  # |Theta| passed the limit, and the label is still ridge
    assert len(passed) >= (2 if limit < 1e5 else 1)


def test_runoff_settings_are_checked():
    with pytest.raises(ValueError, match="runoff_margin"):
        JointMapSettings(runoff_margin=0.5)
    with pytest.raises(ValueError, match="runoff_reach"):
        JointMapSettings(runoff_reach=float("inf"))


@pytest.mark.parametrize(
    ("gains", "growth", "expected"),
    [
        ((2.0, 2.0), 1.2, "unbounded"),  # gains above tol in both segments, outward
        ((2.0, 2.0), 1.04, "gradient"),  # gains, but no magnitude grew by 10 % (1.04^2)
        ((2.0, 0.5), 1.2, "gradient"),  # the second change between tol / 100 and tol
        ((2.0, 0.001), 1.2, "ridge"),  # the second flat (below tol / 100) while moving
    ],
)
def test_runoff_labels_keep_a_margin_between_a_gain_and_flat(monkeypatch, gains, growth, expected):
    """runoff_check's decision on controlled continued segments (the solver, -2 pi and the
    checks at their ends replaced): -2 pi falls by gains[i] * tol in segment i, where
    tol = ridge_value_tol (1 + |-2 pi|), and every component grows by ``growth`` per segment."""
    from ssmobs.joint_map import checks

    model = get_model("same")
    settings = JointMapSettings()
    theta = np.array([[0.5, 1.0, 1.0, 1.0]])
    f_hat = np.array([10.0])
    tol = settings.ridge_value_tol * (1 + 10.0)
    values = iter([10.0 - gains[0] * tol, 10.0 - (gains[0] + gains[1]) * tol])

    def fake_minimize(model, z, start, barrier, cont, mu, divergence_limit=None):
        assert cont.max_newton_iter == settings.runoff_iter
        return start * growth, np.zeros(1), np.full(1, mu), np.array(["max-iter"], dtype=object)

    def fake_checks(model, z, new, mu, stop, barrier, cont, follow_runoff=True):
        assert not follow_runoff
        return {"status": np.array(["gradient"], dtype=object), "reason": np.array(["slow"])}

    monkeypatch.setattr(checks, "minimize_barrier", fake_minimize)
    monkeypatch.setattr(checks, "neg2_log_posterior", lambda *a, **k: (np.array([next(values)]),))
    monkeypatch.setattr(checks, "check_maxima", fake_checks)
    monkeypatch.setattr(
        checks, "_smallest_eigenpair", lambda *a: (np.ones(1), np.ones(1), np.zeros((1, 4)))
    )
    barrier = checks.LogBarrier(model, model.prior_bounds([0.9], "restricted"))
    z = np.zeros((1, 3, 1))
    status, reason = checks.runoff_check(model, z, theta, f_hat, barrier, settings)
    assert status[0] == expected, reason[0]
