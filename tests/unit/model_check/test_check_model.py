"""The model check's Python and Stan-source parts (no compilation)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from factories import same_a09
from ssmobs.config.stage_inputs import model_check_inputs
from ssmobs.model_check.stan_source import declared_names, stan_block, stan_source_problems
from ssmobs.models import MODELS, get_model
from ssmobs.models.base import StateSpaceModel
from ssmobs.models.check_cases import (
    CheckCase,
    cases_from_scenarios,
    default_cases,
    default_values,
)
from ssmobs.models.self_check import python_problems, simulate_problems
from ssmobs.models.sep_d2_p1 import SepD2P1
from ssmobs.models.stoch_vol import StochVol
from ssmobs.stan_backends import stan_file

pytestmark = pytest.mark.unit


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_every_model_passes_the_python_and_source_checks(slug):
    model = get_model(slug)
    cases = default_cases(model)
    assert cases, "no valid default case"
    for case in cases:
        assert python_problems(model, case) == []
    assert stan_source_problems(model, stan_file(slug)) == []


def test_default_cases_cover_every_allowed_variant():
    model = get_model("stoch_vol")
    priors = [c.prior for c in default_cases(model)]
    assert priors == [None, {"phi": "unrestricted"}, {"sigma": "restricted"}]


def test_declared_names_read_bounds_sizes_and_comments():
    code = """
    data { int<lower=1> T;  // steps
      array[T] vector[2] z; real<lower=fmax(a_lower, 0)> a_upper; /* c; */ }
    transformed parameters { real y = 1; }
    parameters {
      real<lower=a_lo, upper=a_upper> a;  # comment
      vector<lower=-1, upper=1>[2] b;
      real x0;
      matrix[T, 2] x;
    }
    """
    assert declared_names(stan_block(code, "parameters")) == ["a", "b", "x0", "x"]
    assert declared_names(stan_block(code, "data")) == ["T", "z", "a_upper"]


def test_swapped_parameters_are_named(tmp_path):
    model = get_model("stoch_vol")
    code = stan_file("stoch_vol").read_text()
    lines = code.splitlines()
    i = next(k for k, l in enumerate(lines) if l.strip().startswith("real<lower=phi_lower, upper"))
    lines[i], lines[i + 1] = lines[i + 1], lines[i]
    bad = tmp_path / "stoch_vol.stan"
    bad.write_text("\n".join(lines))
    (msg,) = stan_source_problems(model, bad)
    assert "declares ['sigma', 'phi', 'x0', 'x']" in msg
    assert "needs exactly ['phi', 'sigma', 'x0', 'x'] in this order" in msg


def test_undeclared_prior_bound_is_named(tmp_path):
    model = get_model("stoch_vol")
    code = stan_file("stoch_vol").read_text()
    code = code.replace("  real<lower=sigma_lower> sigma_upper;\n", "")
    code = code.replace("upper=sigma_upper", "upper=positive_infinity()")
    bad = tmp_path / "stoch_vol.stan"
    bad.write_text(code)
    (msg,) = stan_source_problems(model, bad)
    assert "does not declare ['sigma_upper']" in msg


def test_missing_stan_file(tmp_path):
    (msg,) = stan_source_problems(get_model("stoch_vol"), tmp_path / "nope.stan")
    assert f"no Stan program {tmp_path / 'nope.stan'}: name an existing file" in msg
    assert "the check takes the program generated from the model" in msg


class WrongShape(StateSpaceModel):
    slug = "wrong_shape"
    title = "simulator drops the last axis"
    obs_dim = 1
    state_dim = 1
    param_names = ("a",)
    default_prior = {"a": "restricted"}
    allowed_priors = {"a": ("restricted",)}

    def obs_term(self, omega, x, z):
        return (z[0] - x[0]) ** 2

    def trans_term(self, omega, x_prev, x):
        return (x[0] - omega[0] * x_prev[0]) ** 2

    def simulate(self, omega, x0, eta, eps):
        x = omega[0] * np.cumsum(eta[:, :, 0], axis=1)
        return x, x + eps[:, :, 0]  # (K, T) instead of (K, T, 1)


def test_simulator_with_wrong_shape_is_named():
    problems = python_problems(WrongShape(), CheckCase({"a": 0.5}, [0.0]), T=5)
    assert len(problems) == 2
    assert re.search(
        r"simulate returned x of shape \(3, 5\) for K=3, T=5; expected .* = "
        r"\(3, 5, 1\)",
        problems[0],
    )


def test_cases_from_scenarios_deduplicate():
    scs = [
        {"model": "stoch_vol", "omega": {"phi": 0.9, "sigma": 0.5}, "x0": 0, "prior": None, "T": T}
        for T in (20, 50)
    ] + [same_a09(name=None, T=None, K=None)]
    cases = cases_from_scenarios(scs, "stoch_vol")
    assert cases == [CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0], None)]


def test_default_values_are_distinct_and_valid():
    for slug in sorted(MODELS):
        model = get_model(slug)
        omega, x0 = default_values(model)
        values = list(omega.values()) + x0
        assert len(set(values)) == len(values), slug
        assert model.check_true_values(omega, x0) == [], slug


class SwappedSimulateD2P1(SepD2P1):
    """A user's slip: a and b exchanged in simulate only (terms and Stan are right)."""

    def simulate(self, omega, x0, eta, eps):
        a, b, c = omega
        return super().simulate(np.array([b, a, c]), x0, eta, eps)


