"""|K^Stan|, mean/var/MSE/Cover90 of Omega and x0, and state averages on hand-made records."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ssmobs.models import get_model
from ssmobs.nuts.record_format import records_to_frame
from ssmobs.nuts.stan_metrics import stan_summary

pytestmark = pytest.mark.unit


def rec(k, converged, map_, q5, q95, names):
    return {
        "record_version": 1,
        "key": {"scenario": "s", "k": k, "stan_seed": 100 + k},
        "k": k,
        "scenario": "s",
        "status": "ok",
        "converged": converged,
        "failed_checks": [] if converged else ["rhat"],
        "reason": None if converged else "rhat: ...",
        "diagnostics": {
            "max_rhat": 1.001,
            "min_ess_bulk": 900.0,
            "min_ess_tail": 800.0,
            "n_divergent": 0,
            "n_treedepth_hits": 0,
            "min_ebfmi": 0.7,
        },
        "theta_names": names,
        "map": map_,
        "q5": q5,
        "q95": q95,
    }


@pytest.fixture()
def same_case():
    """Model same, T = 2, K = 4; k = 2 did not converge (its numbers must be ignored).

    Theta = (a, x0, x1, x2); a_true = 0.9, x0_true = 8; design states x~(k) below.
    """
    model = get_model("same")
    names = model.theta_names(2)
    records = [
        #   k  conv   map (a, x0, x1, x2)     q5                      q95
        rec(0, True, [0.88, 7.5, 1.5, 2.0], [0.85, 7.0, 1.0, 1.5], [0.95, 9.0, 2.0, 2.5], names),
        rec(1, True, [0.92, 8.5, 3.0, 3.0], [0.90, 8.1, 2.0, 2.0], [0.95, 9.0, 4.0, 4.5], names),
        rec(2, False, [0.50, 0.0, 9.0, 9.0], [0.10, -5, 0.0, 0.0], [0.99, 5.0, 99.0, 99.0], names),
        rec(3, True, [0.91, 8.0, 5.0, 7.0], [0.80, 7.9, 4.0, 6.5], [0.89, 8.1, 6.0, 7.5], names),
    ]
    x_true = np.array([[1.0, 2.0], [3.0, 4.0], [0.0, 0.0], [5.0, 6.0]])[:, :, None]
    return model, records, x_true


def test_hand_computed_answers(same_case):
    model, records, x_true = same_case
    frame = records_to_frame(records[::-1], model, 2)  # order of records does not matter
    out = stan_summary(frame, model, [0.9], 8.0, x_true)
    assert (out["K"], out["n_stan"], out["ratio"]) == (4, 3, 0.75)
    # a: MAPs 0.88, 0.92, 0.91
    assert out["a_true"] == 0.9
    assert out["a_mean"] == pytest.approx(2.71 / 3)
    assert out["a_var"] == pytest.approx((0.023333333**2 + 0.016666667**2 + 0.006666667**2) / 2)
    assert out["a_bias"] == pytest.approx(2.71 / 3 - 0.9)
    assert out["a_mse"] == pytest.approx((0.0004 + 0.0004 + 0.0001) / 3)
    # (0.85, 0.95) covers 0.9; (0.90, 0.95) does not (strict <); (0.80, 0.89) does not
    assert out["a_cover90"] == pytest.approx(1 / 3)
    # x0: MAPs 7.5, 8.5, 8.0
    assert out["x0_mean"] == pytest.approx(8.0)
    assert out["x0_var"] == pytest.approx(0.25)
    assert out["x0_mse"] == pytest.approx(0.5 / 3)
    assert out["x0_cover90"] == pytest.approx(2 / 3)
    # states: errors t=1: 0.5, 0, 0; t=2: 0, -1, 1
    assert out["x_abs_bias_mean"] == pytest.approx((0.5 / 3 + 0.0) / 2)
    assert out["x_mse_mean"] == pytest.approx((0.25 / 3 + 2 / 3) / 2)
    # cover t=1: (1,2) misses 1 (strict), (2,4) and (4,6) hit; t=2: hit, hit, (6.5,7.5) misses 6
    assert out["x_cover90_mean"] == pytest.approx(2 / 3)


def test_sequence_truth_and_frame_columns(same_case):
    model, records, x_true = same_case
    frame = records_to_frame(records, model, 2)
    assert list(frame["k"]) == [0, 1, 2, 3]
    assert list(frame.columns[:7]) == [
        "k",
        "scenario",
        "stan_seed",
        "status",
        "converged",
        "failed_checks",
        "reason",
    ]
    assert "x2_q95" in frame.columns and frame.loc[2, "failed_checks"] == "rhat"
    a = stan_summary(frame, model, np.array([0.9]), 8.0, x_true)
    b = stan_summary(frame, model, [0.9], [8.0], x_true[:, :, 0])
    assert a == b


def test_no_converged_trajectory_gives_nan(same_case):
    model, records, x_true = same_case
    for r in records:
        r["converged"] = False
    out = stan_summary(records_to_frame(records, model, 2), model, [0.9], 8, x_true)
    assert out["n_stan"] == 0 and out["ratio"] == 0.0
    assert all(
        math.isnan(out[k])
        for k in ("a_mean", "a_var", "a_mse", "a_cover90", "x_mse_mean", "x_cover90_mean")
    )


def test_single_converged_trajectory_has_nan_variance(same_case):
    model, records, x_true = same_case
    out = stan_summary(records_to_frame(records[:1], model, 2), model, [0.9], 8, x_true)
    assert out["n_stan"] == 1 and math.isnan(out["a_var"])
    assert out["a_mse"] == pytest.approx(0.0004)


def test_failed_runs_without_estimates_are_allowed(same_case):
    model, records, x_true = same_case
    records[2].update(map=None, q5=None, q95=None, diagnostics=None, status="error")
    frame = records_to_frame(records, model, 2)
    assert math.isnan(frame.loc[2, "a_map"]) and math.isnan(frame.loc[2, "max_rhat"])
    assert stan_summary(frame, model, [0.9], 8, x_true)["n_stan"] == 3


def test_two_state_components():
    """(Sep, d=1, p=2): per-component state averages and the overall mean over t and i."""
    model = get_model("sep_d1_p2")
    T = 1
    names = model.theta_names(T)  # a b c d x0_1 x0_2 x1_1 x1_2
    omega = [0.6, 0.5, 0.9, 0.9]  # a b c d
    base = [0.6, 0.5, 0.9, 0.9, 8.0, 8.0]
    lo = [v - 0.1 for v in base]
    hi = [v + 0.1 for v in base]
    records = [
        rec(0, True, base + [1.0, 2.0], lo + [0.0, 2.5], hi + [2.0, 3.0], names),
        rec(1, True, base + [3.0, 1.0], lo + [2.0, 0.0], hi + [4.0, 2.0], names),
    ]
    x_true = np.array([[[1.5, 2.0]], [[3.5, 1.0]]])  # (K=2, T=1, p=2)
    out = stan_summary(records_to_frame(records, model, T), model, omega, [8, 8], x_true)
    assert out["x0_1_mse"] == 0.0 and out["d_cover90"] == 1.0
    assert out["x1_abs_bias_mean"] == pytest.approx(0.5)  # errors -0.5, -0.5
    assert out["x2_abs_bias_mean"] == 0.0
    assert out["x1_mse_mean"] == pytest.approx(0.25)
    assert out["x2_cover90_mean"] == pytest.approx(0.5)  # (2.5,3) misses 2, (0,2) hits 1
    assert out["x_mse_mean"] == pytest.approx(0.125)
    assert out["x_cover90_mean"] == pytest.approx(0.75)


def test_mismatched_truth_is_rejected(same_case):
    model, records, x_true = same_case
    frame = records_to_frame(records, model, 2)
    with pytest.raises(ValueError):
        stan_summary(frame, model, [0.9], [8, 8], x_true)
    with pytest.raises(IndexError):
        stan_summary(frame, model, [0.9], 8, x_true[:2])
