#!/usr/bin/env python
"""Benchmark of the NUTS stage (issue 4): our overhead vs. the backend's sample call.

Part 1, overhead (one process, like one batch job): model ``same`` (a = 0.9, x0 = 8),
T = 20 and T = 100, the paper's settings (4 chains, 4 000 warmup + 6 000 kept draws), a
few trajectories through :func:`ssmobs.nuts.batch.run_trajectories` with the PyStan
backend.  Measured:

* per job: imports (``ssmobs.nuts.batch`` and its numerics; ``stan``/``httpstan``, which
  the backend imports at its first use) and the compile call (a cache hit);
* per trajectory: the wall time of the backend's ``sample`` call, and inside it the
  parent process's CPU time (httpstan's server: JSON transfer, gzip, parsing, conversion)
  vs. the chain workers' CPU time (``RUSAGE_CHILDREN``: Stan itself), i.e. the
  transfer/parsing share;
* our own overhead: data preparation, convergence diagnostics, KDE modes and quantiles
  (from the records' timings), and the rest of the loop (writing the record, progress);
  the ratio (everything but the sample call) / (sample call);
* the alternatives we did not take, on the last trajectory's draws: ArviZ's array layer
  (arviz-stats ``rhat``/``ess``/``bfmi``) vs. our vectorised diagnostics, and arviz-stats'
  ``kde`` per component vs. our batched FFT KDE.

Part 2, throughput on 2 cores (``--cores 2``): N trajectories of T = 100 with the paper's
settings, wall time from process start to finish (imports included), as

* A: two stage processes side by side, each with 1 chain worker (N/2 trajectories each);
* B: one stage process with 2 chain workers (N trajectories);
* C: two bare samplers side by side: processes that only call the backend's ``sample``
  (no diagnostics, KDE or records), 1 worker each (N/2 each) -- the ceiling A can reach.

Usage::

    python benchmarks/bench_nuts_stage.py            # full run (about 10 minutes here)
    python benchmarks/bench_nuts_stage.py --quick    # fewer trajectories, T = 20 only
    python benchmarks/bench_nuts_stage.py --no-write # print only

The Markdown is printed and written into the section ``## Stan stage (issue 4)`` of
BENCHMARKS.md (other sections are left untouched).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

T_PROC_START = time.perf_counter()
REPO = Path(__file__).resolve().parents[1]
SECTION = "## Stan stage (issue 4)"


# --------------------------------------------------------------------------- helpers
def _cpu_self() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


class TimedBackend:
    """Wraps a backend; records wall and CPU (parent vs. chain workers) of each sample call."""

    def __init__(self, inner):
        self.inner = inner
        self.name = inner.name
        self.calls: list[dict] = []
        self.last_draws = None

    def compile(self, stan_file):
        return self.inner.compile(stan_file)

    def sample(self, *args, **kwargs):
        c0, k0, t0 = _cpu_self(), _cpu_children(), time.perf_counter()
        draws = self.inner.sample(*args, **kwargs)
        self.calls.append(
            {
                "wall": time.perf_counter() - t0,
                "parent_cpu": _cpu_self() - c0,
                "children_cpu": _cpu_children() - k0,
                "backend": dict(draws.timings),
            }
        )
        self.last_draws = draws
        return draws


def _problem(T: int, n: int, seed: int = 1):
    import numpy as np
    from ssmobs.models import get_model

    model = get_model("same")
    rng = np.random.default_rng(seed)
    x, z = model.simulate(
        np.array([0.9]),
        np.array([8.0]),
        rng.standard_normal((n, T, 1)),
        rng.standard_normal((n, T, 1)),
    )
    return model, x, z


# --------------------------------------------------------------------------- workers
def worker_stage(
    T: int,
    n: int,
    workers: int,
    warmup: int,
    sampling: int,
    records: str,
    first_k: int = 0,
    alternatives: bool = False,
) -> dict:
    """One 'job': imports, compile, n trajectories through run_trajectories."""
    t0 = time.perf_counter()
    from ssmobs.nuts.batch import NutsBatch, run_trajectories
    from ssmobs.nuts.convergence import ConvergenceSettings
    from ssmobs.stan_backends import get_backend, stan_file
    from ssmobs.stan_backends.base import SamplerSettings

    t_import_ssmobs = time.perf_counter() - t0
    t0 = time.perf_counter()
    import stan  # noqa: F401 - what the backend imports at its first use

    t_import_stan = time.perf_counter() - t0

    model, x, z = _problem(T, first_k + n)
    backend = TimedBackend(get_backend("pystan"))
    t0 = time.perf_counter()
    backend.compile(stan_file("same"))
    t_compile = time.perf_counter() - t0
    sampler = SamplerSettings(chains=4, iter_warmup=warmup, iter_sampling=sampling, workers=workers)
    t0 = time.perf_counter()
    batch = NutsBatch(
        model,
        stan_file("same"),
        z,
        x,
        model.prior_bounds({"a": 0.9}),
        model.omega_array({"a": 0.9}),
        8.0,
        f"bench_T{T}",
        1,
        sampler,
        ConvergenceSettings(),
        "random",
    )
    recs = run_trajectories(batch, backend, list(range(first_k, first_k + n)), records)
    t_loop = time.perf_counter() - t0
    out = {
        "T": T,
        "n": n,
        "workers": workers,
        "import_ssmobs": t_import_ssmobs,
        "import_stan": t_import_stan,
        "compile": t_compile,
        "loop": t_loop,
        "calls": backend.calls,
        "timings": [r["timings"] for r in recs],
        "converged": [r["converged"] for r in recs],
        "wall_since_start": time.perf_counter() - T_PROC_START,
    }
    if alternatives and backend.last_draws is not None:
        out["alternatives"] = _alternatives(backend.last_draws, model, T)
    return out


def worker_bare(T: int, n: int, workers: int, warmup: int, sampling: int, first_k: int = 0) -> dict:
    """Only the backend's sample call, n times (no diagnostics, KDE or records)."""
    from ssmobs import seeds
    from ssmobs.stan_backends import get_backend, stan_file
    from ssmobs.stan_backends.base import SamplerSettings

    model, x, z = _problem(T, first_k + n)
    backend = get_backend("pystan")
    backend.compile(stan_file("same"))
    bounds = model.prior_bounds({"a": 0.9})
    sampler = SamplerSettings(chains=4, iter_warmup=warmup, iter_sampling=sampling, workers=workers)
    t0 = time.perf_counter()
    for k in range(first_k, first_k + n):
        backend.sample(
            stan_file("same"),
            model.stan_data(z[k], bounds),
            seeds.int_seed(1, "nuts", f"bench_T{T}", k),
            sampler,
        )
    return {
        "loop": time.perf_counter() - t0,
        "wall_since_start": time.perf_counter() - T_PROC_START,
    }


