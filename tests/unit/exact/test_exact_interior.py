"""The exact stage's interior singularities: where x0 drops out inside the prior support."""

from __future__ import annotations

import numpy as np
import pytest
from ssmobs.exact import marginal as exact_module
from ssmobs.exact.interior_singularities import interior_dropouts
from ssmobs.models import get_model

pytestmark = pytest.mark.unit


def sep_trajectories(T: int, K: int, seed: int, x0: float) -> np.ndarray:
    model = get_model("sep")
    rng = np.random.default_rng(seed)
    eta, eps = rng.standard_normal((K, T, 1)), rng.standard_normal((K, T, 1))
    return model.simulate(np.array([0.9, 0.9]), np.array([x0]), eta, eps)[1]


def test_dropout_points_are_found_inside_the_support_only():
    sep = get_model("sep")
    at = np.array([[0.9, 0.8], [-0.5, 0.3]])
    inside = sep.prior_bounds([0.9, 0.9], {"a": "unrestricted", "b": "restricted"})
    found = interior_dropouts(sep, inside, at)
    assert np.allclose(found[:, 0], 0.0, atol=1e-12) and np.isnan(found[:, 1]).all()
    ends = sep.prior_bounds([0.9, 0.9], "restricted")  # a -> 0 is an end: not interior
    assert np.isnan(interior_dropouts(sep, ends, np.abs(at))).all()
    # two AR(1) components seen through one sum: x0's direction (b, -a) drops out at c = d
    two = get_model("sep_d1_p2")
    found = interior_dropouts(
        two, two.prior_bounds([0.6, 0.5, 0.9, 0.9], "restricted"), np.array([[0.6, 0.5, 0.3, 0.7]])
    )
    assert np.isnan(found[0, :2]).all()
    assert found[0, 2] == pytest.approx(0.7, abs=1e-9) and found[0, 3] == pytest.approx(
        0.3, abs=1e-9
    )


def test_marginal_map_and_quantiles_stay_in_the_interior_basin(monkeypatch):
    """Sep with a on (-1, 1): p(a | z) ~ 1/|a| at 0 inside the support; the slope is
    measured, flagged, and no marginal MAP or quantile falls on the spike (without the
    interior search, some do)."""
    model = get_model("sep")
    z = sep_trajectories(T=8, K=40, seed=3, x0=2.0)
    bounds = model.prior_bounds([0.9, 0.9], {"a": "unrestricted", "b": "restricted"})
    frame = exact_module.exact_marginal(model, z, bounds).to_frame(model)
    unique = frame["maxima"] == "unique"
    assert unique.sum() >= 5
    assert np.allclose(frame.loc[unique, "interior_a"], 0.0, atol=1e-12)
    slopes = frame.loc[unique, "slope_interior_a"]
    assert (slopes.between(-1.05, -0.95)).all() and frame.loc[unique, "improper_interior_a"].all()
    maps = frame.loc[unique, "a_map"].dropna()
    assert len(maps) >= 5 and (maps > 0.5).all()
    assert (frame.loc[unique, "a_q5"] > 0.01).all()
    assert "interior_b" in frame.columns and frame["interior_b"].isna().all()

    monkeypatch.setattr(
        exact_module, "interior_dropouts", lambda *a, **k: np.full(a[2].shape, np.nan)
    )
    blind = exact_module.exact_marginal(model, z, bounds).to_frame(model)
    assert "interior_a" not in blind.columns
    assert (blind.loc[unique, "a_map"] < 0.01).any()  # the spike, as before the search


def test_a_support_without_dropout_keeps_its_columns():
    model = get_model("sep")
    z = sep_trajectories(T=20, K=3, seed=1, x0=8.0)
    frame = exact_module.exact_marginal(model, z, model.prior_bounds([0.9, 0.9], "restricted"))
    assert not any(c.startswith("interior_") for c in frame.to_frame(model).columns)
