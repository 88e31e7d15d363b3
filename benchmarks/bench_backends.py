"""Stan backends against the sampler's floor: CPU and wall seconds per NUTS run.

For each case (model Same at T = 20, 50, 100 and (Sep, d=1, p=2) at T = 50, one trajectory
from random disturbances, the paper's settings: 4 chains x (4000 + 6000), one chain at a
time) it runs, in turn and in the same process, ``--reps`` times each:

- ``floor``: the native driver with its output discarded (the bare Stan sampler),
- ``native``: the native backend's whole ``sample`` call (driver, draws file, reading it),
- ``pystan``: the PyStan backend's whole ``sample`` call,

and reports medians of CPU seconds (this process plus its children: the driver, PyStan's
chain workers) and wall seconds, and the ratios native / floor and native / PyStan of the
CPU medians.  Draws of native and PyStan are also compared (they must be identical).
Appends a section to BENCHMARKS.md unless ``--no-write``.

    python benchmarks/bench_backends.py [--reps 3] [--reps-slow 1]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import resource
import statistics
import time

import numpy as np
from machine import machine_info, report
from ssmobs.models import get_model
from ssmobs.stan_backends import SamplerSettings, get_backend, stan_file
from ssmobs.stan_backends.native import NativeBackend
from ssmobs.stan_backends.native_build import stan_version

PAPER = SamplerSettings(chains=4, iter_warmup=4000, iter_sampling=6000, workers=1)
CASES = [
    ("same", {"a": 0.9}, 20, False),
    ("same", {"a": 0.9}, 50, False),
    ("same", {"a": 0.9}, 100, False),
    ("sep_d1_p2", {"a": 0.6, "b": 0.5, "c": 0.9, "d": 0.9}, 50, True),
]


def cpu_seconds() -> float:
    s = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def trajectory_data(slug: str, omega: dict, T: int) -> dict:
    model = get_model(slug)
    rng = np.random.default_rng(1)
    x0 = np.full(model.state_dim, 8.0)
    eta = rng.standard_normal((1, T, model.state_dim))
    eps = rng.standard_normal((1, T, model.obs_dim))
    _, z = model.simulate(model.omega_array(omega), x0, eta, eps)
    return model.stan_data(z[0], model.prior_bounds(omega))


def timed(backend, slug: str, data: dict, reps: int) -> tuple[list[float], list[float], object]:
    cpu, wall, draws = [], [], None
    for _ in range(reps):
        c0, w0 = cpu_seconds(), time.perf_counter()
        draws = backend.sample(stan_file(slug), data, 20261129, PAPER)
        wall.append(time.perf_counter() - w0)
        cpu.append(cpu_seconds() - c0)
    return cpu, wall, draws


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--reps-slow", type=int, default=1, help="reps for (Sep, d=1, p=2)")
    ap.add_argument("--cases", default="", help="comma-separated <model>:<T>, default all")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    wanted = {c.strip() for c in args.cases.split(",") if c.strip()}
    native, floor, pystan = NativeBackend(), NativeBackend(discard=True), get_backend("pystan")
    load0 = os.getloadavg()[0]
    t_start = time.perf_counter()
    rows = []
    for slug, omega, T, slow in CASES:
        if wanted and f"{slug}:{T}" not in wanted:
            continue
        for b in (native, pystan):
            b.compile(stan_file(slug))
        data = trajectory_data(slug, omega, T)
        reps = args.reps_slow if slow else args.reps
        res = {
            name: timed(b, slug, data, reps)
            for name, b in (("floor", floor), ("native", native), ("pystan", pystan))
        }
        same = all(
            np.array_equal(res["native"][2].params[k], res["pystan"][2].params[k])
            for k in res["native"][2].params
        )
        med = {k: (statistics.median(v[0]), statistics.median(v[1])) for k, v in res.items()}
        rows.append((f"{slug} T={T}", reps, med, same))
        print(rows[-1], flush=True)
    total = time.perf_counter() - t_start
    load1 = os.getloadavg()[0]
    lines = [
        "",
        "## Stan backends against the sampler's floor (issue 9)",
        "",
        f"- Date: {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"- Machine: {machine_info()}; {stan_version()}",
        f"- Command: `python benchmarks/bench_backends.py --reps {args.reps} --reps-slow "
        f"{args.reps_slow}` (total {total:.0f} s)",
        f"- System load (1-min load average at start / end): {load0:.2f} / {load1:.2f} on "
        f"{os.cpu_count()} CPUs. Other jobs shared the machine, so wall times are "
        "pessimistic; CPU seconds (this process + its children) are what the ratios use.",
        "- Settings: the paper's, 4 chains x (4000 + 6000), one chain at a time, one trajectory "
        "per case from random disturbances (seed 1), Stan seed 20261129; medians of the reps.",
        "- floor: the native driver with `--discard` (the bare sampler, no draws written); "
        "native: the native backend's `sample` (driver + draws file + reading it); pystan: "
        "the PyStan backend's `sample`. Targets (issue 9): native / floor <= 1.10, "
        "native / PyStan <= 0.35.",
        "",
        "| case | reps | floor CPU [s] | native CPU [s] | PyStan CPU [s] | floor wall [s] | "
        "native wall [s] | PyStan wall [s] | native / floor (CPU) | native / PyStan (CPU) | "
        "draws identical |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for case, reps, med, same in rows:
        f, n, p = med["floor"], med["native"], med["pystan"]
        lines.append(
            f"| {case} | {reps} | {f[0]:.2f} | {n[0]:.2f} | {p[0]:.2f} | {f[1]:.2f} | "
            f"{n[1]:.2f} | {p[1]:.2f} | **{n[0] / f[0]:.3f}** | **{n[0] / p[0]:.3f}** | "
            f"{'yes' if same else 'NO'} |"
        )
    text = "\n".join(lines) + "\n"
    report(text, write=not args.no_write)


if __name__ == "__main__":
    main()
