#!/usr/bin/env python
"""The LCD design sets before and after the compiled kernel (issue 48), in the same process.

``before``: the optimiser on the NumPy reference of the distance and its gradient
(``kernel="numpy"`` of :func:`ssmobs.lcd_distance.symmetric_distance`, what every set was
made with until then); ``after``: the default (``kernel="auto"``: the compiled kernel of
:mod:`ssmobs.lcd_native` up to q = ``COMPILED_MAX_Q``, NumPy above).  Both run with the
workflow's fixed kernels (the script restarts itself with them) and the same quadrature
rule.

Two parts:

- speed: q = 8 and the default profile's largest q (200), K = 1000, seed 1: CPU seconds
  (``time.process_time``) of ``design_disturbances``, before and after in turn, ``--repeat``
  times (medians and the ratio);
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

SPEED_CASES = [(8, 1000), (200, 1000)]


def design(q: int, K: int, seed: int, kernel: str) -> dict:
    """One design set with the distance on ``kernel``; CPU seconds and the result."""
    import ssmobs.design_disturbances as dd
    from ssmobs.lcd_distance import symmetric_distance

    def on_kernel(*args, **kw):
        return symmetric_distance(*args, kernel=kernel, **kw)

    dd.symmetric_distance = on_kernel  # type: ignore[assignment]
    try:
        t0 = time.process_time()
        res = dd.design_disturbances(q, K, "design", seed)
        cpu = time.process_time() - t0
    finally:
        dd.symmetric_distance = symmetric_distance
    return {
        "q": q,
        "K": K,
        "seed": seed,
        "kernel": kernel,
        "cpu_s": cpu,
        "iterations": res.iterations,
        "distance": res.distance,
        "distance_raw": res.distance_raw,
    }


def default_profile_sets() -> list[tuple[int, int]]:
    """Every (q, K) of a design set of the default profile."""
    import yaml
    from ssmobs.config import validate
    from ssmobs.scenario import Scenario

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the speed part only")
    ap.add_argument("--repeat", type=int, default=1, help="before/after pairs per case")
    ap.add_argument("--json", type=Path, help="write every measurement here")
    args = ap.parse_args()
    from ssmobs.lcd_distance import COMPILED_MAX_Q

    started = _dt.datetime.now(_dt.timezone.utc)
    print(f"# {started:%Y-%m-%d %H:%M} UTC; {machine_info()}")
    print(f"# load average at start: {os.getloadavg()[0]:.2f}; COMPILED_MAX_Q = {COMPILED_MAX_Q}")
    out: dict = {"machine": machine_info(), "started": started.isoformat(), "speed": []}
    print("\n| q | K | before CPU s | after CPU s | speed-up | iterations before / after |")
    print("|---|---|---|---|---|---|")
    for q, K in SPEED_CASES:
        runs: dict[str, list[dict]] = {"numpy": [], "auto": []}
        for _ in range(args.repeat):
            for kernel in ("numpy", "auto"):
                runs[kernel].append(design(q, K, 1, kernel))
        out["speed"] += runs["numpy"] + runs["auto"]
        b = statistics.median(r["cpu_s"] for r in runs["numpy"])
        a = statistics.median(r["cpu_s"] for r in runs["auto"])
        its = f"{runs['numpy'][0]['iterations']} / {runs['auto'][0]['iterations']}"
        print(f"| {q} | {K} | {b:.2f} | {a:.2f} | {b / a:.2f}x | {its} |", flush=True)
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
