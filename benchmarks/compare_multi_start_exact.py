#!/usr/bin/env python
"""Multi-start joint MAP against the exact stage, trajectory by trajectory (issue 36).

For models linear in the states the exact stage (:mod:`ssmobs.exact.marginal`) classifies
the marginal posterior p(Omega | z~(k)) of every trajectory by Definition 3 (``unique`` /
``several`` / ``none`` interior maxima).  The multi-start joint MAP
(:mod:`ssmobs.joint_map.multi_start`) counts the distinct maxima of the *joint* posterior
pi(Theta | z~(k)) that pass the checks of Sec. III.B.  The two answer different questions
(the joint maximum over the states vs the maximum of the integral over them), so they may
disagree; this script counts how often, as a cross table per case: the rows the exact
stage's class, the columns the number of distinct joint maxima (0, 1, 2+), and beside it
|K^max| (the paper's start passes) and |K^max_unique|.

Trajectories come from random N(0, I) disturbances (seed 0) with the fixed kernels of the
workflow's jobs.  Usage: ``python benchmarks/compare_multi_start_exact.py [--K 200]``
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

from ssmobs import kernels  # noqa: E402  (no NumPy at import)

kernels.restart_with_fixed_kernels()

import numpy as np  # noqa: E402

#: (label, slug, omega, x0, T, prior): Section IV settings of the models linear in the states
CASES = [
    ("Same a=0.9 T=4", "same", [0.9], [8.0], 4, "restricted"),
    ("Same a=0.9 T=20", "same", [0.9], [8.0], 20, "restricted"),
    ("ranWalk T=4", "sep_ranwalk", [0.9], [8.0], 4, "half_line"),
    ("Sep a, b restricted T=75", "sep", [0.9, 0.9], [8.0], 75, "restricted"),
    ("Same a=0.7 T=100", "same", [0.7], [8.0], 100, "restricted"),
    ("ranWalk T=100", "sep_ranwalk", [0.9], [8.0], 100, "half_line"),
    ("Sep d=2 p=1 a, b, c restricted T=50", "sep_d2_p1", [0.9, 0.9, 0.9], [8.0], 50, "restricted"),
    ("Sep d=1 p=2 T=50", "sep_d1_p2", [0.6, 0.5, 0.9, 0.9], [8.0, 8.0], 50, "restricted"),
]


def compare(slug, omega, x0, T, prior, K, n_starts):
    from ssmobs.exact.marginal import exact_marginal
    from ssmobs.joint_map.multi_start import multi_start_joint_map
    from ssmobs.joint_map.problem import JointMapProblem
    from ssmobs.joint_map.settings import JointMapSettings
    from ssmobs.models import get_model

    model = get_model(slug)
    rng = np.random.default_rng(0)
    matrix = rng.standard_normal(((model.obs_dim + model.state_dim) * T, K))
    _, z = model.design_trajectories(omega, x0, matrix, T)
    bounds = model.prior_bounds(omega, prior)
    start = time.process_time()
    multi = multi_start_joint_map(
        JointMapProblem(
            model,
            z,
            bounds,
            np.asarray(omega, float),
            np.asarray(x0, float),
            JointMapSettings(n_starts=n_starts),
        )
    )
    cpu_multi = time.process_time() - start
    start = time.process_time()
    exact = exact_marginal(model, z, bounds)
    cpu_exact = time.process_time() - start
    n_max = np.minimum(multi.n_maxima, 2)
    table = {
        cls: [int(((exact.maxima == cls) & (n_max == j)).sum()) for j in (0, 1, 2)]
        for cls in ("unique", "several", "none")
    }
    return (
        table,
        int(multi.runs[0].ok.sum()),
        int((multi.n_maxima == 1).sum()),
        (
            cpu_multi,
            cpu_exact,
        ),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--K", type=int, default=200)
    parser.add_argument("--starts", type=int, default=8)
    parser.add_argument("--only", nargs="*", help="labels of the cases to run (default: all)")
    args = parser.parse_args()
    began = _dt.datetime.now(_dt.UTC)
    print(
        f"`python benchmarks/compare_multi_start_exact.py --K {args.K} --starts "
        f"{args.starts}` ({began:%Y-%m-%d %H:%M} UTC, load average {os.getloadavg()[0]:.1f})\n"
    )
    print(
        "| case | K | K^max | K^max_unique | exact unique: 0 / 1 / 2+ joint maxima | "
        "exact several: 0 / 1 / 2+ | exact none: 0 / 1 / 2+ | CPU s multi-start / exact |"
    )
    print("|---|---:|---:|---:|---|---|---|---|")
    for label, slug, omega, x0, T, prior in CASES:
        if args.only and label not in args.only:
            continue
        table, k_max, k_unique, (c_multi, c_exact) = compare(
            slug, omega, x0, T, prior, args.K, args.starts
        )
        cells = " | ".join(" / ".join(str(v) for v in table[c]) for c in table)
        print(
            f"| {label} | {args.K} | {k_max} | {k_unique} | {cells} | "
            f"{c_multi:.0f} / {c_exact:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
