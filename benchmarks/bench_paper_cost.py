"""Cost of the paper profile's Stan stage: CPU seconds per NUTS run for every scenario.

For each scenario of config/paper.yaml with the Stan stage on, run ``--n`` trajectories
(random disturbances, seed 1) through the real stage (``ssmobs.nuts.batch.run_trajectories``)
with the paper's sampler settings, measure wall time and CPU time (this process plus its
chain worker processes), and extrapolate to CPU-hours per 1000 runs and for the scenario's K.
Appends a section to BENCHMARKS.md unless ``--no-write``.

    python benchmarks/bench_paper_cost.py [--n 1] [--config config/paper.yaml]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from machine import machine_info, report
from ssmobs.config import validation as cfg
from ssmobs.config.scenario import Scenario
from ssmobs.design.trajectories import make_trajectories
from ssmobs.nuts.batch import NutsBatch, run_trajectories
from ssmobs.nuts.convergence import ConvergenceSettings
from ssmobs.stages.stan import sampler_settings
from ssmobs.stan_backends import get_backend, stan_file

REPO = Path(__file__).resolve().parents[1]


def cpu_seconds() -> float:
    s = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=1, help="trajectories per scenario")
    ap.add_argument("--config", default=str(REPO / "config" / "paper.yaml"))
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    conf = cfg.validate(yaml.safe_load(Path(args.config).read_text()))
    backend = get_backend(conf["stan"]["backend"])
    sampler = sampler_settings(conf["stan"], threads=1)
    rows = []
    for sc in map(Scenario.from_config, conf["scenarios"]):
        if not sc.stan:
            continue
        matrix = np.random.default_rng(1).standard_normal((sc.disturbance_dim, args.n))
        traj = make_trajectories(sc.replace(K=args.n), matrix)
        model = traj.model
        bounds = sc.prior_bounds()
        backend.compile(stan_file(model.slug))
        with tempfile.TemporaryDirectory() as tmp:
            t0, c0 = time.perf_counter(), cpu_seconds()
            batch = NutsBatch(
                model,
                stan_file(model.slug),
                traj.z,
                traj.x,
                bounds,
                traj.omega,
                traj.x0,
                sc.name,
                sc.seed,
                sampler=sampler,
                convergence=ConvergenceSettings(**conf["convergence"]),
                init=sc.stan_init,
            )
            recs = run_trajectories(batch, backend, list(range(args.n)), records_dir=tmp)
            wall, cpu = time.perf_counter() - t0, cpu_seconds() - c0
        per_cpu = cpu / args.n
        rows.append(
            {
                "scenario": sc.name,
                "model": model.slug,
                "T": sc.T,
                "K": sc.K,
                "wall_s": wall / args.n,
                "cpu_s": per_cpu,
                "cpu_h_per_1000": per_cpu * 1000 / 3600,
                "cpu_h_total": per_cpu * sc.K / 3600,
                "converged": sum(r["converged"] for r in recs),
            }
        )
        print(rows[-1], flush=True)
    total_runs = sum(r["K"] for r in rows)
    total_h = sum(r["cpu_h_total"] for r in rows)
    lines = [
        "",
        f"## Cost of the paper profile's Stan stage, {backend.name} backend",
        "",
        f"- Date: {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC; machine: "
        f"{machine_info()}; load average at "
        f"end {os.getloadavg()[0]:.2f}",
        f"- Command: `python benchmarks/bench_paper_cost.py --n {args.n}`; config "
        f"`{Path(args.config).relative_to(REPO) if Path(args.config).is_absolute() else args.config}`"
        f" ({sampler.chains} chains x ({sampler.iter_warmup} + {sampler.iter_sampling}), "
        f"1 chain worker, one trajectory after another; backend {backend.name}, "
        f"{backend.identity()['stan_version']})",
        "- CPU: this process and its chain worker processes (getrusage SELF + CHILDREN); "
        f"{args.n} trajectory(ies) per scenario from random disturbances, so a scenario's "
        "figure is a rough per-run estimate (hard trajectories cost more).",
        "",
        "| scenario | model | T | wall s / run | CPU s / run | CPU-h per 1000 runs | K | CPU-h for K | converged |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scenario']} | {r['model']} | {r['T']} | {r['wall_s']:.1f} | "
            f"{r['cpu_s']:.1f} | {r['cpu_h_per_1000']:.2f} | {r['K']} | "
            f"{r['cpu_h_total']:.1f} | {r['converged']}/{args.n} |"
        )
    lines += [
        "",
        f"Total: {total_runs} Stan runs, about {total_h:.0f} CPU-hours "
        f"({total_h * 1000 / total_runs:.2f} CPU-h per 1000 runs on average).",
        "",
    ]
    text = "\n".join(lines)
    report(text, write=not args.no_write)


if __name__ == "__main__":
    main()
