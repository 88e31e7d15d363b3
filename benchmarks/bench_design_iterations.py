"""LCD design sets: can another optimiser setting reach the distance in fewer iterations? (issue 48)

Issue 48 names three ways to fewer L-BFGS iterations of a design set: a better optimiser,
warm starts across K in the nested set variant, or both.  Each variant below runs the
optimisation of `ssmobs.design.disturbances` (SciPy's L-BFGS-B, its gradient test, the
toolbox's relative objective test 1e-6 per iteration, the covariance correction after it)
on the same random start as the workflow, in this process, with the workflow's fixed
kernels:

* ``plain``: the workflow's settings (memory 10); the script checks that it reproduces
  ``design_disturbances`` (iterations and distance to the bit), so it measures the same thing;
* ``memory=M``: L-BFGS memory M instead of 10;
* ``scaled=P``: L-BFGS on per-point scaled unknowns s_i = d_i y_i, d_i = M(|s_i|^2)^-P of the
  start (M: the Gaussian attraction's weight, doc Section 4), normalised to geometric mean 1:
  a diagonal preconditioner for points whose curvature differs in the tails;
* ``rel_tol=R``: the relative objective test R instead of 1e-6 (a looser stop);
* ``warm``: the nested variant's K grid in order, each set started from the optimised set of
  the previous K plus the next rows of its own start (the seed's stream), instead of the
  fresh start of every K.

Prints one JSON line per set (iterations, evaluations, CPU seconds, the distance after the
covariance correction) and a summary per variant.

    python benchmarks/bench_design_iterations.py [--q 8] [--K 1000] [--seeds 1,2,3]
        [--variants plain,memory=20,memory=40,scaled=0.25,scaled=0.5] [--warm-grid 100:1000:100]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))
sys.path.insert(0, str(REPO / "benchmarks"))


def optimise(
    s0: Any, K: int, b_max: float, *, memory: int, scale: Any, rel_tol: float
) -> tuple[Any, float, int, int]:
    """The workflow's optimisation (`disturbances._optimise_half`'s settings) on s = scale * y;
    returns (half-set, raw distance, iterations, evaluations).  It returns SciPy's last point
    where the workflow keeps the best point seen; the ``plain`` check shows they agree."""
    import numpy as np
    from scipy import optimize
    from ssmobs.design.disturbances import GRAD_TOL, MAX_ITER
    from ssmobs.design.lcd_distance import symmetric_distance

    shape = s0.shape
    state = {"it": 0, "nfev": 0, "f_prev": math.inf}

    def fun(y: Any) -> tuple[float, Any]:
        state["nfev"] += 1
        f, g = symmetric_distance(y.reshape(shape) * scale, K, b_max, gradient=True)
        return f, (g * scale).ravel()

    def callback(intermediate_result: optimize.OptimizeResult) -> None:
        state["it"] += 1
        f = float(intermediate_result.fun)
        if abs(state["f_prev"] - f) <= rel_tol * abs(f):
            raise StopIteration
        state["f_prev"] = f

    options = {"maxcor": memory, "gtol": GRAD_TOL / K, "ftol": 1e-15, "maxiter": MAX_ITER}
    options.update(maxfun=10 * MAX_ITER + 100, maxls=40)
    res = optimize.minimize(
        fun, (s0 / scale).ravel(), jac=True, method="L-BFGS-B", callback=callback, options=options
    )
    half = np.asarray(res.x).reshape(shape) * scale
    return half, float(res.fun), state["it"], state["nfev"]


def corrected_distance(half: Any, K: int, b_max: float) -> float:
    """The distance after the workflow's covariance correction."""
    from ssmobs.design.disturbances import _covariance_correct
    from ssmobs.design.lcd_distance import symmetric_distance

    return float(symmetric_distance(_covariance_correct(half, K)[0], K, b_max, gradient=False)[0])


def point_scale(s0: Any, q: int, b_max: float, power: float) -> Any:
    """d_i = M(|s_i|^2)^-power of the start, geometric mean 1, as a column."""
    import numpy as np
    from ssmobs.design.lcd_distance import N_NODES, _quadrature

    _, m = _quadrature(q, b_max, N_NODES).j_prime_and_m(np.einsum("ij,ij->i", s0, s0))
    d = m ** (-power)
    return (d / np.exp(np.mean(np.log(d))))[:, None]


