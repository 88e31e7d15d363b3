"""Prior intervals as documented (issue 60 item 4): infinite bounds pass the whole config
check (the preflight's entry), in a config and in a model's ``default_prior``; every
other key still refuses infinite numbers, and NaN is refused everywhere."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest
import sympy as sp
from factories import same_a09
from ssmobs.config import preflight
from ssmobs.config import validation as cfg
from ssmobs.config.scenario import Scenario
from ssmobs.models import MODELS
from ssmobs.models.base import StateSpaceModel

pytestmark = pytest.mark.unit


class LevelModel(StateSpaceModel):
    """x_t = x_{t-1} + mu + eta_t, z_t = b x_t + eps_t: mu flat on the whole line and b on
    the positive half-line by default, written as intervals in ``default_prior``."""

    slug = "level_test"
    title = "Level with drift (test)"
    obs_dim = 1
    state_dim = 1
    param_names = ("mu", "b")
    default_prior = {"mu": (-math.inf, math.inf), "b": (0.0, math.inf)}
    allowed_priors = {"mu": ("unrestricted",), "b": ("half_line", "restricted")}
    linear_in_states = False

    def obs_term(self, omega: Sequence[sp.Symbol], x: Sequence[sp.Symbol], z: Sequence[sp.Symbol]):
        return (z[0] - omega[1] * x[0]) ** 2

    def trans_term(self, omega, x_prev, x):
        return (x[0] - x_prev[0] - omega[0]) ** 2

    def simulate(self, omega, x0, eta, eps):
        mu, b = np.asarray(omega, dtype=float)
        x = np.asarray(x0, dtype=float)[None, None, :] + np.cumsum(mu + eta, axis=1)
        return x, b * x + eps


@pytest.fixture
def level_model(monkeypatch):
    """The LevelModel in the model registry, as if it were workflow/ssmobs/models/level_test.py."""
    models = MODELS._load()  # type: ignore[attr-defined]
    monkeypatch.setitem(models, "level_test", LevelModel())
    return models["level_test"]


def checked_file(tmp_path, text: str) -> dict:
    path = tmp_path / "study.yaml"
    path.write_text(text)
    return preflight.check_config_file(path)


def test_the_tutorials_prior_passes_the_whole_config_check(tmp_path):
    """docs/your-own-model.md's example (refused before: "scenarios[0].prior.sigma[1] = inf:
    must be a finite number")."""
    c = checked_file(
        tmp_path,
        "scenarios:\n  - {name: sv, model: stoch_vol, omega: {phi: 0.9, sigma: 0.5}, x0: 0,\n"
        "     T: 5, K: 4, prior: {phi: [-1, 1], sigma: [0, .inf]}}\n",
    )
    sc = Scenario.from_config(c["scenarios"][0])
    bounds = sc.prior_bounds()
    assert bounds.lower.tolist() == [-1.0, 0.0] and bounds.upper.tolist() == [1.0, math.inf]


def test_the_whole_line_and_a_half_line_pass_the_whole_config_check(tmp_path, level_model):
    """config/README.md's example ``prior: {mu: [-.inf, .inf], b: [0, .inf]}``."""
    c = checked_file(
        tmp_path,
        "scenarios:\n  - {name: lv, model: level_test, omega: {mu: 0.5, b: 1}, x0: 0,\n"
        "     T: 5, K: 4, stan: false, prior: {mu: [-.inf, .inf], b: [0, .inf]}}\n",
    )
    assert c["scenarios"][0]["prior"] == {"mu": [-math.inf, math.inf], "b": [0, math.inf]}
    bounds = Scenario.from_config(c["scenarios"][0]).prior_bounds()
    assert bounds.variants == ("interval(-inf, inf)", "interval(0, inf)")


