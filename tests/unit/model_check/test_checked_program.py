"""Which generated Stan program the model check runs (ssmobs.model_check.program, issue 62):
in the workflow the one rule build_stan_model wrote, named by its marker, read as it is; on
the command line one written by the check.  No compile: the steps that evaluate the program
are replaced by recorders of what they were given."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import ssmobs.model_check.analytic as analytic_check
import ssmobs.model_check.check as cm
import ssmobs.model_check.program as checked
from ssmobs.config.stage_inputs import model_check_inputs
from ssmobs.models import MODELS, get_model
from ssmobs.models.check_cases import default_cases, default_values
from ssmobs.nuts.analytic_program import (
    AnalyticProgram,
    analytic_program_files,
    write_analytic_program,
)
from ssmobs.stan_backends import stan_file

pytestmark = pytest.mark.unit


def _marker(path: Path, program: Path, header: Path | None) -> Path:
    """A build job's marker naming ``program`` and ``header``, as rule build_stan_model
    writes it."""
    header_file = None if header is None else str(header)
    marker = {"backend": "native", "program_file": str(program), "header_file": header_file}
    path.write_text(json.dumps(marker))
    return path


@pytest.fixture
def build_cache(tmp_path, monkeypatch) -> Path:
    """The program cache of the build job; the test then moves the check to another one."""
    cache = tmp_path / "build_cache"
    monkeypatch.setenv("SSMOBS_CACHE", str(cache))
    return cache


@pytest.fixture
def recorded(monkeypatch) -> dict[str, object]:
    """What the Stan steps of the check were given (steps 3 and 4 replaced: no compile)."""
    seen: dict[str, object] = {}

    def stan_problems(model, path, case, **kwargs):
        seen.setdefault("compiled", (path, kwargs["user_header"]))
        return []

    def analytic_problems(model, path, case, **kwargs):
        seen.setdefault("analytic", kwargs["program"])
        return []

    def generated_problems(model, program, case, **kwargs):
        seen.setdefault("generated", program)
        return []

    monkeypatch.setattr(cm, "stan_problems", stan_problems)
    monkeypatch.setattr(analytic_check, "analytic_problems", analytic_problems)
    monkeypatch.setattr(analytic_check, "generated_problems", generated_problems)
    return seen


def _no_writing(monkeypatch) -> None:
    def refuse(*args, **kwargs):
        raise AssertionError("the check wrote a generated program")

    monkeypatch.setattr(checked, "write_analytic_program", refuse)


def test_the_stan_check_runs_the_analytic_program_its_build_job_wrote(
    build_cache, recorded, tmp_path, monkeypatch
):
    """With analytic gradients the check runs the files the marker names (the program NUTS
    runs, in the build job's cache), writes none, and still checks them against the
    autodiff twin (step 4)."""
    model = get_model("same")
    built = write_analytic_program(model, stan_file("same"))
    marker = _marker(tmp_path / "marker.json", built.stan_file, built.header)
    check_cache = tmp_path / "check_cache"
    monkeypatch.setenv("SSMOBS_CACHE", str(check_cache))
    _no_writing(monkeypatch)
    out = tmp_path / "check.json"
    omega, x0 = default_values(model)  # the default cases only: no case of its own
    entry = {"model": "same", "omega": omega, "x0": x0}
    inputs = model_check_inputs(entry, {"stan": {"gradients": "analytic"}}, against_stan=True)
    paths = {"report": out, "stan": stan_file("same"), "program": marker}
    report = cm.run_check_model(inputs, paths)
    assert recorded["compiled"] == (built.stan_file, built.header)
    assert recorded["analytic"] == AnalyticProgram(built.stan_file, built.header)
    assert any(c.startswith("analytic gradients: ") for c in report.checks)
    assert json.loads(out.read_text())["ok"] is True
    assert not check_cache.exists()  # nothing generated where the check runs


def test_without_a_build_job_the_check_writes_the_program(build_cache, recorded):
    """The command line (and a direct call) has no build job: the check writes the program
    where the build job would, the same files."""
    model = get_model("same")
    expected = analytic_program_files(model, stan_file("same"))
    assert not expected.stan_file.exists()
    report = cm.check_model("same", default_cases(model)[:1], gradients="analytic")
    assert report.problems == []
    assert expected.stan_file.is_file() and expected.header.is_file()
    assert recorded["analytic"] == expected
    assert recorded["compiled"] == (expected.stan_file, expected.header)


def test_a_one_file_model_is_checked_with_the_program_its_build_job_wrote(
    build_cache, recorded, tmp_path, monkeypatch
):
    """A model without stan/<slug>.stan: its whole generated program, from the marker, is
    what steps 2 to 4 read (its gradient against the Python model's)."""
    from cubic_sensor_model import CubicSensor

    model = CubicSensor()
    monkeypatch.setitem(MODELS._load(), model.slug, model)
    built = write_analytic_program(model, None)
    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "check_cache"))
    _no_writing(monkeypatch)
    report = cm.check_model(
        model.slug, default_cases(model)[:1], built=(built.stan_file, built.header)
    )
    assert report.problems == [], report.problems
    assert recorded["generated"] == AnalyticProgram(built.stan_file, built.header)
    assert recorded["compiled"] == (built.stan_file, built.header)
    assert report.checks[1] == "stan program generated from the model"
    assert not (tmp_path / "check_cache").exists()


def test_a_build_jobs_program_that_is_not_the_models_is_refused(build_cache, tmp_path):
    """Files that do not hold what the model generates now (edited, or a program without
    its header) are no program the check vouches for: one line, no check against them."""
    model = get_model("same")
    built = write_analytic_program(model, stan_file("same"))
    edited = tmp_path / "edited.stan"
    edited.write_text(built.stan_file.read_text() + "\n// edited\n")
    with pytest.raises(ValueError, match="is not the one generated from model 'same' now"):
        checked.checked_program(model, stan_file("same"), (edited, built.header))
    with pytest.raises(ValueError, match="without the C\\+\\+ header"):
        checked.checked_program(model, stan_file("same"), (built.stan_file, None))
    assert checked.checked_program(model, stan_file("same"), (built.stan_file, built.header)) == (
        AnalyticProgram(built.stan_file, built.header)
    )


def test_with_autodiff_the_build_jobs_program_is_the_hand_written_one(tmp_path, recorded):
    """Autodiff gradients: the marker names stan/<model>.stan itself; the check compiles it
    and refuses a marker of another program."""
    model = get_model("same")
    report = cm.check_model("same", default_cases(model)[:1], built=(stan_file("same"), None))
    assert report.problems == []
    assert recorded["compiled"] == (stan_file("same"), None)
    other = tmp_path / "same.stan"
    other.write_text(stan_file("same").read_text() + "// another\n")
    with pytest.raises(ValueError, match="is not .*same.stan"):
        checked.same_program(stan_file("same"), (other, None))


def test_a_marker_whose_program_is_gone_says_so_in_one_line(tmp_path):
    program, header = tmp_path / "p.stan", tmp_path / "p.hpp"
    program.write_text("// program\n")
    marker = _marker(tmp_path / "marker.json", program, header)
    with pytest.raises(FileNotFoundError) as err:
        checked.built_program_files(marker)
    assert str(err.value).count("\n") == 0
    assert f"{header}: the Stan program that {marker} names is gone" in str(err.value)
    header.write_text("// header\n")
    assert checked.built_program_files(marker) == (program, header)
    hand_written = _marker(tmp_path / "own.json", program, None)
    assert checked.built_program_files(hand_written) == (program, None)
