"""The model check against compiled Stan, for every model found by slug (not a fixed list).

Each broken Stan program below differs from stan/stoch_vol.stan in one place, the kind of
mistake a user makes; the check must name it.  The check evaluates Stan's log density with
the native driver (one compile per program, shared with sampling; about a minute per program
on first use, cached afterwards); PyStan's ``log_prob`` is the oracle it is compared with.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from ssmobs.model_check.check import check_model
from ssmobs.model_check.stan import stan_density, stan_point, stan_problems
from ssmobs.models import MODELS, get_model
from ssmobs.models.check_cases import CheckCase, sample_theta
from ssmobs.stan_backends import has_stan_file, stan_file

pytestmark = pytest.mark.stan

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_every_model_agrees_with_its_stan_program(slug):
    """The check the default profile runs, on the program `make run` compiled: with analytic
    gradients its hand-written statements are compared too (the program's autodiff twin)."""
    gradients = yaml.safe_load((REPO / "config" / "config.yaml").read_text())["stan"]["gradients"]
    report = check_model(slug, gradients=gradients)
    assert report.problems == []
    assert any("stan compiled" in c for c in report.checks)
    if gradients == "analytic" and has_stan_file(slug):
        assert any(c.startswith("analytic gradients:") for c in report.checks)


def test_the_workflows_check_runs_the_program_its_build_job_wrote(tmp_path, monkeypatch):
    """Rule check_model_stan (issue 62): the analytic program rule build_stan_model wrote and
    compiled, named by its marker, is what the check compiles and compares with the Python
    model and with its autodiff twin; the check writes no program of its own."""
    import json

    import ssmobs.model_check.program as checked
    from ssmobs.config.stage_inputs import model_check_inputs
    from ssmobs.model_check.check import run_check_model
    from ssmobs.stages.stan import run_build_stan_model

    marker = tmp_path / "marker.json"
    built = run_build_stan_model("same", "native", marker, "analytic")

    def refuse(*args, **kwargs):
        raise AssertionError("the check wrote a generated program")

    monkeypatch.setattr(checked, "write_analytic_program", refuse)
    case = {"model": "same", "omega": {"a": 0.9}, "x0": [0.0], "prior": None}
    inputs = model_check_inputs(case, {"stan": {"gradients": "analytic"}}, against_stan=True)
    out = tmp_path / "check.json"
    report = run_check_model(inputs, {"report": out, "stan": stan_file("same"), "program": marker})
    assert json.loads(out.read_text())["ok"] is True
    assert any(c.startswith("stan compiled:") for c in report.checks)
    assert any(c.startswith("analytic gradients:") for c in report.checks)
    assert built["header_file"] is not None and Path(built["program_file"]).is_file()


#: a test that compiles a broken copy of a program (about 30-50 CPU-s each, cached by content
#: only for that copy): the check's messages for a user's mistake, a rare path, so in
#: `make test-slow` (issue 48); the check on the real programs and a program that stanc
#: rejects (no C++ compile) stay in `make test`
BROKEN_PROGRAM = pytest.mark.slow


def _broken(tmp_path, old: str, new: str):
    code = stan_file("stoch_vol").read_text()
    assert old in code
    path = tmp_path / "stoch_vol.stan"
    path.write_text(code.replace(old, new))
    return path


@BROKEN_PROGRAM
def test_prior_bound_stan_does_not_share(tmp_path):
    # sigma bounded below only: the Python prior U(0, 1) ('restricted') is not Stan's
    path = _broken(
        tmp_path, "real<lower=sigma_lo, upper=sigma_upper> sigma;", "real<lower=sigma_lo> sigma;"
    )
    case = CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0], {"sigma": "restricted"})
    problems = stan_problems(get_model("stoch_vol"), path, case)
    assert len(problems) == 1
    msg = problems[0]
    assert "Stan accepts sigma=1.001" in msg and "upper bound 1" in msg
    assert "does not share this prior bound" in msg


