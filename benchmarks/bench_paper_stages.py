"""The paper profile's cost per stage and scenario, on its own design trajectories (issue 63,
item 3): CPU-hours with a 90 % interval, and the wall time on a SLURM cluster.

Phases (each resumable: every measurement is appended to a JSON-lines log in ``--work`` as
it finishes, and a rerun measures only what is missing; run ``sets`` and ``trajectories``
side by side, the second waits for the sets it needs):

- ``sets``: every design set the profile's scenarios use (q, K, method, seed as the
  workflow keys them), built with the workflow's function into ``--work``: the design
  stage's CPU, once per set.
- ``whole``: per scenario, rules joint_map (the scenario's starts) and exact_marginal (models
  linear in the states, the profile's settings) on all K trajectories of its set in one
  call each, as their one job per scenario does (both are vectorised over K): measured
  whole, not sampled.
- ``trajectories``: per scenario the columns floor(K phi_2(j)), j = 0..n-1 (phi_2 the base-2
  radical inverse: any prefix is spread over the set) of its design trajectories, each
  through NUTS on ``stan.gradients`` at the profile's settings (:func:`nuts_paths.run_one`,
  the whole per-trajectory part of a ``sample_nuts`` job).  The scenario with the smallest
  share of its target goes next.
- ``grid``: per k_selection entry and method, the grid's smallest and middle K_i (and
  largest for random sets) measured whole: its set and the joint MAP of its K_i
  trajectories from one start, as rule k_selection_grid computes a point.  The design cost
  of the other K_i: piecewise linear in log K - log t through the measured sets of the same
  q and method (the scenarios' own sets included), the end segments extended; the joint
  MAP's: linear in K from the largest measured point.
- ``compile``: one program compiled into an empty cache (CPU per program).
- ``report``: the Markdown section (appended to BENCHMARKS.md with ``--write``).

    nice -n 10 python benchmarks/bench_paper_stages.py sets --work /tmp/pc &
    nice -n 10 python benchmarks/bench_paper_stages.py trajectories --work /tmp/pc --n 50
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import time
from pathlib import Path
from typing import Any

from paper_stages import (
    build_set,
    compile_cpu,
    exact_cpu,
    grid_point_cpu,
    joint_map_cpu,
    nuts_cpu,
    scenario_set,
    spread_columns,
    trajectories,
)

REPO = Path(__file__).resolve().parents[1]
#: scenarios measured on fewer trajectories (small K x per-trajectory cost, or long runs)
LIGHT = {
    "same_a09_T4": 20,
    "same_a09_T20": 20,
    "sep_d1_p2_T50": 8,
    "sep_d1_p2_T50_true_init": 8,
}


def read_log(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def append(path: Path, row: dict) -> None:
    row = {
        **row,
        "load1": os.getloadavg()[0],
        "finished": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
    }
    with path.open("a") as fh:
        fh.write(json.dumps(row) + "\n")
    print(json.dumps(row), flush=True)


def load_profile(config_path: str) -> tuple[dict, list[Any]]:
    from ssmobs.config.scenario import Scenario
    from ssmobs.config.validation import read_config_file, validate

    config = validate(read_config_file(config_path))
    return config, [Scenario.from_config(e) for e in config["scenarios"]]


def phase_sets(config: dict, scenarios: list[Any], work: Path) -> None:
    log = work / "sets.jsonl"
    done = {r["set"] for r in read_log(log)}
    wanted = sorted({scenario_set(sc) for sc in scenarios}, key=lambda d: d.q * d.K)
    for ds in wanted:
        if ds.name in done:
            continue
        out = work / "sets" / f"{ds.name}.nc"
        out.parent.mkdir(parents=True, exist_ok=True)
        w0 = time.perf_counter()
        cpu = build_set(ds, config["design"], out)
        append(
            log,
            {
                "set": ds.name,
                "q": ds.q,
                "K": ds.K,
                "cpu_s": cpu,
                "wall_s": time.perf_counter() - w0,
            },
        )


def phase_trajectories(config: dict, scenarios: list[Any], work: Path, n: int) -> None:
    from nuts_paths import compiled_programs
    from ssmobs.stan_backends.native import NativeBackend

    log = work / "trajectories.jsonl"
    done = {(r["scenario"], r["k"]) for r in read_log(log)}
    scenarios = [sc for sc in scenarios if sc.stan]
    target = {sc.name: min(LIGHT.get(sc.name, n), n) for sc in scenarios}
    native = NativeBackend()
    gradients = config["stan"]["gradients"]
    programs: dict[str, Any] = {}
    cache: dict[str, Any] = {}
    while True:
        built = {r["set"] for r in read_log(work / "sets.jsonl")}
        todo = []
        for sc in scenarios:
            cols = spread_columns(sc.K, target[sc.name])
            left = [k for k in cols if (sc.name, k) not in done]
            if left:
                todo.append((1 - len(left) / len(cols), sc, left[0]))
        if not todo:
            return
        ready = [t for t in todo if scenario_set(t[1]).name in built]
        if not ready:
            time.sleep(20)
            continue
        _, sc, k = min(ready, key=lambda t: t[0])
        # per scenario: scenarios of other models share a set (same q, K, seed)
        if sc.name not in cache:
            cache[sc.name] = trajectories(sc, work / "sets" / f"{scenario_set(sc).name}.nc")
        traj = cache[sc.name]
        if sc.model.slug not in programs:
            programs[sc.model.slug] = compiled_programs(native, sc.model.slug)[gradients]
        row: dict[str, Any] = {"scenario": sc.name, "k": k}
        row["nuts_cpu_s"], row["converged"] = nuts_cpu(
            native, sc, config, programs[sc.model.slug], traj, k
        )
        append(log, row)
        done.add((sc.name, k))


def phase_whole(config: dict, scenarios: list[Any], work: Path) -> None:
    """Rules joint_map and exact_marginal measured whole: every trajectory of the set in
    one call, as their one job per scenario runs them (both are vectorised over K)."""
    log = work / "whole.jsonl"
    done = {r["scenario"] for r in read_log(log)}
    for sc in sorted(scenarios, key=lambda s: s.disturbance_dim * s.K):
        if sc.name in done or not (sc.joint_map or sc.exact_applies):
            continue
        if sc.exact_applies:
            assert sc.exact_trajectories == sc.K, "the exact stage on its own set: not measured"
        ds = scenario_set(sc)
        traj = trajectories(sc, work / "sets" / f"{ds.name}.nc")
        row: dict[str, Any] = {"scenario": sc.name, "K": sc.K}
        if sc.joint_map:
            row["joint_map_cpu_s"] = joint_map_cpu(sc, config, traj)
        if sc.exact_applies:
            row["exact_cpu_s"] = exact_cpu(sc, config, traj)
        append(log, row)


def grid_points(entry: dict, method: str) -> list[int]:
    """The K_i measured of a grid: its smallest and middle K_i, and its largest for the
    random baselines (cheap)."""
    grid = sorted(entry["K_grid"])
    points = [grid[0], grid[len(grid) // 2]]
    if method != "design":
        points.append(grid[-1])
    return sorted(set(points))


def phase_grid(config: dict, scenarios: list[Any], work: Path) -> None:
    log = work / "grid.jsonl"
    done = {(r["entry"], r["method"], r["K"]) for r in read_log(log)}
    by_name = {sc.name: sc for sc in scenarios}
    for entry in config.get("k_selection") or []:
        sc = by_name.get(entry["scenario"])
        if sc is None:
            continue
        for method in entry["methods"]:
            for K in grid_points(entry, method):
                if (entry["name"], method, K) in done:
                    continue
                seed, sets = entry["seeds"][0], entry["sets"][0]
                design, jm = grid_point_cpu(sc, config, K, method, seed, sets, work)
                append(
                    log,
                    {
                        "entry": entry["name"],
                        "method": method,
                        "K": K,
                        "q": sc.disturbance_dim,
                        "design_cpu_s": design,
                        "joint_map_cpu_s": jm,
                    },
                )


def phase_compile(work: Path, slug: str, gradients: str) -> None:
    log = work / "compile.jsonl"
    if any(r["slug"] == slug for r in read_log(log)):
        return
    cpu, wall = compile_cpu(slug, gradients)
    append(log, {"slug": slug, "gradients": gradients, "cpu_s": cpu, "wall_s": wall})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("phase", choices=["sets", "whole", "trajectories", "grid", "compile", "report"])
    ap.add_argument("--config", default=str(REPO / "config" / "paper.yaml"))
    ap.add_argument("--work", default="paper_stages", help="sets and JSON-lines logs")
    ap.add_argument("--n", type=int, default=50, help="trajectories per heavy scenario")
    ap.add_argument("--scenarios", default="", help="comma-separated names (default: all)")
    ap.add_argument("--write", action="store_true", help="append the report to BENCHMARKS.md")
    args = ap.parse_args()
    config, scenarios = load_profile(args.config)
    wanted = {s for s in args.scenarios.split(",") if s}
    if wanted:
        scenarios = [sc for sc in scenarios if sc.name in wanted]
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.phase == "sets":
        phase_sets(config, scenarios, work)
    elif args.phase == "trajectories":
        phase_trajectories(config, scenarios, work, args.n)
    elif args.phase == "whole":
        phase_whole(config, scenarios, work)
    elif args.phase == "grid":
        phase_grid(config, scenarios, work)
    elif args.phase == "compile":
        phase_compile(work, scenarios[0].model.slug, config["stan"]["gradients"])
    else:
        from machine import report
        from paper_stages_report import report_section

        report(report_section(config, scenarios, work, args), args.write)


if __name__ == "__main__":
    main()
