"""Propriety of the posterior decided from a model's terms (issue 60): each rule on a test
model, and the shipped models under the priors of config/config.yaml give exactly the cases
docs/method/improper-posteriors.md documents."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from growth_model import Growth
from phase_model import PhaseTracking
from repo_paths import REPO_DIR
from ricker_model import Ricker
from ssmobs.models import get_model
from ssmobs.models.propriety import model_dropouts, posterior_propriety
from two_component_model import TwoComponents
from two_gain_model import TwoGains

pytestmark = pytest.mark.unit


def test_a_translation_on_a_flat_x0_makes_the_posterior_improper():
    model = PhaseTracking()
    bounds = model.prior_bounds({"mu": 0.5, "b": 1.0}, {"mu": [-math.inf, math.inf]})
    found = posterior_propriety(model, bounds)
    assert found.is_improper
    assert found.improper == (
        "x -> x + 2*pi (x0 and every state together) leaves the density unchanged and x0 is "
        "flat on the line",
    )
    assert found.label() == "improper: " + found.improper[0]
    assert found.edge == (
        "b -> 0: x0 drops out of the likelihood at the end of the prior (0, inf) of b",
    )
    assert posterior_propriety(model, bounds) is found  # memoised


def test_a_ridge_is_improper_only_where_its_orbits_have_infinite_mass():
    model = Ricker()
    half_lines = model.prior_bounds({"a": 1.0, "b": 0.5, "c": 0.5})
    (reason,) = posterior_propriety(model, half_lines).improper
    assert reason.startswith("the ridge (b, c, x) -> (b e^-s, c e^-s, x + s)")
    # b and c on (0, 1): the orbit leaves the box as b, c grow and shrinks the volume by
    # e^(-2 s) as they fall: finite mass
    boxed = model.prior_bounds({"a": 1.0, "b": 0.5, "c": 0.5}, {"b": [0, 1], "c": [0, 1]})
    assert posterior_propriety(model, boxed).improper == ()


def test_a_scaling_ridge_is_improper_where_an_end_of_its_orbit_stays_in_the_box():
    model = TwoGains()
    omega = {"a": 0.5, "b": 0.5, "c": 0.5}
    reason = (
        "the ridge (b, c) -> (b e^s, c e^-s) leaves the density unchanged along orbits of "
        "infinite mass inside the prior"
    )
    assert posterior_propriety(model, model.prior_bounds(omega)).improper == (reason,)
    # b on (0, 1), c on (0, inf): the orbit runs on as b -> 0, c -> inf (volume kept)
    one_side = model.prior_bounds(omega, {"b": [0, 1]})
    assert posterior_propriety(model, one_side).improper == (reason,)
    # both on (0, 1): every orbit is a finite stretch
    both = model.prior_bounds(omega, {"b": [0, 1], "c": [0, 1]})
    assert posterior_propriety(model, both).improper == ()


def test_x0_dropping_out_inside_the_prior_is_improper_and_at_its_end_an_edge():
    model = TwoComponents()
    omega = {"a1": 0.9, "a2": 0.3}
    inside = posterior_propriety(model, model.prior_bounds(omega))  # (-1, 1)^2
    assert inside.improper == (
        "x0_1 drops out of the likelihood at a1 = 0, inside the prior (-1, 1) of a1: the "
        "marginal posterior diverges there",
        "x0_2 drops out of the likelihood at a2 = 0, inside the prior (-1, 1) of a2: the "
        "marginal posterior diverges there",
        "a direction of x0 drops out of the likelihood where a1 = a2, inside the prior: the "
        "marginal posterior diverges there",
    )
    assert inside.edge == ()
    restricted = posterior_propriety(model, model.prior_bounds(omega, "restricted"))
    assert restricted.edge == (
        "a1 -> 0: x0_1 drops out of the likelihood at the end of the prior (0, 1) of a1",
        "a2 -> 0: x0_2 drops out of the likelihood at the end of the prior (0, 1) of a2",
    )
    assert [r.split(",")[0] for r in restricted.improper] == [
        "a direction of x0 drops out of the likelihood where a1 = a2"
    ]
    # a1 = a2 lies outside a box that keeps a1 > a2
    apart = model.prior_bounds(omega, {"a1": [0.5, 1], "a2": [0, 0.5]})
    assert posterior_propriety(model, apart).improper == ()


def test_a_drop_out_of_codimension_two_is_a_note_at_the_edge_and_undetermined_inside():
    growth = Growth()
    omega = {"a": 0.5, "b": 2.0}
    at_edge = posterior_propriety(growth, growth.prior_bounds(omega))  # a on (0, 1)
    assert not at_edge.is_improper and at_edge.label() == "" and at_edge.edge == ()
    assert at_edge.undetermined == ()
    assert at_edge.notes == (
        "a = 0 and b = 0: x0 drops out of the likelihood at the edge of the prior box (a set "
        "of codimension 2)",
    )
    inside = posterior_propriety(growth, growth.prior_bounds(omega, {"a": [-1, 1], "b": [-3, 3]}))
    assert inside.notes == () and not inside.is_improper
    assert inside.undetermined == (
        "x0 drops out of the likelihood where a = 0 and b = 0 (a set of codimension 2): "
        "whether the posterior is proper there is not determined",
    )
    outside = posterior_propriety(growth, growth.prior_bounds(omega, {"b": [1, 3]}))
    assert (outside.notes, outside.undetermined) == ((), ())


def _ends(reasons):
    """'a -> 0: ...' -> 'a -> 0'."""
    return sorted(r.split(":")[0] for r in reasons)


#: docs/method/improper-posteriors.md, per scenario of config/config.yaml: the ends where the
#: density is not integrable (edge), and the sets inside the prior (improper)
DOCUMENTED = {
    "same": (["a -> 0"], []),
    "sep_ab": (["a -> 0", "b -> 0"], []),
    "sep_b": (["b -> 0"], ["x0 drops out of the likelihood at a = 0"]),
    "sep_d2_p1_abc": (["c -> 0"], []),
    "sep_d2_p1_a": ([], ["x0 drops out of the likelihood at c = 0"]),
    "sep_d1_p2": (
        ["a -> 0", "b -> 0", "c -> 0", "d -> 0"],
        ["a direction of x0 drops out of the likelihood where c = d"],
    ),
    "ranwalk": (["a -> 0"], []),
    "mult": ([], []),
}


def _documented(name):
    key = next(k for k in sorted(DOCUMENTED, key=len, reverse=True) if name.startswith(k + "_"))
    edges, inside = DOCUMENTED[key]
    return edges, inside


def test_shipped_models_under_the_config_priors_give_the_documented_cases():
    config = yaml.safe_load((REPO_DIR / "config" / "config.yaml").read_text())
    seen = set()
    for sc in config["scenarios"]:
        model = get_model(sc["model"])
        bounds = model.prior_bounds(sc["omega"], sc.get("prior"))
        found = posterior_propriety(model, bounds)
        edges, inside = _documented(sc["name"])
        assert _ends(found.edge) == edges, sc["name"]
        assert [r.split(",")[0] for r in found.improper] == inside, sc["name"]
        assert found.undetermined == (), sc["name"]  # nothing is left undecided
        seen.add(sc["model"])
    assert seen >= {"same", "sep", "sep_d2_p1", "sep_d1_p2", "sep_ranwalk", "sep_mult"}
    # the tutorial's model: phi -> 0 at the end of (0, 1), 1/phi (your-own-model.md)
    sv = get_model("stoch_vol")
    found = posterior_propriety(sv, sv.prior_bounds({"phi": 0.9, "sigma": 0.5}))
    assert _ends(found.edge) == ["phi -> 0"] and found.improper == ()


def test_drop_out_sets_are_solved_from_the_terms():
    sets = {(d.variable, d.text) for d in model_dropouts(get_model("sep_d2_p1")).sets}
    assert sets == {("x0", "c = 0"), ("x0", "a = 0 and b = 0")}
    assert {(d.variable, d.text) for d in model_dropouts(get_model("sep_mult")).sets} == set()
    # the drop-out is real: at a = 0 the Same model's density does not change with x0
    from ssmobs.models.log_posterior import neg2_log_posterior

    same = get_model("same")
    rng = np.random.default_rng(1)
    theta = np.concatenate([np.zeros((5, 1)), rng.normal(0, 1, (5, 5))], axis=1)
    z = rng.normal(0, 1, (5, 4, 1))
    _, grad = neg2_log_posterior(same, theta, z, order=1)
    assert np.allclose(grad[:, 1], 0.0)  # d/dx0 at a = 0
    theta[:, 0] = 0.3
    _, grad = neg2_log_posterior(same, theta, z, order=1)
    assert np.all(np.abs(grad[:, 1]) > 1e-6)
