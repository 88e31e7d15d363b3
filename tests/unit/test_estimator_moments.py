"""One definition of an estimator's mean, variance, bias and MSE (Tables II and III), and
the typed summary every stage's statistics are read back with."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ssmobs.estimator_moments import (
    MOMENTS,
    EstimatorSummary,
    estimator_moments,
    moment_entries,
)

pytestmark = pytest.mark.unit


def test_moments_by_their_definitions():
    est = np.array([0.8, 0.9, 1.0, 1.3])
    out = estimator_moments(est, 0.9)
    assert list(out) == list(MOMENTS)
    assert out["mean"] == pytest.approx(1.0)
    assert out["var"] == pytest.approx(np.sum((est - 1.0) ** 2) / 3)  # ddof = 1
    assert out["bias"] == pytest.approx(0.1)
    assert out["mse"] == pytest.approx(out["var"] * 3 / 4 + 0.1**2)  # MSE = var (ddof 0) + bias^2


def test_undefined_moments_are_nan():
    none = estimator_moments(np.array([]), 0.5)
    assert all(math.isnan(v) for v in none.values())
    one = estimator_moments(np.array([0.7]), 0.5)
    assert math.isnan(one["var"]) and one["mse"] == pytest.approx(0.04)


def test_summary_reads_back_what_the_stages_write():
    """The keys moment_entries writes are the ones EstimatorSummary reads, for each stage."""
    values = {"K": 5, "n_stan": 4, **moment_entries("a", [0.8, 1.0], 0.9), "x_cover90_mean": 0.85}
    summ = EstimatorSummary.read("stan", values)
    assert summ.present and summ.count == 4 and summ.get("K") == 5
    assert summ.stat("a", "mean") == pytest.approx(0.9) and summ.stat("a", "mse") == pytest.approx(
        0.01
    )
    assert summ.states("cover90") == 0.85
    assert math.isnan(summ.stat("x0", "mean")) and math.isnan(summ.states("mse"))
    assert EstimatorSummary.read("joint", {"K_max": 3}).count == 3
    assert EstimatorSummary.read("exact", {"n_exact": 2}).count == 2


def test_absent_summary_is_nan_everywhere():
    summ = EstimatorSummary.read("joint", None)
    assert not summ.present
    assert math.isnan(summ.count) and math.isnan(summ.stat("a", "mean"))
    with pytest.raises(ValueError, match="unknown stage 'gibbs'"):
        EstimatorSummary("gibbs")
