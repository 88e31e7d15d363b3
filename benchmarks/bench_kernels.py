#!/usr/bin/env python
"""What the fixed kernels cost (issue 34): the design stage and the exact stage with this
machine's own kernels against the fixed ones (ssmobs/kernels.py), in the same run.

Each measurement is a fresh process started with one of two environments, in turn (own,
fixed, own, fixed, ...), so that drifts of a noisy machine hit both alike:

- ``own``: what a shell has when nothing is set: OpenBLAS's kernel for this CPU, NumPy's
  widest SIMD targets (the variables ``OPENBLAS_CORETYPE`` and ``NPY_DISABLE_CPU_FEATURES``
  removed); one BLAS thread, as the design stage always had;
- ``fixed``: :func:`ssmobs.kernels.environment`.

The child times the call alone (CPU seconds of ``time.process_time``, imports and inputs
excluded): a design set (q = 8, K = 1000, the optimiser's defaults: the largest set of the
choice of K at T = 4) and the exact stage of (Same, d = p = 1), a = 0.9, x0 = 8, T = 20 on
1300 trajectories (the paper's K there).  Printed: the medians and
the ratio fixed/own of each pair.

Usage: ``python benchmarks/bench_kernels.py [--pairs 5]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

CHILD = """
import json, sys, time
import numpy as np
from ssmobs import kernels
stage = sys.argv[1]
if stage == "design":
    from ssmobs.design.disturbances import design_disturbances
    start = time.process_time()
    design_disturbances(8, 1000, "design", 1)
else:
    from ssmobs.exact.marginal import exact_marginal
    from ssmobs.models import get_model
    from ssmobs.config.scenario import Scenario
    from ssmobs.design.trajectories import make_trajectories
    sc = Scenario.from_config({"name": "same", "model": "same", "T": 20, "K": 1300, "x0": 8.0,
                               "omega": {"a": 0.9}})
    traj = make_trajectories(sc, np.random.default_rng(0).standard_normal((40, 1300)))
    bounds = traj.model.prior_bounds(traj.omega, None)
    start = time.process_time()
    exact_marginal(traj.model, traj.z, bounds)
seconds = time.process_time() - start
state = kernels.in_force()
print(json.dumps({"seconds": seconds, "blas": state["blas"][0]["kernel"],
                  "numpy": (state["numpy_dispatch"] or ["baseline"])[-1]}))
"""


def environments() -> dict[str, dict[str, str]]:
    from ssmobs import kernels

    own = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")}  # fmt: skip
    own.update(dict.fromkeys(kernels.THREAD_VARIABLES, "1"))
    return {"own": own, "fixed": {**os.environ, **kernels.environment()}}


def measure(stage: str, env: dict[str, str]) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CHILD, stage],
        env={**env, "PYTHONPATH": str(REPO / "workflow")},
        capture_output=True,
        text=True,
        check=True,
    )
    return dict(json.loads(out.stdout))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=5)
    args = parser.parse_args()
    envs = environments()
    for stage in ("design", "exact"):
        runs: dict[str, list[float]] = {"own": [], "fixed": []}
        seen = {}
        for _ in range(args.pairs):
            for name, env in envs.items():
                result = measure(stage, env)
                runs[name].append(result["seconds"])
                seen[name] = f"OpenBLAS {result['blas']}, NumPy up to {result['numpy']}"
        ratios = [f / o for f, o in zip(runs["fixed"], runs["own"])]
        print(
            f"{stage}: own ({seen['own']}) median {statistics.median(runs['own']):.2f} CPU-s "
            f"[{min(runs['own']):.2f}-{max(runs['own']):.2f}]; fixed ({seen['fixed']}) "
            f"median {statistics.median(runs['fixed']):.2f} "
            f"[{min(runs['fixed']):.2f}-{max(runs['fixed']):.2f}]; fixed/own per pair: "
            f"median {statistics.median(ratios):.3f} [{min(ratios):.3f}-{max(ratios):.3f}]"
        )


if __name__ == "__main__":
    main()
