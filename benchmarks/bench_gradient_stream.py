"""A whole NUTS run with our ``stan/model/gradient.hpp`` against Stan's own (issue 49, item 4).

Stan's ``stan::model::gradient`` (the overload the sampler calls once per leapfrog step)
constructs a ``std::stringstream`` per call; the native backend compiles with a header of
ours in its place that reuses one stream per thread (``native_build.SHADOW_INCLUDE_DIR``).
For each case (same a = 0.7 T = 100, sep_d2_p1 a = b = c = 0.9 T = 50, sep_ranwalk a = 0.9
T = 100, as ``bench_analytic_gradients.py``) and gradient path (the hand-written program,
autodiff; the generated one, analytic) the program is built twice, with Stan's header only
(an empty directory in place of ours) and with ours, and sampled ``--reps`` times at the
paper's settings, the two builds interleaved (Stan's first in even reps, ours first in odd
ones), rep r with Stan seed 20261205 + r for both.  Reported: the driver's CPU seconds per
run (its rusage), the ratio Stan's / ours of each rep (median and range), of the sums and
of the fastest runs, and whether every pair of runs gave bitwise-identical draws and sampler columns.  Appends
a section to BENCHMARKS.md unless ``--no-write``.

    python benchmarks/bench_gradient_stream.py [--reps 3] [--paths autodiff,analytic]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_analytic_gradients import CASES, PAPER, SETTINGS_LINE, load_line, trajectory_data
from machine import machine_info, report
from ssmobs.models import get_model
from ssmobs.nuts.analytic_program import write_analytic_program
from ssmobs.stan_backends import Draws, native_build, stan_file
from ssmobs.stan_backends.native import NativeBackend
from ssmobs.stan_backends.native_build import stan_version

BUILDS = ("stan", "ours")


def same_draws(a: Draws, b: Draws) -> bool:
    """Bitwise-equal parameters and sampler columns."""
    return all(np.array_equal(a.params[k], b.params[k]) for k in a.params) and all(
        np.array_equal(a.sample_stats[k], b.sample_stats[k]) for k in a.sample_stats
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--cases", default="", help="comma-separated model slugs, default all")
    ap.add_argument("--paths", default="autodiff,analytic")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    wanted = {c.strip() for c in args.cases.split(",") if c.strip()}
    paths = [p.strip() for p in args.paths.split(",") if p.strip()]
    ours_dir = native_build.SHADOW_INCLUDE_DIR
    stan_dir = Path(tempfile.mkdtemp(prefix="no-shadow-headers-"))  # empty: Stan's own only
    backends = {"stan": NativeBackend(), "ours": NativeBackend()}
    loads = [os.getloadavg()[0]]
    started = dt.datetime.now(dt.timezone.utc)
    rows = []
    for slug, omega, T in CASES:
        if wanted and slug not in wanted:
            continue
        data = trajectory_data(slug, omega, T)
        for path_name in paths:
            if path_name == "analytic":
                program = write_analytic_program(get_model(slug), stan_file(slug))
                source, header = program.stan_file, program.header
            else:
                source, header = stan_file(slug), None
            for build in BUILDS:  # the backend keeps the marker: later calls find this build
                native_build.SHADOW_INCLUDE_DIR = stan_dir if build == "stan" else ours_dir
                backends[build].compile(source, header)
            native_build.SHADOW_INCLUDE_DIR = ours_dir
            cpu: dict[str, list[float]] = {b: [] for b in BUILDS}
            identical = True
            for r in range(args.reps):
                order = BUILDS if r % 2 == 0 else BUILDS[::-1]  # ABBA: no drift bias
                draws = {}
                for build in order:
                    draws[build] = backends[build].sample(
                        source, data, 20261205 + r, PAPER, user_header=header
                    )
                    cpu[build].append(draws[build].timings["sample_cpu"])
                    loads.append(os.getloadavg()[0])
                    print(
                        f"{slug} T={T} {path_name} rep {r} {build}: {cpu[build][-1]:.2f} CPU-s",
                        flush=True,
                    )
                identical &= same_draws(draws["stan"], draws["ours"])
            pairs = [a / b for a, b in zip(cpu["stan"], cpu["ours"])]
            rows.append(
                f"| {slug} {', '.join(f'{k} = {v}' for k, v in omega.items())}, T = {T} "
                f"| {path_name} | {args.reps} | {np.median(cpu['stan']):.2f} "
                f"| {np.median(cpu['ours']):.2f} | **{np.median(pairs):.3f}** "
                f"| {min(pairs):.3f}-{max(pairs):.3f} | {sum(cpu['stan']) / sum(cpu['ours']):.3f} "
                f"| {min(cpu['stan']) / min(cpu['ours']):.3f} | {'yes' if identical else 'NO'} |"
            )
    finished = dt.datetime.now(dt.timezone.utc)
    text = "\n".join(
        [
            "",
            f"## NUTS with one message stream per thread (issue 49 item 4, {finished:%Y-%m-%d})",
            "",
            f"- Date: {started:%Y-%m-%d %H:%M}-{finished:%H:%M} UTC",
            f"- Machine: {machine_info()}; {stan_version()}",
            f"- Command: `python benchmarks/bench_gradient_stream.py --reps {args.reps} "
            f"--paths {','.join(paths)}` (at `nice -n 10`)",
            load_line(loads, " (another benchmark on the other core)", "builds"),
            SETTINGS_LINE,
            "- Builds: Stan's `stan/model/gradient.hpp` (a stringstream per gradient call) and "
            "ours first on the include path (one per thread, `native_include/`). CPU: the "
            "driver's CPU seconds per whole run (rusage); speed-up: Stan's CPU / ours of each "
            "rep (median, range), of the sums, and of the fastest runs (load only adds time); "
            "same draws: every rep's draws and sampler columns bitwise equal.",
            "",
            "| case | gradient | reps | Stan's header CPU [s] (median) | ours CPU [s] (median) "
            "| speed-up (median) | range | of sums | of minima | same draws |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|---|",
            *rows,
            "",
        ]
    )
    report(text, write=not args.no_write)


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"({time.perf_counter() - t0:.0f} s)")
