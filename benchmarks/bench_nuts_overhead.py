"""Stan's per-step machinery before and after a change of ours: the same NUTS runs with the
programs and driver of a base revision and of this checkout (issue 49, item 4).

For each case of :mod:`bench_analytic_gradients` (one trajectory, the paper's 4 chains x
(4000 + 6000) unless ``--chains``/``--warmup``/``--samples`` say otherwise, one chain at a
time) the four executables -- autodiff and analytic, base and here -- run ``--reps`` times
each on the same data and Stan seed, interleaved (the order reversed in every other rep),
each in the environment its revision's backend gives the driver.  Reported per executable:
CPU seconds (the driver's rusage) as median and minimum (this VM's neighbours add up to
+50 % to single runs, the minimum is the least disturbed run), the speed-up of here over
base, the ratio autodiff / analytic within each revision, and whether base and here wrote
the same draws file, byte for byte.  Appends a section to BENCHMARKS.md unless
``--no-write``.

    python benchmarks/bench_nuts_overhead.py --base 842e5c5 [--reps 10] [--chains 1]
"""

from __future__ import annotations

import argparse
import datetime as dt
import hashlib
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench_analytic_gradients import CASES, trajectory_data
from machine import machine_info, report
from ssmobs.stan_backends.native_build import stan_version
from ssmobs.stan_backends.native_run import write_json_file

ROOT = Path(__file__).resolve().parents[1]

#: run in a revision's checkout: build both programs of every case, print their drivers and
#: the environment that revision's backend gives a driver
_BUILD = """
import json, sys
from ssmobs.models import get_model
try:  # since the sixth session of 2026-12-05
    from ssmobs.nuts.analytic_program import write_analytic_program
except ImportError:
    from ssmobs.nuts.analytic_gradients import write_analytic_program
from ssmobs.stan_backends import stan_file
from ssmobs.stan_backends.native import NativeBackend
from ssmobs.stan_backends import native_run
native, out = NativeBackend(), {}
for slug in sys.argv[1:]:
    prog = write_analytic_program(get_model(slug), stan_file(slug))
    out[slug] = {
        "autodiff": native.compile(stan_file(slug))["exe_file"],
        "analytic": native.compile(prog.stan_file, prog.header)["exe_file"],
    }
env = getattr(native_run, "driver_environment", None)
tunables = (env() if env else {}).get("GLIBC_TUNABLES")
print(json.dumps({"exes": out, "GLIBC_TUNABLES": tunables}))
"""


