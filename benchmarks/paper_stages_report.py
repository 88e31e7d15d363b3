"""The Markdown section of ``bench_paper_stages.py``: CPU-hours per stage and scenario with
90 % intervals, and the wall time of the profile's jobs on a SLURM cluster (simulated from
the measured costs with the SLURM profile's settings)."""

from __future__ import annotations

import datetime as dt
import heapq
import math
import os
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from bench_paper_stages import read_log
from machine import machine_info
from paper_stages import loglog_interp, scenario_set
from scipy import stats

LEVEL = 0.90
STAGES = ("nuts",)
WHOLE = ("joint_map", "exact")
#: the SLURM profile (config/profiles/slurm/config.yaml): at most this many jobs at a time
SLURM_JOBS = 200
CORES = (8, 32, 128)


def t_interval(values: np.ndarray) -> tuple[float, float, float]:
    """(mean, half-width of the LEVEL Student-t interval of the mean, standard error)."""
    n = values.size
    mean = float(values.mean())
    if n < 2:
        return mean, math.nan, math.nan
    se = float(values.std(ddof=1) / math.sqrt(n))
    return mean, float(stats.t.ppf(0.5 + LEVEL / 2, n - 1) * se), se


def per_trajectory(work: Path) -> dict[str, dict[str, np.ndarray]]:
    """Scenario -> stage -> CPU seconds of each measured trajectory."""
    out: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in read_log(work / "trajectories.jsonl"):
        for st in STAGES:
            if f"{st}_cpu_s" in r:
                out[r["scenario"]][st].append(r[f"{st}_cpu_s"])
        if "converged" in r:
            out[r["scenario"]]["converged"].append(float(r["converged"]))
    return {s: {k: np.array(v) for k, v in d.items()} for s, d in out.items()}


def grid_costs(config: dict, scenarios: list[Any], work: Path, sets: dict) -> list[dict]:
    """Per k_selection entry and method: its sets, and CPU seconds of its design sets and
    joint MAPs (bench_paper_stages' docstring, phase ``grid``)."""
    from ssmobs.k_selection import set_seed

    by_name = {sc.name: sc for sc in scenarios}
    measured = read_log(work / "grid.jsonl")
    rows = []
    for entry in config.get("k_selection") or []:
        sc = by_name.get(entry["scenario"])
        if sc is None:
            continue
        q = sc.disturbance_dim
        for method in entry["methods"]:
            mine = [m for m in measured if m["entry"] == entry["name"] and m["method"] == method]
            if not mine:
                continue
            same_q = [
                (m["K"], m["design_cpu_s"])
                for m in measured
                if m["q"] == q and m["method"] == method
            ]
            if method == "design":
                same_q += [(r["K"], r["cpu_s"]) for r in sets.values() if r["q"] == q]
            grids = [(seed, s) for seed in entry["seeds"] for s in entry["sets"]]
            keys = {(K, set_seed(seed, K, s)) for K in entry["K_grid"] for seed, s in grids}
            Ks = np.array(sorted(K for K, _ in keys), dtype=float)
            big = max(mine, key=lambda m: m["K"])
            design = float(loglog_interp(same_q, Ks).sum())
            jm = float((big["joint_map_cpu_s"] / big["K"] * Ks).sum())
            rows.append(
                {
                    "entry": entry["name"],
                    "method": method,
                    "q": q,
                    "n_sets": len(keys),
                    "K_range": f"{int(Ks.min())}-{int(Ks.max())}",
                    "points": sorted(mine, key=lambda m: m["K"]),
                    "n_fit": len({k for k, _ in same_q}),
                    "design_s": design,
                    "joint_map_s": jm,
                    # one job per (seed, sets) grid, its share of the entry's work
                    "jobs": [(design + jm) / len(grids)] * len(grids),
                }
            )
    return rows


def simulate_wall(jobs: list[tuple[float, float, str]], cores: int) -> float:
    """Makespan of ``jobs`` (duration, earliest start) on ``cores`` single-CPU slots (at
    most SLURM_JOBS at a time), taken by earliest start, then longest first."""
    slots = [0.0] * min(cores, SLURM_JOBS)
    heapq.heapify(slots)
    end = 0.0
    for dur, ready, _ in sorted(jobs, key=lambda j: (j[1], -j[0])):
        start = max(heapq.heappop(slots), ready)
        heapq.heappush(slots, start + dur)
        end = max(end, start + dur)
    return end


