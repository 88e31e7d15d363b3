"""The NUTS stage of default-profile scenarios with Stan's autodiff against the analytic
gradients (issue 49, item 6): may the default profile switch ``stan.gradients``?

For each scenario (its settings from ``config/config.yaml``: omega, x0, T, prior, Stan
init, the stan block's sampler settings) one batch of ``--n`` trajectories is simulated
from fixed disturbances (numpy seed 1; the same for both paths) and each trajectory goes
through the whole per-trajectory code of rule ``sample_nuts``
(:func:`ssmobs.nuts.batch.run_trajectories`: sampling, checks, marginal MAP, record; no
draws kept), once per path, the two interleaved (autodiff first for even k, analytic first
for odd k) with the same Stan seed.  Measured per path: CPU seconds of this process and
its children (the whole job's part per trajectory), of the driver alone (the records'
``sample_cpu``, its rusage), and wall seconds.  The draws' agreement, trajectory by
trajectory (paired): for every parameter of Omega and x0, the record's marginal MAP and its
5 and 95 % quantiles (Eq. (11), (12)); per statistic the mean over k of analytic -
autodiff in units of its standard error over k (a paired t; equal in distribution: |t|
mostly below 2, none far above 3, whether or not the chains converge).  Also: how many
runs pass the configured convergence checks per path.  Prints a table; writes nothing.

    python benchmarks/bench_gradients_profile.py [--n 25] [--scenarios a,b]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np
from nuts_paths import compiled_programs, run_one, simulate

REPO = Path(__file__).resolve().parents[1]
DEFAULT = ("same_a09_T20", "sep_ab_T75", "ranwalk_T100", "sep_d1_p2_T50")
QUANTILES = (0.05, 0.5, 0.95)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=25, help="trajectories per scenario (one batch)")
    ap.add_argument("--scenarios", default=",".join(DEFAULT))
    ap.add_argument("--config", default=str(REPO / "config" / "config.yaml"))
    args = ap.parse_args()

    from ssmobs.config.scenario import Scenario
    from ssmobs.config.validation import read_config_file, validate
    from ssmobs.stan_backends.native import NativeBackend

    config = validate(read_config_file(args.config))
    entries = {sc["name"]: sc for sc in config["scenarios"]}
    native = NativeBackend()
    print(f"load at start {os.getloadavg()[0]:.1f}; {args.n} trajectories per scenario")
    rows = []
    for name in [s for s in args.scenarios.split(",") if s]:
        sc = Scenario.from_config(entries[name])
        model = sc.model
        n = min(args.n, sc.K)
        xz = simulate(sc, n)
        if sc.stan_init == "joint_map":
            raise SystemExit(f"{name}: stan_init joint_map is not measured here")
        programs = compiled_programs(native, model.slug)
        cpu = {g: 0.0 for g in programs}
        wall = {g: 0.0 for g in programs}
        converged = {g: 0 for g in programs}
        both: dict[int, bool] = {}
        stats: dict[str, list[np.ndarray]] = {g: [] for g in programs}
        driver = {g: 0.0 for g in programs}
        names = [*model.param_names, model.theta_names(sc.T)[model.n_params]]
        with tempfile.TemporaryDirectory() as tmp:
            for k in range(n):
                order = ["autodiff", "analytic"] if k % 2 == 0 else ["analytic", "autodiff"]
                for g in order:
                    one = run_one(native, sc, config, programs[g], xz, k, Path(tmp) / g)
                    rec = one.record
                    cpu[g] += one.cpu_s
                    wall[g] += one.wall_s
                    driver[g] += one.driver_cpu_s
                    converged[g] += one.converged
                    both[k] = both.get(k, True) and one.converged
                    idx = [rec["theta_names"].index(v) for v in names]
                    row_stats = [
                        np.nan if rec[f] is None else rec[f][i]
                        for f in ("map", "q5", "q95")
                        for i in idx
                    ]
                    stats[g].append(np.array(row_stats, dtype=float))
        diff = np.array(stats["analytic"]) - np.array(stats["autodiff"])
        with np.errstate(invalid="ignore", divide="ignore"):
            count = np.sum(np.isfinite(diff), axis=0)
            tstat = np.nanmean(diff, axis=0) / (np.nanstd(diff, axis=0, ddof=1) / np.sqrt(count))
        zall = tstat[np.isfinite(tstat)] if np.isfinite(tstat).any() else np.array([np.nan])
        row = (
            name,
            n,
            cpu["autodiff"],
            cpu["analytic"],
            cpu["autodiff"] / cpu["analytic"],
            wall["autodiff"] / wall["analytic"],
            float(np.max(np.abs(zall))),
            float(np.mean(np.abs(zall) > 3)),
            float(np.mean(zall)),
            converged["autodiff"],
            converged["analytic"],
            sum(both.values()),
            driver["autodiff"] / driver["analytic"],
        )
        rows.append(row)
        print(
            f"{name}: n={n} CPU-s autodiff {row[2]:.1f} analytic {row[3]:.1f} "
            f"ratio CPU {row[4]:.2f} (driver alone {row[12]:.2f}) wall {row[5]:.2f}; paired "
            f"|t| max {row[6]:.2f}, share > 3 {row[7]:.3f}, mean t {row[8]:+.2f} "
            f"({zall.size} statistics); converged {row[9]}/{row[10]} of {n} (both {row[11]})",
            flush=True,
        )
    print(f"load at end {os.getloadavg()[0]:.1f}")
    print(
        "| scenario | n | CPU-s autodiff | CPU-s analytic | CPU ratio | driver CPU ratio |"
        " wall ratio | converged (autodiff/analytic/both) | paired max abs t | mean t |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r[0]} | {r[1]} | {r[2]:.1f} | {r[3]:.1f} | {r[4]:.2f} | {r[12]:.2f} | "
            f"{r[5]:.2f} | {r[9]}/{r[10]}/{r[11]} | {r[6]:.2f} | {r[8]:+.2f} |"
        )


if __name__ == "__main__":
    main()
