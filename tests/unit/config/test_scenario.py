"""The Scenario object: built once from a config entry, typed, frozen, with clear errors."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml
from factories import same_a09
from ssmobs.config import validation as cfg
from ssmobs.config.scenario import Scenario
from ssmobs.models import get_model

pytestmark = pytest.mark.unit

ENTRY = {
    "name": "s",
    "model": "sep_d1_p2",
    "omega": {"d": 0.9, "c": 0.8, "b": 0.5, "a": 0.6},
    "x0": [8, 7],
    "T": 3,
    "K": 5,
}


def test_omega_follows_the_models_order_not_the_entrys():
    sc = Scenario.from_config(ENTRY)
    assert get_model("sep_d1_p2").param_names == ("a", "b", "c", "d")
    np.testing.assert_array_equal(sc.omega, [0.6, 0.5, 0.8, 0.9])
    np.testing.assert_array_equal(sc.x0, [8.0, 7.0])
    assert sc.omega.dtype == sc.x0.dtype == np.float64
    assert sc.model is get_model("sep_d1_p2") and sc.slug == "sep_d1_p2"
    assert sc.disturbance_dim == (1 + 2) * 3
    scalar = Scenario.from_config({**ENTRY, "model": "same", "omega": {"a": 0.9}, "x0": 8})
    assert scalar.x0.shape == (1,) and scalar.x0[0] == 8.0


def test_defaults_are_the_schemas():
    items = cfg.load_schema()["properties"]["scenarios"]["items"]["properties"]
    sc = Scenario.from_config(ENTRY)
    assert sc.seed == items["seed"]["default"] == 1
    assert (sc.method, sc.stan_init, sc.joint_map_start) == (
        items["method"]["default"],
        items["stan_init"]["default"],
        items["joint_map_start"]["default"],
    )
    assert sc.joint_map is sc.stan is True
    assert (sc.prior, sc.stan_batch_size, sc.exact_K, sc.paper_ref) == (None, None, None, "")
    assert sc.exact  # absent means enabled (config/README.md)
    # a validated config gives the same Scenario as the raw entry
    conf = cfg.validate({"scenarios": [dict(ENTRY)]})
    validated = Scenario.from_config(conf["scenarios"][0])
    assert dataclasses.astuple(validated.replace(model=None, omega=0, x0=0)) == dataclasses.astuple(
        sc.replace(model=None, omega=0, x0=0)
    )


def test_every_configured_scenario_converts():
    for path in ("config/config.yaml", "config/smoke.yaml", "config/paper.yaml"):
        conf = cfg.validate(yaml.safe_load(open(path)))
        for entry in conf["scenarios"]:
            sc = Scenario.from_config(entry)
            assert dict(zip(sc.model.param_names, sc.omega)) == entry["omega"]
            assert (sc.name, sc.T, sc.K, sc.seed) == (
                entry["name"],
                entry["T"],
                entry["K"],
                entry["seed"],
            )


def test_frozen_and_read_only():
    sc = Scenario.from_config({**ENTRY, "prior": {"a": "unrestricted"}})
    with pytest.raises(dataclasses.FrozenInstanceError):
        sc.seed = 2
    with pytest.raises(ValueError):
        sc.omega[0] = 0.0
    with pytest.raises(TypeError):
        sc.prior["a"] = "restricted"
    assert json.dumps(sc.prior_config) == '{"a": "unrestricted"}'
    other = sc.replace(K=40, seed=3)
    assert (other.K, other.seed, sc.K, sc.seed) == (40, 3, 5, 1)


def test_helpers_for_the_stages():
    sc = Scenario.from_config(
        {
            **ENTRY,
            "model": "same",
            "omega": {"a": 0.9},
            "x0": 8,
            "exact_K": 300,
            "stan_batch_size": 7,
        }
    )
    assert sc.exact_applies and sc.exact_trajectories == 300
    assert sc.batch_size({"batch_size": 20}) == 7
    plain = Scenario.from_config({**ENTRY, "model": "same", "omega": {"a": 0.9}, "x0": 8})
    assert plain.exact_trajectories == plain.K and plain.batch_size({"batch_size": 20}) == 20
    assert not plain.replace(exact=False).exact_applies
    assert not Scenario.from_config(
        {**ENTRY, "model": "sep_mult", "omega": {"a": 0.9}, "x0": 8}
    ).exact_applies  # not linear in the states
    bounds = plain.prior_bounds()
    assert (bounds.lower[0], bounds.upper[0]) == (0.0, 1.0)


def test_a_scenarios_stan_settings_override_the_block():
    from ssmobs.config.validation import ConfigError

    entry = {**ENTRY, "model": "same", "omega": {"a": 0.9}, "x0": 8}
    block = {"chains": 4, "adapt_delta": 0.8, "init_radius": 2, "batch_size": 50}
    assert Scenario.from_config(entry).stan_config(block) == block
    sc = Scenario.from_config({**entry, "stan_settings": {"adapt_delta": 0.95}, "stan_seed": 5})
    assert sc.stan_config(block) == {**block, "adapt_delta": 0.95}
    assert sc.stan_seed == 5 and Scenario.from_config(entry).stan_seed is None
    with pytest.raises(ConfigError, match="joint_map must be true"):
        Scenario.from_config({**entry, "stan_init": "joint_map", "joint_map": False})
    assert Scenario.from_config({**entry, "stan_init": "joint_map"}).stan_init == "joint_map"
    with pytest.raises(ConfigError, match="batch_size"):  # not a NUTS setting of a run
        Scenario.from_config({**entry, "stan_settings": {"batch_size": 5}})
    with pytest.raises(ConfigError, match="adapt_delta"):
        Scenario.from_config({**entry, "stan_settings": {"adapt_delta": 1.0}})


def test_stan_every_picks_every_mth_trajectory_and_its_batches():
    from ssmobs.config.validation import ConfigError

    entry = {**ENTRY, "model": "same", "omega": {"a": 0.9}, "x0": 8, "K": 10}
    plain = Scenario.from_config(entry)
    assert plain.stan_trajectories == range(10)
    sc = Scenario.from_config({**entry, "stan_every": 3})
    assert list(sc.stan_trajectories) == [0, 3, 6, 9]
    assert [list(b) for b in sc.stan_batches(3)] == [[0, 3, 6], [9]]
    assert [list(b) for b in plain.stan_batches(4)] == [
        [0, 1, 2, 3],
        [4, 5, 6, 7],
        [8, 9],
    ]
    with pytest.raises(ConfigError, match="stan_every = 11: larger than K = 10"):
        Scenario.from_config({**entry, "stan_every": 11})
    with pytest.raises(ConfigError, match="stan_every"):
        Scenario.from_config({**entry, "stan_every": 0})


@pytest.mark.parametrize(
    "change, message",
    [
        ({"seed": -1}, r"seed = -1: must be >= 0"),
        ({"T": "4"}, r"T = '4': must be of type integer"),
        ({"method": "lcd"}, r"method = 'lcd': allowed values are"),
        ({"colour": 1}, r"colour.*(unexpected|not allowed)"),
        ({"model": "nope"}, r"model = 'nope': unknown model; allowed: \[.*'same'"),
        ({"omega": {"a": 0.6, "b": 0.5, "c": 0.8}}, r"missing \['d'\]"),
        ({"x0": 8}, r"x0 must have 2 component"),
        ({"omega": {"a": 0.6, "b": 0.5, "c": 0.8, "d": 1.5}}, r"d=1.5 must satisfy \|d\| < 1"),
    ],
)
def test_bad_entries_fail_naming_scenario_key_and_value(change, message):
    with pytest.raises(cfg.ConfigError, match=r"(?s)invalid scenario 's'.*" + message):
        Scenario.from_config({**ENTRY, **change})


def test_missing_keys_and_non_mappings_fail_clearly():
    with pytest.raises(cfg.ConfigError, match="'K' is a required property"):
        Scenario.from_config({k: v for k, v in ENTRY.items() if k != "K"})
    with pytest.raises(cfg.ConfigError, match="must be a mapping"):
        Scenario.from_config(["s"])
    Scenario.from_config(ENTRY)  # the entry itself is not changed by the defaults
    assert "seed" not in ENTRY


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"stan_every": 6}, r"stan_every = 6: larger than K = 5"),
        ({"stan_init": "joint_map", "joint_map": False}, r"stan_init = 'joint_map'"),
        ({"joint_map_start": "sign_of_x0"}, r"joint_map_start = 'sign_of_x0': model 'same'"),
        ({"omega": {"a": 1.5}}, r"true value a=1.5"),
    ],
)
def test_one_check_of_an_entry_for_scenarios_map_cells_and_the_scenario_object(change, message):
    """The config's scenarios, an observability map's cells and Scenario.from_config all
    refuse an entry by the same check (ssmobs.config.scenario.entry_problems)."""
    entry = same_a09(K=5, **change)
    with pytest.raises(cfg.ConfigError, match=r"scenarios\[0\] \('s'\): " + message):
        cfg.validate({"scenarios": [dict(entry)]})
    base = {k: v for k, v in entry.items() if k not in ("name", "T", "K", "joint_map")}
    values = [entry["omega"]["a"]]
    the_map = {"name": "m", "base": base, "vary": "a", "values": values, "T": [4], "K": 5}
    good = same_a09(name="ok", K=5)
    if "joint_map" not in change:  # a map's cells always run the joint MAP
        with pytest.raises(cfg.ConfigError, match=r"cell m_a[0-9.]+_T4: " + message):
            cfg.validate({"scenarios": [good], "observability_maps": [the_map]})
    with pytest.raises(cfg.ConfigError, match=r"invalid scenario 's'"):
        Scenario.from_config(entry)


def test_a_config_prior_interval_reaches_the_bounds():
    """Issue 47: the YAML form [0, .inf] is accepted by the schema and used as the support;
    a list of three numbers is a config error naming the key and the value."""
    import yaml
    from ssmobs.config.validation import ConfigError

    entry = {**ENTRY, "model": "stoch_vol", "omega": {"phi": 0.9, "sigma": 0.5}, "x0": 0}
    prior = yaml.safe_load("{sigma: [0, .inf], phi: [-1, 1]}")
    sc = Scenario.from_config({**entry, "prior": prior})
    bounds = sc.prior_bounds()
    assert bounds.lower.tolist() == [-1.0, 0.0] and bounds.upper.tolist() == [1.0, np.inf]
    with pytest.raises(ConfigError, match=r"prior\.sigma = \[0, 1, 2\]"):
        Scenario.from_config({**entry, "prior": {"sigma": [0, 1, 2]}})
