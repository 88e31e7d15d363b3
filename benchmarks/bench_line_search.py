"""The joint MAP's line search: one halving per evaluation against several (issue 48).

`ssmobs.joint_map.barrier` tries, after the first trial step, as many halvings of the
step in one evaluation of -2 pi as fit ``LINE_SEARCH_VALUES`` per-step terms;
``LINE_SEARCH_VALUES = 0`` is the search as it was, one halving per evaluation.
Both run in this process on the same trajectories, in turn, with the workflow's fixed
kernels: the joint MAPs of the default profile's choice of K (random and antithetic sets
of same_a09_T4, q = 8, the seeds `set_seed` gives) and of some scenarios' random sets.
Prints CPU seconds (medians), the evaluations of the line search, and whether every
column of the joint-MAP table is the same to the bit.

    python benchmarks/bench_line_search.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))
sys.path.insert(0, str(REPO / "benchmarks"))

#: (scenario, method, K, seed of the set): the choice of K's grids, then other scenarios
CASES: tuple[tuple[str, str, int, int], ...] = (
    ("same_a09_T4", "random", 1000, 1),
    ("same_a09_T4", "random", 3000, 1),
    ("same_a09_T4", "random", 5000, 1),
    ("same_a09_T4", "antithetic", 2000, 2),
    ("same_a09_T4", "antithetic", 4500, 2),
    ("same_a09_T20", "random", 300, 3),
    ("mult_T50", "random", 100, 4),
    ("sep_d2_p1_a_T50", "random", 100, 5),
    ("sep_b_T75", "random", 100, 2),
    ("ranwalk_T100", "random", 60, 11),
)


def _same_bits(a, b) -> bool:  # type: ignore[no-untyped-def]
    """Two table columns equal to the bit (floats by their bits, others by value)."""
    import numpy as np

    if a.dtype.kind == "f" and b.dtype.kind == "f":
        return bool(np.array_equal(a.view(np.uint64), b.view(np.uint64)))
    return bool(np.array_equal(a.astype(str), b.astype(str)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()

    from ssmobs import kernels

    kernels.restart_with_fixed_kernels()  # the workflow's kernels, as its jobs run
    from machine import machine_info
    from ssmobs.config.preflight import load_config_file
    from ssmobs.config.scenario import Scenario
    from ssmobs.design.disturbances import design_disturbances
    from ssmobs.design.trajectories import make_trajectories
    from ssmobs.joint_map import barrier
    from ssmobs.joint_map.driver import joint_map_of
    from ssmobs.joint_map.problem import JointMapProblem
    from ssmobs.k_selection import set_seed

    config = load_config_file(REPO / "config" / "config.yaml")
    scenarios = {s["name"]: s for s in config["scenarios"]}
    settings = dict(config.get("joint_map", {}))
    value_only = barrier.neg2_log_posterior
    evaluations: list[int] = []

    def counted(model, theta, z, bounds=None, order=0):  # type: ignore[no-untyped-def]
        if order == 0:
            evaluations.append(theta.shape[0])
        return value_only(model, theta, z, bounds, order=order)

    barrier.neg2_log_posterior = counted  # type: ignore[assignment]
    ways = {"before": 0, "after": barrier.LINE_SEARCH_VALUES}
    print(f"# {machine_info()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    print(
        "| case | K | CPU s before | CPU s after | before / after | evaluations before / after | same bits |"
    )
    print("|---|---:|---:|---:|---:|---|---|")
    totals = {w: 0.0 for w in ways}
    for name, method, K, seed in CASES:
        sc = Scenario.from_config(scenarios[name])
        s = set_seed(seed, K, "independent") if name == "same_a09_T4" else seed
        sc = sc.replace(K=K, method=method, seed=s)
        matrix = design_disturbances(sc.disturbance_dim, K, method, s).matrix
        traj = make_trajectories(sc, matrix, provenance={})
        cpu: dict[str, list[float]] = {w: [] for w in ways}
        count, frames = {}, {}
        for _ in range(args.repeat):
            for way, values in ways.items():
                barrier.LINE_SEARCH_VALUES = values
                evaluations.clear()
                t0 = time.process_time()
                _, frame, _ = joint_map_of(
                    JointMapProblem.of_trajectories(traj, sc.prior, settings)
                )
                cpu[way].append(time.process_time() - t0)
                count[way], frames[way] = len(evaluations), frame
        same = list(frames["before"].columns) == list(frames["after"].columns) and all(
            _same_bits(frames["before"][c].to_numpy(), frames["after"][c].to_numpy())
            for c in frames["before"].columns
        )
        med = {w: statistics.median(v) for w, v in cpu.items()}
        for w in ways:
            totals[w] += med[w]
        print(
            f"| {name} {method} seed {s} | {K} | {med['before']:.2f} | {med['after']:.2f} | "
            f"{med['before'] / med['after']:.2f}x | {count['before']} / {count['after']} | "
            f"{'yes' if same else 'NO'} |",
            flush=True,
        )
    print(
        f"| all | | {totals['before']:.2f} | {totals['after']:.2f} | "
        f"{totals['before'] / totals['after']:.2f}x | | |"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
