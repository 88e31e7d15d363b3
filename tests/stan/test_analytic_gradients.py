"""Analytic gradients generated from the model's terms (issue 49), compiled and run with the
native driver: equal to Stan's autodiff at random points, a planted error found in one line,
draws equal in distribution over seeds.  One compile per program (about a minute on first
use, cached afterwards by content)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from ssmobs.model_check.analytic import analytic_problems
from ssmobs.model_check.check import check_model
from ssmobs.models import MODELS, get_model
from ssmobs.models.check_cases import default_cases
from ssmobs.nuts.analytic_program import AnalyticProgram, write_analytic_program
from ssmobs.stan_backends import stan_file
from ssmobs.stan_backends.base import SamplerSettings
from ssmobs.stan_backends.native import NativeBackend

pytestmark = pytest.mark.stan

#: `make test` compiles one generated program, model Same's (the other tests of this module
#: use it too); each other model's is one more compile of about a minute on a cold cache
#: (`make run` compiles and checks all of them), so they run with `slow` (`make test-slow`,
#: issue 48)
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


def _same_data(a: float, x0: float, T: int, seed: int) -> dict:
    """Stan data of model Same: one trajectory simulated from (a, x0), its prior bounds."""
    model = get_model("same")
    rng = np.random.default_rng(seed)
    omega = np.array([a])
    _, z = model.simulate(
        omega, np.array([x0]), rng.normal(size=(1, T, 1)), rng.normal(size=(1, T, 1))
    )
    return model.stan_data(z[0], model.prior_bounds(omega))


def test_check_model_runs_the_analytic_check_on_the_one_program_nuts_runs(monkeypatch):
    compiled = []
    real = NativeBackend.compile

    def recording(self, stan_path, *args, **kwargs):
        compiled.append(str(stan_path))
        return real(self, stan_path, *args, **kwargs)

    monkeypatch.setattr(NativeBackend, "compile", recording)
    report = check_model("same", gradients="analytic")
    assert report.problems == []
    assert any(c.startswith("analytic gradients:") for c in report.checks)
    program = write_analytic_program(get_model("same"), stan_file("same"))
    assert compiled and set(compiled) == {str(program.stan_file)}


def test_the_twin_is_the_hand_written_model_block():
    """--autodiff-twin evaluates the program's hand-written statements: the hand-written
    program's log density and gradients, bit for bit (Stan's constants kept, so its value
    differs from the generated block's by one constant); without it the generated block."""
    model = get_model("same")
    T = 6
    data = _same_data(a=0.8, x0=2.0, T=T, seed=5)
    points = [{"a": a, "x0": 1.5, "x": list(np.linspace(-1, 2, T) * a)} for a in (0.3, 0.8)]
    program = write_analytic_program(model, stan_file("same"))
    native = NativeBackend()
    for sampler in (False, True):
        own = native.log_density(stan_file("same"), data, points, sampler=sampler)
        twin = native.log_density(
            program.stan_file, data, points, program.header, sampler, twin=True
        )
        generated = native.log_density(program.stan_file, data, points, program.header, sampler)
        assert twin.values == own.values and twin.gradients == own.gradients
        if not sampler:  # constants kept: the two blocks differ by one constant
            gaps = [t - g for t, g in zip(twin.values, generated.values)]
            assert gaps[0] != 0 and abs(gaps[0] - gaps[1]) < 1e-9


@OWN_COMPILE
def test_planted_error_in_a_generated_term_is_one_line(tmp_path):
    model = get_model("same")
    good = write_analytic_program(model, stan_file("same"))
    text = good.header.read_text()
    # the gradient of the transition term in x_t, off by one part in a million
    target = re.search(r"\n(\s+gx_now0 \+= r_c4\*.*);\n", text)
    assert target is not None
    planted = text.replace(target.group(1), target.group(1) + "*1.000001")
    header = tmp_path / "same_analytic.hpp"
    header.write_text(planted)
    program = AnalyticProgram(stan_file=good.stan_file, header=header)
    problems = analytic_problems(model, stan_file("same"), default_cases(model)[0], program=program)
    assert len(problems) == 1 and "\n" not in problems[0]
    assert "gradient in x[" in problems[0] and "differs from Stan's autodiff" in problems[0]


