"""The numerical kernels every job computes with: one commit, the same bits on any x86-64 CPU
with AVX2 (issue 34).

OpenBLAS picks a kernel for the CPU it finds (SkylakeX with AVX-512, Haswell or Zen with AVX2),
NumPy dispatches its loops (``exp``, ``log``, ``sin``, ...) to the widest SIMD target the CPU
has, and OpenBLAS splits products over as many threads as there are cores.  Each choice
changes the rounding of some results, and the LCD optimiser of the design sets follows its
path to another local optimum from a different last bit, so everything after it differs.

The workflow therefore fixes all three for every job before NumPy loads (:func:`apply`, at the
top of the Snakefile; jobs inherit the environment locally and on SLURM, whose job-side
Snakemake reads the Snakefile again), and every job checks that they are in force
(:func:`require`) before it computes:

- OpenBLAS's ``Haswell`` kernels (AVX2 + FMA3), which every x86-64 CPU with AVX2 runs;
- NumPy's dispatch targets above AVX2 switched off (``X86_V4`` and the AVX-512 groups), so
  NumPy runs its AVX2/FMA3 loops, or glibc's, everywhere;
- one BLAS/OpenMP thread (the workflow runs jobs, not threads, in parallel).

On a CPU without AVX2 and FMA3, or not x86-64, only the thread count is fixed: results there
may differ from those of an AVX2 machine (:func:`guarantee` says so, and ``provenance.json``
records it).  Not covered anywhere: other BLAS builds (the wheels' OpenBLAS is pinned by the
constraints file), other versions of NumPy, SciPy, Stan or the C++ compiler.

This module imports nothing of ours and does not import NumPy at module level.
"""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import Mapping, MutableMapping
from functools import lru_cache
from pathlib import Path
from typing import Any

#: OpenBLAS's kernel for every x86-64 CPU with AVX2 and FMA3
OPENBLAS_CORE = "Haswell"
#: NumPy's dispatch targets above AVX2, switched off: names of NumPy 2.x (``X86_V4``,
#: ``AVX512_ICL``, ``AVX512_SPR``) and of 1.x (``AVX512F`` ... ``AVX512_SPR``); NumPy ignores
#: names it does not dispatch to
NUMPY_DISABLED: tuple[str, ...] = (
    "X86_V4",
    "AVX512F",
    "AVX512CD",
    "AVX512_KNL",
    "AVX512_KNM",
    "AVX512_SKX",
    "AVX512_CLX",
    "AVX512_CNL",
    "AVX512_ICL",
    "AVX512_SPR",
)
#: variables that set the thread count of a BLAS or OpenMP runtime
THREAD_VARIABLES: tuple[str, ...] = (
    "OPENBLAS_NUM_THREADS",
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "BLIS_NUM_THREADS",
)
#: CPU flags (``/proc/cpuinfo``) a CPU needs for the fixed kernels
REQUIRED_FLAGS: tuple[str, ...] = ("avx2", "fma")
#: what the fixed settings are, as part of every cache key: an edit of them reruns everything
SETTINGS_ID = (
    f"openblas={OPENBLAS_CORE};numpy-off={','.join(NUMPY_DISABLED)};threads=1"
    ";x86-64 with avx2+fma, else threads only"
)


class KernelsNotFixed(RuntimeError):
    """A job about to compute with kernels other than the fixed ones."""


@lru_cache(maxsize=1)
def cpu_flags() -> frozenset[str]:
    """This CPU's flags from ``/proc/cpuinfo`` (empty where there is none)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return frozenset()


@lru_cache(maxsize=1)
def cpu_model() -> str:
    """This CPU's model name from ``/proc/cpuinfo`` (else :func:`platform.processor`)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def covered() -> bool:
    """True on an x86-64 CPU with AVX2 and FMA3: there the kernels are fixed, not only threads."""
    return platform.machine() in ("x86_64", "AMD64") and set(REQUIRED_FLAGS) <= cpu_flags()


def environment() -> dict[str, str]:
    """The variables every job runs with on this CPU (set before NumPy loads)."""
    env = dict.fromkeys(THREAD_VARIABLES, "1")
    if covered():
        env["OPENBLAS_CORETYPE"] = OPENBLAS_CORE
        env["NPY_DISABLE_CPU_FEATURES"] = " ".join(NUMPY_DISABLED)
    return env


