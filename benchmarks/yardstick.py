"""This machine's speed now, by a fixed NumPy workload that none of our code touches.

These machines' speed varies by 20-40 % from hour to hour (BENCHMARKS.md, Newcomer), so a
whole-run time alone cannot tell a change of the code from a change of the machine.
`benchmarks/newcomer.sh` runs this before `make run` and after `make test`.  It follows
the run only sometimes (BENCHMARKS.md, 2026-12-06: 0.257 CPU-s beside the slowest of four
runs and 0.366 beside the fastest; later 0.468 and 0.326 beside a slow and a fast run of
the same code): it runs alone on one core with the machine's own kernels, the run on both
cores with the workflow's.  Record it; do not divide by it.

The workload (issue 48's yardstick): 40 evaluations of sum_ij exp(-|x_i - x_j|^2 / 2) over
the 1000 x 1000 pairs of 1000 fixed points in 8 dimensions, one OpenBLAS thread.  Prints
one line: the fastest of ``--repeat`` runs in CPU seconds, and the median.

    python benchmarks/yardstick.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

# one thread, whatever the caller's environment: the yardstick measures one core
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ["OMP_NUM_THREADS"] = "1"

import numpy as np  # noqa: E402  (after the thread count)

#: evaluations of the pair sum in one run
EVALUATIONS = 40
#: points and their dimension
N_POINTS, DIM = 1000, 8


def pair_sum(x: np.ndarray) -> float:
    """sum_ij exp(-|x_i - x_j|^2 / 2) by the Gram matrix."""
    n = np.einsum("ij,ij->i", x, x)
    d2 = n[:, None] + n[None, :] - 2.0 * (x @ x.T)
    return float(np.exp(-0.5 * np.maximum(d2, 0.0)).sum())


def one_run(x: np.ndarray) -> float:
    """CPU seconds of :data:`EVALUATIONS` evaluations."""
    t0 = time.process_time()
    for _ in range(EVALUATIONS):
        pair_sum(x)
    return time.process_time() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    if args.repeat < 1:
        parser.error(f"--repeat must be >= 1; got {args.repeat}")
    x = np.random.default_rng(48).standard_normal((N_POINTS, DIM))
    one_run(x)  # warm-up: page faults and the first BLAS call
    times = [one_run(x) for _ in range(args.repeat)]
    print(
        f"yardstick: fastest {min(times):.3f} CPU-s, median {statistics.median(times):.3f} "
        f"CPU-s over {args.repeat} runs ({EVALUATIONS} pair sums, {N_POINTS} points, q = {DIM})"
    )


if __name__ == "__main__":
    main()