@OWN_COMPILE
def test_planted_error_in_the_tapeless_gradient_is_one_line(tmp_path):
    """The sampler's gradient without the tape (ssmobs/gradient_slot.hpp), off by one part
    in a million in a's bound transform: Stan's log density agrees, the sampler's does not."""
    model = get_model("same")
    good = write_analytic_program(model, stan_file("same"))
    text = good.header.read_text()
    target = re.search(r"\n(\s+out\[0\] = ssmobs::bound_chain\(.*\));\n", text)
    assert target is not None
    header = tmp_path / "same_analytic.hpp"
    header.write_text(text.replace(target.group(1), target.group(1) + " * 1.000001"))
    program = AnalyticProgram(stan_file=good.stan_file, header=header)
    problems = analytic_problems(model, stan_file("same"), default_cases(model)[0], program=program)
    assert len(problems) == 1 and "\n" not in problems[0]
    assert "the sampler's gradient in a differs from Stan's autodiff" in problems[0]


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
    data = _same_data(a=0.7, x0=8.0, T=20, seed=7)
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
    from ssmobs.nuts.batch import NutsBatch, run_trajectories
    from ssmobs.nuts.convergence import ConvergenceSettings
    from ssmobs.nuts.record_cache import program_hash
    from ssmobs.nuts.stan_program import stan_program

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
        batch = NutsBatch(
            model,
            program,
            z,
            x,
            model.prior_bounds(omega),
            omega,
            np.array([8.0]),
            "same_T20",
            1,
            sampler,
            ConvergenceSettings(),
            user_header=header,
        )
        return run_trajectories(batch, NativeBackend(), [0], records_dir=tmp_path / "records")[0]

    rec = run()
    assert rec["status"] == "ok" and rec["map"] is not None
    assert rec["key"]["program_hash"] == program_hash(program, header)
    assert rec["key"]["program_hash"] != program_hash(stan_file("same"))
    again = run()  # the stored record, found again under the same key, not a new run
    assert again["key"] == rec["key"] and again["timings"] == rec["timings"]


@pytest.fixture
def cubic_sensor(monkeypatch):
    """The cubic sensor test model (tests/cubic_sensor_model.py) as a model without a Stan
    program of its own."""
    from cubic_sensor_model import CubicSensor

    model = CubicSensor()
    monkeypatch.setitem(MODELS._load(), model.slug, model)
    assert not (REPO_STAN / f"{model.slug}.stan").exists()
    return model


REPO_STAN = stan_file("same").parent


def test_model_check_checks_a_one_file_model_by_its_generated_program(cubic_sensor):
    """No stan/<slug>.stan: the check compiles the generated program and compares its log
    density (up to a constant) and support with the Python model, and its gradient with
    the Python model's through Stan's bound transforms (issue 49, item 5)."""
    report = check_model(cubic_sensor.slug)
    assert report.problems == [], report.problems
    assert any(c.startswith("stan program generated from the model") for c in report.checks)
    assert any(c.startswith("generated gradients: equal to") for c in report.checks)


@pytest.mark.slow  # a rare path (a broken generator), with a program build of its own
def test_planted_error_in_a_generated_program_is_one_line(cubic_sensor, tmp_path):
    from ssmobs.model_check.analytic import generated_problems

    good = write_analytic_program(cubic_sensor, None)
    text = good.header.read_text()
    # the gradient of the observation term in b, off by one part in ten million
    target = re.search(r"\n(\s+gw0 \+= .*);\n", text)
    assert target is not None
    header = tmp_path / "planted.hpp"
    header.write_text(text.replace(target.group(1), target.group(1) + "*1.0000001"))
    case = default_cases(cubic_sensor)[0]
    assert generated_problems(cubic_sensor, good, case) == []
    problems = generated_problems(cubic_sensor, AnalyticProgram(good.stan_file, header), case)
    assert len(problems) == 1 and "\n" not in problems[0]
    assert "gradient in b differs from the Python model's" in problems[0]


def test_support_constraints_stop_a_one_file_model_in_one_line(monkeypatch):
    """sep_d1_p2's a^2 + b^2 < 1 is no parameter bound: without its hand-written program
    the check names the constraint and the remedy in one line, before any compile."""
    from ssmobs.models.sep_d1_p2 import SepD1P2
    from ssmobs.nuts.analytic_program import generation_problem

    class Unwritten(SepD1P2):
        slug = "test_unwritten"

    monkeypatch.setitem(MODELS._load(), "test_unwritten", Unwritten())
    assert generation_problem(get_model("sep_d1_p2")) is not None
    assert generation_problem(get_model("stoch_vol")) is None
    report = check_model("test_unwritten")
    assert report.failed == "stan program generated from the model"
    assert len(report.problems) == 1 and "\n" not in report.problems[0]
    assert "support constraints (a^2 + b^2 < 1)" in report.problems[0]
    assert "write stan/test_unwritten.stan by hand" in report.problems[0]
