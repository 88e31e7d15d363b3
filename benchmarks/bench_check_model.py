"""The model check's cost per model: the native driver's log-density mode against PyStan.

For each model (``--models``, default all) it measures, in the same process and in turn:

- ``compile native``: a cold native build of the program into an empty temporary cache
  (stanc, the program's object file, the link; the driver's own object file is built once
  beforehand and reported apart), CPU and wall seconds;
- ``compile pystan`` (with ``--cold-pystan``): a cold PyStan build, after removing the
  program's entry from httpstan's cache;
- ``check native`` / ``check pystan``: :func:`ssmobs.model_check.check.check_model` on the default
  cases with the program already built (the check itself), median of ``--reps``.

Appends a section to BENCHMARKS.md unless ``--no-write``.

    python benchmarks/bench_check_model.py [--models same sep_d1_p2] [--reps 3] [--cold-pystan]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_backends import cpu_seconds
from machine import machine_info, report
from ssmobs.model_check.check import check_model
from ssmobs.models import MODELS
from ssmobs.stan_backends import stan_file


def measure(fn) -> tuple[float, float]:
    c0, t0 = cpu_seconds(), time.perf_counter()
    fn()
    return cpu_seconds() - c0, time.perf_counter() - t0


def cold_native(slug: str) -> tuple[float, float]:
    """A cold native build into a fresh cache that holds only the driver's object file."""
    from ssmobs.stan_backends.native import NativeBackend
    from ssmobs.stan_backends.native_build import driver_object

    shared = driver_object().parent
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "native").mkdir()
        shutil.copytree(shared, Path(tmp) / "native" / shared.name)
        old = os.environ.get("SSMOBS_CACHE")
        os.environ["SSMOBS_CACHE"] = tmp
        try:
            return measure(lambda: NativeBackend().compile(stan_file(slug)))
        finally:
            if old is None:
                os.environ.pop("SSMOBS_CACHE")
            else:
                os.environ["SSMOBS_CACHE"] = old


def cold_pystan(slug: str) -> tuple[float, float]:
    """A cold PyStan build: the program's httpstan cache entry removed first."""
    import httpstan.cache
    import httpstan.models

    code = stan_file(slug).read_text()
    name = httpstan.models.calculate_model_name(code)
    httpstan.cache.delete_model_directory(name)
    script = f"import stan; stan.build(open({str(stan_file(slug))!r}).read())"
    # building without data fails after the compile (the model needs data): the compile's time
    return measure(lambda: subprocess.run([sys.executable, "-c", script], capture_output=True))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--models", nargs="*", default=sorted(MODELS))
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--cold-pystan", action="store_true")
    parser.add_argument("--no-write", action="store_true")
    args = parser.parse_args()
    from ssmobs.stan_backends.native_build import driver_object

    load0 = os.getloadavg()[0]
    driver_cpu, driver_wall = measure(driver_object)
    rows = []
    for slug in args.models:
        nat_cpu, nat_wall = cold_native(slug)
        py = cold_pystan(slug) if args.cold_pystan else None
        check_model(slug, backend="pystan")  # build once for the warm checks
        checks = {}
        for backend in ("native", "pystan"):
            runs = [
                measure(lambda b=backend: check_model(slug, backend=b)) for _ in range(args.reps)
            ]
            checks[backend] = (
                statistics.median(r[0] for r in runs),
                statistics.median(r[1] for r in runs),
            )
        rows.append(
            f"| {slug} | {nat_cpu:.0f} / {nat_wall:.0f} | "
            + (f"{py[0]:.0f} / {py[1]:.0f}" if py else "not measured")
            + f" | {checks['native'][0]:.1f} / {checks['native'][1]:.1f}"
            f" | {checks['pystan'][0]:.1f} / {checks['pystan'][1]:.1f}"
            f" | {checks['native'][1] / checks['pystan'][1]:.2f} |"
        )
    load1 = os.getloadavg()[0]
    text = "\n".join(
        [
            "",
            f"## The model check per model: native log-density mode vs PyStan (issue 23, {dt.date.today()})",
            "",
            f"Machine: {machine_info()}; load average {load0:.1f} at the start, {load1:.1f} at the end.",
            f"The driver's object file, built once for every program: {driver_cpu:.0f} CPU-s / {driver_wall:.0f} s wall"
            + (" (cached already)" if driver_wall < 1 else "")
            + ". Cells: CPU seconds / wall seconds; checks are medians of "
            f"{args.reps} runs on the default cases with the program built.",
            "",
            "| model | compile native (cold) | compile PyStan (cold) | check native | check PyStan | check wall native / PyStan |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    report(text, not args.no_write)


if __name__ == "__main__":
    main()
