"""Running the native backend's driver (:mod:`.native`): its input files, its process group
(killed with the call) and the draws and log densities it writes.

Sampling
    Data and inits go as JSON into a temporary directory (deleted afterwards, and swept
    when a killed job left one), the driver writes the draws in a binary layout (a short
    text header, then little-endian float64 rows per chain) that NumPy maps without
    parsing.  The driver runs in its own process group, killed with the group when the
    call is interrupted (an exception, KeyboardInterrupt, SIGTERM; see :func:`run_driver`),
    and on Linux it dies with its parent (``PR_SET_PDEATHSIG``).  Exit code 3
    (initialisation failed, exception in the model) raises :class:`SamplingError`, 4 (the
    model rejected the data) ValueError, anything else (6: an input file cannot be read or
    parsed, a missing library, a killed process) :class:`BackendError` with the tail of the
    driver's messages.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import stanio

from ..io import json_default
from .base import SAMPLER_COLUMNS, BackendError, Draws

#: binary draws file: magic bytes, then uint32 header length (little-endian)
MAGIC = b"SSMOBSD1"
#: the fields of the draws file's header, all required
HEADER_FIELDS: tuple[str, ...] = ("byteorder", "chains", "draws", "columns")
#: driver exit codes (see driver.cpp)
EXIT_USAGE = 2
EXIT_SAMPLER_FAILED = 3
EXIT_DATA_REJECTED = 4
EXIT_WRITE_FAILED = 5
EXIT_INPUT_UNREADABLE = 6
EXIT_ORPHANED = 7
TMP_PREFIX = "ssmobs-native-"
#: glibc keeps 7 freed blocks per size for a thread to reuse; a NUTS step frees and
#: allocates more Eigen vectors of one size than that, so the rest took malloc's slow path
#: (BENCHMARKS.md, "NUTS per step: Stan's machinery before and after").  Allocation does
#: not touch a result.
MALLOC_TUNABLE = "glibc.malloc.tcache_count=1024"


def write_json_file(path: Path, obj: Mapping[str, Any]) -> None:
    """A data, init or point file in Stan's JSON (NumPy values converted)."""
    path.write_text(json.dumps(dict(obj), default=json_default))


def read_draws_file(path: str | os.PathLike) -> tuple[list[str], np.ndarray]:
    """Column names and an array (chain, draw, column) from the driver's output.

    Layout (driver.cpp): ``MAGIC``, uint32 header length (little-endian), the header text
    (``key=value`` lines: ``byteorder=little``, ``chains``, ``draws``, ``columns`` comma
    separated), then chains x draws x columns little-endian float64.  Every field is
    checked; a file that does not match raises BackendError naming the field.
    """

    def bad(field: str, why: str) -> BackendError:
        return BackendError(f"{path}: draws file of the native driver: {field}: {why}")

    try:
        raw = Path(path).read_bytes()
    except OSError as err:
        raise BackendError(f"{path}: cannot read the draws file: {err}") from err
    if raw[:8] != MAGIC:
        raise bad("magic", f"expected {MAGIC!r}, found {raw[:8]!r}")
    if len(raw) < 12:
        raise bad("header length", f"file ends after {len(raw)} bytes")
    n = int.from_bytes(raw[8:12], "little")
    if 12 + n > len(raw):
        raise bad("header length", f"{n} bytes, but only {len(raw) - 12} follow")
    try:
        text = raw[12 : 12 + n].decode("utf-8")
    except UnicodeDecodeError as err:
        raise bad("header", f"not UTF-8 text ({err})") from err
    header: dict[str, str] = {}
    for line in text.splitlines():
        if not line:
            continue
        key, sep, value = line.partition("=")
        if not sep:
            raise bad("header", f"line {line!r} is not key=value")
        if key not in HEADER_FIELDS:
            raise bad(key, f"unknown field (expected {', '.join(HEADER_FIELDS)})")
        if key in header:
            raise bad(key, "given twice")
        header[key] = value
    for key in HEADER_FIELDS:
        if key not in header:
            raise bad(key, "missing")
    if header["byteorder"] != "little":
        raise bad("byteorder", f"{header['byteorder']!r}, expected 'little'")
    counts = {}
    for key in ("chains", "draws"):
        value = header[key]
        if not (value.isascii() and value.isdigit() and int(value) > 0):
            raise bad(key, f"{value!r} is not a positive integer")
        counts[key] = int(value)
    columns = header["columns"].split(",")
    if not all(columns):
        raise bad("columns", f"empty column name in {header['columns']!r}")
    if len(set(columns)) != len(columns):
        raise bad("columns", "duplicate column names")
    chains, draws = counts["chains"], counts["draws"]
    size = len(raw) - 12 - n
    expected = chains * draws * len(columns) * 8
    if size != expected:
        raise bad(
            "values",
            f"{size} bytes, expected {chains} chains x {draws} draws x {len(columns)} "
            f"columns x 8 = {expected}",
        )
    values = np.frombuffer(raw, dtype="<f8", offset=12 + n)
    return columns, values.reshape(chains, draws, len(columns))


