#!/usr/bin/env python
"""Benchmark of one trajectory's convergence diagnostics: ours vs. arviz-stats (issue 13).

Issue 13 asked: use ArviZ's array layer (``arviz_stats.base.array_stats``) if it is within
1.5x of our vectorised :mod:`ssmobs.nuts.diagnostics`, else keep ours.  The workflow computes
these diagnostics for every trajectory (thousands per scenario).

Draws: one NUTS run of model ``same`` (a = 0.9, x0 = 8, T = 100: 102 parameters a, x0,
x[1..100]) with the native backend, 4 chains, 1 000 warmup and 6 000 kept draws (the
paper's kept draws; warmup does not enter the diagnostics), and its first 1 000 draws per
chain.  Each is measured as sampled and with two defects written in: a stuck chain (chain
2 of x0 held at its first draw) and a constant column (a = 0.5 in every draw).

Measured per case:

* correctness: the largest relative difference of R-hat (rank-normalised split, max of
  bulk and folded), bulk-ESS, tail-ESS and per-chain E-BFMI between ours and
  arviz-stats, and whether both give NaN for the same parameters;
* speed: the wall and CPU time (``time.process_time``: less inflated by other load) of all
  four statistics for all parameters, ours and arviz-stats alternating in each of
  ``--rounds`` rounds (so both see the same load); the median of each and the median of the
  per-round ratio arviz-stats / ours.

Usage::

    python benchmarks/bench_diagnostics.py             # full run (several minutes here)
    python benchmarks/bench_diagnostics.py --quick     # T = 20, 1 000 draws, 2 rounds
    python benchmarks/bench_diagnostics.py --no-write  # print only

The Markdown is printed and (unless ``--no-write``) appended to BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))
sys.path.insert(0, str(REPO / "benchmarks"))

from machine import machine_info, report  # noqa: E402

SECTION = "## Diagnostics: ours vs arviz-stats (issue 13)"


def sample_draws(T: int, draws: int, seed: int = 1):
    """One NUTS run of model ``same`` at a = 0.9, x0 = 8 (native backend, 4 chains)."""
    from ssmobs.models import get_model
    from ssmobs.stan_backends import get_backend, stan_file
    from ssmobs.stan_backends.base import SamplerSettings

    model = get_model("same")
    rng = np.random.default_rng(seed)
    _, z = model.simulate(
        np.array([0.9]),
        np.array([8.0]),
        rng.standard_normal((1, T, 1)),
        rng.standard_normal((1, T, 1)),
    )
    backend = get_backend("native")
    settings = SamplerSettings(chains=4, iter_warmup=1000, iter_sampling=draws, workers=2)
    return backend.sample(
        stan_file("same"), model.stan_data(z[0], model.prior_bounds({"a": 0.9})), seed, settings
    )


def ours(x: np.ndarray, energy: np.ndarray) -> dict[str, np.ndarray]:
    from ssmobs.nuts.diagnostics import ebfmi, rank_diagnostics

    return {**rank_diagnostics(x), "ebfmi": ebfmi(energy)}


def arviz_stats(x: np.ndarray, energy: np.ndarray) -> dict[str, np.ndarray]:
    from arviz_stats.base import array_stats

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {
            "rhat": array_stats.rhat(x, method="rank"),
            "ess_bulk": array_stats.ess(x, method="bulk"),
            "ess_tail": array_stats.ess(x, method="tail", prob=(0.05, 0.95)),
            "ebfmi": array_stats.bfmi(energy),
        }


def compare(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, tuple[float, bool]]:
    """Per statistic: (max relative difference over non-NaN entries, same NaN pattern)."""
    out = {}
    for key, ref in b.items():
        x, y = np.asarray(a[key], float), np.asarray(ref, float)
        same_nan = bool(np.array_equal(np.isnan(x), np.isnan(y)))
        ok = ~np.isnan(x) & ~np.isnan(y)
        rel = float(np.max(np.abs(x[ok] - y[ok]) / np.abs(y[ok]))) if ok.any() else 0.0
        out[key] = (rel, same_nan)
    return out


def measure(x: np.ndarray, energy: np.ndarray, rounds: int) -> dict:
    ours(x[:2], energy), arviz_stats(x[:2], energy)  # imports and first-call costs
    t_ours, t_az, c_ours, c_az = [], [], [], []
    for _ in range(rounds):
        t0, c0 = time.perf_counter(), time.process_time()
        r_ours = ours(x, energy)
        t_ours.append(time.perf_counter() - t0)
        c_ours.append(time.process_time() - c0)
        t0, c0 = time.perf_counter(), time.process_time()
        r_az = arviz_stats(x, energy)
        t_az.append(time.perf_counter() - t0)
        c_az.append(time.process_time() - c0)
    return {
        "ours": statistics.median(t_ours),
        "arviz_stats": statistics.median(t_az),
        "cpu_ours": statistics.median(c_ours),
        "cpu_arviz_stats": statistics.median(c_az),
        "cpu_ratio": statistics.median(a / o for a, o in zip(c_az, c_ours)),
        "ratio": statistics.median(a / o for a, o in zip(t_az, t_ours)),
        "ratios": [a / o for a, o in zip(t_az, t_ours)],
        "diff": compare(r_ours, r_az),
        "nan_rows": int(np.isnan(r_ours["rhat"]).sum()),
    }


def cases(draws, n_short: int) -> list[tuple[str, np.ndarray, np.ndarray]]:
    from ssmobs.nuts.convergence import stack_params

    names, x = stack_params(draws)
    energy = np.asarray(draws.sample_stats["energy__"], dtype=float)
    defect = x.copy()
    i_x0, i_a = names.index("x0"), names.index("a")
    defect[i_x0, 2, :] = defect[i_x0, 2, 0]  # a stuck chain
    defect[i_a] = 0.5  # a constant column
    n = x.shape[2]
    out = [(f"{n} draws", x, energy), (f"{n} draws, stuck chain + constant column", defect, energy)]
    if n_short < n:
        out += [
            (f"{n_short} draws", x[:, :, :n_short], energy[:, :n_short]),
            (
                f"{n_short} draws, stuck chain + constant column",
                defect[:, :, :n_short],
                energy[:, :n_short],
            ),
        ]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="T = 20, 1 000 draws, 2 rounds")
    ap.add_argument("--rounds", type=int, default=None, help="timing rounds (default 5)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args()
    T, n, rounds = (20, 1000, 2) if args.quick else (100, 6000, 5)
    rounds = args.rounds or rounds
    started = _dt.datetime.now(_dt.UTC)
    load0 = os.getloadavg()
    import arviz_stats

    t0 = time.perf_counter()
    draws = sample_draws(T, n)
    t_sample = time.perf_counter() - t0
    rows = []
    for label, x, energy in cases(draws, 1000):
        res = measure(x, energy, rounds)
        rows.append((label, x.shape, res))
        print(
            f"{label}: {res['ours']:.3f} s vs {res['arviz_stats']:.3f} s, ratio "
            f"{res['ratio']:.2f} ({', '.join(f'{r:.2f}' for r in res['ratios'])}), CPU "
            f"{res['cpu_ours']:.3f} s vs {res['cpu_arviz_stats']:.3f} s",
            file=sys.stderr,
        )
    load1 = os.getloadavg()
    lines = [
        f"\n{SECTION}\n",
        f"\nRun {started:%Y-%m-%d %H:%M} UTC on {machine_info()}; arviz-stats "
        f"{arviz_stats.__version__}. Load average (1 min) {load0[0]:.1f} at the start, "
        f"{load1[0]:.1f} at the end (other jobs shared the 2 cores; this one ran "
        f"under `nice -n 19`, so absolute times are inflated: read the same-run ratio). "
        f"Draws: model `same`, a = 0.9, x0 = 8, T = {T}, native backend, 4 chains x "
        f"(1 000 warmup + {n} kept) draws, sampled in {t_sample:.0f} s. Per trajectory "
        f"(all {rows[0][1][0]} parameters): R-hat (rank), bulk-ESS, tail-ESS, E-BFMI; "
        f"median of {rounds} rounds, ours and arviz-stats alternating "
        f"(`benchmarks/bench_diagnostics.py`).\n",
        "\n| draws (chain x draw) | case | ours wall (CPU) [s] | arviz-stats wall (CPU) [s] "
        "| ratio wall (CPU) | max rel. diff R-hat / bulk / tail / E-BFMI | same NaNs |",
        "\n|---|---|---|---|---|---|---|",
    ]
    for label, shape, res in rows:
        d = res["diff"]
        lines.append(
            f"\n| {shape[1]} x {shape[2]} | {label.split(', ', 1)[1] if ', ' in label else 'as sampled'} "
            f"| {res['ours']:.3f} ({res['cpu_ours']:.3f}) | {res['arviz_stats']:.3f} "
            f"({res['cpu_arviz_stats']:.3f}) | {res['ratio']:.2f} ({res['cpu_ratio']:.2f}) | "
            f"{' / '.join(f'{d[k][0]:.1e}' for k in ('rhat', 'ess_bulk', 'ess_tail', 'ebfmi'))} | "
            f"{'yes' if all(v[1] for v in d.values()) else 'no'} ({res['nan_rows']} NaN R-hat) |"
        )
    worst = min(min(res["ratio"], res["cpu_ratio"]) for _, _, res in rows)
    verdict = (
        "within 1.5x: use arviz-stats"
        if worst <= 1.5
        else "more than 1.5x slower in every case: keep ours (`ssmobs.nuts.diagnostics`)"
    )
    lines.append(f"\n\nSmallest ratio arviz-stats / ours (wall or CPU): {worst:.2f}; {verdict}.\n")
    report("".join(lines), write=not args.no_write)


if __name__ == "__main__":
    main()
