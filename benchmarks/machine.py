"""What machine a benchmark ran on (shared by the benchmark scripts)."""

from __future__ import annotations

import contextlib
import os
import platform
from pathlib import Path


def _proc_field(path: str, key: str) -> str | None:
    with contextlib.suppress(OSError):
        for line in Path(path).read_text().splitlines():
            if line.startswith(key):
                return line.split(":", 1)[1].strip()
    return None


def cpu_model() -> str:
    return _proc_field("/proc/cpuinfo", "model name") or "unknown CPU"


def machine_info() -> str:
    """'N CPUs (nproc), <CPU model>, <RAM>; Python x, NumPy y, SciPy z'."""
    import numpy
    import scipy

    mem = _proc_field("/proc/meminfo", "MemTotal")
    ram = f"{int(mem.split()[0]) / 1024**2:.1f} GiB RAM" if mem else "unknown RAM"
    return (
        f"{os.cpu_count()} CPUs (nproc), {cpu_model()}, {ram}; Python "
        f"{platform.python_version()}, NumPy {numpy.__version__}, SciPy {scipy.__version__}"
    )


def report(text: str, write: bool) -> None:
    """Print a benchmark's Markdown section and, if ``write``, append it to BENCHMARKS.md."""
    print(text)
    if write:
        with open(Path(__file__).resolve().parents[1] / "BENCHMARKS.md", "a") as fh:
            fh.write(text)
