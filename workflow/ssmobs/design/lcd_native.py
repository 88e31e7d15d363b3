"""The compiled pair kernel of the LCD distance (``lcd_kernel/lcd_kernel.cpp``): built on
first use, loaded with ctypes.

The kernel computes what the NumPy reference of :mod:`ssmobs.design.lcd_distance` computes (the
point-symmetric distance and its gradient, docs/lcd-design-disturbances.md Sections 2.4 and
4) in one fused pass over the pairs, with its own ``log``, ``exp`` and ``expm1``, one fixed
order of every sum and one thread, compiled for the x86-64 baseline without contraction or
fast-math (:data:`CXXFLAGS`): the same bits on any x86-64 CPU, whatever NumPy's or
OpenBLAS's kernels and thread counts, and whichever compiler built it (IEEE 754 arithmetic
in the order the source writes).  Its source and :data:`CXXFLAGS` are part of the design
sets' cache key (:mod:`ssmobs.cache_keys`).

Three builds of the one source (:data:`BUILDS`): ``x86-64`` (the baseline, SSE2: two
lanes), ``x86-64-avx2`` (the same flags and ``-mavx2 -mtune=haswell``: four lanes, table
lookups by gathers) and ``x86-64-avx512`` (``-mavx512f -mprefer-vector-width=512
-mtune=skylake-avx512``: eight lanes), the last two still without contraction, so no
``a*b+c`` becomes a fused multiply-add.  :func:`kernel` loads the widest build the CPU runs
(AVX2 on every CPU of the workflow's same-bytes guarantee, :mod:`ssmobs.kernels`; AVX-512
where the CPU has AVX-512F); ``SSMOBS_LCD_BUILD`` (``auto`` or a build's name) forces one,
for the tests and the benchmark.  All give the same bits: the source fixes the order of
every sum (the compiler may not reorder floating-point sums without fast-math), and every
vectorised loop runs element-wise IEEE operations (+, -, *, /, compares and selects, bit
operations on the doubles' bits, loads), which are correctly rounded on two lanes as on
eight; a test (``tests/unit/design/test_lcd_native.py``) compares the bytes of value and gradient
of every build this CPU runs on random sets, and the kernels test runs the build
:func:`kernel` picks and the baseline.

Building: ``$CXX`` (default ``g++``, which the Stan driver needs anyway) compiles the
source once into ``<cache>/lcd/kernel-<key>/liblcd.so`` (the cache of the compiled Stan
programs, :func:`cache_root`), ``<key>`` a hash of the source
and the flags, under a lock and in a temporary directory renamed into place, as the Stan
driver (:mod:`ssmobs.stan_backends.native_build`).  Without a compiler (and no entry in the
cache) :func:`kernel` raises :class:`LcdKernelUnavailable` with one line saying so: there
is no silent fallback to NumPy, whose results differ in the last bits and so would put
other sets under the same cache key.  The library carries a checksum ``liblcd.so.sha256``
(:func:`ssmobs.io.write_checksum`) written at build time, before the rename, and is
verified before it is loaded: a library that does not match (replaced, truncated, a byte
flipped) or has none (an entry of an older layout) is rebuilt, never loaded, and where it
cannot be rebuilt :class:`LcdKernelUnavailable` names it in one line.
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import logging
import os
import platform
import shutil
import subprocess
import tempfile
import time
from functools import cache, lru_cache
from pathlib import Path

import numpy as np

from .. import io

__all__ = [
    "CXXFLAGS",
    "BUILDS",
    "SOURCE",
    "LcdKernelUnavailable",
    "build_key",
    "chosen_build",
    "kernel",
    "symmetric_distance",
]

LOG = logging.getLogger("ssmobs")

#: the kernel's C++ source
SOURCE = Path(__file__).resolve().parent / "lcd_kernel" / "lcd_kernel.cpp"
#: compiler flags: the x86-64 baseline (no -march), IEEE arithmetic as written (no
#: contraction, no fast-math); -fno-trapping-math only lets the compiler run the branch-free
#: logarithm on vector lanes (same operations per lane: a test compares with an -O0 build)
CXXFLAGS: tuple[str, ...] = (
    "-O3",
    "-std=c++17",
    "-ffp-contract=off",
    "-fno-fast-math",
    "-fno-trapping-math",
    "-fPIC",
    "-shared",
)
#: the builds of the kernel: name -> flags (see the module docstring), in the order of
#: preference (the last one the CPU runs is picked); AVX2 and AVX-512 without contraction,
#: tuned (instruction choice only, not what is computed) for the first CPU with each, so
#: that the compiler loads the logarithm's table entries with gathers (untuned, the AVX-512
#: build took twice the time); AVX-512 on full-width vectors
BUILDS: dict[str, tuple[str, ...]] = {
    "x86-64": CXXFLAGS,
    "x86-64-avx2": (*CXXFLAGS, "-mavx2", "-mtune=haswell"),
    "x86-64-avx512": (
        *CXXFLAGS,
        "-mavx512f",
        "-mprefer-vector-width=512",
        "-mtune=skylake-avx512",
    ),
}
#: the CPU flag each build needs (``/proc/cpuinfo``)
BUILD_CPU_FLAG: dict[str, str] = {
    "x86-64": "",
    "x86-64-avx2": "avx2",
    "x86-64-avx512": "avx512f",
}
#: the environment variable that forces a build (``auto``: by the CPU)
BUILD_ENV = "SSMOBS_LCD_BUILD"
#: the shared library's name in a cache entry
LIB_NAME = "liblcd.so"
#: the record every finished entry holds (written last, before the rename)
BUILD_RECORD = "build.json"

_DP = ctypes.POINTER(ctypes.c_double)
_VP = ctypes.c_void_p
_IP = ctypes.POINTER(ctypes.c_int)
_SIZE = ctypes.c_ssize_t


class LcdKernelUnavailable(RuntimeError):
    """The compiled LCD kernel can be neither found in the cache nor built."""


def compiler() -> str:
    """The C++ compiler (``$CXX``, default g++)."""
    return os.environ.get("CXX", "g++")


def build_key(flags: tuple[str, ...] = CXXFLAGS, source: Path = SOURCE) -> str:
    """16 hex digits of SHA-256 over the source and the flags: names the cache entry (not
    the compiler, see the module docstring)."""
    h = hashlib.sha256()
    h.update(source.read_bytes())
    h.update(b"\0" + " ".join(flags).encode())
    return h.hexdigest()[:16]


def _declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    lib.ssmobs_lcd_symmetric.restype = None
    # addresses as plain integers (``ndarray.ctypes.data``): a thousand calls a second
    # from the optimiser, where building seven pointer objects per call cost 4 % of a set
    lib.ssmobs_lcd_symmetric.argtypes = [
        _VP, _SIZE, _SIZE, _SIZE, ctypes.c_double, _VP, _VP, _VP, _VP, _SIZE,
        ctypes.c_double, ctypes.c_double, ctypes.c_int, _VP, _VP,
    ]  # fmt: skip
    lib.ssmobs_lcd_elementwise.restype = None
    lib.ssmobs_lcd_elementwise.argtypes = [_DP, _SIZE, ctypes.c_int, _DP]
    lib.ssmobs_lcd_e1_psi.restype = None
    lib.ssmobs_lcd_e1_psi.argtypes = [_DP, _SIZE, _DP, _DP]
    if hasattr(lib, "ssmobs_lcd_terms"):  # not in the sources before it (the benchmark's)
        lib.ssmobs_lcd_terms.restype = None
        lib.ssmobs_lcd_terms.argtypes = [_DP, _SIZE, _IP, _IP]
    return lib


def build(
    directory: Path, flags: tuple[str, ...] = CXXFLAGS, source: Path = SOURCE
) -> tuple[Path, list[str]]:
    """Compile ``source`` with ``flags`` into ``directory/liblcd.so``; returns the library
    and the command.  LcdKernelUnavailable (one line) when the compiler is missing or fails."""
    out = directory / LIB_NAME
    cmd = [compiler(), *flags, str(source), "-o", str(out)]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True)
    except OSError as err:
        raise LcdKernelUnavailable(
            f"the LCD design kernel needs a C++ compiler: cannot run {compiler()!r} ({err}); "
            "install g++ or set CXX"
        ) from None
    if done.returncode != 0:
        first = next((ln for ln in done.stderr.splitlines() if "error" in ln), done.stderr)
        raise LcdKernelUnavailable(
            f"compiling the LCD design kernel failed ({compiler()} exit {done.returncode}): "
            f"{first.strip()}"
        )
    return out, cmd


def cache_root() -> Path:
    """The cache of compiled programs: ``$SSMOBS_CACHE``, else ``$XDG_CACHE_HOME/ssmobs``
    (default ``~/.cache/ssmobs``), as :func:`ssmobs.stan_backends.cache.cache_root` (not
    imported: the design sets' key would then follow every edit of the Stan backends)."""
    explicit = os.environ.get("SSMOBS_CACHE")
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ssmobs"


def _publish(entry: Path, flags: tuple[str, ...]) -> None:
    """Build with ``flags`` into a temporary sibling of ``entry`` and rename it into place
    (the caller holds the lock)."""
    work = Path(tempfile.mkdtemp(prefix=f".{entry.name}.tmp-", dir=entry.parent))
    try:
        t0 = time.perf_counter()
        _, cmd = build(work, flags)
        version = subprocess.run([compiler(), "--version"], capture_output=True, text=True)
        record = {
            "key": build_key(flags),
            "flags": list(flags),
            "command": cmd,
            "compiler_version": (version.stdout.splitlines() or [""])[0],
        }
        io.write_checksum(work / LIB_NAME)
        (work / BUILD_RECORD).write_text(json.dumps(record, indent=1))
        work.chmod(0o777 & ~_umask())
        if entry.exists():  # unfinished (no build record) or damaged
            shutil.rmtree(entry)
        os.replace(work, entry)
        LOG.info(
            "compiled the LCD design kernel in %.1f s into %s", time.perf_counter() - t0, entry
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@lru_cache(maxsize=1)
def cpu_flags() -> frozenset[str]:
    """The flags of this CPU in ``/proc/cpuinfo`` (empty off x86-64); read here, not with
    :func:`ssmobs.kernels.cpu_flags`: the design sets' key would then follow every edit of
    that module (the build does not change a result)."""
    if platform.machine() not in ("x86_64", "AMD64"):
        return frozenset()
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return frozenset()
    for line in text.splitlines():
        if line.startswith("flags"):
            return frozenset(line.split(":", 1)[-1].split())
    return frozenset()


def runs(name: str) -> bool:
    """Whether this CPU runs the build ``name`` of :data:`BUILDS`."""
    flag = BUILD_CPU_FLAG[name]
    return not flag or flag in cpu_flags()


def has_avx2() -> bool:
    """Whether this CPU runs AVX2 (x86-64 with the ``avx2`` flag)."""
    return runs("x86-64-avx2")


def chosen_build() -> str:
    """The build :func:`kernel` loads: ``$SSMOBS_LCD_BUILD`` unless ``auto`` (or unset), else
    the last build of :data:`BUILDS` this CPU runs (AVX-512, AVX2, the baseline).
    ValueError (one line) for an unknown name or a build the CPU cannot run."""
    name = os.environ.get(BUILD_ENV, "auto") or "auto"
    if name == "auto":
        return [b for b in BUILDS if runs(b)][-1]
    if name not in BUILDS:
        raise ValueError(f"{BUILD_ENV} must be auto or one of {sorted(BUILDS)}; got {name!r}")
    if not runs(name):
        raise ValueError(f"{BUILD_ENV}={name}: this CPU has no {BUILD_CPU_FLAG[name]}")
    return name


def kernel() -> ctypes.CDLL:
    """The compiled kernel of :func:`chosen_build`, built into the cache on first use (see
    the module docstring)."""
    return kernel_of(chosen_build())


@cache
def kernel_of(name: str) -> ctypes.CDLL:
    """The build ``name`` of :data:`BUILDS`, built into the cache on first use:
    ``<cache>/lcd/kernel-<key>/`` (``<key>``: source and that build's flags), under an
    exclusive lock, published by a rename."""
    flags = BUILDS[name]
    entry = cache_root() / "lcd" / f"kernel-{build_key(flags)}"
    damage = entry_problem(entry)
    if damage is not None or not (entry / BUILD_RECORD).is_file():
        if damage is not None:
            LOG.warning("%s: rebuilding it", damage)
        try:
            entry.parent.mkdir(parents=True, exist_ok=True)
            with io.file_lock(entry.parent / f".{entry.name}.lock"):
                if entry_problem(entry) is not None or not (entry / BUILD_RECORD).is_file():
                    _publish(entry, flags)
        except (OSError, LcdKernelUnavailable) as err:
            if damage is not None:
                raise LcdKernelUnavailable(
                    f"{damage}; it is not loaded, and it cannot be rebuilt: {err}"
                ) from None
            if isinstance(err, LcdKernelUnavailable):
                raise
            raise LcdKernelUnavailable(
                f"cannot write the LCD design kernel into the cache {entry.parent} ({err}); "
                "point SSMOBS_CACHE at a writable directory"
            ) from None
        problem = entry_problem(entry)
        if problem is not None:
            raise LcdKernelUnavailable(f"{problem} right after its build; it is not loaded")
    return _declare(ctypes.CDLL(str(entry / LIB_NAME)))


def entry_problem(entry: Path) -> str | None:
    """Why the kernel entry ``entry`` cannot be loaded (unfinished, the library missing or
    not matching its checksum), or None; None also when there is no entry (it is built)."""
    if not entry.exists():
        return None
    if not (entry / BUILD_RECORD).is_file():
        return f"{entry} is unfinished (no {BUILD_RECORD})"
    if not (entry / LIB_NAME).is_file():
        return f"{entry / LIB_NAME} is missing"
    return io.checksum_problem(entry / LIB_NAME)


def load(path: Path) -> ctypes.CDLL:
    """A kernel library built elsewhere (:func:`build`), for tests."""
    return _declare(ctypes.CDLL(str(path)))


def _ptr(a: np.ndarray) -> ctypes._Pointer:
    return a.ctypes.data_as(_DP)


def symmetric_distance(
    half: np.ndarray,
    K: int,
    b_max: float,
    rule: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float],
    gradient: bool,
    lib: ctypes.CDLL | None = None,
) -> tuple[float, np.ndarray | None]:
    """Distance of the point-symmetric set of ``half`` (N x q, K = 2N or 2N + 1 points) and,
    with ``gradient``, its gradient w.r.t. ``half`` (doc 2.4, 4), as
    :func:`ssmobs.design.lcd_distance.symmetric_distance` with ``kernel="numpy"`` to ~1e-12.
    ``rule``: the quadrature rule of (q, B) as (lam, sig, alpha, beta, D1', J'(0))."""
    lib = kernel() if lib is None else lib
    s = np.ascontiguousarray(half, dtype=np.float64)
    n, q = s.shape
    lam, sig, alpha, beta = (np.ascontiguousarray(a, dtype=np.float64) for a in rule[:4])
    value = np.zeros(1)
    grad = np.empty((n, q)) if gradient else np.empty((1, 1))
    lib.ssmobs_lcd_symmetric(
        s.ctypes.data, n, q, int(K), float(b_max), lam.ctypes.data, sig.ctypes.data,
        alpha.ctypes.data, beta.ctypes.data, lam.size, float(rule[4]), float(rule[5]),
        int(gradient), value.ctypes.data, grad.ctypes.data,
    )  # fmt: skip
    return float(value[0]), (grad if gradient else None)


def elementwise(x: np.ndarray, function: str, lib: ctypes.CDLL | None = None) -> np.ndarray:
    """The kernel's own ``log``, ``exp`` or ``expm1`` of each entry (for the tests)."""
    lib = kernel() if lib is None else lib
    which = {"log": 0, "exp": 1, "expm1": 2}[function]
    x = np.ascontiguousarray(x, dtype=np.float64).ravel()
    out = np.empty_like(x)
    lib.ssmobs_lcd_elementwise(_ptr(x), x.size, which, _ptr(out))
    return out


def e1_psi(c: np.ndarray, lib: ctypes.CDLL | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's E1(c) and psi / (4 B^2) = c E1(c) + 1 - exp(-c) (for the tests)."""
    lib = kernel() if lib is None else lib
    c = np.ascontiguousarray(c, dtype=np.float64).ravel()
    e1 = np.empty_like(c)
    psi = np.empty_like(c)
    lib.ssmobs_lcd_e1_psi(_ptr(c), c.size, _ptr(e1), _ptr(psi))
    return e1, psi


def series_terms(c: np.ndarray, lib: ctypes.CDLL | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's number of E1 series terms of each ``c`` in [0, 1]: by its rule (first
    omitted term <= 1e-17, from products) and by the thresholds its pair loop uses (for the
    test that they agree)."""
    lib = kernel() if lib is None else lib
    c = np.ascontiguousarray(c, dtype=np.float64).ravel()
    reference = np.empty(c.size, dtype=np.intc)
    fast = np.empty(c.size, dtype=np.intc)
    lib.ssmobs_lcd_terms(_ptr(c), c.size, reference.ctypes.data_as(_IP), fast.ctypes.data_as(_IP))
    return reference, fast