def _alternatives(draws, model, T: int) -> dict:
    """Time the roads not taken on real draws: ArviZ diagnostics and its KDE per component."""
    import warnings

    import numpy as np
    from ssmobs.nuts.convergence import ConvergenceSettings, check_convergence
    from ssmobs.nuts.marginal_map import marginal_summary, theta_draws

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        from arviz_stats.base import array_stats

        t_import_arviz = time.perf_counter() - t0
        res = {"import_arviz": t_import_arviz}

        def best_of(fn, repeats=3):
            """(smallest wall time of ``repeats`` calls, the last result)."""
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                out = fn()
                times.append(time.perf_counter() - t0)
            return min(times), out

        res["diag_vectorized"], ours = best_of(lambda: check_convergence(draws))
        res["diag_arviz"], ref = best_of(
            lambda: check_convergence(draws, ConvergenceSettings(implementation="arviz"))
        )
        res["diag_max_rel_diff"] = max(
            abs(ours[k] / ref[k] - 1) for k in ("max_rhat", "min_ess_bulk", "min_ess_tail")
        )
        res["kde_ours"], summ = best_of(lambda: marginal_summary(draws, model, T))
        th = theta_draws(draws, model, T)

        def arviz_modes():
            modes = []
            for row in th:
                g, d, _ = array_stats.kde(row)
                modes.append(g[np.argmax(d)])
            return modes

        res["kde_arviz"], modes = best_of(arviz_modes)
        sd = th.std(axis=1)
        res["kde_max_mode_diff_sd"] = float(np.max(np.abs(summ["map"] - np.array(modes)) / sd))
    return res


