"""Convergence checks on synthetic draws: thresholds, each failure, and equivalence with
ArviZ (arviz-stats)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from ssmobs.nuts.convergence import (
    CHECKS,
    ConvergenceSettings,
    check_convergence,
    ebfmi,
    rank_diagnostics,
    stack_params,
)
from ssmobs.stan_backends.base import Draws

pytestmark = pytest.mark.unit


def ar1(rng, shape, phi):
    """AR(1) series along the last axis with unit stationary variance."""
    e = rng.standard_normal(shape)
    x = np.empty(shape)
    x[..., 0] = e[..., 0]
    s = np.sqrt(1 - phi**2)
    for i in range(1, shape[-1]):
        x[..., i] = phi * x[..., i - 1] + s * e[..., i]
    return x


def make_draws(seed=0, chains=4, n=1000, T=5, phi=0.3, energy_phi=0.2, shift=0.0):
    """Well-mixed draws of (a, x0, x[T]); ``shift`` moves chain c by c * shift in x0."""
    rng = np.random.default_rng(seed)
    a = 0.9 + 0.02 * ar1(rng, (chains, n), phi)
    x0 = 8 + ar1(rng, (chains, n), phi) + shift * np.arange(chains)[:, None]
    x = np.moveaxis(ar1(rng, (T, chains, n), phi), 0, -1)
    stats = {
        "divergent__": np.zeros((chains, n)),
        "treedepth__": np.full((chains, n), 3.0),
        "energy__": 10 + ar1(rng, (chains, n), energy_phi),
        "lp__": rng.standard_normal((chains, n)),
    }
    return Draws(params={"a": a, "x0": x0, "x": x}, sample_stats=stats)


def test_defaults_are_the_facts_sheet_decisions():
    s = ConvergenceSettings()
    assert (
        s.max_divergences,
        s.rhat_max,
        s.ess_bulk_min,
        s.ess_tail_min,
        s.ebfmi_min,
        s.treedepth_fails,
    ) == (0, 1.01, 400, 400, 0.3, False)
    with pytest.raises(ValueError):
        ConvergenceSettings(implementation="stan")


def test_well_mixed_draws_pass():
    res = check_convergence(make_draws())
    assert res["converged"], res["messages"]
    assert res["failed_checks"] == [] and res["warnings"] == []
    assert res["max_rhat"] < 1.01
    assert res["min_ess_bulk"] > 400 and res["min_ess_tail"] > 400
    assert res["n_divergent"] == 0 and res["n_treedepth_hits"] == 0
    assert len(res["ebfmi"]) == 4 and res["min_ebfmi"] == min(res["ebfmi"])
    assert (res["n_chains"], res["n_draws"]) == (4, 1000)


def test_divergences_fail_and_threshold_is_configurable():
    d = make_draws()
    d.sample_stats["divergent__"][2, 17] = 1
    d.sample_stats["divergent__"][0, 3] = 1
    res = check_convergence(d)
    assert not res["converged"] and res["failed_checks"] == ["divergences"]
    assert res["n_divergent"] == 2
    assert check_convergence(d, ConvergenceSettings(max_divergences=2))["converged"]


def test_shifted_chain_fails_rhat_and_names_the_parameter():
    res = check_convergence(make_draws(shift=0.5))
    assert "rhat" in res["failed_checks"]
    assert res["max_rhat_param"] == "x0"
    assert res["max_rhat"] > 1.01


def test_sticky_chains_fail_ess():
    res = check_convergence(make_draws(phi=0.995))
    assert "ess_bulk" in res["failed_checks"] and "ess_tail" in res["failed_checks"]
    assert res["min_ess_bulk"] < 400


def test_low_ebfmi_fails():
    # energy that changes slowly between draws: E-BFMI = mean(dE^2)/var(E) ~ 2(1 - phi)
    res = check_convergence(make_draws(energy_phi=0.95))
    assert res["failed_checks"] == ["ebfmi"]
    assert res["min_ebfmi"] < 0.3


def test_ebfmi_formula():
    e = np.array([[1.0, 3.0, 2.0, 5.0], [0.0, 1.0, 0.0, 1.0]])
    expected = [np.mean(np.diff(r) ** 2) / np.var(r, ddof=1) for r in e]
    assert np.allclose(ebfmi(e), expected)


def test_treedepth_warns_by_default_and_fails_when_configured():
    d = make_draws()
    d.sample_stats["treedepth__"][1, :5] = 10
    res = check_convergence(d, max_treedepth=10)
    assert res["converged"] and res["n_treedepth_hits"] == 5
    assert res["warnings"] and "max_treedepth 10" in res["warnings"][0]
    res = check_convergence(d, ConvergenceSettings(treedepth_fails=True), max_treedepth=10)
    assert res["failed_checks"] == ["treedepth"]
    assert check_convergence(d, max_treedepth=11)["n_treedepth_hits"] == 0


def test_nonfinite_draws_fail_without_crashing():
    d = make_draws()
    d.params["x"][0, 10, 2] = np.nan
    d.params["a"][1, 3] = np.inf
    res = check_convergence(d)
    assert not res["converged"]
    assert res["failed_checks"][0] == "nonfinite" and res["n_nonfinite"] == 2
    assert "rhat" in res["failed_checks"]  # NaN diagnostics count as failures


def test_constant_parameter_fails_rhat():
    d = make_draws()
    d.params["a"][:] = 0.5
    res = check_convergence(d)
    assert "rhat" in res["failed_checks"] and res["max_rhat_param"] == "a"


def test_failed_checks_are_in_canonical_order():
    d = make_draws(shift=0.5, energy_phi=0.95)
    d.sample_stats["divergent__"][0, 0] = 1
    res = check_convergence(d)
    assert res["failed_checks"] == [c for c in CHECKS if c in res["failed_checks"]]
    assert res["failed_checks"][:2] == ["divergences", "rhat"]
    assert len(res["messages"]) == len(res["failed_checks"])


def test_stack_params_names_and_order():
    names, arr = stack_params(make_draws(T=3, n=10))
    assert names == ["a", "x0", "x[0]", "x[1]", "x[2]"]
    assert arr.shape == (5, 4, 10)


def arviz_stats_reference(x):
    """R-hat, bulk- and tail-ESS of every row of (P, chain, draw) by arviz-stats' array layer."""
    from arviz_stats.base import array_stats

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {
            "rhat": array_stats.rhat(x, method="rank"),
            "ess_bulk": array_stats.ess(x, method="bulk"),
            "ess_tail": array_stats.ess(x, method="tail", prob=(0.05, 0.95)),
        }


