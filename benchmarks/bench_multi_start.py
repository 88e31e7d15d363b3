#!/usr/bin/env python
"""CPU per trajectory per start of the multi-start joint MAP (issue 36).

For each case, K design-like trajectories (random N(0, I) disturbances; the optimiser's
cost does not depend on whether they are design points) are optimised by
:func:`ssmobs.joint_map.multi_start.multi_start_joint_map` with ``n_starts`` starts; every start is
timed on its own (CPU seconds of ``time.process_time`` around its
:func:`ssmobs.joint_map.driver.joint_map` call, checks and ridge re-optimisations included), so the
paper's start (start 0) and the extra starts (Halton points of the start box, which start
farther from the optimum) are reported apart.  The process runs with the fixed kernels of
the workflow's jobs (:mod:`ssmobs.kernels`, set before NumPy loads).  Printed: a Markdown
table and |K^max| vs |K^max_unique| of each case.

Usage: ``python benchmarks/bench_multi_start.py [--K 200] [--starts 8]``
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
from machine import machine_info  # noqa: E402

#: (label, slug, omega, x0, T, prior)
CASES = [
    ("Same a=0.9 T=50", "same", [0.9], [8.0], 50, "restricted"),
    ("Sep a=b=0.9 T=75", "sep", [0.9, 0.9], [8.0], 75, None),
    ("Mult a=0.9 T=50", "sep_mult", [0.9], [8.0], 50, "half_line"),
    ("stoch_vol T=50", "stoch_vol", [0.9, 0.5], [0.0], 50, None),
]


def run_case(slug, omega, x0, T, prior, K, n_starts):
    import ssmobs.joint_map.images as images
    import ssmobs.joint_map.multi_start as ms
    from ssmobs.joint_map.driver import joint_map
    from ssmobs.joint_map.problem import JointMapProblem
    from ssmobs.joint_map.settings import JointMapSettings
    from ssmobs.models import get_model

    model = get_model(slug)
    rng = np.random.default_rng(0)
    matrix = rng.standard_normal(((model.obs_dim + model.state_dim) * T, K))
    _, z = model.design_trajectories(omega, x0, matrix, T)
    bounds = model.prior_bounds(omega, prior)
    seconds: list[float] = []

    def timed(*args, **kwargs):
        start = time.process_time()
        out = joint_map(*args, **kwargs)
        seconds.append(time.process_time() - start)
        return out

    # time every start's call and every image run's, the same function underneath
    ms.joint_map = images.joint_map = timed
    try:
        multi = ms.multi_start_joint_map(
            JointMapProblem(
                model,
                z,
                bounds,
                np.asarray(omega, float),
                np.asarray(x0, float),
                JointMapSettings(n_starts=n_starts),
            )
        )
    finally:
        ms.joint_map = images.joint_map = joint_map
    k_max = int(multi.runs[0].ok.sum())
    k_unique = int((multi.n_maxima == 1).sum())
    return seconds, k_max, k_unique, int((multi.n_maxima > 1).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument("--K", type=int, default=200)
    parser.add_argument("--starts", type=int, default=8)
    args = parser.parse_args()
    began = _dt.datetime.now(_dt.UTC)
    load = os.getloadavg()
    rows = []
    for label, slug, omega, x0, T, prior in CASES:
        sec, k_max, k_unique, k_several = run_case(slug, omega, x0, T, prior, args.K, args.starts)
        paper_ms = 1e3 * sec[0] / args.K
        extra_ms = 1e3 * float(np.mean(sec[1:])) / args.K
        rows.append(
            f"| {label} | {args.K} | {args.starts} | {paper_ms:.2f} | {extra_ms:.2f} | "
            f"{sum(sec):.1f} | {k_max} | {k_unique} | {k_several} |"
        )
        print(rows[-1], flush=True)
    end_load = os.getloadavg()
    print(
        f"\n`python benchmarks/bench_multi_start.py --K {args.K} --starts {args.starts}` "
        f"({began:%Y-%m-%d %H:%M} UTC; {machine_info()}; fixed kernels "
        f"({kernels.guarantee()}; load average {load[0]:.1f} at the start, "
        f"{end_load[0]:.1f} at the end)\n"
    )
    print(
        "| case | K | starts | CPU ms per trajectory, paper's start | CPU ms per trajectory "
        "per extra start (mean) | CPU s, all starts | K^max | K^max_unique | several maxima |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
