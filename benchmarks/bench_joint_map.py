#!/usr/bin/env python
"""Benchmark of the joint-MAP stage (issue 3): batched barrier-Newton vs. SciPy per trajectory.

Main case (the issue's target): (Same, d=p=1), (a, x0) = (0.9, 8), T = 50.  All K trajectories
are optimised by ``ssmobs.joint_map.driver.joint_map`` in this process (vectorised across k, with the
numerical checks of Sec. III.B: Lanczos eigenvalue ratio, local variances, ridge
re-optimisations), and in the same run the first ``--scipy-K`` of the same trajectories are
optimised one at a time by ``scipy.optimize.minimize`` from the same start, with the same
analytic derivatives and the prior bounds:

* ``L-BFGS-B`` (bounds moved 1e-8 inside the open prior support, since L-BFGS-B evaluates
  on the closed box and -2 pi is singular at a = 1; analytic gradient; gtol 1e-7,
  ftol 1e-15), the cheapest bounded SciPy method;
* ``trust-exact`` (analytic gradient and dense Hessian, gtol 1e-8; no bounds argument, the
  objective is +inf outside the prior support), the SciPy analogue of our Newton iteration;
* ``trust-constr`` (bounds -> SciPy's interior-point/barrier method, analytic gradient and
  dense Hessian, gtol 1e-8), the SciPy analogue of the paper's primal barrier method.


SciPy times are for the optimisation alone (no eigenvalues, no local variances), so the
ratio flatters SciPy.  A second table times every model at its paper-like T (K = --K-models).

Trajectories come from random N(0, I) disturbances (the optimiser's cost does not depend on
whether they are design points).  BLAS runs with one thread (as in the design benchmark):
multi-threaded OpenBLAS slows small LAPACK calls (SciPy's dense Hessian work) by 10x or more
when the two cores are shared.

Usage::

    python benchmarks/bench_joint_map.py              # full run, writes BENCHMARKS.md
    python benchmarks/bench_joint_map.py --quick      # smaller K, no model table
    python benchmarks/bench_joint_map.py --no-write   # print only

The section ``## Joint MAP (issue 3)`` of BENCHMARKS.md is replaced (or appended); other
sections are left untouched.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import os
import re
import sys
import time
from pathlib import Path

import numpy as np
from machine import machine_info

REPO = Path(__file__).resolve().parents[1]
SECTION = "## Joint MAP (issue 3)"

#: (label, slug, omega, x0, T, prior) for the per-model table
MODEL_CASES = [
    ("Same T=20", "same", [0.9], [8.0], 20, None),
    ("Same T=50", "same", [0.9], [8.0], 50, None),
    ("Same (0.7) T=100", "same", [0.7], [8.0], 100, None),
    ("Sep T=75", "sep", [0.9, 0.9], [8.0], 75, None),
    ("Sep d=2 p=1 T=50", "sep_d2_p1", [0.9, 0.9, 0.9], [8.0], 50, None),
    ("Sep d=1 p=2 T=50", "sep_d1_p2", [0.6, 0.5, 0.9, 0.9], [8.0, 8.0], 50, None),
    ("ranWalk T=4", "sep_ranwalk", [0.9], [8.0], 4, None),
    ("ranWalk T=100", "sep_ranwalk", [0.9], [8.0], 100, None),
    ("Mult T=50", "sep_mult", [0.9], [8.0], 50, None),
]


def blas_one_thread():
    """One OpenBLAS thread if the helper is available, else a no-op."""
    try:
        from ssmobs.openblas_threads import openblas_threads
    except Exception:  # pragma: no cover - optional
        return contextlib.nullcontext()
    return openblas_threads(1)


def trajectories(slug, omega, x0, T, K, seed=0):
    from ssmobs.models import get_model

    model = get_model(slug)
    rng = np.random.default_rng(seed)
    matrix = rng.standard_normal(((model.obs_dim + model.state_dim) * T, K))
    x, z = model.design_trajectories(omega, x0, matrix, T)
    return model, z


def time_ours(model, z, omega, x0, repeat=1):
    from ssmobs.joint_map.driver import joint_map
    from ssmobs.joint_map.problem import JointMapProblem

    bounds = model.prior_bounds(omega)
    joint_map(
        JointMapProblem(model, z[:4], bounds, omega, x0)
    )  # compile the symbolic derivatives once
    best, res = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = joint_map(JointMapProblem(model, z, bounds, omega, x0))
        best = min(best, time.perf_counter() - t0)
    return best, res


def time_scipy(model, z, omega, x0, method):
    from scipy.optimize import Bounds, minimize
    from ssmobs.joint_map.driver import initial_theta
    from ssmobs.models.log_posterior import neg2_log_posterior

    bounds = model.prior_bounds(omega)
    theta0 = initial_theta(model, z, np.asarray(omega, float), np.asarray(x0, float))
    n, m = theta0.shape[1], model.n_params
    lb, ub = np.full(n, -np.inf), np.full(n, np.inf)
    lb[:m], ub[:m] = bounds.lower, bounds.upper
    out = np.empty_like(theta0)
    t0 = time.perf_counter()
    for k in range(z.shape[0]):
        zk = z[k]

        def fun(t):
            v, g = neg2_log_posterior(model, t, zk, None, 1)
            return v, g

        def hess(t):
            return neg2_log_posterior(model, t, zk, None, 2)[2]

        if method == "L-BFGS-B":  # closed box: keep 1e-8 off the prior's open bounds
            r = minimize(
                fun,
                theta0[k],
                jac=True,
                method="L-BFGS-B",
                bounds=Bounds(lb + 1e-8 * (1 + np.abs(lb)), ub - 1e-8 * (1 + np.abs(ub))),
                options={"maxiter": 20000, "maxfun": 50000, "gtol": 1e-7, "ftol": 1e-15},
            )
        elif method == "trust-exact":

            def fun_b(t):
                v, g = neg2_log_posterior(model, t, zk, bounds, 1)
                return v, g

            with np.errstate(all="ignore"):
                r = minimize(
                    fun_b,
                    theta0[k],
                    jac=True,
                    hess=hess,
                    method="trust-exact",
                    options={"maxiter": 500, "gtol": 1e-8},
                )
        else:
            with np.errstate(all="ignore"):
                r = minimize(
                    fun,
                    theta0[k],
                    jac=True,
                    hess=hess,
                    method="trust-constr",
                    bounds=Bounds(lb, ub),
                    options={"maxiter": 3000, "gtol": 1e-8, "xtol": 1e-12},
                )
        out[k] = r.x
    return time.perf_counter() - t0, out


def load_avg() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:  # pragma: no cover
        return float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--T", type=int, default=50)
    ap.add_argument("--K", type=int, default=2000, help="trajectories for ssmobs.joint_map.driver")
    ap.add_argument("--scipy-K", type=int, default=40, help="trajectories per SciPy method")
    ap.add_argument("--K-models", type=int, default=300, help="K per model in the model table")
    ap.add_argument("--repeat", type=int, default=3, help="best of this many runs (ours)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--output", type=Path, default=REPO / "BENCHMARKS.md")
    args = ap.parse_args(argv)
    if args.quick:
        args.K, args.scipy_K, args.repeat = 300, 10, 1

    from ssmobs.models.log_posterior import neg2_log_posterior

    command = "python benchmarks/bench_joint_map.py" + (
        " " + " ".join(argv or sys.argv[1:]) if (argv or sys.argv[1:]) else ""
    )
    load0 = load_avg()
    t_start = time.perf_counter()
    lines = []
    with blas_one_thread():
        omega, x0, T = [0.9], [8.0], args.T
        model, z = trajectories("same", omega, x0, T, args.K)
        t_ours, res = time_ours(model, z, omega, x0, args.repeat)
        per_ours = t_ours / args.K
        status, counts = np.unique(res.status, return_counts=True)
        print(
            f"ours: K={args.K} T={T}: {t_ours:.2f} s, {1e3 * per_ours:.3f} ms/trajectory, "
            f"status {dict(zip(status.tolist(), counts.tolist()))}",
            flush=True,
        )
        rows = [
            (
                "ssmobs.joint_map.driver (batched barrier-Newton + all checks)",
                args.K,
                t_ours,
                per_ours,
                1.0,
                "-",
                "-",
            )
        ]
        zs = z[: args.scipy_K]
        for method in ("L-BFGS-B", "trust-exact", "trust-constr"):
            t_sp, x_sp = time_scipy(model, zs, omega, x0, method)
            per_sp = t_sp / args.scipy_K
            dist = np.abs(x_sp - res.theta_hat[: args.scipy_K]).max(axis=1)
            g = neg2_log_posterior(model, x_sp, zs, None, 1)[1]
            grad_ok = np.abs(g).max(axis=1) < 1e-5
            print(
                f"scipy {method}: K={args.scipy_K}: {t_sp:.2f} s, {1e3 * per_sp:.2f} "
                f"ms/trajectory, ratio {per_sp / per_ours:.1f}",
                flush=True,
            )
            rows.append(
                (
                    f"scipy.optimize.minimize {method}, one call per trajectory",
                    args.scipy_K,
                    t_sp,
                    per_sp,
                    per_sp / per_ours,
                    f"{np.mean(dist < 1e-4):.2f} (median {np.median(dist):.1e})",
                    f"{grad_ok.mean():.2f}",
                )
            )
        lines.append(
            "| optimiser | K timed | wall [s] | ms / trajectory | SciPy / ours "
            "| share within 1e-4 of ours (sup norm) | share with max abs(grad) < 1e-5 |"
        )
        lines.append("|---|---:|---:|---:|---:|---|---:|")
        for r in rows:
            lines.append(
                f"| {r[0]} | {r[1]} | {r[2]:.2f} | {1e3 * r[3]:.3f} | "
                f"{r[4]:.1f} | {r[5]} | {r[6]} |"
            )
        main_table = "\n".join(lines)

        model_lines = []
        if not args.quick:
            model_lines.append(
                "| case | n = abs(Theta) | K | wall [s] | ms / trajectory "
                "| mean Newton iterations | status counts |"
            )
            model_lines.append("|---|---:|---:|---:|---:|---:|---|")
            for label, slug, om, x0m, Tm, _prior in MODEL_CASES:
                mdl, zm = trajectories(slug, om, x0m, Tm, args.K_models, seed=1)
                t_m, r_m = time_ours(mdl, zm, om, x0m, 1)
                st, ct = np.unique(r_m.status, return_counts=True)
                counts_txt = ", ".join(f"{s} {c}" for s, c in zip(st, ct))
                print(
                    f"{label}: {t_m:.2f} s, {1e3 * t_m / args.K_models:.2f} ms/traj, {counts_txt}",
                    flush=True,
                )
                model_lines.append(
                    f"| {label} | {mdl.n_theta(Tm)} | {args.K_models} | {t_m:.2f} | "
                    f"{1e3 * t_m / args.K_models:.2f} | {r_m.iterations.mean():.1f} | "
                    f"{counts_txt} |"
                )
    total = time.perf_counter() - t_start
    load1 = load_avg()
    text = section_text(
        main_table,
        "\n".join(model_lines),
        command,
        total,
        f"{load0:.2f} / {load1:.2f} on {os.cpu_count()} CPUs",
        T,
        per_ours,
        rows,
    )
    print(text)
    if not args.no_write:
        write_section(args.output, text)
        print(f"wrote {args.output}")
    return 0


def section_text(main_table, model_table, command, total, load, T, per_ours, rows) -> str:
    ratios = ", ".join(f"{r[0].split(' ')[1].rstrip(',')} {r[4]:.0f}x" for r in rows[1:])
    out = (
        f"{SECTION}\n\n"
        f"`ssmobs.joint_map.driver.joint_map`: primal log-barrier method (Nocedal & Wright Sec. 19.6) "
        f"with Newton steps on the analytic Hessian, vectorised across k; each Newton system is "
        f"solved through the arrow structure of the Hessian (block-tridiagonal states + m dense "
        f"rows/columns: block Cholesky + m x m Schur complement, O(n) per trajectory); the "
        f"checks use Lanczos on H and H^-1 for the eigenvalue ratio and a selected inversion for "
        f"the local variances (no dense n x n matrix anywhere).\n\n"
        f"- Date: {_dt.date.today().isoformat()}\n"
        f"- Machine: {machine_info()}\n"
        f"- Command: `{command}` (total {total:.0f} s)\n"
        f"- System load (1-min load average at start / end): {load}; a load above the CPU "
        f"count means other jobs shared the cores, so all times are pessimistic (ours and "
        f"SciPy's alike, measured in the same run).\n"
        f"- Threads: one OpenBLAS thread for the whole run.\n"
        f"- Case: (Same, d=p=1), (a, x0) = (0.9, 8), T = {T}, random N(0, I) disturbances; "
        f"ours = best of the repeats for all K in one call (incl. the checks and ridge "
        f"re-optimisations); SciPy: the first trajectories, same start (Omega_true, x0_true, z), "
        f"same analytic derivatives, prior bounds, optimisation only.\n"
        f"- Targets (issue 3): < 5 ms per trajectory at T = 50: **{1e3 * per_ours:.2f} ms**; "
        f">= 10x faster than SciPy per trajectory: **{ratios}**.\n\n"
        f"{main_table}\n"
        f"\nReading the SciPy rows: L-BFGS-B and trust-exact reach our optimum (accuracy "
        f"columns), so their ratios are the like-for-like speed-ups; L-BFGS-B stops on its "
        f"relative-decrease rule with max abs(grad) often just above 1e-5.  trust-constr "
        f"(SciPy's barrier method) does not converge from this start within 3000 iterations "
        f"(it ends about 1 away in sup norm), so its time is that of a failed run and its "
        f"ratio is not comparable.\n"
    )
    if model_table:
        out += (
            f"\nAll models at paper-like T (same code, K trajectories in one call, "
            f"random disturbances, seed 1):\n\n{model_table}\n\n"
            f"Trajectories that end at the boundary or keep climbing a ridge run up to "
            f"`max_newton_iter` (200) iterations, which dominates the cost of (Sep, d=1, "
            f"p=2) and ranWalk; p = 2 is also slower per iteration (2 x 2 blocks).\n"
        )
    return out


def write_section(path: Path, text: str) -> None:
    """Replace (or append) this benchmark's section, leaving the rest of the file unchanged."""
    old = path.read_text() if path.exists() else "# Benchmarks\n"
    if not old.lstrip().startswith("# Benchmarks"):
        old = "# Benchmarks\n\n" + old
    pattern = re.compile(rf"^{re.escape(SECTION)}\n.*?(?=^## |\Z)", re.S | re.M)
    if pattern.search(old):
        new = pattern.sub(lambda _m: text.rstrip("\n") + "\n\n", old, count=1)
    else:
        new = old.rstrip("\n") + "\n\n" + text
    path.write_text(new.rstrip("\n") + "\n")


if __name__ == "__main__":
    sys.exit(main())
