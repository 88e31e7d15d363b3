"""Marginal MAP by binned FFT KDE (Eq. (11)) and the 90 % intervals (Eq. (12))."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from ssmobs.models import get_model
from ssmobs.nuts.marginal_map import (
    KDEError,
    binned_kde,
    kde_mode,
    kde_modes,
    marginal_summary,
    silverman_bandwidth,
    theta_draws,
)
from ssmobs.stan_backends.base import Draws

pytestmark = pytest.mark.unit

R = 24_000  # the paper's number of kept draws (4 chains x 6 000)


def test_gamma_mode_within_tolerance():
    """Gamma(3, 1) has its mode at 2 and is clearly skewed.

    With R = 24 000 iid draws the KDE mode has a Monte Carlo sd of about 0.12 (measured,
    40 replicates) and a smoothing bias of about h^2/2 = 0.02 (h ~ 0.2, Silverman's rule).
    Stated tolerance: each of 10 replicates within 0.4 (> 3 sd) of 2, and their mean within
    0.1 (> 2.5 sd of a mean of 10 plus the bias).
    """
    rng = np.random.default_rng(20240101)
    modes = np.array([kde_mode(rng.gamma(3.0, 1.0, R)) for _ in range(10)])
    assert np.all(np.abs(modes - 2.0) < 0.4), modes
    assert abs(modes.mean() - 2.0) < 0.1, modes.mean()


def test_normal_and_beta_modes():
    rng = np.random.default_rng(7)
    assert kde_mode(rng.normal(5.0, 2.0, R)) == pytest.approx(5.0, abs=0.3)
    # beta(18, 2): mode 17/18 near the bound 1, left-skewed; sd of the draws 0.049
    modes = [kde_mode(rng.beta(18, 2, R)) for _ in range(5)]
    assert np.mean(modes) == pytest.approx(17 / 18, abs=0.015)


def test_binned_kde_matches_exact_gaussian_kde():
    """Binning + FFT vs the exact O(n * grid) sum with the same bandwidth."""
    rng = np.random.default_rng(1)
    x = rng.gamma(3.0, 1.0, 5000)
    lo, delta, dens = binned_kde(x)
    bw = silverman_bandwidth(x)[0]
    grid = lo[0] + delta[0] * np.arange(dens.shape[1])
    exact = stats.gaussian_kde(x, bw_method=bw / x.std(ddof=1))(grid)
    assert np.max(np.abs(dens[0] - exact)) < 1e-3 * exact.max()
    assert dens[0].sum() * delta[0] == pytest.approx(1.0, abs=1e-6)


def test_mode_agrees_with_arviz_kde():
    """Same draws: our mode and ArviZ's KDE's differ by far less than the Monte Carlo sd (0.12)."""
    from arviz_stats.base import array_stats

    x = np.random.default_rng(3).gamma(3.0, 1.0, R)
    g, d, _ = array_stats.kde(x)
    assert kde_mode(x) == pytest.approx(g[np.argmax(d)], abs=0.12)


def test_vectorised_modes_equal_one_by_one():
    rng = np.random.default_rng(2)
    m = np.stack([rng.normal(1, 1, 4000), rng.gamma(2, 3, 4000), rng.normal(-50, 0.01, 4000)])
    assert np.allclose(kde_modes(m), [kde_mode(r) for r in m], rtol=0, atol=1e-3 * m.std(axis=1))


def test_heavy_tails_keep_a_fine_grid():
    x = np.random.default_rng(4).standard_cauchy(R)
    assert abs(kde_mode(x)) < 0.1


@pytest.mark.parametrize(
    "bad,match",
    [
        (np.full(100, 3.0), "zero spread"),
        (np.r_[np.ones(50), np.nan], "non-finite"),
        (np.r_[np.ones(50), np.inf, 2.0], "non-finite"),
        (np.array([1.0]), "at least 2"),
    ],
)
def test_bad_draws_raise_kde_error(bad, match):
    with pytest.raises(KDEError, match=match):
        kde_mode(bad)


def test_mostly_tied_draws_use_the_sd():
    # IQR = 0 (more than half equal) but spread > 0: the bandwidth falls back to the sd
    x = np.r_[np.zeros(600), np.random.default_rng(0).normal(0, 1, 400)]
    assert silverman_bandwidth(x)[0] > 0
    assert abs(kde_mode(x)) < 0.05


def _draws_for(model, T, rng, chains=4, n=500):
    p = model.state_dim
    params = {name: rng.normal(0.5, 0.1, (chains, n)) for name in model.param_names}
    params["x0"] = rng.normal(8, 1, (chains, n) + ((p,) if p > 1 else ()))
    params["x"] = rng.normal(0, 1, (chains, n, T) + ((p,) if p > 1 else ()))
    return Draws(params=params, sample_stats={"lp__": np.zeros((chains, n))})


@pytest.mark.parametrize("slug", ["same", "sep_d1_p2"])
def test_theta_draws_order_matches_theta_names(slug):
    model = get_model(slug)
    T = 3
    d = _draws_for(model, T, np.random.default_rng(0))
    th = theta_draws(d, model, T)
    names = model.theta_names(T)
    assert th.shape == (len(names), 4 * 500)
    # pooled draw r = chain * n + draw
    assert th[0, 500 + 7] == d.params[model.param_names[0]][1, 7]
    if model.state_dim == 1:
        assert th[names.index("x2"), 3] == d.params["x"][0, 3, 1]
    else:
        assert th[names.index("x2_1"), 3] == d.params["x"][0, 3, 1, 0]
        assert th[names.index("x0_2"), 3] == d.params["x0"][0, 3, 1]
        # a program that stores the states as (p, T) is transposed
        d.params["x"] = np.swapaxes(d.params["x"], 2, 3).copy()
        assert np.array_equal(theta_draws(d, model, T), th)


def test_theta_draws_accept_x_with_x0_inside_and_reject_wrong_shapes():
    model = get_model("same")
    T = 4
    d = _draws_for(model, T, np.random.default_rng(1))
    ref = theta_draws(d, model, T)
    joined = Draws(
        params={
            "a": d.params["a"],
            "x": np.concatenate([d.params["x0"][..., None], d.params["x"]], -1),
        },
        sample_stats=d.sample_stats,
    )
    assert np.array_equal(theta_draws(joined, model, T), ref)
    with pytest.raises(ValueError, match="shape"):
        theta_draws(d, model, T + 1)
    del d.params["x0"]
    with pytest.raises(ValueError):
        theta_draws(d, model, T)


def test_marginal_summary_quantiles_are_eq12():
    """q5/q95 are the empirical 5 % and 95 % quantiles (type 7) of the pooled draws."""
    model = get_model("same")
    T = 2
    rng = np.random.default_rng(5)
    d = _draws_for(model, T, rng, n=1000)
    s = marginal_summary(d, model, T)
    assert s["names"] == ["a", "x0", "x1", "x2"]
    pooled = d.params["a"].reshape(-1)
    assert s["q5"][0] == np.quantile(pooled, 0.05)
    assert s["q95"][0] == np.quantile(pooled, 0.95)
    # type 7 by hand: h = (n - 1) p, value = x[floor h] + frac(h) (x[floor h + 1] - x[floor h])
    srt = np.sort(pooled)
    h = (srt.size - 1) * 0.05
    lo = int(np.floor(h))
    assert s["q5"][0] == pytest.approx(srt[lo] + (h - lo) * (srt[lo + 1] - srt[lo]))
    assert np.all(s["q5"] < s["map"]) and np.all(s["map"] < s["q95"])
    assert s["map"][1] == pytest.approx(8.0, abs=0.3)


def test_marginal_summary_names_the_zero_spread_component():
    model = get_model("same")
    d = _draws_for(model, 2, np.random.default_rng(6))
    d.params["x"][..., 1] = 4.0
    with pytest.raises(KDEError, match="x2"):
        marginal_summary(d, model, 2)
