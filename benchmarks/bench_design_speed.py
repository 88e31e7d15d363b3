#!/usr/bin/env python
"""The LCD design sets of today's code and of this tree, in the same process (issue 48).

Four ways to make one design set, all with the workflow's fixed kernels (the script restarts
itself with them) and the same quadrature rule:

- ``numpy``: the optimiser on the NumPy reference of the distance and its gradient
  (``kernel="numpy"`` of :func:`ssmobs.design.lcd_distance.symmetric_distance`: every set was made
  with it up to the compiled kernel, e.g. at commit 1feb615);
- ``main``: the compiled kernel's source at git revision ``--main-rev`` (default: the commit
  this work started from), built with that revision's own choice on this CPU (its AVX2 build
  where there is AVX2, flags ``-mavx2 -mtune=haswell``), into a temporary directory;
- ``avx2``: this tree's kernel, its AVX2 build forced (what a CPU without AVX-512 runs);
- ``auto``: this tree's default (``kernel="auto"``: the compiled kernel in the build it picks
  for this CPU up to q = ``COMPILED_MAX_Q``, NumPy above).

Parts:

- speed: q = 8, K = 1000 and the default profile's largest q with a design set, K = 1000
  (its grid of the choice of K), seed 1: CPU seconds (``time.process_time``) of
  ``design_disturbances``, the ways in turn, ``--repeat`` times (medians and ratios); the
  quadrature rule of (q, B), the same in every way, is made before the clock starts;
- one evaluation of distance and gradient (a random set, K = 1000) at q = 8, 40, 200 in each
  way: the fastest of 5 (milliseconds);
- distances (unless ``--quick``): every design set of the default profile
  (``config/config.yaml``: each scenario's K and exact K with its seed, and the grids of the
  choice of K with the seeds ``--seeds`` of each set variant): the distance reached (after
  the covariance correction) and the CPU seconds in each way; ``main`` and ``auto`` must
  give the same bits (the matrix's SHA-256), the script says if not.

Usage: ``python benchmarks/bench_design_speed.py [--quick] [--repeat 1] [--seeds 1 2]
[--json out.json]``
"""

from __future__ import annotations

import argparse
import datetime as _dt
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

from ssmobs import kernels  # noqa: E402 - before NumPy loads

kernels.restart_with_fixed_kernels()

from machine import machine_info  # noqa: E402

#: the commit this work started from (the compiled kernel of main then)
MAIN_REV = "85ac34c"
#: the dimensions of the per-evaluation part
EVAL_QS = [8, 40, 200]
#: the ways to make a set: name -> (kernel of symmetric_distance, library or build)
#: (``main`` and ``avx2`` as ``auto``, NumPy above COMPILED_MAX_Q, as main's own code)
WAYS = {"numpy": ("numpy", ""), "main": ("auto", "main"), "avx2": ("auto", "x86-64-avx2"),
        "auto": ("auto", "")}  # fmt: skip
#: the loaded kernel of ``main`` (set in main())
MAIN_LIB: list = []


