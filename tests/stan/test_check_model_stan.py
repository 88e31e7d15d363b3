"""The model check against compiled Stan, for every model found by slug (not a fixed list).

Each broken Stan program below differs from stan/stoch_vol.stan in one place, the kind of
mistake a user makes; the check must name it.  Needs PyStan compilation (about a minute per
program on first use; cached afterwards).
"""

from __future__ import annotations

import pytest
from ssmobs.check_model import CheckCase, check_model, stan_problems
from ssmobs.models import MODELS, get_model
from ssmobs.stan_backends import stan_file

pytestmark = pytest.mark.stan


@pytest.mark.parametrize("slug", sorted(MODELS))
def test_every_model_agrees_with_its_stan_program(slug):
    report = check_model(slug)
    assert report.problems == []
    assert any("stan compiled" in c for c in report.checks)


def _broken(tmp_path, old: str, new: str):
    code = stan_file("stoch_vol").read_text()
    assert old in code
    path = tmp_path / "stoch_vol.stan"
    path.write_text(code.replace(old, new))
    return path


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


def test_log_density_that_differs_is_named(tmp_path):
    # exp(x) instead of exp(x / 2): the observation standard deviation is wrong
    path = _broken(tmp_path, "z ~ normal(0, exp(x / 2));", "z ~ normal(0, exp(x));  // wrong scale")
    problems = stan_problems(
        get_model("stoch_vol"), path, CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0])
    )
    assert len(problems) == 1
    assert "differs from the Python log posterior by more than a constant" in problems[0]


def test_agreeing_program_gives_no_problem_for_configured_case():
    problems = stan_problems(
        get_model("stoch_vol"),
        stan_file("stoch_vol"),
        CheckCase({"phi": 0.9, "sigma": 0.5}, [0.0]),
        T=9,
        seed=3,
    )
    assert problems == []
