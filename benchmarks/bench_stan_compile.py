"""Cold compile of one Stan program with the native backend, with and without a precompiled
header (g++ ``.gch``) of ``stan/model/model_header.hpp``, the heavy Stan Math include of
every stanc-generated program (issue 48).

Everything builds in an empty temporary cache (``SSMOBS_CACHE``), so nothing is reused:
the driver's object file (once per machine), the program as the backend builds it (stanc,
its object file, the link), the precompiled header, and the program's object file again
with it.  Costs are CPU seconds of the child processes (user + system) and wall seconds.
The two object files are compared byte for byte, and the two linked executables sample the
same data with the same seed: their draws files must be identical.

    python benchmarks/bench_stan_compile.py [--model same]
"""

from __future__ import annotations

import argparse
import filecmp
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))


def timed(cmd: list[str]) -> tuple[float, float]:
    """Run ``cmd`` (must succeed); its CPU seconds (children's user + system) and wall."""
    before, t0 = os.times(), time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    after = os.times()
    cpu = after.children_user - before.children_user
    cpu += after.children_system - before.children_system
    return cpu, time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="same")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_stan_compile-"))
    os.environ["SSMOBS_CACHE"] = str(work / "cache")

    from ssmobs.stan_backends import stan_file
    from ssmobs.stan_backends.native_build import (
        LDFLAGS,
        compile_flags,
        compiler,
        driver_object,
        httpstan_dir,
    )

    cxx, flags, hdir = compiler(), compile_flags(), httpstan_dir()
    rows: list[tuple[str, float, float]] = []

    before, t0 = os.times(), time.perf_counter()
    driver_o = driver_object()
    after = os.times()
    cpu = after.children_user - before.children_user
    cpu += after.children_system - before.children_system
    rows.append(("the driver's object file (once per machine)", cpu, time.perf_counter() - t0))

    model_hpp = work / "model.hpp"
    rows.append(
        (
            "stanc",
            *timed(
                [str(hdir / "stanc"), "--name", f"{args.model}_model", "--o", str(model_hpp)]
                + [str(stan_file(args.model))]
            ),
        )
    )
    plain_o, pch_o = work / "plain.o", work / "pch.o"
    rows.append(
        (
            "the program's object file",
            *timed([cxx, *flags, "-x", "c++", "-c", str(model_hpp), "-o", str(plain_o)]),
        )
    )
    header = work / "pch" / "stan_model_header.hpp"
    header.parent.mkdir()
    header.write_text("#include <stan/model/model_header.hpp>\n")
    rows.append(
        (
            "the precompiled header (once per machine)",
            *timed([cxx, *flags, "-x", "c++-header", str(header), "-o", f"{header}.gch"]),
        )
    )
    rows.append(
        (
            "the program's object file with the precompiled header",
            *timed(
                [cxx, *flags, "-Winvalid-pch", "-include", str(header), "-x", "c++", "-c"]
                + [str(model_hpp), "-o", str(pch_o)]
            ),
        )
    )
    exes = {}
    for name, obj in (("plain", plain_o), ("pch", pch_o)):
        exe = work / f"driver_{name}"
        cpu, wall = timed(
            [cxx, str(driver_o), str(obj), "-o", str(exe), f"-L{hdir / 'lib'}", "-ltbb", *LDFLAGS]
        )
        rows.append((f"the link ({name})", cpu, wall))
        exes[name] = exe
    (work / "libtbb.so.2").symlink_to(hdir / "lib" / "libtbb.so.2")

    import numpy as np
    from ssmobs.models import get_model
    from ssmobs.models.check_cases import default_cases, sample_theta
    from ssmobs.stan_backends.native_run import write_json_file

    model = get_model(args.model)
    _, z, bounds = sample_theta(model, default_cases(model)[0], 20, 1, np.random.default_rng(1))
    data = work / "data.json"
    write_json_file(data, model.stan_data(z, bounds))
    draws = {}
    for name, exe in exes.items():
        out = work / f"draws_{name}.bin"
        subprocess.run(
            [str(exe), "--data", str(data), "--seed", "7", "--chains", "2", "--warmup", "300"]
            + ["--samples", "300", "--output", str(out)],
            check=False,
            capture_output=True,
        )
        draws[name] = out
    gch_mb = Path(f"{header}.gch").stat().st_size / 2**20

    print(f"model {args.model}; compiler {cxx}; work dir {work}")
    print("| step | CPU s | wall s |\n|---|---:|---:|")
    for what, cpu, wall in rows:
        print(f"| {what} | {cpu:.1f} | {wall:.1f} |")
    print(f"precompiled header: {gch_mb:.0f} MiB")
    same_o = filecmp.cmp(plain_o, pch_o, shallow=False)
    print(f"object files identical byte for byte: {same_o}")
    if all(p.exists() for p in draws.values()):
        same = filecmp.cmp(draws["plain"], draws["pch"], shallow=False)
        print(f"draws identical byte for byte: {same}")
    else:
        print("draws: a driver wrote no draws file (see the data file for this model)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
