"""One commit, the same bytes whatever kernels this CPU's libraries would pick (issue 34).

A small run through the workflow (a design set of dimension (d + p) T = 40, its trajectories,
the joint MAP, the exact stage, a few NUTS runs and the tables) twice: once started with this
machine's own kernels (OpenBLAS's choice for this CPU, NumPy's widest SIMD targets) and four
BLAS threads, once with OpenBLAS's Haswell kernels, NumPy without its AVX-512 targets and one
thread.  Every cached result and every table must be the same bytes.  Where this machine's
kernels give the same bits either way (no AVX-512 here), the test says so and skips: it
could not fail there.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from helpers import make_workdir, snakemake

OUT = "paper_figures/kernels"
CONFIG = {
    "outputs_dir": OUT,
    "scenarios": [
        # q = (d + p) T = 40: the design set's optimiser runs through BLAS and NumPy's exp
        {"name": "same_T20", "model": "same", "omega": {"a": 0.9}, "x0": 8, "T": 20, "K": 6,
         "prior": "restricted"},
    ],
    "paper_outputs": {"tables_2_3": ["same_T20"], "figure3": []},
    "observability_studies": [],
    "observability_maps": [],
    "k_selection": [],
    # the default profile's NUTS path, and the program `make run` compiled for it
    "stan": {"gradients": "analytic", "chains": 2, "iter_warmup": 150, "iter_sampling": 150,
             "batch_size": 3, "keep_draws": [0]},
    "convergence": {"ess_bulk_min": 50, "ess_tail_min": 50},
}  # fmt: skip

#: the machine's own choice: what a user's shell has when nothing is set
OWN = {"OPENBLAS_NUM_THREADS": "4", "OMP_NUM_THREADS": "4"}
UNSET_FOR_OWN = ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")
#: the kernels the workflow fixes (ssmobs/kernels.py), set by hand
FIXED = {
    "OPENBLAS_CORETYPE": "Haswell",
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
}
#: a product through BLAS and NumPy's exp, without our package: does this machine's own
#: choice of kernels change bits?
PROBE = """
import hashlib, numpy as np
rng = np.random.default_rng(0)
a, b = rng.standard_normal((300, 257)), rng.standard_normal((257, 301))
h = hashlib.sha256((a @ b).tobytes() + np.exp(np.linspace(-5, 5, 10001)).tobytes())
print(h.hexdigest())
"""


#: the compiled LCD kernel (ssmobs.design.lcd_native) on a few sets, as bytes: value and gradient
LCD_KERNEL = """
import hashlib, numpy as np
from ssmobs.design import lcd_native
from ssmobs.design.lcd_distance import _quadrature
h = hashlib.sha256()
for q, K, b in [(8, 301, 10.0), (40, 120, 50.0), (2, 33, 0.7), (200, 41, 100.0),
                (8, 1000, 10.0), (13, 77, 0.5)]:
    s = np.random.default_rng(q + K).standard_normal((K // 2, q))
    quad = _quadrature(q, b, 80)
    rule = (quad.lam, quad.sig, quad.alpha, quad.beta, quad.d1p, quad.j0p)
    v, g = lcd_native.symmetric_distance(s, K, b, rule, True)
    h.update(np.float64(v).tobytes() + g.tobytes())
print(h.hexdigest())
"""


def environment(variant: dict[str, str], unset: tuple[str, ...] = ()) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in unset}
    env.update(variant)
    return env


def probe(env: dict[str, str], code: str = PROBE) -> str:
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return out.stdout.strip()


def comparable(workdir: Path) -> dict[str, bytes]:
    """Every file the run wrote under results/ and its outputs_dir, as the bytes a result is:
    without logs and timings (job benchmarks, the records' ``timings``, the build records of
    the compiled programs, which name their build directory and time)."""
    files: dict[str, bytes] = {}
    for root in (workdir / "results", workdir / OUT):
        for path in sorted(root.rglob("*")):
            rel = str(path.relative_to(workdir))
            if not path.is_file() or path.suffix == ".log" or "benchmark" in rel:
                continue  # logs and job benchmarks (wall and CPU times)
            if rel.startswith("results/shared/stan/"):
                continue  # compiled programs and their build records
            if rel.startswith("results/checksums/"):
                continue  # the outputs' checksums: the outputs themselves are compared
            data = path.read_bytes()
            if "/records/" in rel and path.suffix == ".json":
                record = json.loads(data)
                record.pop("timings", None)
                record.pop("record_sha256", None)  # a checksum over the timings too
                data = json.dumps(record, sort_keys=True).encode()
            files[rel] = data
    return files


def run(tmp_path: Path, name: str, env: dict[str, str]) -> dict[str, bytes]:
    work = make_workdir(tmp_path / name)
    (work / "config" / "kernels.yaml").write_text(yaml.safe_dump(CONFIG, sort_keys=False))
    snakemake(work, "--cores", "2", "--configfile", "config/kernels.yaml", env=env)
    return comparable(work)


def test_one_commit_gives_the_same_bytes_under_any_kernels_and_thread_count(tmp_path):
    own = environment(OWN, UNSET_FOR_OWN)
    fixed = environment(FIXED)
    if probe(own) == probe(fixed):
        pytest.skip(
            "this machine's own kernels and thread count give the same bits as the fixed ones "
            "(no AVX-512 here?): it cannot show a difference, so the test could not fail"
        )
    first = run(tmp_path, "own_kernels_4_threads", own)
    second = run(tmp_path, "fixed_kernels_1_thread", fixed)
    assert any(k.endswith(".nc") and "/design_disturbances/" in k for k in first), sorted(first)
    assert any("/exact_marginal/" in k for k in first) and any("/draws/" in k for k in first)
    assert any(k.startswith(OUT) and k.endswith(".csv") for k in first)
    assert set(first) == set(second), sorted(set(first) ^ set(second))
    differ = sorted(k for k in first if first[k] != second[k])
    assert not differ, f"{len(differ)} of {len(first)} files differ: {differ[:20]}"


def test_the_compiled_lcd_kernel_gives_the_same_bytes_under_any_kernels_and_thread_count():
    """The design sets' distance and gradient up to q = COMPILED_MAX_Q (the compiled kernel,
    with its own log/exp and its quadrature rule in decimal arithmetic): the same bytes with
    this machine's own NumPy and OpenBLAS kernels and 4 threads, the fixed ones and 1
    thread, and another OpenBLAS kernel with 2 threads; each with the build the kernel
    picks for this CPU (the widest: AVX-512 or AVX2) and, forced, the x86-64 baseline build;
    and every vector build this CPU runs, forced.  Not skipped where the kernels give the
    same bits anyway: the kernel must not depend on them in any case.  (The workflow run
    above makes its q = 40 design set with this kernel, in the build it picks.)"""
    from ssmobs.design import lcd_native
    from ssmobs.design.lcd_distance import COMPILED_MAX_Q

    assert COMPILED_MAX_Q >= 40  # the set of the run above goes through the compiled kernel
    other = {"OPENBLAS_CORETYPE": "Sandybridge", "OPENBLAS_NUM_THREADS": "2"}
    baseline = {lcd_native.BUILD_ENV: "x86-64"}
    runs = [
        ("own, 4 threads", environment(OWN, UNSET_FOR_OWN + (lcd_native.BUILD_ENV,))),
        ("fixed, 1 thread", environment(FIXED, (lcd_native.BUILD_ENV,))),
        ("Sandybridge, 2 threads", environment(other, UNSET_FOR_OWN)),
        ("own, 4 threads, x86-64 build", environment({**OWN, **baseline}, UNSET_FOR_OWN)),
        ("fixed, 1 thread, x86-64 build", environment({**FIXED, **baseline})),
    ]
    # every other build this CPU runs, forced (the picked one also ran above, unforced)
    for name in lcd_native.BUILDS:
        if name != "x86-64" and lcd_native.runs(name):
            forced = {lcd_native.BUILD_ENV: name}
            runs.append((f"fixed, 1 thread, {name} build", environment({**FIXED, **forced})))
    digests = {name: probe(env, LCD_KERNEL) for name, env in runs}
    assert len(digests) >= (6 if lcd_native.has_avx2() else 5)
    assert len(set(digests.values())) == 1, digests


@pytest.mark.stan
def test_the_tapeless_gradient_gives_the_same_draws_on_any_thread_count():
    """The native driver runs chains in threads; the analytic program's gradient without
    Stan's tape keeps per-thread state (ssmobs/gradient_slot.hpp): 4 chains on 1 or on 4
    threads give the same draws.  (The driver links neither NumPy nor OpenBLAS, so the
    kernels above do not reach it.)"""
    import numpy as np
    from ssmobs.models import get_model
    from ssmobs.nuts.analytic_program import write_analytic_program
    from ssmobs.stan_backends import stan_file
    from ssmobs.stan_backends.base import SamplerSettings
    from ssmobs.stan_backends.native import NativeBackend

    model = get_model("sep_ranwalk")
    rng = np.random.default_rng(11)
    _, z = model.simulate(
        np.array([0.8]), np.array([1.0]), rng.normal(size=(1, 30, 1)), rng.normal(size=(1, 30, 1))
    )
    data = model.stan_data(z[0], model.prior_bounds({"a": 0.8}))
    program = write_analytic_program(model, stan_file("sep_ranwalk"))
    draws = []
    for workers in (1, 4):
        settings = SamplerSettings(chains=4, iter_warmup=200, iter_sampling=200, workers=workers)
        d = NativeBackend().sample(program.stan_file, data, 5, settings, user_header=program.header)
        draws.append({k: np.asarray(v) for k, v in {**d.params, **d.sample_stats}.items()})
    assert draws[0].keys() == draws[1].keys()
    for k in draws[0]:
        assert np.array_equal(draws[0][k], draws[1][k], equal_nan=True), k
