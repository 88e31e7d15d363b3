"""The command line of the model check: ``python -m ssmobs.model_check <slug> [--configfile
config/x.yaml] [--no-stan] [--backend pystan] [--gradients analytic]`` checks one model
(:func:`ssmobs.model_check.check.check_model`), prints what was checked, the model's
symmetries and the propriety of its posterior per prior (found from its terms), and exits 1
on a problem.

Being the package's command line, it may read a config file (:mod:`ssmobs.config`), which
the check itself never imports (the config's validation runs the check's Python stage).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ..models import get_model
from ..models.check_cases import cases_from_scenarios, default_cases
from .check import check_model
from .stan import CHECK_BACKENDS


def _stan_problem(slug: str, backend: str) -> str | None:
    """One line when the Stan check of ``slug`` cannot start here: no Stan program and
    none can be generated, or the native driver must build it and finds no C++ compiler
    (the workflow's own line)."""
    import shutil

    from ..stan_backends import has_stan_file, stan_file

    if not has_stan_file(slug):  # the program generated from the model, if it can be
        from ..nuts.analytic_program import generation_problem, write_analytic_program

        problem = generation_problem(get_model(slug))
        if problem is not None:
            return f"{problem}, or check the Python model alone: --no-stan"
        if backend != "native":
            return (
                f"model '{slug}' has no stan/{slug}.stan; its generated program calls C++ "
                f"that only the native backend evaluates: --backend native"
            )
        generated = write_analytic_program(get_model(slug), None)
        program, header = generated.stan_file, generated.header
    else:
        program, header = stan_file(slug), None
    if backend != "native":
        return None
    from ..stan_backends.native import NativeBackend
    from ..stan_backends.native_build import compiler

    if shutil.which(compiler()) or NativeBackend().is_built(program, header):
        return None
    return (
        f"the native Stan backend must build {program} but finds no C++ compiler "
        f"{compiler()!r}: install g++ (apt-get install g++), set CXX to a C++ compiler, or "
        f"point SSMOBS_CACHE at a cache that holds the program (or check the Python model "
        f"alone: --no-stan)"
    )


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: check one model, print what was checked; exit 1 on a problem."""
    parser = argparse.ArgumentParser(
        prog="python -m ssmobs.model_check",
        description="Check workflow/ssmobs/models/<slug>.py against stan/<slug>.stan.",
    )
    parser.add_argument("slug", help="model slug (the file name of the model module)")
    parser.add_argument(
        "--configfile",
        help="also check every (omega, x0, prior) of this config's scenarios of the model",
    )
    parser.add_argument("--no-stan", action="store_true", help="Python checks only")
    parser.add_argument(
        "--backend",
        choices=CHECK_BACKENDS,
        default="native",
        help="what evaluates Stan's log density (default: the native driver)",
    )
    parser.add_argument(
        "--gradients",
        choices=("autodiff", "analytic"),
        default="autodiff",
        help="analytic: also check the generated gradients against Stan's autodiff",
    )
    args = parser.parse_args(argv)
    from ..stan_backends import has_stan_file

    try:
        model = get_model(args.slug)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    cases = default_cases(model)
    prior_cases = None
    if args.configfile:
        from ..config.validation import ConfigError, read_config_file, validate

        try:
            config = validate(read_config_file(args.configfile))
        except ConfigError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
        prior_cases = cases_from_scenarios(config["scenarios"], args.slug) or None
        cases += [c for c in prior_cases or [] if c not in cases]
    problem = None if args.no_stan else _stan_problem(args.slug, args.backend)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    report = check_model(
        args.slug,
        cases,
        stan=not args.no_stan,
        backend=args.backend,
        gradients=args.gradients,
        prior_cases=prior_cases,
    )
    for line in report.checks:
        print(f"checked  {line}")
    if report.analysis is not None:
        print("\n".join(report.analysis.lines(args.slug)))
    if report.problems:
        print(f"failed   {report.failed}", file=sys.stderr)
        print(f"model '{args.slug}': {len(report.problems)} problem(s):", file=sys.stderr)
        for p in report.problems:
            print(f"  - {p}", file=sys.stderr)
        return 1
    which = "Stan program" if has_stan_file(args.slug) else "generated Stan program"
    print(f"model '{args.slug}': Python model and {which} agree")
    return 0


if __name__ == "__main__":
    sys.exit(main())
