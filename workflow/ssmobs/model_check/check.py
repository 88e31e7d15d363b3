"""Check a model's Python module and Stan program against each other, for any model.

The Python model (``workflow/ssmobs/models/<slug>.py``) drives the joint MAP (Sec. III.B)
and the Stan program (``stan/<slug>.stan``) the marginal MAP (Sec. III.C); the paper's
comparison of the two is only meaningful when both encode the same log posterior (2).
:func:`check_model` tells exactly what disagrees, cheapest checks first:

1. Python alone: the simulator (Eq. (1)) and ``initial_states`` return the declared
   shapes and finite values; the symbolic gradient and Hessian of -2 pi match central finite
   differences at random points inside the prior support.
2. Stan source, without compiling: the ``parameters`` block declares exactly
   ``(*param_names, x0, x)`` in this order, and the ``data`` block declares ``T``, ``z`` and
   the prior bounds ``<name>_lower`` / ``<name>_upper`` of every parameter.
3. Compiled Stan (the native driver's ``--log-density`` mode, or PyStan's ``log_prob``;
   the model block without Jacobian): parameter names
   and shapes; log density equal to the Python one up to one additive constant at random
   points inside the support; the support itself equal to Python's (points just inside
   every finite prior bound are accepted, points just outside and points violating a model
   constraint are rejected).
4. With analytic gradients (config key ``stan.gradients``): the log density and gradient
   generated from the model's terms against Stan's autodiff of the program's own
   statements, at random points, to 1e-12 relative (value up to a constant;
   :mod:`ssmobs.model_check.analytic`).  Steps 3 and 4 then run the program NUTS runs,
   which holds both model blocks: one compile per model.

Once step 1 passes, the model's symmetries and the propriety of its posterior under each
checked prior are found from its terms and reported (printed, and written under the keys
``symmetries``, ``propriety`` and ``symmetry_warnings`` of the check's file;
:mod:`ssmobs.model_check.symmetry_report`): findings, never problems.  A ``mirror_images``
declaration whose images no found symmetry gives is a warning line.

A model without ``stan/<slug>.stan`` is checked with the program generated from it
(:func:`ssmobs.nuts.analytic_program.generated_stan_code`, the one NUTS runs): steps 2 and 3
on that program, and in step 4 its gradient against the Python model's (it has no
autodiff twin); a model whose support constraints no generated program can express stops
with one line.  In the workflow a generated program is the one rule build_stan_model wrote
and compiled, named by its marker; the command line writes it itself
(:mod:`ssmobs.model_check.program`).

Each step lives in its own module: the cases in :mod:`ssmobs.models.check_cases`, step 1 in
:mod:`ssmobs.models.self_check` (the symmetry report in
:mod:`ssmobs.model_check.symmetry_report`), step 2 in
:mod:`ssmobs.model_check.stan_source`, step 3 in :mod:`ssmobs.model_check.stan`; this module
runs them in turn and reports.

Its command line is :mod:`ssmobs.model_check.__main__` (``python -m ssmobs.model_check``); the
Snakemake
rule ``check_model`` runs it for every model a config uses, before any design trajectory.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..log import LOGGER_NAME
from ..models import StateSpaceModel, get_model
from ..models.check_cases import (
    CheckCase,
    ModelCheckError,
    cases_from_scenarios,
    default_cases,
    prior_variant_cases,
)
from ..models.self_check import CHECK_T, model_check_seed, python_stage_problems
from .program import ProgramFiles, built_program_files, checked_program, same_program
from .stan import stan_problems
from .stan_source import stan_source_problems
from .symmetry_report import SymmetryReport, symmetry_report

if TYPE_CHECKING:  # the inputs object is built by the rule, not here
    from ..config.stage_inputs import ModelCheckInputs


@dataclass
class CheckReport:
    """What was checked and passed, the check that failed (``failed``, "" if none) and the
    problems it found (empty ``problems``: the model passes)."""

    slug: str
    checks: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    failed: str = ""
    #: the symmetries and propriety found from the terms (after the Python stage passes)
    analysis: SymmetryReport | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {
            "slug": self.slug,
            "ok": not self.problems,
            "checks": self.checks,
            "failed": self.failed,
            "problems": self.problems,
        }
        if self.analysis is not None:
            out["symmetries"] = self.analysis.symmetries
            out["propriety"] = self.analysis.propriety
            out["symmetry_warnings"] = self.analysis.warnings
        return out

    def record(self, check: str, problems: Sequence[str]) -> None:
        """A check's outcome: passed (``checks``) or the failed one with its problems."""
        if problems:
            self.failed, self.problems = check, [*self.problems, *problems]
        else:
            self.checks.append(check)


# ----------------------------------------------------------------------------- driver


def _first_problems(
    cases: Sequence[CheckCase], problems_of: Callable[[int, CheckCase], list[str]]
) -> list[str]:
    """The problems of the first case (in order, with its index) that has any, else none:
    one mistake, one message."""
    for i, case in enumerate(cases):
        found = problems_of(i, case)
        if found:
            return found
    return []


def _analysis(model: StateSpaceModel, cases: list[CheckCase], T: int, seed: int) -> SymmetryReport:
    """The symmetry report; an analysis that fails is a warning line, not a problem."""
    try:
        return symmetry_report(model, cases, T, seed)
    except Exception as err:  # noqa: BLE001 - reported as a warning
        why = " ".join(f"{type(err).__name__}: {err}".split())
        return SymmetryReport(warnings=[f"the symmetry and propriety analysis failed: {why}"])