def timed(
    s0: Any, K: int, b_max: float, memory: int, scale: Any, rel_tol: float
) -> tuple[Any, int, int, float]:
    """:func:`optimise` and its CPU seconds: (half-set, iterations, evaluations, CPU s)."""
    t0 = time.process_time()
    half, _, iterations, evaluations = optimise(
        s0, K, b_max, memory=memory, scale=scale, rel_tol=rel_tol
    )
    return half, iterations, evaluations, time.process_time() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--q", type=int, default=8)
    parser.add_argument("--K", type=int, default=1000)
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--variants", default="plain,memory=20,memory=40,scaled=0.25,scaled=0.5")
    parser.add_argument("--warm-grid", default="100:1000:100", help="first:last:step, or none")
    args = parser.parse_args()

    from ssmobs import kernels

    kernels.restart_with_fixed_kernels()  # the workflow's kernels, as its jobs run
    import numpy as np
    from machine import machine_info
    from ssmobs.design.disturbances import REL_TOL, design_disturbances
    from ssmobs.design.lcd_distance import b_max_rule

    print(json.dumps({"machine": machine_info()}), flush=True)
    q, b_max = args.q, b_max_rule(args.q)
    seeds = [int(s) for s in args.seeds.split(",")]
    rows: list[dict[str, Any]] = []

    def record(row: dict[str, Any]) -> None:
        rows.append(row)
        print(json.dumps(row), flush=True)

    for seed in seeds:
        s0 = np.random.default_rng(seed).standard_normal((args.K // 2, q))
        for variant in args.variants.split(","):
            name, _, value = variant.partition("=")
            memory = int(value) if name == "memory" else 10
            scale = point_scale(s0, q, b_max, float(value)) if name == "scaled" else 1.0
            rel_tol = float(value) if name == "rel_tol" else REL_TOL
            half, it, nfev, cpu = timed(s0, args.K, b_max, memory, scale, rel_tol)
            d = corrected_distance(half, args.K, b_max)
            if name == "plain":  # the same optimisation as the workflow's
                ref = design_disturbances(q, args.K, "design", seed)
                assert (ref.iterations, ref.distance) == (it, d), "not the workflow's optimisation"
            record({"variant": variant, "q": q, "K": args.K, "seed": seed, "iterations": it,
                    "evaluations": nfev, "cpu_s": round(cpu, 3), "distance": d})  # fmt: skip

    if args.warm_grid != "none":
        first, last, step = (int(x) for x in args.warm_grid.split(":"))
        for seed in seeds:
            previous = None  # the warm chain's optimised set of the previous K
            for K in range(first, last + 1, step):
                s0 = np.random.default_rng(seed).standard_normal((K // 2, q))
                starts = {"cold": s0}
                if previous is not None:
                    starts["warm"] = np.concatenate([previous, s0[previous.shape[0] :]])
                for variant, start in starts.items():
                    half, it, nfev, cpu = timed(start, K, b_max, 10, 1.0, REL_TOL)
                    row = {"variant": f"nested {variant}", "q": q, "K": K, "seed": seed,
                           "iterations": it, "evaluations": nfev, "cpu_s": round(cpu, 3),
                           "distance": corrected_distance(half, K, b_max)}  # fmt: skip
                    record(row)
                    if previous is None:  # the first K starts cold in both chains
                        record({**row, "variant": "nested warm"})
                    if variant == "warm" or previous is None:
                        chain = half
                previous = chain

    print("\nvariant                 sets  iterations  evaluations   CPU s   mean distance")
    for variant in dict.fromkeys(r["variant"] for r in rows):
        sel = [r for r in rows if r["variant"] == variant]
        print(
            f"{variant:22s} {len(sel):5d} {sum(r['iterations'] for r in sel):11d} "
            f"{sum(r['evaluations'] for r in sel):12d} {sum(r['cpu_s'] for r in sel):7.2f} "
            f"  {np.mean([r['distance'] for r in sel]):.6e}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