def report_section(config: dict, scenarios: list[Any], work: Path, args: Any) -> str:
    traj = per_trajectory(work)
    sets = {r["set"]: r for r in read_log(work / "sets.jsonl")}
    compiles = read_log(work / "compile.jsonl")
    rows_t = read_log(work / "trajectories.jsonl")
    loads = [r["load1"] for r in rows_t + list(sets.values())]
    first = min(r["finished"] for r in rows_t + list(sets.values()))
    last = max(r["finished"] for r in rows_t + list(sets.values()))
    z = stats.norm.ppf(0.5 + LEVEL / 2)
    lines = [
        "",
        f"## The paper profile's cost per stage on its design trajectories (issue 63, item 3, "
        f"{dt.date.fromisoformat(first[:10])})",
        "",
        "- Command: `benchmarks/bench_paper_stages.py sets`, then `grid` and `compile`, beside "
        f"`trajectories --n {args.n}` (both `nice -n 10`, the workflow's fixed kernels' "
        f"settings), then `report`; config `{os.path.relpath(args.config)}`, "
        f"`stan.gradients: {config['stan']['gradients']}`, native backend.",
        f"- Machine: {machine_info()}; measured {first[11:16]}-{last[11:16]} UTC; 1-min load "
        f"average {min(loads):.2f}-{max(loads):.2f} after each measurement (other jobs "
        "shared the 2 cores).",
        "- Per-trajectory stages: columns floor(K phi_2(j)), j = 0..n-1, phi_2 the base-2 "
        "radical inverse (0, K/2, K/4, 3K/4, ...) of the scenario's own LCD design set; "
        f"interval: {LEVEL:.0%} Student t of the mean over the n trajectories, times K / 3600.",
        "",
        "| scenario | K | n | NUTS CPU-s / trajectory: mean | 90 % interval | range "
        "| CPU-h for K | 90 % interval | converged | batch |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    total, var = 0.0, 0.0
    per_stage: dict[str, float] = defaultdict(float)
    jobs: list[tuple[float, float, str]] = []
    rng = np.random.default_rng(0)
    longest = ("", 0.0, 0.0)
    for sc in scenarios:
        d = traj.get(sc.name, {})
        ds = sets.get(scenario_set(sc).name)
        ready = ds["cpu_s"] if ds else 0.0
        v = d.get("nuts")
        if v is None or v.size == 0:
            continue
        mean, half, se = t_interval(v)
        h = sc.K / 3600
        total += mean * h
        var += (se * h) ** 2 if se == se else 0.0
        per_stage["nuts"] += mean * h
        c = d["converged"]
        batch = sc.stan_batch_size or config["stan"]["batch_size"]
        for j in range(math.ceil(sc.K / batch)):
            size = min(batch, sc.K - j * batch)
            dur = float(rng.choice(v, size=size, replace=True).sum())
            jobs.append((dur, ready, f"sample_nuts {sc.name}"))
            if dur + ready > longest[1] + longest[2]:
                longest = (sc.name, dur, ready)
        lo, hi = max(mean - half, 0.0), mean + half
        lines.append(
            f"| {sc.name} | {sc.K} | {v.size} | {mean:.2f} | {lo:.2f}-{hi:.2f} | "
            f"{v.min():.2f}-{v.max():.2f} | {mean * h:.2f} | {lo * h:.2f}-{hi * h:.2f} | "
            f"{int(c.sum())}/{c.size} | {batch} |"
        )
    whole = {r["scenario"]: r for r in read_log(work / "whole.jsonl")}
    lines += [
        "",
        "Rules joint_map and exact_marginal measured whole (all K trajectories in one call, "
        "as their one job per scenario runs them; CPU-s):",
        "",
        "| scenario | K | joint MAP | exact marginal |",
        "|---|---:|---:|---:|",
    ]
    for sc in scenarios:
        r = whole.get(sc.name)
        if r is None:
            continue
        cells = []
        for st in WHOLE:
            if f"{st}_cpu_s" in r:
                cpu = r[f"{st}_cpu_s"]
                per_stage[st] += cpu / 3600
                jobs.append((cpu, sets[scenario_set(sc).name]["cpu_s"], f"{st} {sc.name}"))
                cells.append(f"{cpu:.1f}")
            else:
                cells.append("not run")
        lines.append(f"| {sc.name} | {sc.K} | {' | '.join(cells)} |")
    lines += [
        "",
        "Per-set stages, each measured once (no interval):",
        "",
        "| design set (q, K, seed) | scenarios | CPU-s | wall s |",
        "|---|---|---:|---:|",
    ]
    users: dict[str, list[str]] = defaultdict(list)
    for sc in scenarios:
        users[scenario_set(sc).name].append(sc.name)
    design_s = 0.0
    for name, r in sets.items():
        design_s += r["cpu_s"]
        jobs.append((r["cpu_s"], 0.0, f"design_disturbances {name}"))
        lines.append(
            f"| {name} | {', '.join(users[name])} | {r['cpu_s']:.1f} | {r['wall_s']:.1f} |"
        )
    grids = grid_costs(config, scenarios, work, sets)
    grid_s = 0.0
    if grids:
        lines += [
            "",
            "| choice-of-K grid | method | q | sets | K_i | measured points: K (design CPU-s, "
            "joint MAP CPU-s) | sets of this q in the fit | design CPU-h | joint MAP CPU-h |",
            "|---|---|---:|---:|---|---|---:|---:|---:|",
        ]
        for g in grids:
            pts = "; ".join(
                f"{m['K']} ({m['design_cpu_s']:.1f}, {m['joint_map_cpu_s']:.1f})"
                for m in g["points"]
            )
            grid_s += g["design_s"] + g["joint_map_s"]
            jobs += [(j, 0.0, f"k_selection_grid {g['entry']} {g['method']}") for j in g["jobs"]]
            lines.append(
                f"| {g['entry']} | {g['method']} | {g['q']} | {g['n_sets']} | {g['K_range']} | "
                f"{pts} | {g['n_fit']} | "
                f"{g['design_s'] / 3600:.3f} | {g['joint_map_s'] / 3600:.3f} |"
            )
    compile_s = 0.0
    if compiles:
        slugs = {sc.model.slug for sc in scenarios if sc.stan}
        per = float(np.mean([c["cpu_s"] for c in compiles]))
        compile_s = per * len(slugs)
        jobs += [(per, 0.0, "build_stan_model")] * len(slugs)
        lines += [
            "",
            f"Compiles: {per:.1f} CPU-s for one program ({compiles[0]['slug']}, "
            f"{compiles[0]['gradients']}, into an empty cache; wall {compiles[0]['wall_s']:.1f} s) "
            f"x {len(slugs)} models with Stan = {compile_s / 3600:.3f} CPU-h.",
        ]
    fixed = design_s + grid_s + compile_s
    grand = total + fixed / 3600 + per_stage["joint_map"] + per_stage["exact"]
    sd = math.sqrt(var)
    lines += [
        "",
        "| stage | CPU-hours |",
        "|---|---:|",
        f"| NUTS (mean per trajectory x K) | {per_stage['nuts']:.2f} |",
        f"| joint MAP (whole, measured) | {per_stage['joint_map']:.3f} |",
        f"| exact marginal (whole, measured) | {per_stage['exact']:.3f} |",
        f"| design sets of the scenarios | {design_s / 3600:.2f} |",
        f"| choice-of-K grids | {grid_s / 3600:.2f} |",
        f"| compiles | {compile_s / 3600:.3f} |",
        f"| **total** | **{grand:.1f}** (90 % interval {grand - z * sd:.1f}-{grand + z * sd:.1f}) |",
        "",
        f"Total's interval: the scenarios' NUTS standard errors in quadrature (normal, "
        f"{LEVEL:.0%}); every other stage added as measured.",
        "",
        "| cores | wall time (h), simulated | CPU-h / cores |",
        "|---:|---:|---:|",
    ]
    chain = max(jobs, key=lambda j: j[0] + j[1])
    for n_cores in CORES:
        wall = simulate_wall(jobs, n_cores) / 3600
        lines.append(f"| {n_cores} | {wall:.2f} | {grand / n_cores:.2f} |")
    lines += [
        "",
        f"Wall time: every job on one CPU (`cores: 1`, `group-components: nuts: 1`, at most "
        f"{SLURM_JOBS} jobs at a time: config/profiles/slurm), {len(jobs)} jobs, longest "
        "first once ready; a Stan job's length is the sum of its `stan_batch_size` "
        "per-trajectory CPU-s resampled from the measured ones (seed 0), ready when its "
        "design set is; no queueing, submission or start-up time. The longest chain, "
        f"{chain[2]} (ready after {chain[1] / 60:.1f} min, then {chain[0] / 60:.1f} min), "
        f"bounds the wall time from below on any number of cores: "
        f"{(chain[0] + chain[1]) / 3600:.2f} h; the longest Stan job: {longest[0]}, "
        f"{longest[1] / 60:.1f} min.",
        "",
    ]
    return "\n".join(lines)