def test_infinite_bounds_from_the_command_line_are_read(level_model):
    cli = pytest.importorskip("snakemake.cli")
    given = cli.parse_config(
        [
            "scenarios=[{name: lv, model: level_test, omega: {mu: 0.5, b: 1}, x0: 0, T: 5, "
            "K: 4, stan: false, prior: {mu: [-.inf, .inf], b: [0, .inf]}}]"
        ]
    )
    assert given["scenarios"][0]["prior"]["mu"] == ["-.inf", ".inf"]  # Snakemake's strings
    c = cfg.validate(given)
    assert c["scenarios"][0]["prior"] == {"mu": [-math.inf, math.inf], "b": [0, math.inf]}


def test_a_map_base_takes_infinite_prior_bounds(level_model):
    entry = {
        "name": "m",
        "base": {"model": "level_test", "omega": {"mu": 0.5, "b": 1.0}, "x0": 0.0},
        "vary": "b",
        "values": [0.5, 2.0],
        "T": [5],
        "K": 4,
    }
    entry["base"]["prior"] = {"mu": [-math.inf, math.inf]}
    c = cfg.validate({"scenarios": [same_a09()], "observability_maps": [entry]})
    assert c["observability_maps"][0]["base"]["prior"]["mu"] == [-math.inf, math.inf]


@pytest.mark.parametrize(
    ("where", "value"),
    [
        (("scenarios", 0, "prior", "a", 0), math.nan),
        (("scenarios", 0, "omega", "a"), math.inf),
        (("scenarios", 0, "x0"), -math.inf),
        (("stan", "init_radius"), math.inf),
        (("figure2", "x0"), -math.inf),
    ],
)
def test_nan_and_every_other_infinite_number_are_still_refused(where, value):
    config = {"scenarios": [same_a09(prior={"a": [0.0, 1.0]})], "stan": {}, "figure2": {}}
    target = config
    for key in where[:-1]:
        target = target[key]
    target[where[-1]] = value
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate(config)
    key = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in where).lstrip(".")
    assert f"{key} = {value!r}: must be a finite number" in str(err.value)


def test_an_empty_or_reversed_infinite_interval_is_refused():
    for interval in ([math.inf, math.inf], [0.0, -math.inf]):
        with pytest.raises(cfg.ConfigError, match="must have lower < upper"):
            cfg.validate({"scenarios": [same_a09(prior={"a": interval})]})


def test_a_default_prior_may_be_an_interval(level_model):
    """Flat on the whole line written in the model file; the config may still name a
    variant or an interval over it."""
    assert LevelModel.default_prior_problems() == []
    bounds = level_model.prior_bounds({"mu": -0.5, "b": 2.0})
    assert bounds.lower.tolist() == [-math.inf, 0.0]
    assert bounds.upper.tolist() == [math.inf, math.inf]
    assert level_model.prior_bounds({"mu": -0.5, "b": 0.5}, {"b": "restricted"}).upper[1] == 1.0
    c = cfg.validate(
        {
            "scenarios": [
                {
                    "name": "lv",
                    "model": "level_test",
                    "omega": {"mu": -0.5, "b": 2.0},
                    "x0": 0,
                    "T": 5,
                    "K": 4,
                    "stan": False,
                }
            ]
        }
    )
    assert c["scenarios"][0].get("prior") is None
    with pytest.raises(cfg.ConfigError, match=r"true value b=-1.0 lies outside the support"):
        cfg.validate(
            {
                "scenarios": [
                    {
                        "name": "lv",
                        "model": "level_test",
                        "omega": {"mu": 0.5, "b": -1.0},
                        "x0": 0,
                        "T": 5,
                        "K": 4,
                        "stan": False,
                    }
                ]
            }
        )


@pytest.mark.parametrize(
    ("default", "words"),
    [
        ((1.0, 0.0), "must have lower < upper"),
        ((math.nan, 1.0), "must have lower < upper"),
        ((0.0,), "must be a variant name or an interval [lower, upper] of two numbers"),
        ("flat", "default_prior['b'] = 'flat' is not in allowed_priors['b']"),
    ],
)
def test_a_broken_default_prior_is_named(default, words):
    broken = type("Broken", (LevelModel,), {"default_prior": {"mu": (0.0, 1.0), "b": default}})
    problems = broken.default_prior_problems()
    assert len(problems) == 1 and words in problems[0]
