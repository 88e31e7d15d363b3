"""Cost of the paper profile's Stan stage per scenario, on both gradient paths (issue 49,
items 1 and 4): CPU seconds per NUTS run, CPU-hours for the scenario's K, with an interval.

For each scenario of ``--config`` with the Stan stage on, ``--n`` trajectories are simulated
from random disturbances (numpy seed 1: draws of the distribution the design set
approximates) and each goes through the whole per-trajectory code of rule ``sample_nuts``
(:func:`ssmobs.nuts.batch.run_trajectories`: sampling at the profile's settings, checks,
marginal MAP, record) on every path of ``--paths``, the paths interleaved trajectory by
trajectory (order alternating), native backend, one chain process at a time.

Resumable: every measured trajectory is appended to ``--log`` (JSON lines) as it finishes,
and a rerun with the same log measures only what is missing.  Per scenario and path: the
mean CPU seconds per run, a 90 % Student-t interval of that mean over the n trajectories,
their range, and mean x K / 3600 CPU-hours; the total's interval adds the scenarios'
standard errors in quadrature (normal).  Appends a section to BENCHMARKS.md unless
``--no-write``.

    python benchmarks/bench_paper_cost.py --n 5 --log paper_cost.jsonl
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import tempfile
from pathlib import Path

import numpy as np
from machine import machine_info, report
from nuts_paths import PATHS, compiled_programs, run_one, simulate
from scipy import stats

REPO = Path(__file__).resolve().parents[1]
LEVEL = 0.90


def _done(log: Path) -> dict[tuple[str, int, str], dict]:
    rows: dict[tuple[str, int, str], dict] = {}
    if log.exists():
        for line in log.read_text().splitlines():
            if line.strip():
                r = json.loads(line)
                rows[(r["scenario"], r["k"], r["path"])] = r
    return rows


def _interval(values: np.ndarray) -> tuple[float, float, float]:
    """(mean, half-width of the LEVEL t-interval of the mean, standard error)."""
    n = values.size
    mean = float(values.mean())
    if n < 2:
        return mean, float("nan"), float("nan")
    se = float(values.std(ddof=1) / np.sqrt(n))
    return mean, float(stats.t.ppf(0.5 + LEVEL / 2, n - 1) * se), se


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=5, help="trajectories per scenario")
    ap.add_argument("--config", default=str(REPO / "config" / "paper.yaml"))
    ap.add_argument("--paths", default=",".join(PATHS), help="autodiff, analytic or both")
    ap.add_argument("--scenarios", default="", help="comma-separated names (default: all)")
    ap.add_argument("--log", default="paper_cost.jsonl", help="JSON lines, one per run")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()

    from ssmobs.config.scenario import Scenario
    from ssmobs.config.validation import read_config_file, validate
    from ssmobs.stan_backends.native import NativeBackend

    config = validate(read_config_file(args.config))
    paths = [p for p in args.paths.split(",") if p]
    wanted = {s for s in args.scenarios.split(",") if s}
    native = NativeBackend()
    log = Path(args.log)
    done = _done(log)
    load_start = os.getloadavg()[0]
    started = dt.datetime.now(dt.timezone.utc)
    scenarios = []
    for entry in config["scenarios"]:
        sc = Scenario.from_config(entry)
        if not sc.stan or (wanted and sc.name not in wanted):
            continue
        if sc.stan_init == "joint_map":
            raise SystemExit(f"{sc.name}: stan_init joint_map is not measured here")
        scenarios.append(sc)
        xz = simulate(sc, args.n)
        programs = compiled_programs(native, sc.model.slug)
        for k in range(args.n):
            for g in paths if k % 2 == 0 else paths[::-1]:
                if (sc.name, k, g) in done:
                    continue
                with tempfile.TemporaryDirectory() as tmp:
                    one = run_one(native, sc, config, programs[g], xz, k, Path(tmp))
                row = {
                    "scenario": sc.name,
                    "k": k,
                    "path": g,
                    "cpu_s": one.cpu_s,
                    "wall_s": one.wall_s,
                    "driver_cpu_s": one.driver_cpu_s,
                    "converged": one.converged,
                    "load1": os.getloadavg()[0],
                    "finished": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
                }
                with log.open("a") as fh:
                    fh.write(json.dumps(row) + "\n")
                done[(sc.name, k, g)] = row
                print(
                    f"{sc.name} k={k} {g}: {one.cpu_s:.1f} CPU-s, {one.wall_s:.1f} s, "
                    f"converged {one.converged}",
                    flush=True,
                )
    report(_section(args, config, scenarios, paths, done, load_start, started), not args.no_write)


def _section(args, config, scenarios, paths, done, load_start, started) -> str:  # noqa: ANN001
    from ssmobs.stages.stan import sampler_settings

    sampler = sampler_settings(config["stan"], threads=1)
    loads = [r["load1"] for r in done.values()]
    lines = [
        "",
        f"## Cost of the paper profile's Stan stage per scenario, {' and '.join(paths)} "
        f"(issue 49, {started:%Y-%m-%d})",
        "",
        f"- Command: `python benchmarks/bench_paper_cost.py --n {args.n} --paths "
        f"{','.join(paths)}`; config `{os.path.relpath(args.config, REPO)}` "
        f"({sampler.chains} chains x ({sampler.iter_warmup} + {sampler.iter_sampling})), "
        "native backend, one chain process at a time, the paths interleaved trajectory by "
        "trajectory.",
        f"- Machine: {machine_info()}; 1-min load average {load_start:.2f} at the start, "
        f"{min(loads):.2f}-{max(loads):.2f} after each run.",
        f"- CPU: the whole per-trajectory part of a `sample_nuts` job (this process and its "
        f"chain workers); {args.n} trajectories per scenario from random disturbances; "
        f"interval: {LEVEL:.0%} Student t of the mean over them; total's interval: the "
        "scenarios' standard errors in quadrature.",
        "",
        "| scenario | K | path | CPU-s / run: mean | 90 % interval | range | CPU-h for K "
        "| 90 % interval | converged |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    totals = {g: [0.0, 0.0] for g in paths}
    for sc in scenarios:
        for g in paths:
            cpu = np.array([done[(sc.name, k, g)]["cpu_s"] for k in range(args.n)])
            conv = sum(done[(sc.name, k, g)]["converged"] for k in range(args.n))
            mean, half, se = _interval(cpu)
            h = sc.K / 3600
            totals[g][0] += mean * h
            totals[g][1] += (se * h) ** 2
            lines.append(
                f"| {sc.name} | {sc.K} | {g} | {mean:.1f} | {max(mean - half, 0):.1f}-"
                f"{mean + half:.1f} | {cpu.min():.1f}-{cpu.max():.1f} | {mean * h:.2f} | "
                f"{max(mean - half, 0) * h:.2f}-{(mean + half) * h:.2f} | {conv}/{args.n} |"
            )
    lines.append("")
    z = stats.norm.ppf(0.5 + LEVEL / 2)
    for g in paths:
        total, var = totals[g]
        lines.append(
            f"- **{g}: {total:.1f} CPU-hours** for the profile's Stan stage "
            f"({LEVEL:.0%} interval {max(total - z * var**0.5, 0):.1f}-{total + z * var**0.5:.1f})."
        )
    if len(paths) == 2:
        a, b = (totals[g][0] for g in paths)
        lines.append(f"- Ratio {paths[0]} / {paths[1]} of the totals: {a / b:.2f}.")
    lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