class SwappedSimulateStochVol(StochVol):
    def simulate(self, omega, x0, eta, eps):
        phi, sigma = omega
        return super().simulate(np.array([sigma, phi]), x0, eta, eps)


@pytest.mark.parametrize(
    ("model", "term"),
    [(SwappedSimulateD2P1(), "observation"), (SwappedSimulateStochVol(), "transition")],
)
def test_swapped_parameters_in_simulate_are_named(model, term):
    case = default_cases(model)[0]
    assert python_problems(model, case) == []  # shapes and derivatives cannot see it
    problems = simulate_problems(model, case)
    assert problems and f"simulate does not match the {term} term" in problems[0]
    assert "check the order of the parameters in simulate" in problems[0]


def test_simulate_with_wrong_noise_scale_is_named():
    class WrongScale(StochVol):
        def simulate(self, omega, x0, eta, eps):
            x, z = super().simulate(omega, x0, eta, eps)
            return x, 1.1 * z

    (msg,) = simulate_problems(WrongScale(), default_cases(WrongScale())[0])
    assert "does not match the observation term" in msg


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_every_model_simulates_what_its_terms_say(slug):
    model = get_model(slug)
    for case in default_cases(model):
        assert simulate_problems(model, case) == []


def test_one_mistake_gives_one_message_and_its_check_is_not_checked(monkeypatch, capsys):
    """A swapped simulate is wrong in every case (3 default cases): one message, and the
    check that found it is printed as failed, not as checked (issue 36)."""
    import ssmobs.model_check.__main__ as cli
    import ssmobs.model_check.check as cm

    model = SwappedSimulateStochVol()
    assert len(default_cases(model)) == 3
    monkeypatch.setattr(cm, "get_model", lambda slug: model)
    monkeypatch.setattr(cli, "get_model", lambda slug: model)
    report = cm.check_model("stoch_vol", stan=False)
    assert len(report.problems) == 1
    assert report.checks == [] and report.failed.startswith("python:")
    assert report.to_dict()["failed"] == report.failed
    assert cli.main(["stoch_vol", "--no-stan"]) == 1
    out, err = capsys.readouterr()
    assert "checked" not in out
    assert f"failed   {report.failed}" in err and err.count("  - [python") == 1
    # the model as shipped: the check passes and is printed as checked
    monkeypatch.setattr(cm, "get_model", lambda slug: StochVol())
    monkeypatch.setattr(cli, "get_model", lambda slug: StochVol())
    assert cli.main(["stoch_vol", "--no-stan"]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("checked  python:") and "failed" not in err


def test_a_sign_error_in_every_step_is_reported_at_every_step():
    """A sign error in the transition mean makes every step wrong, and the message says so
    instead of naming the first step only (issue 36)."""

    class MinusPhi(StochVol):
        def simulate(self, omega, x0, eta, eps):
            phi, sigma = omega
            return super().simulate(np.array([-phi, sigma]), x0, eta, eps)

    model = MinusPhi()
    case = CheckCase({"phi": 0.5, "sigma": 0.5}, [2.0])
    (msg,) = simulate_problems(model, case, T=5)
    assert "does not match the transition term at every t = 1..5" in msg

    # a mistake in one step only is named at that step
    class LastStep(StochVol):
        def simulate(self, omega, x0, eta, eps):
            x, z = super().simulate(omega, x0, eta, eps)
            x, z = x.copy(), z.copy()
            x[:, -1] += 1.0
            return x, z

    msgs = simulate_problems(LastStep(), case, T=5)
    assert any("at t = 5 (of 1..5)" in m for m in msgs)


def test_a_model_mistake_is_named_before_the_size_check_blames_the_config(monkeypatch):
    """Issue 36: the growth model with ``b, a = omega`` swapped in simulate explodes the
    noise-free trajectory at (a, b) = (0.5, 25); the config's validation must report the
    model's own check, not that the config's true values reach |x_t| = 4.3e+52."""
    from growth_model import Growth
    from ssmobs.config import validation as cfg
    from ssmobs.models import MODELS

    class Swapped(Growth):
        def simulate(self, omega, x0, eta, eps):
            b, a = omega  # the planted mistake: param_names = ("a", "b")
            return super().simulate(np.array([a, b]), x0, eta, eps)

    entry = {"name": "g", "model": "test_growth", "omega": {"a": 0.5, "b": 25.0}, "x0": 0.1}
    entry.update(T=20, K=4, stan=False)
    monkeypatch.setitem(MODELS._load(), "test_growth", Swapped())
    with pytest.raises(cfg.ConfigError) as err:
        cfg.validate({"scenarios": [dict(entry)]})
    msg = str(err.value)
    assert "model 'test_growth' fails its own check (python -m ssmobs.model_check" in msg
    assert "simulate does not match the transition term" in msg
    assert "check the order of the parameters in simulate" in msg
    assert "reach |x_t|" not in msg
    # the message of `python -m ssmobs.model_check test_growth`, word for word
    from ssmobs.model_check.check import check_model

    assert check_model("test_growth", stan=False).problems[0] in msg
    # an observability map of that model is judged by the model's check too
    grid = {"name": "m", "base": {k: entry[k] for k in ("model", "omega", "x0")}}
    grid.update(vary="a", values=[0.5], T=[20], K=4)
    with pytest.raises(cfg.ConfigError, match="fails its own check"):
        cfg.validate({"scenarios": [{**entry, "T": 2}], "observability_maps": [grid]})
    # the correct model at the same values passes; a correct model at values that do blow
    # up is still refused by the size check, naming the config's values
    monkeypatch.setitem(MODELS._load(), "test_growth", Growth())
    cfg.validate({"scenarios": [dict(entry)]})
    with pytest.raises(cfg.ConfigError, match=r"reach \|x_t\| or \|z_t\| = .* within T=20"):
        cfg.validate({"scenarios": [{**entry, "omega": {"a": 0.99, "b": 1e4}}]})


def test_the_check_command_on_a_cold_cache_without_a_compiler_says_one_line(
    tmp_path, monkeypatch, capsys
):
    """Found before (issue 46): the tutorial's step 3 on a cold cache without g++ gave a
    57-line traceback and no remedy."""
    from ssmobs.model_check.__main__ import main

    monkeypatch.setenv("CXX", "no-such-compiler")
    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "cold"))
    assert main(["same"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "finds no C++ compiler 'no-such-compiler': install g++" in err
    assert "same.stan" in err and "--no-stan" in err


# ------------------------------------------------ symmetries and propriety (issue 60)
def _patch_model(monkeypatch, model):
    import ssmobs.model_check.__main__ as cli
    import ssmobs.model_check.check as cm

    monkeypatch.setattr(cm, "get_model", lambda slug: model)
    monkeypatch.setattr(cli, "get_model", lambda slug: model)
    return cm, cli


def test_the_check_reports_symmetries_and_propriety_per_scenario_prior(monkeypatch, tmp_path):
    import json

    from two_component_model import TwoComponents

    model = TwoComponents()
    cm, _ = _patch_model(monkeypatch, model)
    scenario = {"model": model.slug, "omega": {"a1": 0.9, "a2": 0.3}, "x0": [2.0, -1.0]}
    scenario["prior"] = None
    out = tmp_path / "check.json"
    inputs = model_check_inputs(scenario, {"stan": {}})
    report = cm.run_check_model(inputs, {"report": out})
    written = json.loads(out.read_text())
    assert written == report.to_dict()
    assert list(written)[:5] == ["slug", "ok", "checks", "failed", "problems"]
    assert [r["name"] for r in written["symmetries"]] == ["swap (a1, x_1) <-> (a2, x_2)"]
    (prior,) = written["propriety"]  # the scenario's prior only
    assert prior["prior"] == "a1: (-1, 1), a2: (-1, 1)"
    assert prior["label"].startswith("improper: x0_1 drops out of the likelihood at a1 = 0")
    assert len(prior["improper"]) == 3 and prior["edge"] == []
    assert written["symmetry_warnings"] == []


def test_the_check_command_prints_the_symmetry_table(monkeypatch, capsys):
    from phase_model import PhaseTracking

    _patch_model(monkeypatch, PhaseTracking())
    from ssmobs.model_check.__main__ import main

    assert main(["test_phase", "--no-stan"]) == 0
    out = capsys.readouterr().out
    assert "symmetries of model 'test_phase' (found from its terms" in out
    assert "  translation (infinite order)  x -> x + 2*pi" in out
    assert "  reflection" in out and "(mu, x) -> (-mu, pi - x)" in out
    assert "    improper: x -> x + 2*pi (x0 and every state together) leaves the density" in out


def test_a_declared_mirror_image_is_checked_against_the_found_maps(monkeypatch):
    from growth_model import Growth
    from phase_model import PhaseTracking

    # the growth model declares x -> -x, which the search finds: no warning
    cm, _ = _patch_model(monkeypatch, Growth())
    report = cm.check_model("test_growth", stan=False)
    assert report.analysis is not None and report.analysis.warnings == []
    assert report.to_dict()["symmetries"][0]["name"] == "x -> -x"

    class FourPi(PhaseTracking):
        """Declares x -> x + 4 pi (a symmetry, but no found map's image) and x -> -x (not
        one: the drift mu would have to change sign too)."""

        def mirror_images(self, theta):
            theta = np.asarray(theta, dtype=float)
            shifted = np.concatenate([theta[:, :2], theta[:, 2:] + 4 * np.pi], axis=1)
            flipped = np.concatenate([theta[:, :2], -theta[:, 2:]], axis=1)
            return [shifted, flipped]

    cm, _ = _patch_model(monkeypatch, FourPi())
    report = cm.check_model("test_phase", stan=False)
    assert not report.problems  # warnings, not problems
    first, second = report.analysis.warnings
    assert first.startswith("mirror_images: declared image 1 is not the image under any")
    assert "leaves -2 log pi unchanged at random points" in first
    assert "declared image 2" in second and "changes -2 log pi" in second
    assert report.to_dict()["symmetry_warnings"] == [first, second]


def test_a_map_sympy_cannot_show_is_not_used_and_is_a_warning(monkeypatch):
    import ssmobs.models.symmetries as symmetries
    from growth_model import Growth

    class Unproven(Growth):
        """The growth model, with SymPy made unable to show any map (fresh memo key)."""

        def mirror_images(self, theta):
            return []

    monkeypatch.setattr(symmetries, "_symbolically_invariant", lambda cand, syms: False)
    cm, _ = _patch_model(monkeypatch, Unproven())
    report = cm.check_model("test_growth", stan=False)
    assert report.to_dict()["symmetries"] == []
    (warning,) = report.analysis.warnings
    assert warning.startswith("x -> -x: leaves both terms unchanged at random points, but SymPy")
    assert "not used" in warning
