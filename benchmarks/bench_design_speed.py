#!/usr/bin/env python
"""The LCD design sets before and after the compiled kernel (issue 48), in the same process.

``before``: the optimiser on the NumPy reference of the distance and its gradient
(``kernel="numpy"`` of :func:`ssmobs.design.lcd_distance.symmetric_distance`, what every set was
made with until then), and on the compiled kernel's x86-64 baseline build of the source at
git revision ``--before-rev`` (default: the kernel's last commit before the AVX2 build), built into a
temporary directory; ``after``: the default (``kernel="auto"``: the compiled
kernel of :mod:`ssmobs.design.lcd_native` in the build it picks for this CPU, up to
q = ``COMPILED_MAX_Q``, NumPy above).  All run with the workflow's fixed kernels (the
script restarts itself with them) and the same quadrature rule.

Three parts:

- speed: q = 8, K = 1000 and q = 40, K = 1300, seed 1: CPU seconds (``time.process_time``)
  of ``design_disturbances``, the three in turn, ``--repeat`` times (medians and ratios);
- one evaluation of distance and gradient (value and gradient of a random set, K = 1000)
  at q = 8 .. 100 on NumPy and on each build: the fastest of 5, for ``COMPILED_MAX_Q``;
- distances (unless ``--quick``): every (q, K) of a design set of the default profile
  (``config/config.yaml``: each scenario's K and exact K, each design grid of the choice of
  K), seed 1: the distance reached (after the covariance correction, and the raw optimum)
  before and after.

Usage: ``python benchmarks/bench_design_speed.py [--quick] [--repeat 1] [--json out.json]``
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

from ssmobs import kernels  # noqa: E402 - before NumPy loads

kernels.restart_with_fixed_kernels()

from machine import machine_info  # noqa: E402

SPEED_CASES = [(8, 1000), (40, 1300)]
#: the dimensions of the per-evaluation part
EVAL_QS = [8, 40, 48, 56, 64, 80, 100]
#: the runs of the speed part: name -> (kernel of symmetric_distance, forced build or "")
RUNS = {"numpy": ("numpy", ""), "x86-64": ("compiled", "before"), "auto": ("auto", "")}
#: the kernel's last commit before its AVX2 build and the work on its loops (issue 48)
BEFORE_REV = "55e6947"
#: the kernel library of the "before" build (set in main)
BEFORE_LIB: list = []


def build_before(rev: str) -> object:
    """The x86-64 baseline build of the kernel source at git revision ``rev``, loaded."""
    import subprocess
    import tempfile

    from ssmobs.design import lcd_native

    source = subprocess.run(
        ["git", "-C", str(REPO), "show", f"{rev}:workflow/ssmobs/design/lcd_kernel/lcd_kernel.cpp"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    work = Path(tempfile.mkdtemp(prefix="lcd-before-"))
    (work / "lcd_kernel.cpp").write_text(source)
    path, _ = lcd_native.build(work, lcd_native.BUILDS["x86-64"], work / "lcd_kernel.cpp")
    return lcd_native.load(path)


def design(q: int, K: int, seed: int, kernel: str, build: str = "") -> dict:
    """One design set with the distance on ``kernel`` (and the compiled ``build``, if
    given); CPU seconds and the result."""
    import ssmobs.design.disturbances as dd
    from ssmobs.design import lcd_native
    from ssmobs.design.lcd_distance import symmetric_distance
    from ssmobs.design.lcd_native import BUILD_ENV

    if build == "before":
        original = lcd_native.kernel
        lcd_native.kernel = lambda: BEFORE_LIB[0]  # type: ignore[assignment]
    elif build:
        os.environ[BUILD_ENV] = build
    else:
        os.environ.pop(BUILD_ENV, None)

    def on_kernel(*args, **kw):
        return symmetric_distance(*args, kernel=kernel, **kw)

    dd.symmetric_distance = on_kernel  # type: ignore[assignment]
    try:
        t0 = time.process_time()
        res = dd.design_disturbances(q, K, "design", seed)
        cpu = time.process_time() - t0
    finally:
        dd.symmetric_distance = symmetric_distance
        os.environ.pop(BUILD_ENV, None)
        if build == "before":
            lcd_native.kernel = original  # type: ignore[assignment]
    return {
        "q": q,
        "K": K,
        "seed": seed,
        "kernel": kernel,
        "build": build,
        "cpu_s": cpu,
        "iterations": res.iterations,
        "distance": res.distance,
        "distance_raw": res.distance_raw,
    }


def default_profile_sets() -> list[tuple[int, int]]:
    """Every (q, K) of a design set of the default profile."""
    import yaml
    from ssmobs.config.scenario import Scenario
    from ssmobs.config.validation import validate

    cfg = validate(yaml.safe_load((REPO / "config" / "config.yaml").read_text()))
    by_name = {sc["name"]: sc for sc in cfg["scenarios"]}
    sets = set()
    for sc in cfg["scenarios"]:
        s = Scenario.from_config(sc)
        if s.method != "design":
            continue
        sets.add((s.disturbance_dim, s.K))
        if sc.get("exact_K") and sc.get("exact", True) is not False:
            sets.add((s.disturbance_dim, int(sc["exact_K"])))
    for ks in cfg["k_selection"]:
        if "design" in ks["methods"]:
            q = Scenario.from_config(by_name[ks["scenario"]]).disturbance_dim
            sets.update((q, int(K)) for K in ks["K_grid"])
    return sorted(sets)


def per_evaluation(q: int, K: int, repeat: int = 5) -> dict:
    """CPU seconds of one evaluation of distance and gradient (the fastest of ``repeat``) of
    a random set on NumPy and on each compiled build."""
    import numpy as np
    from ssmobs.design import lcd_native
    from ssmobs.design.lcd_distance import _quadrature, b_max_rule, symmetric_distance

    b = b_max_rule(q)
    half = np.random.default_rng(q).standard_normal((K // 2, q))
    quad = _quadrature(q, b, 80)
    rule = (quad.lam, quad.sig, quad.alpha, quad.beta, quad.d1p, quad.j0p)
    calls = {"numpy": lambda: symmetric_distance(half, K, b, gradient=True, kernel="numpy")}
    before = BEFORE_LIB[0]
    calls["before"] = lambda: lcd_native.symmetric_distance(half, K, b, rule, True, before)
    for name in lcd_native.BUILDS:
        if name == "x86-64-avx2" and not lcd_native.has_avx2():
            continue
        lib = lcd_native.kernel_of(name)
        calls[name] = lambda lib=lib: lcd_native.symmetric_distance(half, K, b, rule, True, lib)
    out: dict = {"q": q, "K": K}
    for name, call in calls.items():
        call()
        times = []
        for _ in range(repeat):
            t0 = time.process_time()
            call()
            times.append(time.process_time() - t0)
        out[name] = min(times)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the speed part only")
    ap.add_argument("--repeat", type=int, default=1, help="before/after pairs per case")
    ap.add_argument("--json", type=Path, help="write every measurement here")
    ap.add_argument(
        "--before-rev", default=BEFORE_REV, help="git revision of the before build's source"
    )
    args = ap.parse_args()
    from ssmobs.design.lcd_distance import COMPILED_MAX_Q

    started = _dt.datetime.now(_dt.timezone.utc)
    print(f"# {started:%Y-%m-%d %H:%M} UTC; {machine_info()}")
    print(f"# load average at start: {os.getloadavg()[0]:.2f}; COMPILED_MAX_Q = {COMPILED_MAX_Q}")
    out: dict = {"machine": machine_info(), "started": started.isoformat(), "speed": []}
    from ssmobs.design.lcd_native import chosen_build

    BEFORE_LIB.append(build_before(args.before_rev))
    print(f"# before: the x86-64 build of {args.before_rev}; after: the {chosen_build()} build")
    print(
        "\n| q | K | NumPy CPU s | before build CPU s | after (auto) CPU s "
        "| after vs NumPy | after vs before build | iterations NumPy / before / after |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for q, K in SPEED_CASES:
        runs: dict[str, list[dict]] = {name: [] for name in RUNS}
        for _ in range(args.repeat):
            for name, (kernel, build) in RUNS.items():
                runs[name].append(design(q, K, 1, kernel, build))
        out["speed"] += [r for name in RUNS for r in runs[name]]
        med = {name: statistics.median(r["cpu_s"] for r in runs[name]) for name in RUNS}
        its = " / ".join(str(runs[name][0]["iterations"]) for name in RUNS)
        same = len({runs[name][0]["distance"] for name in ("x86-64", "auto")}) == 1
        out.setdefault("before_and_after_same_distance", []).append(same)
        print(
            f"| {q} | {K} | {med['numpy']:.2f} | {med['x86-64']:.2f} | {med['auto']:.2f} "
            f"| {med['numpy'] / med['auto']:.2f}x | {med['x86-64'] / med['auto']:.2f}x "
            f"| {its}{' (the same distance)' if same else ' (the distances differ!)'} |",
            flush=True,
        )
    print(
        "\n| q | K | NumPy ms | before build ms | x86-64 build ms | AVX2 build ms "
        "| before / AVX2 | NumPy / x86-64 | NumPy / AVX2 |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    out["per_evaluation"] = []
    for q in EVAL_QS:
        e = per_evaluation(q, 1000)
        out["per_evaluation"].append(e)
        avx2 = e.get("x86-64-avx2", float("nan"))
        print(
            f"| {q} | 1000 | {1e3 * e['numpy']:.2f} | {1e3 * e['before']:.2f} "
            f"| {1e3 * e['x86-64']:.2f} | {1e3 * avx2:.2f} | {e['before'] / avx2:.2f}x "
            f"| {e['numpy'] / e['x86-64']:.2f}x | {e['numpy'] / avx2:.2f}x |",
            flush=True,
        )
    if not args.quick:
        print("\n| q | K | distance before | distance after | after / before - 1 |")
        print("|---|---|---|---|---|")
        out["distances"] = []
        for q, K in default_profile_sets():
            before = design(q, K, 1, "numpy")
            after = design(q, K, 1, "auto")
            out["distances"] += [before, after]
            rel = after["distance"] / before["distance"] - 1.0
            print(
                f"| {q} | {K} | {before['distance']:.6e} | {after['distance']:.6e} | {rel:+.2e} |",
                flush=True,
            )
    out["load_at_end"] = os.getloadavg()[0]
    print(f"\n# load average at end: {out['load_at_end']:.2f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
