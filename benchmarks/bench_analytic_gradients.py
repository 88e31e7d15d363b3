"""A whole NUTS run with analytic gradients against Stan's autodiff (issue 49).

For each case (same a = 0.7 T = 100, sep_d2_p1 a = b = c = 0.9 T = 50, sep_ranwalk a = 0.9
T = 100; one trajectory from random disturbances, x0 = 8; the paper's settings: 4 chains x
(4000 + 6000), one chain at a time) the native backend samples ``--reps`` times with the
hand-written program (autodiff) and with the generated one (analytic,
:mod:`ssmobs.nuts.analytic_gradients`), the two interleaved (autodiff first in even reps,
analytic first in odd ones), rep r with Stan seed 20261205 + r for both.  Reported: the
driver's CPU seconds per run (its rusage), the post-warmup leapfrog steps per draw, the
ratio autodiff / analytic of each rep (median and range), of the summed CPU seconds and of
CPU seconds per leapfrog step.  Appends a section to
BENCHMARKS.md unless ``--no-write``.

    python benchmarks/bench_analytic_gradients.py [--reps 3]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import time

import numpy as np
from machine import machine_info, report
from ssmobs.models import get_model
from ssmobs.nuts.analytic_program import write_analytic_program
from ssmobs.stan_backends import SamplerSettings, stan_file
from ssmobs.stan_backends.native import NativeBackend
from ssmobs.stan_backends.native_build import stan_version

PAPER = SamplerSettings(chains=4, iter_warmup=4000, iter_sampling=6000, workers=1)
CASES = [
    ("same", {"a": 0.7}, 100),
    ("sep_d2_p1", {"a": 0.9, "b": 0.9, "c": 0.9}, 50),
    ("sep_ranwalk", {"a": 0.9}, 100),
]


#: the settings bullet of the paired NUTS benchmarks' sections
SETTINGS_LINE = (
    "- Settings: the paper's, 4 chains x (4000 + 6000), one chain at a time, native "
    "backend; one trajectory per case from random disturbances (seed 1), x0 = 8."
)


def load_line(loads: list[float], why: str, what: str) -> str:
    """The load bullet of a paired benchmark's section: the range of the 1-min load average,
    ``why`` it was loaded (or ""), and that the two ``what`` ran interleaved."""
    return (
        f"- System load (1-min load average): {min(loads):.1f}-{max(loads):.1f} on "
        f"{os.cpu_count()} CPUs{why}, so the ratios count, not the seconds; the two {what} "
        "run interleaved, rep by rep (order alternating), with the same Stan seed."
    )


def trajectory_data(slug: str, omega: dict, T: int) -> dict:
    model = get_model(slug)
    rng = np.random.default_rng(1)
    x0 = np.full(model.state_dim, 8.0)
    eta = rng.standard_normal((1, T, model.state_dim))
    eps = rng.standard_normal((1, T, model.obs_dim))
    _, z = model.simulate(model.omega_array(omega), x0, eta, eps)
    return model.stan_data(z[0], model.prior_bounds(omega))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--cases", default="", help="comma-separated model slugs, default all")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    wanted = {c.strip() for c in args.cases.split(",") if c.strip()}
    native = NativeBackend()
    loads = [os.getloadavg()[0]]
    started = dt.datetime.now(dt.timezone.utc)
    rows = []
    for slug, omega, T in CASES:
        if wanted and slug not in wanted:
            continue
        model = get_model(slug)
        data = trajectory_data(slug, omega, T)
        program = write_analytic_program(model, stan_file(slug))
        paths = {
            "autodiff": (stan_file(slug), None),
            "analytic": (program.stan_file, program.header),
        }
        for path, header in paths.values():
            native.compile(path, header)
        cpu: dict[str, list[float]] = {k: [] for k in paths}
        leap: dict[str, list[float]] = {k: [] for k in paths}
        for r in range(args.reps):
            order = list(paths) if r % 2 == 0 else list(paths)[::-1]  # ABBA: no drift bias
            for name in order:
                path, header = paths[name]
                draws = native.sample(path, data, 20261205 + r, PAPER, user_header=header)
                cpu[name].append(draws.timings["sample_cpu"])
                leap[name].append(float(draws.sample_stats["n_leapfrog__"].mean()))
                loads.append(os.getloadavg()[0])
                print(f"{slug} T={T} rep {r} {name}: {cpu[name][-1]:.2f} CPU-s", flush=True)
        ratio = sum(cpu["autodiff"]) / sum(cpu["analytic"])
        per_step = {k: sum(cpu[k]) / sum(leap[k]) for k in paths}
        pairs = [a / b for a, b in zip(cpu["autodiff"], cpu["analytic"])]
        rows.append(
            f"| {slug} {', '.join(f'{k} = {v}' for k, v in omega.items())}, T = {T} "
            f"| {args.reps} | {np.median(cpu['autodiff']):.2f} | {np.median(cpu['analytic']):.2f} "
            f"| {np.mean(leap['autodiff']):.1f} / {np.mean(leap['analytic']):.1f} "
            f"| **{np.median(pairs):.2f}** | {min(pairs):.2f}-{max(pairs):.2f} | {ratio:.2f} "
            f"| {per_step['autodiff'] / per_step['analytic']:.2f} |"
        )
    finished = dt.datetime.now(dt.timezone.utc)
    text = "\n".join(
        [
            "",
            f"## NUTS with analytic gradients vs Stan's autodiff (issue 49, {finished:%Y-%m-%d})",
            "",
            f"- Date: {started:%Y-%m-%d %H:%M}-{finished:%H:%M} UTC",
            f"- Machine: {machine_info()}; {stan_version()}",
            f"- Command: `python benchmarks/bench_analytic_gradients.py --reps {args.reps}` (at `nice`)",
            load_line(loads, "", "paths"),
            SETTINGS_LINE,
            "- CPU: the driver's CPU seconds per whole NUTS run (its rusage); leapfrog: mean "
            "post-warmup `n_leapfrog__` per draw; speed-up: autodiff CPU / analytic CPU of each "
            "rep (the pair run back to back), median and range over reps; of sums: summed "
            "autodiff CPU / summed analytic CPU; per step: the same per post-warmup leapfrog "
            "step. Target (issue 49): >= 1.8.",
            "",
            "| case | reps | autodiff CPU [s] (median) | analytic CPU [s] (median) | leapfrog per draw (autodiff / analytic) | speed-up (median) | range | of sums | of sums per step |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
            *rows,
            "",
        ]
    )
    report(text, write=not args.no_write)


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"({time.perf_counter() - t0:.0f} s)")
