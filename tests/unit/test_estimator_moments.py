"""One definition of an estimator's mean, variance, bias and MSE (Tables II and III)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ssmobs.estimator_moments import MOMENTS, estimator_moments

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