def git(*args: str) -> str:
    """Output of ``git -C <this checkout> args``, stripped."""
    done = subprocess.run(
        ["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True
    )
    return done.stdout.strip()


def build(checkout: Path, slugs: list[str]) -> dict:
    """Drivers of ``checkout``'s programs (compiled into the shared cache if missing)."""
    env = {**os.environ, "PYTHONPATH": str(checkout / "workflow")}
    env.pop("GLIBC_TUNABLES", None)
    done = subprocess.run(
        [sys.executable, "-c", _BUILD, *slugs], env=env, capture_output=True, text=True
    )
    if done.returncode != 0:
        raise SystemExit(f"building in {checkout} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def run(exe: str, args: list[str], tunables: str | None, out: Path) -> tuple[float, str]:
    """CPU seconds of one driver run and the SHA-256 of its draws file."""
    env = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
    if tunables:
        env["GLIBC_TUNABLES"] = tunables
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(
        [exe, *args, "--output", str(out)],
        env=env,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return cpu, hashlib.sha256(out.read_bytes()).hexdigest()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--base", required=True, help="git revision to compare against")
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--chains", type=int, default=4)
    ap.add_argument("--warmup", type=int, default=4000)
    ap.add_argument("--samples", type=int, default=6000)
    ap.add_argument("--cases", default="", help="comma-separated model slugs, default all")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    wanted = {c.strip() for c in args.cases.split(",") if c.strip()}
    cases = [c for c in CASES if not wanted or c[0] in wanted]
    slugs = [slug for slug, _, _ in cases]
    base_sha = git("rev-parse", "--short", args.base)
    here_sha = git("rev-parse", "--short", "HEAD")
    dirty = git("status", "--porcelain", "--untracked-files=no")
    with tempfile.TemporaryDirectory(prefix="bench-nuts-overhead-") as tmp_name:
        tmp = Path(tmp_name)
        worktree = tmp / "base"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(worktree), args.base],
            check=True,
            capture_output=True,
        )
        try:
            builds = {"base": build(worktree, slugs), "here": build(ROOT, slugs)}
        finally:
            subprocess.run(
                ["git", "-C", str(ROOT), "worktree", "remove", "--force", str(worktree)],
                check=False,
                capture_output=True,
            )
        loads = [os.getloadavg()[0]]
        started = dt.datetime.now(dt.timezone.utc)
        rows = []
        for slug, omega, T in cases:
            data = tmp / f"{slug}.json"
            write_json_file(data, trajectory_data(slug, omega, T))
            common = [
                "--data",
                str(data),
                "--seed",
                "20261205",
                "--chains",
                str(args.chains),
                "--warmup",
                str(args.warmup),
                "--samples",
                str(args.samples),
                "--delta",
                "0.8",
                "--max-depth",
                "10",
                "--init-radius",
                "2.0",
                "--threads",
                "1",
            ]
            keys = [(rev, path) for rev in ("base", "here") for path in ("autodiff", "analytic")]
            cpu: dict = {k: [] for k in keys}
            digests: dict = {k: set() for k in keys}
            for r in range(args.reps):
                for rev, path in keys if r % 2 == 0 else keys[::-1]:
                    exe = builds[rev]["exes"][slug][path]
                    seconds, digest = run(exe, common, builds[rev]["GLIBC_TUNABLES"], tmp / "d.bin")
                    cpu[rev, path].append(seconds)
                    digests[rev, path].add(digest)
                    loads.append(os.getloadavg()[0])
                print(
                    f"{slug} rep {r}: "
                    + ", ".join(f"{rev} {path} {cpu[rev, path][-1]:.2f}" for rev, path in keys),
                    flush=True,
                )
            med = {k: statistics.median(v) for k, v in cpu.items()}
            low = {k: min(v) for k, v in cpu.items()}
            for path in ("autodiff", "analytic"):
                same = (
                    digests["base", path] == digests["here", path]
                    and len(digests["here", path]) == 1
                )
                rows.append(
                    f"| {slug} T = {T} | {path} | {med['base', path]:.2f} / {low['base', path]:.2f} "
                    f"| {med['here', path]:.2f} / {low['here', path]:.2f} "
                    f"| {med['base', path] / med['here', path]:.2f} / {low['base', path] / low['here', path]:.2f} "
                    f"| {'yes' if same else 'NO'} |"
                )
            rows.append(
                f"| {slug} T = {T} | autodiff / analytic | "
                f"{med['base', 'autodiff'] / med['base', 'analytic']:.2f} / "
                f"{low['base', 'autodiff'] / low['base', 'analytic']:.2f} | "
                f"{med['here', 'autodiff'] / med['here', 'analytic']:.2f} / "
                f"{low['here', 'autodiff'] / low['here', 'analytic']:.2f} | | |"
            )
    finished = dt.datetime.now(dt.timezone.utc)
    text = "\n".join(
        [
            "",
            f"## NUTS per step: Stan's machinery before and after (issue 49, {finished:%Y-%m-%d})",
            "",
            f"- Date: {started:%Y-%m-%d %H:%M}-{finished:%H:%M} UTC; base {base_sha}, here "
            f"{here_sha}{' with uncommitted changes' if dirty else ''}",
            f"- Machine: {machine_info()}; {stan_version()}",
            f"- Command: `python benchmarks/bench_nuts_overhead.py --base {args.base} --reps "
            f"{args.reps} --chains {args.chains} --warmup {args.warmup} --samples {args.samples}`",
            f"- System load (1-min load average): {min(loads):.1f}-{max(loads):.1f} on "
            f"{os.cpu_count()} CPUs; the four executables interleaved, the order reversed every "
            "other rep, the same data and Stan seed.",
            "- CPU: the driver's CPU seconds (rusage), median / minimum over the reps.",
            "",
            "| case | path | base CPU s (median / min) | here CPU s (median / min) | speed-up here (median / min) | same draws file |",
            "|---|---|---:|---:|---:|---|",
            *rows,
            "",
        ]
    )
    report(text, write=not args.no_write)


if __name__ == "__main__":
    main()