def _spawn(args: list[str]) -> subprocess.Popen:
    env = dict(os.environ)
    return subprocess.Popen(
        [sys.executable, __file__, *args], stdout=subprocess.PIPE, text=True, env=env, cwd=REPO
    )


def _collect(procs: list[subprocess.Popen]) -> list[dict]:
    outs = []
    for p in procs:
        stdout, _ = p.communicate()
        if p.returncode != 0:
            raise RuntimeError(f"worker failed with exit code {p.returncode}")
        outs.append(json.loads(stdout.strip().splitlines()[-1]))
    return outs


# --------------------------------------------------------------------------- report
def _fmt(v: float, nd: int = 2) -> str:
    return f"{v:.{nd}f}"


def overhead_table(res: dict) -> list[str]:
    calls, tims = res["calls"], res["timings"]
    n = len(calls)
    sample = sum(c["wall"] for c in calls)
    parent = sum(c["parent_cpu"] for c in calls)
    child = sum(c["children_cpu"] for c in calls)
    diag = sum(t["diagnostics"] for t in tims)
    marg = sum(t["marginal"] for t in tims)
    prep = sum(t["prepare"] for t in tims)
    recorded = sum(t["overhead"] for t in tims)
    ours_cpu = sum(t["overhead_cpu"] for t in tims)
    loop_rest = res["loop"] - sum(t["sample_call"] for t in tims) - recorded
    ours = res["loop"] - sum(t["sample_call"] for t in tims)
    per = lambda v: v / n
    alt = res.get("alternatives", {})
    lines = [
        f"| T = {res['T']} | {n} | {_fmt(per(sample))} | "
        f"{_fmt(per(parent))} / {_fmt(per(child))} ({100 * parent / (parent + child):.0f} %) | "
        f"{_fmt(per(prep), 4)} | {_fmt(per(diag), 3)} | {_fmt(per(marg), 3)} | "
        f"{_fmt(per(loop_rest), 3)} | {_fmt(per(ours), 3)} ({_fmt(per(ours_cpu), 3)}) | "
        f"**{100 * ours / sample:.1f} %** ({100 * ours_cpu / sample:.1f} %) | "
        f"{_fmt(alt.get('diag_arviz', float('nan')), 3)} / "
        f"{_fmt(alt.get('diag_vectorized', float('nan')), 3)} | "
        f"{_fmt(alt.get('kde_arviz', float('nan')), 3)} / {_fmt(alt.get('kde_ours', float('nan')), 3)} |"
    ]
    return lines