def columns_to_draws(columns: list[str], values: np.ndarray) -> Draws:
    """Group Stan's flat columns (``x.1``, ``m.2.3``, column-major) into named arrays of
    shape (chain, draw, *dims), by stanio's parser of Stan's output names."""
    params: dict[str, np.ndarray] = {}
    stats: dict[str, np.ndarray] = {}
    for name, var in stanio.parse_header(",".join(columns)).items():
        arr = np.ascontiguousarray(var.extract_reshape(values))
        (stats if name in SAMPLER_COLUMNS else params)[name] = arr
    return Draws(params=params, sample_stats=stats)


class Terminated(BaseException):
    """SIGTERM arrived during :meth:`NativeBackend.sample` (see :func:`sigterm_unwinds`)."""


@contextlib.contextmanager
def sigterm_unwinds() -> Iterator[None]:
    """Within the block, SIGTERM unwinds (so the driver is killed and temporaries removed)
    and then terminates the process as it would have without the block.

    Only in the main thread and only while SIGTERM has its default action: a handler
    someone installed is left alone (it decides), as is an ignored SIGTERM.
    """
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
    ):
        yield
        return

    def handler(signum: int, frame: object) -> None:
        raise Terminated()

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    except Terminated:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)
        raise  # pragma: no cover - the signal ends the process
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL the child's process group (the child leads it) and reap the child."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
    while True:
        try:
            proc.wait()
            return
        except KeyboardInterrupt:  # a second Ctrl-C: still reap the killed child
            continue


def driver_environment(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """``env`` (default: this process's) with :data:`MALLOC_TUNABLE` added to
    ``GLIBC_TUNABLES`` unless that already sets the tcache count (other C libraries ignore
    the variable)."""
    out = dict(os.environ if env is None else env)
    tunables = out.get("GLIBC_TUNABLES", "")
    if "glibc.malloc.tcache_count=" not in tunables:
        out["GLIBC_TUNABLES"] = ":".join(t for t in (tunables, MALLOC_TUNABLE) if t)
    return out


def run_driver(cmd: list[str]) -> tuple[int, str]:
    """Run the driver in its own process group, in :func:`driver_environment`; return
    (exit code, stdout + stderr).

    Any exception while it runs (KeyboardInterrupt, SIGTERM under
    :func:`sigterm_unwinds`) kills the group before propagating, so no driver outlives the
    call.  OSError when it cannot be started.
    """
    proc = subprocess.Popen(
        cmd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        errors="replace",
        process_group=0,
        env=driver_environment(),
    )
    try:
        out, _ = proc.communicate()
    except BaseException:
        kill_group(proc)
        raise
    return proc.returncode, out or ""


@dataclass
class LogDensities:
    """What the driver's ``--log-density`` mode wrote: the parameters' names and shapes,
    and per point the log density and gradient (None where the model rejects the point)."""

    param_names: list[str]
    dims: list[list[int]]
    values: list[float | None]
    gradients: list[list[float] | None]
    messages: list[str]

    @classmethod
    def parse(cls, text: str) -> LogDensities:
        out = cls([], [], [], [], [])
        for line in text.splitlines():
            kind, _, rest = line.partition(" ")
            if kind == "param":
                name, *sizes = rest.split()
                out.param_names.append(name)
                out.dims.append([int(n) for n in sizes])
            elif kind == "ok":
                lp, *grad = (float(v) for v in rest.split())
                out.values.append(lp if np.isfinite(lp) else None)
                out.gradients.append(grad)
                out.messages.append("")
            elif kind == "rejected":
                out.values.append(None)
                out.gradients.append(None)
                out.messages.append(rest)
            else:
                raise BackendError(f"unexpected line in the driver's log-density output: {line!r}")
        return out
