"""Analytic gradients generated from the model's terms (issue 49), compiled and run with the
native driver: equal to Stan's autodiff at random points, a planted error found in one line,
draws equal in distribution over seeds.  One compile per program (about a minute on first
use, cached afterwards by content)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from ssmobs.analytic_gradients import AnalyticProgram, write_analytic_program
from ssmobs.check_model import check_model
from ssmobs.check_model_analytic import analytic_problems
from ssmobs.check_model_cases import default_cases
from ssmobs.models import MODELS, get_model
from ssmobs.stan_backends import stan_file
from ssmobs.stan_backends.base import SamplerSettings
from ssmobs.stan_backends.native import NativeBackend

pytestmark = pytest.mark.stan

#: `make test` compiles one generated program, model Same's (the other tests of this module
#: use it too); each other model's is one more compile of about a minute on a cold cache, and
#: analytic gradients are a setting a user opts into (stan.gradients), so they run with
#: `slow` (`make test-slow`, issue 48)
FAST = ("same",)
#: a compile of a program that only this test uses (a planted error, a generated whole
#: program): `make test-slow` (issue 48)
OWN_COMPILE = pytest.mark.slow


@pytest.mark.parametrize(
    "slug", [s if s in FAST else pytest.param(s, marks=pytest.mark.slow) for s in sorted(MODELS)]
)
def test_analytic_equals_autodiff(slug):
    model = get_model(slug)
    for i, case in enumerate(default_cases(model)[:2]):
        assert analytic_problems(model, stan_file(slug), case, seed=i) == []


def test_check_model_runs_the_analytic_check():
    report = check_model("same", gradients="analytic")
    assert report.problems == []
    assert any(c.startswith("analytic gradients:") for c in report.checks)


@OWN_COMPILE
def test_planted_error_in_a_generated_term_is_one_line(tmp_path):
    model = get_model("same")
    good = write_analytic_program(model, stan_file("same"))
    text = good.header.read_text()
    # the gradient of the transition term in x_t, off by one part in a million
    target = re.search(r"\n(\s+g_x\[\(t \+ 1\) \* 1 \+ 0\] \+= r_c4\*.*);\n", text)
    assert target is not None
    planted = text.replace(target.group(1), target.group(1) + "*1.000001")
    header = tmp_path / "same_analytic.hpp"
    header.write_text(planted)
    program = AnalyticProgram(stan_file=good.stan_file, header=header)
    problems = analytic_problems(model, stan_file("same"), default_cases(model)[0], program=program)
    assert len(problems) == 1 and "\n" not in problems[0]
    assert "gradient in x[" in problems[0] and "differs from Stan's autodiff" in problems[0]


def _summaries(draws) -> np.ndarray:
    a = draws.params["a"].reshape(-1)
    x = draws.params["x"].reshape(-1, draws.params["x"].shape[-1])
    return np.array(
        [a.mean(), a.std(), *np.quantile(a, [0.05, 0.5, 0.95]), x[:, 4].mean(), x[:, 4].std()]
    )


def test_draws_equal_in_distribution_over_seeds():
    """same, a = 0.7, x0 = 8, T = 20: per seed the posterior mean, sd and 5/50/95 % quantiles
    of a and the mean and sd of x_5, each path over 6 seeds; the two paths' averages differ
    by less than 4.5 standard errors of their difference (the run-to-run spread)."""
    model = get_model("same")
    rng = np.random.default_rng(7)
    omega, T = np.array([0.7]), 20
    x, z = model.simulate(
        omega, np.array([8.0]), rng.normal(size=(1, T, 1)), rng.normal(size=(1, T, 1))
    )
    data = model.stan_data(z[0], model.prior_bounds(omega))
    program = write_analytic_program(model, stan_file("same"))
    settings = SamplerSettings(chains=2, iter_warmup=300, iter_sampling=500)
    native = NativeBackend()
    auto, ana = [], []
    for seed in range(1, 7):
        auto.append(_summaries(native.sample(stan_file("same"), data, seed, settings)))
        ana.append(
            _summaries(
                native.sample(program.stan_file, data, seed, settings, user_header=program.header)
            )
        )
    auto_a, ana_a = np.array(auto), np.array(ana)
    assert not np.array_equal(auto_a, ana_a)  # another summation order: other draws
    se = np.sqrt(auto_a.var(axis=0, ddof=1) / len(auto) + ana_a.var(axis=0, ddof=1) / len(ana))
    gap = np.abs(auto_a.mean(axis=0) - ana_a.mean(axis=0))
    assert np.all(gap < 4.5 * se), (gap / se).round(2).tolist()


@OWN_COMPILE
def test_generated_whole_program_equals_the_hand_written_one():
    """A model without a Stan program gets one (bounds from its prior intervals and
    parameter kinds, the analytic log density): checked against the hand-written program."""
    model = get_model("stoch_vol")
    program = write_analytic_program(model, None)
    for i, case in enumerate(default_cases(model)[:2]):
        assert analytic_problems(model, stan_file("stoch_vol"), case, seed=i, program=program) == []


def test_nuts_stage_runs_the_analytic_program_and_keys_its_records(tmp_path):
    from ssmobs.convergence import ConvergenceSettings
    from ssmobs.nuts_stage import run_trajectories
    from ssmobs.record_cache import program_hash
    from ssmobs.stages.stan import stan_program

    model = get_model("same")
    program, header = stan_program("same", "analytic")
    assert header is not None and program != stan_file("same")
    assert stan_program("same", "autodiff") == (stan_file("same"), None)
    omega = model.omega_array({"a": 0.7})
    rng = np.random.default_rng(2)
    x, z = model.simulate(
        omega, np.array([8.0]), rng.normal(size=(1, 20, 1)), rng.normal(size=(1, 20, 1))
    )
    sampler = SamplerSettings(chains=2, iter_warmup=200, iter_sampling=200)

    def run():
        return run_trajectories(
            model,
            NativeBackend(),
            program,
            z,
            x,
            [0],
            model.prior_bounds(omega),
            omega,
            np.array([8.0]),
            "same_T20",
            1,
            sampler,
            ConvergenceSettings(),
            records_dir=tmp_path / "records",
            user_header=header,
        )[0]

    rec = run()
    assert rec["status"] == "ok" and rec["map"] is not None
    assert rec["key"]["program_hash"] == program_hash(program, header)
    assert rec["key"]["program_hash"] != program_hash(stan_file("same"))
    again = run()  # the stored record, found again under the same key, not a new run
    assert again["key"] == rec["key"] and again["timings"] == rec["timings"]