def check_model(
    slug: str,
    cases: Sequence[CheckCase] | None = None,
    *,
    stan: bool = True,
    stan_path: str | Path | None = None,
    T: int = CHECK_T,
    seed: int | None = None,
    backend: str = "native",
    gradients: str = "autodiff",
    prior_cases: Sequence[CheckCase] | None = None,
    built: ProgramFiles | None = None,
) -> CheckReport:
    """Every check of this module for one model; the report lists each problem found.

    ``cases`` default to :func:`default_cases`; ``stan=False`` skips the Stan checks (for a
    config that never runs Stan for this model).  Checks stop at the first stage, and within
    it at the first case, with problems, so that one mistake gives one message.  Once the
    Python stage passes, the symmetries and the propriety of the posterior under the prior
    of each of ``prior_cases`` (default ``cases``) are found from the terms
    (:mod:`ssmobs.model_check.symmetry_report`): reported, never a problem.  ``built``: the
    program and header rule build_stan_model compiled for NUTS (its marker:
    :func:`~ssmobs.model_check.program.built_program_files`), what steps 3 and 4 run; None:
    a generated program is written here (:mod:`ssmobs.model_check.program`).
    """
    from ..stan_backends import has_stan_file, stan_file

    model = get_model(slug)
    report = CheckReport(slug)
    cases = list(cases) if cases else default_cases(model)
    seed = model_check_seed(model) if seed is None else seed
    found = python_stage_problems(model, cases, T=T, seed=seed)
    report.record(
        f"python: simulator shapes, initial_states, gradient and Hessian vs finite "
        f"differences, simulated disturbances recovered by the terms ({len(cases)} case(s))",
        found,
    )
    if not report.problems:
        report.analysis = _analysis(model, list(prior_cases) if prior_cases else cases, T, seed)
    if report.problems or not stan:
        return report
    from ..nuts.analytic_program import generation_problem

    generated = None
    if stan_path is not None or has_stan_file(slug):
        path = Path(stan_path) if stan_path is not None else stan_file(slug)
    else:  # no hand-written program: the one the workflow generates and runs
        problem = generation_problem(model)
        report.record("stan program generated from the model", [problem] if problem else [])
        if report.problems:
            return report
        generated = checked_program(model, None, built)
        path = generated.stan_file
    report.record(
        f"stan source {path.name}: parameter names/order, data declarations",
        stan_source_problems(model, path),
    )
    if report.problems:
        return report
    # what steps 3 and 4 compile: the program NUTS runs
    analytic = None
    if generated is None and gradients == "analytic":
        analytic = checked_program(model, path, built)
    elif generated is None and built is not None:
        same_program(path, built)
    program = generated or analytic
    compiled, header = (path, None) if program is None else (program.stan_file, program.header)
    found = _first_problems(
        cases,
        lambda i, case: stan_problems(
            model, compiled, case, T=T, seed=seed + i, backend=backend, user_header=header
        ),
    )
    report.record(
        f"stan compiled: names, shapes, log density up to a constant, support "
        f"bounds ({len(cases)} case(s))",
        found,
    )
    if report.problems:
        return report
    if generated is not None:
        from .analytic import GENERATED_RTOL, generated_problems

        found = _first_problems(
            cases, lambda i, case: generated_problems(model, generated, case, T=T, seed=seed + i)
        )
        report.record(
            f"generated gradients: equal to the Python model's through Stan's bound "
            f"transforms to {GENERATED_RTOL:g} relative ({len(cases)} case(s))",
            found,
        )
        return report
    if gradients == "autodiff":
        return report
    from .analytic import ANALYTIC_RTOL, analytic_problems

    found = _first_problems(
        cases,
        lambda i, case: analytic_problems(model, path, case, T=T, seed=seed + i, program=analytic),
    )
    report.record(
        f"analytic gradients: log density up to a constant and gradient equal to Stan's "
        f"autodiff to {ANALYTIC_RTOL:g} relative ({len(cases)} case(s))",
        found,
    )
    return report


def run_check_model(inputs: ModelCheckInputs, paths: Mapping[str, Any]) -> CheckReport:
    """Rules check_model and check_model_stan: check ``inputs.model`` for the default cases
    and the true values of the scenario's case under every prior variant
    (:func:`prior_variant_cases`), and its analytic gradients when NUTS uses them; write the
    report to ``paths["report"]``; raise :class:`ModelCheckError` listing every problem.
    Against Stan, ``paths["stan"]``: the program's source (None: generated) and
    ``paths["program"]``: rule build_stan_model's marker (with the native backend), whose
    program the Stan check runs as it is (no generated program is written here); None: see
    :func:`check_model`."""
    slug = inputs.model
    model = get_model(slug)
    cases = default_cases(model)
    scenario_cases = cases_from_scenarios([inputs.case_config], slug)
    for scenario_case in scenario_cases:
        for case in prior_variant_cases(model, scenario_case):
            if case not in cases:
                cases.append(case)
    program_marker = paths.get("program") if inputs.against_stan else None
    report = check_model(
        slug,
        cases,
        stan=inputs.against_stan,
        stan_path=paths.get("stan") if inputs.against_stan else None,
        gradients=inputs.gradients,
        prior_cases=scenario_cases or None,
        built=None if program_marker is None else built_program_files(program_marker),
    )
    if report.problems:
        raise ModelCheckError(
            f"model '{slug}': the Python model and the Stan program "
            f"disagree:\n  - " + "\n  - ".join(report.problems)
        )
    if report.analysis is not None:
        for line in report.analysis.lines(slug):
            logging.getLogger(LOGGER_NAME).info("%s", line)
    out = Path(paths["report"])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report.to_dict(), indent=2) + "\n")
    return report