@BROKEN_PROGRAM
def test_interval_prior_of_the_config_is_checked_against_stan(tmp_path):
    """Issue 47: a config's interval [0.1, 5] for sigma is compared with Stan's bounds: the
    program that declares only the lower bound accepts sigma beyond 5."""
    from ssmobs.models.check_cases import prior_variant_cases

    model = get_model("stoch_vol")
    case = CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0], {"sigma": [0.1, 5.0]})
    assert case in prior_variant_cases(model, case)  # the configured interval is a case
    path = _broken(
        tmp_path, "real<lower=sigma_lo, upper=sigma_upper> sigma;", "real<lower=sigma_lo> sigma;"
    )
    problems = stan_problems(model, path, case)
    assert len(problems) == 1
    assert "Stan accepts sigma=5.00" in problems[0] and "interval(0.1, 5)" in problems[0]
    assert stan_problems(model, stan_file("stoch_vol"), case) == []


@BROKEN_PROGRAM
def test_log_density_that_differs_is_named(tmp_path):
    # exp(x) instead of exp(x / 2): the observation standard deviation is wrong
    path = _broken(tmp_path, "z ~ normal(0, exp(x / 2));", "z ~ normal(0, exp(x));  // wrong scale")
    problems = stan_problems(
        get_model("stoch_vol"), path, CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0])
    )
    assert len(problems) == 1
    assert "differs from the Python log posterior by more than a constant" in problems[0]
    # the difference is located: it moves with the states and the data, not with Omega
    assert "moves with x_1..x_T, the data z:" in problems[0]
    assert "look at the observation term" in problems[0]


@BROKEN_PROGRAM
def test_transition_that_differs_is_located(tmp_path):
    # the transition's mean ignores phi: a term in Omega and the states, not in the data
    path = _broken(
        tmp_path,
        "x ~ normal(mu + phi * (append_row(x0, head(x, T - 1)) - mu), sigma);",
        "x ~ normal(mu + 0.5 * (append_row(x0, head(x, T - 1)) - mu), sigma);",
    )
    (msg,) = stan_problems(
        get_model("stoch_vol"), path, CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0])
    )
    assert "moves with Omega (phi, sigma), x0, x_1..x_T:" in msg
    assert "the data z" not in msg
    assert "look at the transition term at t = 1" in msg


def test_agreeing_program_gives_no_problem_for_configured_case():
    problems = stan_problems(
        get_model("stoch_vol"),
        stan_file("stoch_vol"),
        CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0]),
        T=9,
        seed=3,
    )
    assert problems == []


@pytest.mark.pystan
def test_native_log_density_equals_pystan_oracle():
    # the same points, inside and outside the support: equal up to PyStan's dropped constants
    model = get_model("stoch_vol")
    case = CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0], {"sigma": "restricted"})
    theta, z, bounds = sample_theta(model, case, 7, 5, np.random.default_rng(1))
    points = [stan_point(model, th, 7) for th in theta]
    points += [{**points[0], "sigma": 1.2}, {**points[0], "phi": -1.5}]
    data = model.stan_data(z, bounds)
    values = {}
    for backend in ("native", "pystan"):
        with stan_density(stan_file("stoch_vol"), data, backend) as density:
            assert density.param_names == ["phi", "sigma", "x0", "x"]
            assert density.dims == [[], [], [], [7]]
            values[backend] = density.evaluate(points)
    native, pystan = values["native"], values["pystan"]
    assert native[-2:] == [None, None] and pystan[-2:] == [None, None]
    gap = np.array(native[:-2]) - np.array(pystan[:-2])
    np.testing.assert_allclose(gap, gap[0], rtol=0, atol=1e-9)
    assert abs(gap[0] - (-7 * np.log(2 * np.pi))) < 1e-9  # 2 x 7 normal densities' constants


def test_program_that_does_not_compile_is_a_problem(tmp_path):
    path = _broken(tmp_path, "x ~ normal(", "x ~ nromal(")
    (msg,) = stan_problems(
        get_model("stoch_vol"), path, CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0])
    )
    assert "building the program with the Python model's data failed" in msg
    assert "nromal" in msg