def apply(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """Set :func:`environment` in ``environ`` (default ``os.environ``, inherited by every job
    this process starts); returns what was set.  Call before NumPy loads in this process."""
    env = environment()
    (os.environ if environ is None else environ).update(env)
    return env


def restart_with_fixed_kernels() -> None:
    """Run this script again in a process started with :func:`environment`, unless it was
    (for benchmarks and scripts run outside Snakemake; call before NumPy loads)."""
    if any(os.environ.get(k) != v for k, v in environment().items()):
        apply()
        os.execv(sys.executable, [sys.executable, *sys.argv])


def _load_scipy_blas() -> None:
    """Load SciPy's own OpenBLAS, so that :func:`in_force` lists it: the wheel's library in
    ``scipy.libs/`` (the file SciPy's extensions name, so they find it loaded), without
    importing ``scipy.linalg`` (0.35 CPU-s, in jobs that mostly need no SciPy); a SciPy
    without that folder (another build) is imported."""
    import ctypes
    import importlib.util

    spec = importlib.util.find_spec("scipy")
    if spec is not None and spec.origin is not None:
        libs = sorted((Path(spec.origin).parents[1] / "scipy.libs").glob("libscipy_openblas*.so"))
        if len(libs) == 1:
            ctypes.CDLL(str(libs[0]))
            return
    import scipy.linalg  # noqa: F401 - loads SciPy's OpenBLAS


def in_force() -> dict[str, Any]:
    """What this process computes with: OpenBLAS libraries (kernel, threads, version) and
    NumPy's enabled dispatch targets above its baseline (loads NumPy and threadpoolctl)."""
    import numpy as np
    from threadpoolctl import threadpool_info

    _load_scipy_blas()

    features = _numpy_features()
    dispatch = [t for t in _numpy_dispatch() if features.get(t)]
    return {
        # sorted: the order in which NumPy and SciPy loaded their libraries is no setting
        "blas": sorted(
            (
                {
                    "api": info.get("internal_api"),
                    "version": info.get("version"),
                    "kernel": info.get("architecture"),
                    "threads": info.get("num_threads"),
                    "library": Path(str(info.get("filepath", ""))).name,
                }
                for info in threadpool_info()
                if info.get("user_api") == "blas"
            ),
            key=lambda blas: str(blas["library"]),
        ),
        "numpy": np.__version__,
        "numpy_dispatch": dispatch,
    }


def problems(state: Mapping[str, Any] | None = None) -> list[str]:
    """Where ``state`` (default :func:`in_force`) differs from the fixed kernels; [] if none."""
    state = in_force() if state is None else state
    found = []
    for blas in state["blas"]:
        if blas["threads"] != 1:
            found.append(f"{blas['library']} runs {blas['threads']} threads, not 1")
        if covered() and blas["api"] == "openblas" and blas["kernel"] != OPENBLAS_CORE:
            found.append(f"{blas['library']} uses {blas['kernel']} kernels, not {OPENBLAS_CORE}")
    if covered():
        above = sorted(set(state["numpy_dispatch"]) & set(NUMPY_DISABLED))
        if above:
            found.append(f"NumPy dispatches to {', '.join(above)}")
    return found


def require() -> str:
    """Raise :class:`KernelsNotFixed` unless this process computes with the fixed kernels;
    else one line saying which (for the job's log)."""
    state = in_force()
    found = problems(state)
    if found:
        raise KernelsNotFixed(
            "this job's numbers would depend on the CPU: "
            + "; ".join(found)
            + ". Jobs get the fixed kernels from the environment the Snakefile sets "
            "(ssmobs/kernels.py); start the workflow with snakemake, not a script on its own, "
            f"or set {', '.join(f'{k}={v}' for k, v in environment().items())}"
        )
    blas = ", ".join(
        f"{b['api']} {b['version']} {b['kernel']} x{b['threads']}" for b in state["blas"]
    )
    top = state["numpy_dispatch"][-1:] or ["baseline"]
    return f"kernels: BLAS {blas}; NumPy {state['numpy']} up to {top[0]}; {guarantee()}"


class KernelsWarning(UserWarning):
    """A direct call of the library computes with this machine's kernels, not the fixed ones."""


#: whether :func:`warn_once_if_not_fixed` has looked in this process
_LOOKED: list[bool] = []


def warn_once_if_not_fixed(entry: str) -> None:
    """Warn once per process (:class:`KernelsWarning`, one line) when a public entry point
    of the library, ``entry``, is called in a process that does not compute with the fixed
    kernels: a direct call in plain Python, where NumPy loaded before they could be set.
    Its numbers may then differ in the last bits from the workflow's (whose every job
    checks the kernels, :func:`require`), and so may the optimum a design set ends in."""
    if _LOOKED:
        return
    _LOOKED.append(True)
    found = problems()
    if found:
        import shlex
        import warnings

        settings = " ".join(f"{k}={shlex.quote(v)}" for k, v in environment().items())
        warnings.warn(
            f"{entry} computes with this machine's kernels ({'; '.join(found)}), not the "
            f"workflow's fixed ones: its numbers may differ from the workflow's on another CPU; "
            f"for the workflow's numbers start Python with {settings} (docs/reproducibility.md)",
            KernelsWarning,
            stacklevel=3,
        )


def guarantee() -> str:
    """What the fixed kernels guarantee on this CPU, in one phrase."""
    if covered():
        return "the same bits as on any x86-64 CPU with AVX2 (fixed kernels)"
    return (
        f"not covered ({platform.machine()} without {'+'.join(REQUIRED_FLAGS)}): "
        "only the thread count is fixed"
    )


def record() -> dict[str, Any]:
    """What the numbers depended on, for ``provenance.json``: CPU, flags, the kernels in
    force, and the versions of NumPy, SciPy and threadpoolctl."""
    import scipy
    import threadpoolctl

    return {
        "cpu_model": cpu_model(),
        "architecture": platform.machine(),
        "cpu_flags": sorted(cpu_flags()),
        "settings": environment(),
        "guarantee": guarantee(),
        **in_force(),
        "scipy": scipy.__version__,
        "threadpoolctl": threadpoolctl.__version__,
    }


def _numpy_features() -> dict[str, bool]:
    try:
        from numpy._core._multiarray_umath import __cpu_features__
    except ImportError:  # NumPy 1.x
        from numpy.core._multiarray_umath import __cpu_features__  # type: ignore[no-redef]
    return dict(__cpu_features__)


def _numpy_dispatch() -> list[str]:
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__
    except ImportError:  # NumPy 1.x
        from numpy.core._multiarray_umath import __cpu_dispatch__  # type: ignore[no-redef]
    return list(__cpu_dispatch__)
