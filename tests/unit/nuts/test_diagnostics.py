"""Array-level diagnostics (ssmobs.nuts.diagnostics) on cases whose answer is known by hand."""

from __future__ import annotations

import numpy as np
import pytest
from ssmobs.nuts.diagnostics import ebfmi, rank_diagnostics

pytestmark = pytest.mark.unit


def test_iid_normal_draws_give_rhat_one_and_ess_about_n():
    # 4 chains x 2000 iid draws: R-hat -> 1 and ESS ~ 8000 (Monte Carlo spread ~ a few %)
    x = np.random.default_rng(0).standard_normal((6, 4, 2000))
    d = rank_diagnostics(x)
    assert np.all(np.abs(d["rhat"] - 1) < 0.005)
    assert np.all((d["ess_bulk"] > 0.85 * 8000) & (d["ess_bulk"] < 1.15 * 8000))
    assert np.all((d["ess_tail"] > 0.7 * 8000) & (d["ess_tail"] < 1.3 * 8000))


def test_chains_with_different_means_give_large_rhat():
    # two chains at 0 and two at 3 standard deviations: the between-chain variance dominates
    x = np.random.default_rng(1).standard_normal((1, 4, 1000))
    x[0, 2:] += 3.0
    d = rank_diagnostics(x)
    assert d["rhat"][0] > 1.5
    # the well-mixed control row stays at 1
    y = np.random.default_rng(1).standard_normal((1, 4, 1000))
    assert rank_diagnostics(y)["rhat"][0] < 1.01


def test_rhat_of_two_halves_by_hand():
    # one chain per row split in halves: first half all below, second all above the other
    # chain's values -> rank-normalised split R-hat far above 1; a trend inside a chain is
    # what the split detects (Vehtari et al. 2021, Sec. 3)
    x = np.concatenate([np.linspace(0, 1, 500), np.linspace(10, 11, 500)])[None, None, :]
    x = np.repeat(x, 2, axis=1) + np.random.default_rng(2).normal(0, 1e-3, (1, 2, 1000))
    assert rank_diagnostics(x)["rhat"][0] > 1.5


def test_strongly_autocorrelated_draws_have_small_ess():
    # AR(1) with phi = 0.9: ESS ~ N (1 - phi) / (1 + phi) = 8000 / 19 ~ 420
    rng = np.random.default_rng(3)
    e = rng.standard_normal((1, 4, 8000))
    x = np.empty_like(e)
    x[..., 0] = e[..., 0]
    for i in range(1, 8000):
        x[..., i] = 0.9 * x[..., i - 1] + np.sqrt(1 - 0.81) * e[..., i]
    x = x[..., 6000:]  # 4 x 2000
    ess = rank_diagnostics(x)["ess_bulk"][0]
    assert 8000 / 19 * 0.75 < ess < 8000 / 19 * 1.25


def test_constant_and_nan_rows():
    x = np.random.default_rng(4).standard_normal((3, 4, 100))
    x[0] = 2.5  # constant: R-hat 0/0 -> NaN (fails the check), ESS = all draws (ArviZ's rule)
    x[1, 0, 7] = np.nan  # a NaN anywhere -> NaN everywhere for that row
    d = rank_diagnostics(x)
    assert np.isnan(d["rhat"][0]) and d["ess_bulk"][0] == 400 and d["ess_tail"][0] == 400
    assert np.isnan([d[k][1] for k in d]).all()
    assert np.isfinite([d[k][2] for k in d]).all()


def test_too_few_draws_or_one_chain():
    x = np.random.default_rng(5).standard_normal((2, 1, 50))
    d = rank_diagnostics(x)
    assert np.isnan(d["rhat"]).all() and np.isfinite(d["ess_bulk"]).all()  # R-hat needs 2 chains
    d = rank_diagnostics(np.zeros((2, 4, 3)) + np.arange(3.0))
    assert all(np.isnan(v).all() for v in d.values())  # fewer than 4 draws


def test_chunking_does_not_change_results():
    x = np.random.default_rng(6).standard_normal((40, 4, 200)).cumsum(axis=2)
    together = rank_diagnostics(x)
    one_by_one = [rank_diagnostics(x[i : i + 1]) for i in range(40)]
    for k in together:
        np.testing.assert_allclose(together[k], [r[k][0] for r in one_by_one], rtol=1e-12)


def test_ebfmi_by_hand():
    # E = [0, 2, 0, 2]: mean(diff^2) = 4, var(ddof=1) = 4/3 -> E-BFMI 3
    assert ebfmi(np.array([[0.0, 2.0, 0.0, 2.0]]))[0] == pytest.approx(3.0)
    # a slowly moving energy (random walk) has a small E-BFMI
    walk = np.random.default_rng(7).standard_normal((2, 2000)).cumsum(axis=1)
    assert (ebfmi(walk) < 0.3).all()


def test_rank_rhat_of_chains_in_separate_modes_is_a_fixed_value():
    """docs/reproducing-the-paper.md reads the failed runs' largest R-hat this way: with rank
    normalisation, one chain of four apart from the other three gives 1.528 whatever the
    distance between the modes, two apart from two 1.733."""
    x = np.random.default_rng(0).standard_normal((4, 6000))
    for shift, rhat in (
        ([0, 0, 0, 100], 1.528),
        ([0, 0, 0, 1e4], 1.528),
        ([0, 0, 100, 100], 1.733),
    ):
        got = rank_diagnostics((x + np.array(shift, float)[:, None])[None])["rhat"][0]
        assert got == pytest.approx(rhat, abs=0.001)