def render(over: list[dict], thr: dict | None, args, started: str, load: tuple) -> str:
    from machine import cpu_model

    cpu = cpu_model()
    import numpy

    import stan

    out = [
        SECTION,
        "",
        f"Machine: {platform.node() or 'VM'}, {os.cpu_count()} vCPUs ({cpu}), "
        f"{platform.python_implementation()} {platform.python_version()}, numpy "
        f"{numpy.__version__}, pystan {stan.__version__}. Date: {started} (UTC). "
        f"Load average at start / end: {load[0]:.1f} / {load[1]:.1f} (other work was "
        f"running on this 2-vCPU machine, so absolute times are noisy; the ratios below "
        f"come from the same run).",
        "",
        f"Command: `python benchmarks/bench_nuts_stage.py{' --quick' if args.quick else ''}`",
        "",
        f"### Our overhead vs. the backend's sample call (model same, a = 0.9, x0 = 8, "
        f"4 chains x ({args.warmup} + {args.sampling}), 1 chain worker, one process)",
        "",
        "Seconds per trajectory. *parent / workers CPU*: CPU time of this process during "
        "the sample call (httpstan: JSON transfer, gzip, parsing, conversion) vs. of the "
        "chain worker processes (Stan); the percentage is the transfer/parsing share. "
        "*rest*: writing the record, logging, progress. *ours*: everything in the loop "
        "but the sample call, wall time (in brackets: CPU time of our per-trajectory "
        "code, which other load on the machine does not inflate). Last two columns, on the last trajectory's draws (best of 3 "
        "calls each): ArviZ (arviz-stats' array layer: `rhat`/`ess`/`bfmi`) vs. our "
        "vectorised diagnostics, and arviz-stats' `kde` per component vs. our batched FFT KDE "
        "(incl. quantiles and the copy of the draws).",
        "",
        "| case | n | sample call | parent / workers CPU | prepare | diagnostics | "
        "KDE + quantiles | rest | ours | ours / sample | diag ArviZ / ours | "
        "KDE ArviZ / ours |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in over:
        out += overhead_table(r)
    out.append("")
    r0 = over[0]
    out.append(
        f"Once per job (a process): importing `ssmobs.nuts.batch` and the backend module "
        f"(numpy, scipy) {_fmt(r0['import_ssmobs'])} s, `import stan` "
        f"{_fmt(r0['import_stan'])} s, compile call (cache hit) {_fmt(r0['compile'])} s; "
        f"ArviZ is imported only to keep draws ({_fmt(r0['alternatives']['import_arviz'])} s"
        f" when it is).  Agreement on these draws: diagnostics max relative difference "
        f"{r0['alternatives']['diag_max_rel_diff']:.1e}; KDE modes differ by at most "
        f"{r0['alternatives']['kde_max_mode_diff_sd']:.3f} posterior sd (different "
        f"bandwidths: Silverman vs. ArviZ's default)."
    )
    for r in over:
        conv = sum(r["converged"])
        out.append(f"T = {r['T']}: {conv}/{len(r['converged'])} converged.")
    out.append("")
    if thr:
        n = thr["n"]
        out += [
            f"### Throughput on 2 cores: {n} trajectories, T = {thr['T']}, 4 x "
            f"({args.warmup} + {args.sampling}), wall time incl. process start and "
            f"imports",
            "",
            "| layout | wall per round (s) | trajectories / min | throughput vs. B |",
            "|---|---|---|---|",
        ]
        # the fastest round: other load on the machine only ever adds time
        med = {k: min(thr[k]) for k in ("A", "B", "C")}
        for key, label in (
            ("A", "A: 2 stage processes x 1 worker"),
            ("B", "B: 1 stage process x 2 workers"),
            ("C", "C: 2 bare samplers x 1 worker (no stage work)"),
        ):
            runs = ", ".join(_fmt(w, 1) for w in thr[key])
            out.append(
                f"| {label} | {runs} | {60 * n / med[key]:.2f} | {med['B'] / med[key]:.2f}x |"
            )
        out += [
            "",
            f"Wall times of {len(thr['A'])} rounds (layouts run in turn); trajectories "
            f"per minute and the ratios use each layout's fastest round (other "
            f"work on the machine only adds time). A vs. C (the stage's "
            f"cost under contention, incl. one more import of ssmobs per process): "
            f"{100 * (med['A'] / med['C'] - 1):+.1f} % wall time.",
            "",
        ]
        best = "A" if med["A"] < med["B"] else "B"
        over_pct = [
            100 * sum(t["overhead"] for t in r["timings"]) / sum(c["wall"] for c in r["calls"])
            for r in over
        ]
        share = [
            100
            * sum(c["parent_cpu"] for c in r["calls"])
            / sum(c["parent_cpu"] + c["children_cpu"] for c in r["calls"])
            for r in over
        ]
        out += [
            "**Reading.** Our per-trajectory work costs "
            + " and ".join(f"{p:.1f} % (T = {r['T']})" for p, r in zip(over_pct, over))
            + " of the backend's sample call (target: at most 10 %). Inside the sample "
            "call, PyStan's own transfer and parsing in the parent process take "
            + " and ".join(f"{p:.0f} %" for p in share)
            + " of its CPU time (Stan's chains: the rest). "
            + (
                "On 2 cores, two jobs with 1 chain worker each (`threads: 1`, two "
                "Snakemake jobs at once) give the most trajectories per minute: they run "
                "two of PyStan's serial parent processes side by side, whereas one job "
                "with 2 workers leaves its parent the bottleneck."
                if best == "A"
                else "On 2 cores, one job with 2 chain workers gave the most trajectories "
                "per minute in this run."
            ),
            "",
        ]
    return "\n".join(out) + "\n"


def write_section(path: Path, text: str) -> None:
    old = path.read_text() if path.exists() else "# Benchmarks\n"
    pattern = re.compile(rf"^{re.escape(SECTION)}\n.*?(?=^## |\Z)", re.S | re.M)
    if pattern.search(old):
        new = pattern.sub(lambda _: text, old)
    else:
        new = old.rstrip("\n") + "\n\n" + text
    from ssmobs import io

    io.write_text(path, new)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--output", type=Path, default=REPO / "BENCHMARKS.md")
    ap.add_argument("--warmup", type=int, default=4000)
    ap.add_argument("--sampling", type=int, default=6000)
    ap.add_argument("--n", type=int, default=3, help="trajectories per overhead case")
    ap.add_argument("--n-throughput", type=int, default=4)
    ap.add_argument("--throughput-T", type=int, default=100)
    ap.add_argument("--worker", choices=["stage", "bare"], help=argparse.SUPPRESS)
    ap.add_argument("--T", type=int, default=20, help=argparse.SUPPRESS)
    ap.add_argument("--workers", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--first-k", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--records", default="", help=argparse.SUPPRESS)
    ap.add_argument("--alternatives", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument(
        "--repeats",
        type=int,
        default=2,
        help="rounds of the throughput layouts (run in turn A, B, C, A, B, C, ...)",
    )
    args = ap.parse_args()

    if args.worker == "stage":
        print(
            json.dumps(
                worker_stage(
                    args.T,
                    args.n,
                    args.workers,
                    args.warmup,
                    args.sampling,
                    args.records,
                    args.first_k,
                    args.alternatives,
                )
            )
        )
        return
    if args.worker == "bare":
        print(
            json.dumps(
                worker_bare(args.T, args.n, args.workers, args.warmup, args.sampling, args.first_k)
            )
        )
        return

    started = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M")
    load0 = os.getloadavg()[0]
    common = ["--warmup", str(args.warmup), "--sampling", str(args.sampling)]
    Ts = [20] if args.quick else [20, 100]
    n = 2 if args.quick else args.n
    with tempfile.TemporaryDirectory(prefix="bench-nuts-") as tmp:
        over = []
        for T in Ts:
            print(f"overhead: T = {T}, {n} trajectories ...", file=sys.stderr)
            over += _collect(
                [
                    _spawn(
                        [
                            "--worker",
                            "stage",
                            "--T",
                            str(T),
                            "--n",
                            str(n),
                            "--records",
                            f"{tmp}/over{T}",
                            "--alternatives",
                            *common,
                        ]
                    )
                ]
            )
        thr = None
        if not args.quick:
            T, N = args.throughput_T, args.n_throughput
            half = N // 2
            thr = {"T": T, "n": N, "A": [], "B": [], "C": []}
            layouts = {
                "A": lambda r: [
                    _spawn(
                        [
                            "--worker",
                            "stage",
                            "--T",
                            str(T),
                            "--n",
                            str(half),
                            "--first-k",
                            str(i * half),
                            "--records",
                            f"{tmp}/A{r}",
                            *common,
                        ]
                    )
                    for i in range(2)
                ],
                "B": lambda r: [
                    _spawn(
                        [
                            "--worker",
                            "stage",
                            "--T",
                            str(T),
                            "--n",
                            str(N),
                            "--workers",
                            "2",
                            "--records",
                            f"{tmp}/B{r}",
                            *common,
                        ]
                    )
                ],
                "C": lambda r: [
                    _spawn(
                        [
                            "--worker",
                            "bare",
                            "--T",
                            str(T),
                            "--n",
                            str(half),
                            "--first-k",
                            str(i * half),
                            *common,
                        ]
                    )
                    for i in range(2)
                ],
            }
            for r in range(args.repeats):
                for key, procs in layouts.items():
                    print(f"throughput {key}, round {r + 1} ...", file=sys.stderr)
                    t0 = time.perf_counter()
                    _collect(procs(r))
                    thr[key].append(time.perf_counter() - t0)
    load1 = os.getloadavg()[0]
    text = render(over, thr, args, started, (load0, load1))
    print(text)
    if not args.no_write:
        write_section(args.output, text)
        print(f"wrote {SECTION!r} to {args.output}", file=sys.stderr)


if __name__ == "__main__":
    main()
