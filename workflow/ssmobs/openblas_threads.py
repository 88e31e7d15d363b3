"""The thread count of the OpenBLAS libraries loaded in this process, set for a while."""

from __future__ import annotations

import ctypes
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import lru_cache

OPENBLAS_THREAD_SYMBOLS = (
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("openblas_get_num_threads", "openblas_set_num_threads"),
)


@lru_cache(maxsize=1)
def openblas_thread_controls() -> tuple[tuple[Callable[[], int], Callable[[int], None]], ...]:
    """(get, set) thread-count functions of the OpenBLAS libraries loaded in this process.

    Found via /proc/self/maps (Linux); empty elsewhere or if nothing is found.
    """
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted(
                {
                    line.split()[-1]
                    for line in fh
                    if "openblas" in line.lower() and line.split()[-1].startswith("/")
                }
            )
    except OSError:
        return ()
    controls = []
    mode = getattr(os, "RTLD_NOLOAD", 0) | getattr(os, "RTLD_NOW", 2)
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=mode)
        except OSError:
            continue
        for get_name, set_name in OPENBLAS_THREAD_SYMBOLS:
            get_fn = getattr(lib, get_name, None)
            set_fn = getattr(lib, set_name, None)
            if get_fn is not None and set_fn is not None:
                get_fn.restype = ctypes.c_int
                get_fn.argtypes = []
                set_fn.restype = None
                set_fn.argtypes = [ctypes.c_int]
                controls.append((get_fn, set_fn))
                break
    return tuple(controls)


@contextmanager
def openblas_threads(n: int | None) -> Iterator[None]:
    """Temporarily set the OpenBLAS thread count (no-op for None or if OpenBLAS is not found).

    The pairwise work is dominated by single-threaded NumPy element-wise loops; multi-threaded
    BLAS gains little on an idle machine and slows the small GEMMs down by 10-25x when the cores
    are shared with other processes (OpenBLAS threads spin), so the optimisation runs with 1.
    """
    saved = []
    if n is not None:
        for get_fn, set_fn in openblas_thread_controls():
            try:
                old = int(get_fn())
                set_fn(int(n))
                saved.append((set_fn, old))
            except Exception:  # pragma: no cover - defensive, foreign library
                continue
    try:
        yield
    finally:
        for set_fn, old in reversed(saved):
            set_fn(old)
