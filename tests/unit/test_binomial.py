"""Clopper-Pearson intervals of the observability fractions (ssmobs.binomial)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from ssmobs.binomial import clopper_pearson, format_fraction


@pytest.mark.parametrize("x,n", [(0, 40), (1, 40), (20, 40), (34, 40), (40, 40), (2972, 4000)])
def test_equals_scipy_binomtest_exact_interval(x, n):
    ci = stats.binomtest(x, n).proportion_ci(confidence_level=0.95, method="exact")
    assert np.allclose(clopper_pearson(x, n), (ci.low, ci.high), rtol=0, atol=1e-12)


def test_width_at_k_40_is_about_plus_minus_015():
    lo, hi = clopper_pearson(20, 40)
    assert 0.14 < 0.5 - lo < 0.17 and 0.14 < hi - 0.5 < 0.17
    lo, hi = clopper_pearson(2000, 4000)  # the paper's K: about +-0.016
    assert hi - lo < 0.035


def test_ends_and_missing_counts():
    assert clopper_pearson(0, 6)[0] == 0.0 and clopper_pearson(6, 6)[1] == 1.0
    assert all(math.isnan(v) for v in clopper_pearson(math.nan, 40))
    assert all(math.isnan(v) for v in clopper_pearson(3, 0))
    assert format_fraction(math.nan, 40) == ""
    assert format_fraction(20, 40) == "0.50 [0.34, 0.66]"


@pytest.mark.parametrize("x,n", [(5, 4), (-1, 4), (1.5, 4)])
def test_impossible_counts_are_refused(x, n):
    with pytest.raises(ValueError, match="whole counts"):
        clopper_pearson(x, n)