def build_main(rev: str) -> tuple[object, str]:
    """The kernel source at git revision ``rev``, built as that revision picked its build on
    this CPU (AVX2 where there is AVX2), loaded; and the build's name."""
    from ssmobs.design import lcd_native

    source = subprocess.run(
        ["git", "-C", str(REPO), "show", f"{rev}:workflow/ssmobs/lcd_kernel/lcd_kernel.cpp"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    name = "x86-64-avx2" if lcd_native.has_avx2() else "x86-64"
    work = Path(tempfile.mkdtemp(prefix="lcd-main-"))
    (work / "lcd_kernel.cpp").write_text(source)
    path, _ = lcd_native.build(work, lcd_native.BUILDS[name], work / "lcd_kernel.cpp")
    return lcd_native.load(path), name


def design(q: int, K: int, seed: int, way: str) -> dict:
    """One design set made in ``way`` (:data:`WAYS`): CPU seconds and the result."""
    import ssmobs.design.disturbances as dd
    from ssmobs.design import lcd_native
    from ssmobs.design.lcd_distance import N_NODES, _quadrature, b_max_rule, symmetric_distance

    kernel, build = WAYS[way]
    # the quadrature rule of (q, B) (decimal arithmetic, cached): made before the clock runs,
    # the same work in every way
    _quadrature(q, b_max_rule(q), N_NODES)
    original = lcd_native.kernel
    if build == "main":
        lcd_native.kernel = lambda: MAIN_LIB[0]  # type: ignore[assignment]
    elif build:
        lcd_native.kernel = lambda: lcd_native.kernel_of(build)  # type: ignore[assignment]

    def on_kernel(*args, **kw):
        return symmetric_distance(*args, kernel=kernel, **kw)

    dd.symmetric_distance = on_kernel  # type: ignore[assignment]
    try:
        t0 = time.process_time()
        res = dd.design_disturbances(q, K, "design", seed)
        cpu = time.process_time() - t0
    finally:
        dd.symmetric_distance = symmetric_distance
        lcd_native.kernel = original  # type: ignore[assignment]
    return {
        "q": q,
        "K": K,
        "seed": seed,
        "way": way,
        "cpu_s": cpu,
        "iterations": res.iterations,
        "distance": res.distance,
        "distance_raw": res.distance_raw,
        "sha256": hashlib.sha256(res.matrix.tobytes()).hexdigest()[:16],
    }


def default_profile_sets(seeds: list[int]) -> list[tuple[int, int, int, str]]:
    """Every design set of the default profile as (q, K, seed, what): each scenario's K and
    exact K with its seed; each grid of the choice of K with the seeds ``seeds`` (those of
    the grid's own seeds among them) of each set variant, seeded as the workflow seeds them
    (:func:`ssmobs.k_selection.set_seed`)."""
    import yaml
    from ssmobs.config.scenario import Scenario
    from ssmobs.config.validation import validate
    from ssmobs.k_selection import set_seed

    cfg = validate(yaml.safe_load((REPO / "config" / "config.yaml").read_text()))
    by_name = {sc["name"]: sc for sc in cfg["scenarios"]}
    sets: dict[tuple[int, int, int], str] = {}
    for sc in cfg["scenarios"]:
        s = Scenario.from_config(sc)
        if s.method != "design":
            continue
        sets.setdefault((s.disturbance_dim, s.K, s.seed), f"scenario {s.name}")
        if sc.get("exact_K") and sc.get("exact", True) is not False:
            sets.setdefault((s.disturbance_dim, int(sc["exact_K"]), s.seed), f"exact {s.name}")
    for ks in cfg["k_selection"]:
        if "design" not in ks["methods"]:
            continue
        q = Scenario.from_config(by_name[ks["scenario"]]).disturbance_dim
        for seed in [s for s in ks["seeds"] if s in seeds]:
            for variant in ks.get("sets", ["nested"]):
                for K in ks["K_grid"]:
                    key = (q, int(K), set_seed(seed, int(K), variant))
                    sets.setdefault(key, f"choice of K {ks['name']} {variant} seed {seed}")
    return sorted((q, K, seed, what) for (q, K, seed), what in sets.items())


def per_evaluation(q: int, K: int, repeat: int = 5) -> dict:
    """CPU seconds of one evaluation of distance and gradient (the fastest of ``repeat``) of
    a random set in each way."""
    import numpy as np
    from ssmobs.design import lcd_native
    from ssmobs.design.lcd_distance import _quadrature, b_max_rule, symmetric_distance

    b = b_max_rule(q)
    half = np.random.default_rng(q).standard_normal((K // 2, q))
    quad = _quadrature(q, b, 80)
    rule = (quad.lam, quad.sig, quad.alpha, quad.beta, quad.d1p, quad.j0p)
    libs = {"main": MAIN_LIB[0]}
    for name in lcd_native.BUILDS:
        if lcd_native.runs(name):
            libs[name] = lcd_native.kernel_of(name)
    calls = {"numpy": lambda: symmetric_distance(half, K, b, gradient=True, kernel="numpy")}
    for name, lib in libs.items():
        calls[name] = lambda lib=lib: lcd_native.symmetric_distance(half, K, b, rule, True, lib)
    out: dict = {"q": q, "K": K}
    bits = set()
    for name, call in calls.items():
        v, g = call()
        if name != "numpy":
            bits.add(hashlib.sha256(np.float64(v).tobytes() + g.tobytes()).hexdigest())
        times = []
        for _ in range(repeat):
            t0 = time.process_time()
            call()
            times.append(time.process_time() - t0)
        out[name] = min(times)
    out["compiled_same_bits"] = len(bits) == 1
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="speed and evaluations only")
    ap.add_argument("--repeat", type=int, default=1, help="runs per way and case")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2],
                    help="the seeds of the choice of K in the distance part")  # fmt: skip
    ap.add_argument("--json", type=Path, help="write every measurement here")
    ap.add_argument("--main-rev", default=MAIN_REV, help="git revision of main's kernel")
    args = ap.parse_args()
    from ssmobs.design.lcd_distance import COMPILED_MAX_Q
    from ssmobs.design.lcd_native import chosen_build

    started = _dt.datetime.now(_dt.timezone.utc)
    print(f"# {started:%Y-%m-%d %H:%M} UTC; {machine_info()}")
    print(f"# load average at start: {os.getloadavg()[0]:.2f}; COMPILED_MAX_Q = {COMPILED_MAX_Q}")
    out: dict = {"machine": machine_info(), "started": started.isoformat(), "speed": []}
    lib, main_build = build_main(args.main_rev)
    MAIN_LIB.append(lib)
    print(
        f"# main: the {main_build} build of {args.main_rev}'s kernel; auto: this tree's "
        f"{chosen_build()} build"
    )
    q_max = max(q for q, _, _, _ in default_profile_sets(args.seeds))
    print(
        "\n| q | K | NumPy CPU s | main CPU s | AVX2 build CPU s | auto CPU s | NumPy / auto "
        "| main / auto | NumPy / AVX2 build | iterations | same set main, AVX2, auto |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for q, K in [(8, 1000), (q_max, 1000)]:
        runs: dict[str, list[dict]] = {way: [] for way in WAYS}
        for _ in range(args.repeat):
            for way in WAYS:
                runs[way].append(design(q, K, 1, way))
        out["speed"] += [r for way in WAYS for r in runs[way]]
        med = {way: statistics.median(r["cpu_s"] for r in runs[way]) for way in WAYS}
        its = " / ".join(str(runs[way][0]["iterations"]) for way in WAYS)
        same = len({runs[way][0]["sha256"] for way in ("main", "avx2", "auto")}) == 1
        print(
            f"| {q} | {K} | {med['numpy']:.2f} | {med['main']:.2f} | {med['avx2']:.2f} "
            f"| {med['auto']:.2f} | {med['numpy'] / med['auto']:.2f}x "
            f"| {med['main'] / med['auto']:.2f}x | {med['numpy'] / med['avx2']:.2f}x "
            f"| {its} | {'yes' if same else 'NO'} |",
            flush=True,
        )
    print(
        "\n| q | K | NumPy ms | main ms | x86-64 build ms | AVX2 build ms | AVX-512 build ms "
        "| main / AVX2 build | main / AVX-512 build | same bits |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    out["per_evaluation"] = []
    nan = float("nan")
    for q in EVAL_QS:
        e = per_evaluation(q, 1000)
        out["per_evaluation"].append(e)
        avx2, avx512 = e.get("x86-64-avx2", nan), e.get("x86-64-avx512", nan)
        print(
            f"| {q} | 1000 | {1e3 * e['numpy']:.2f} | {1e3 * e['main']:.2f} "
            f"| {1e3 * e['x86-64']:.2f} | {1e3 * avx2:.2f} | {1e3 * avx512:.2f} "
            f"| {e['main'] / avx2:.2f}x | {e['main'] / avx512:.2f}x "
            f"| {'yes' if e['compiled_same_bits'] else 'NO'} |",
            flush=True,
        )
    if not args.quick:
        print(
            "\n| q | K | seed | set | distance NumPy | distance auto | auto / NumPy - 1 "
            "| iterations NumPy / auto | CPU s NumPy / main / auto | main = auto |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|")
        out["distances"] = []
        total = {way: 0.0 for way in ("numpy", "main", "auto")}
        for q, K, seed, what in default_profile_sets(args.seeds):
            if q <= COMPILED_MAX_Q:
                row = {way: design(q, K, seed, way) for way in ("numpy", "main", "auto")}
            else:  # NumPy in every way: made once
                numpy_set = design(q, K, seed, "numpy")
                row = {way: numpy_set for way in ("numpy", "main", "auto")}
            out["distances"].append({"what": what, **row})
            for way in total:
                total[way] += row[way]["cpu_s"]
            before, after = row["numpy"], row["auto"]
            rel = after["distance"] / before["distance"] - 1.0
            same = row["main"]["sha256"] == after["sha256"]
            print(
                f"| {q} | {K} | {seed} | {what} | {before['distance']:.6e} "
                f"| {after['distance']:.6e} | {rel:+.2e} "
                f"| {before['iterations']} / {after['iterations']} "
                f"| {before['cpu_s']:.2f} / {row['main']['cpu_s']:.2f} / {after['cpu_s']:.2f} "
                f"| {'yes' if same else 'NO'} |",
                flush=True,
            )
        out["total_cpu_s"] = total
        print(
            f"\n# all {len(out['distances'])} sets: CPU s NumPy {total['numpy']:.1f}, main "
            f"{total['main']:.1f}, auto {total['auto']:.1f} (NumPy / auto "
            f"{total['numpy'] / total['auto']:.2f}x, main / auto "
            f"{total['main'] / total['auto']:.2f}x)"
        )
    out["load_at_end"] = os.getloadavg()[0]
    print(f"\n# load average at end: {out['load_at_end']:.2f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
