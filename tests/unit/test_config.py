"""Config validation: all profiles pass, every bad value gets one clear message."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
from ssmobs import config as cfg

pytestmark = pytest.mark.unit

PROFILES = ["config.yaml", "smoke.yaml", "paper.yaml"]


def load(name: str) -> dict:
    return yaml.safe_load((REPO / "config" / name).read_text())


@pytest.mark.parametrize("name", PROFILES)
def test_profiles_validate_and_get_defaults(name):
    c = cfg.validate(load(name))
    assert c["stan"]["backend"] == "auto"
    assert c["joint_map"]["grad_tol"] == 1e-5
    assert c["joint_map"]["eig_ratio_min"] == 1e-5
    assert c["convergence"]["rhat_max"] == 1.01
    for sc in c["scenarios"]:
        assert sc["method"] in ("design", "random", "antithetic")
        assert isinstance(sc["seed"], int)


def base() -> dict:
    return {"scenarios": [{"name": "s", "model": "same", "omega": {"a": 0.9}, "x0": 8,
                           "T": 4, "K": 10}]}


def with_(path, value):
    c = base()
    target = c
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    return c


BAD = [
    ("unknown model", with_(["scenarios", 0, "model"], "nope"), ["scenarios[0]", "model", "nope", "same"]),
    ("unknown prior", with_(["scenarios", 0, "prior"], "flat"), ["flat", "restricted"]),
    ("prior not allowed", with_(["scenarios", 0, "prior"], "half_line"), ["half_line", "allowed"]),
    ("K zero", with_(["scenarios", 0, "K"], 0), ["scenarios[0].K", "0", ">= 1"]),
    ("K negative", with_(["scenarios", 0, "K"], -3), ["scenarios[0].K", "-3", ">= 1"]),
    ("K not integer", with_(["scenarios", 0, "K"], 2.5), ["scenarios[0].K", "2.5", "integer"]),
    ("T zero", with_(["scenarios", 0, "T"], 0), ["scenarios[0].T", "0", ">= 1"]),
    ("|a| >= 1", with_(["scenarios", 0, "omega"], {"a": 1.2}), ["a=1.2", "|a| < 1"]),
    ("a outside restricted prior", with_(["scenarios", 0, "omega"], {"a": 0.0}), ["a", "0"]),
    ("seed not integer", with_(["scenarios", 0, "seed"], "abc"), ["scenarios[0].seed", "abc", "integer"]),
    ("negative threshold", {**base(), "joint_map": {"grad_tol": -1.0}}, ["joint_map.grad_tol", "-1.0", "> 0"]),
    ("negative ess", {**base(), "convergence": {"ess_bulk_min": -5}}, ["convergence.ess_bulk_min", "-5", ">= 0"]),
    ("unknown key", with_(["scenarios", 0, "colour"], "red"), ["colour"]),
    ("missing x0 entry", with_(["scenarios", 0, "omega"], {"b": 0.5}), ["'a'", "missing"]),
]


@pytest.mark.parametrize("label,conf,needles", BAD, ids=[b[0] for b in BAD])
def test_bad_values_named(label, conf, needles):
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(copy.deepcopy(conf))
    msg = str(err.value)
    for needle in needles:
        assert needle in msg, f"{needle!r} not in message: {msg}"


def test_sep_d1_p2_needs_a2_plus_b2_below_one():
    c = base()
    c["scenarios"][0].update(model="sep_d1_p2", omega={"a": 0.8, "b": 0.7, "c": 0.9, "d": 0.9},
                             x0=[8, 8])
    with pytest.raises(cfg.ConfigError, match=r"a\^2 \+ b\^2 < 1"):
        cfg.validate(c)


def test_half_line_prior_needs_positive_true_value_in_mult():
    c = base()
    c["scenarios"][0].update(model="sep_mult", omega={"a": -0.5})
    with pytest.raises(cfg.ConfigError, match="must be > 0"):
        cfg.validate(c)


def test_duplicate_scenario_names():
    c = base()
    c["scenarios"].append(copy.deepcopy(c["scenarios"][0]))
    with pytest.raises(cfg.ConfigError, match="used twice"):
        cfg.validate(c)


def test_k_grid_must_increase():
    c = base()
    c["k_selection"] = [{"name": "k", "scenario": "s", "K_grid": [10, 30, 20]}]
    with pytest.raises(cfg.ConfigError, match="strictly increasing"):
        cfg.validate(c)


def test_k_selection_unknown_scenario():
    c = base()
    c["k_selection"] = [{"name": "k", "scenario": "zzz", "K_grid": [10, 20]}]
    with pytest.raises(cfg.ConfigError, match="zzz"):
        cfg.validate(c)


def test_x0_dimension_checked():
    c = with_(["scenarios", 0, "x0"], [1.0, 2.0])
    with pytest.raises(cfg.ConfigError, match="x0 must have 1 component"):
        cfg.validate(c)


def test_cmdstanpy_backend_without_cmdstan_is_refused():
    from ssmobs.stan_backends import have_cmdstan

    if have_cmdstan():
        pytest.skip("CmdStan is installed here, so the cmdstanpy backend is valid")
    c = {**base(), "stan": {"backend": "cmdstanpy"}}
    with pytest.raises(cfg.ConfigError, match=r"stan.backend = 'cmdstanpy'.*CmdStan.*'pystan'"):
        cfg.validate(c)


def test_unknown_backend_name():
    with pytest.raises(cfg.ConfigError, match=r"stan.backend = 'stan'.*allowed values"):
        cfg.validate({**base(), "stan": {"backend": "stan"}})