@pytest.mark.parametrize("chains,n,odd", [(4, 1000, False), (4, 301, True), (2, 50, False)])
def test_vectorized_equals_arviz(chains, n, odd):
    d = make_draws(seed=3, chains=chains, n=n, phi=0.7, shift=0.05)
    d.params["x"][..., 0] = np.round(d.params["x"][..., 0], 1)  # ties
    names, arr = stack_params(d)
    ours = rank_diagnostics(arr)
    for key, vals in arviz_stats_reference(arr).items():
        np.testing.assert_allclose(ours[key], vals, rtol=1e-10, err_msg=key)


def test_arviz_implementation_gives_the_same_result():
    d = make_draws(seed=5, n=600, phi=0.8, shift=0.1)
    a = check_convergence(d)
    b = check_convergence(d, ConvergenceSettings(implementation="arviz"))
    assert a["failed_checks"] == b["failed_checks"]
    for key in ("max_rhat", "min_ess_bulk", "min_ess_tail", "min_ebfmi"):
        assert a[key] == pytest.approx(b[key], rel=1e-10)
    assert a["max_rhat_param"] == b["max_rhat_param"]


@pytest.mark.parametrize("chains", [1, 2, 4])
@pytest.mark.parametrize("n", [4, 5, 6, 7, 10, 13])
def test_vectorized_equals_arviz_for_tiny_runs(chains, n):
    x = np.random.default_rng(n * 10 + chains).standard_normal((4, chains, n)).cumsum(axis=2)
    ours = rank_diagnostics(x)
    for key, vals in arviz_stats_reference(x).items():
        np.testing.assert_allclose(ours[key], vals, rtol=1e-10, err_msg=key)
