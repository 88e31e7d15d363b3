"""Native backend: the Stan programs compiled with httpstan's stanc and Stan sources into a
small executable of ours (``native_driver/driver.cpp``), one process per run.

Why
    PyStan's parent process decodes every draw from JSON (two thirds of a run's CPU time at
    the paper's settings); CmdStan cannot be installed everywhere.  The httpstan wheel that
    pip installs ships ``stanc``, the Stan and Stan Math headers and a built TBB, which is
    all a driver needs.  The driver calls the same service as CmdStan and PyStan
    (``stan::services::sample::hmc_nuts_diag_e_adapt``, chain ids 1..C with one seed, the
    same defaults), so a trajectory gives the same draws, bit for bit, on all three.

Compiling
    :meth:`NativeBackend.compile` runs ``stanc`` and ``g++`` once per :func:`build_key`
    into ``<cache_root>/native/<slug>-<key>/`` (:mod:`.cache`), under an exclusive lock, in a
    temporary directory renamed into place when complete.  The driver is compiled once into
    an object file of its own (:func:`driver_object`, ``<cache_root>/native/driver-<key>/``)
    and linked with each program's object file, so a program costs one compile of the
    stanc-generated C++ only (as CmdStan's ``main.o``).  A stanc or compiler error raises
    RuntimeError with the tool's own message; nothing is written into the repository.

Cached programs are self-contained
    An entry holds the executable ``driver``, the shared libraries it needs from the wheel
    (:data:`RUNTIME_LIBS`, i.e. TBB) copied beside it, and ``build.json`` (key, compiler
    version, command).  The executable's RUNPATH is ``$ORIGIN`` only, so it finds the
    copies wherever the entry is and whether or not the environment that built it still
    exists; at run time it needs only the system's C and C++ runtime (glibc, libstdc++ at
    least as new as the building compiler's, libgcc_s, libm).  Looking a program up runs
    ``stanc --version`` from the wheel but never the C++ compiler, so a node without g++
    uses programs built elsewhere (see :func:`build_key`).

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
import logging
import os
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import stanio

from ..io import json_default
from .base import (
    SAMPLER_COLUMNS,
    BackendError,
    Draws,
    SamplerSettings,
    SamplingError,
    check_sample_args,
    log_captured,
    program_code,
)
from .cache import (
    BUILD_RECORD,
    build_lock,
    cache_root,
    content_key,
    entry_complete,
    new_build_dir,
    owned_tempdir_name,
    publish_entry,
    shared_mode,
    sweep_stale,
    tail,
)

LOG = logging.getLogger("ssmobs.stan")

#: the driver's C++ source
DRIVER_SOURCE = Path(__file__).resolve().parent / "native_driver" / "driver.cpp"
#: preprocessor definitions httpstan builds its models with (same numerics as PyStan)
DEFINES: tuple[str, ...] = (
    "BOOST_DISABLE_ASSERTS",
    "BOOST_PHOENIX_NO_VARIADIC_EXPRESSION",
    "STAN_THREADS",
    "_REENTRANT",
    "_GLIBCXX_USE_CXX11_ABI=0",
)
#: compiler flags (optimisation as httpstan's; C++17 for the driver)
CXXFLAGS: tuple[str, ...] = (
    "-O3",
    "-std=c++17",
    "-Wno-sign-compare",
    "-Wno-ignored-attributes",
    "-Wno-deprecated-declarations",
)
#: linker flags: the executable finds its libraries beside itself, wherever the entry is
LDFLAGS: tuple[str, ...] = ("-Wl,--enable-new-dtags", "-Wl,-rpath,$ORIGIN")
#: shared libraries of the wheel's ``lib/`` the executable needs (copied into the entry)
RUNTIME_LIBS: tuple[str, ...] = ("libtbb.so.2",)
#: the executable's name in a cache entry
EXE_NAME = "driver"
#: the driver's object file in its own cache entry (:func:`driver_object`)
DRIVER_OBJECT = "driver.o"
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


@lru_cache(maxsize=1)
def httpstan_dir() -> Path:
    """The installed httpstan package directory (stanc, include/, lib/)."""
    try:
        import httpstan
    except ImportError as err:  # pragma: no cover - httpstan is a dependency
        raise BackendError(
            "the native backend needs the httpstan wheel (pip install "
            "httpstan): it ships stanc, the Stan sources and TBB"
        ) from err
    return Path(httpstan.__file__).resolve().parent


def _tool_version(cmd: list[str]) -> str:
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as err:
        raise BackendError(f"cannot run {cmd[0]}: {err}") from err
    if out.returncode != 0:
        raise BackendError(f"{' '.join(cmd)} failed: {tail(out.stderr or out.stdout)}")
    return (out.stdout or out.stderr).strip().splitlines()[0]


@lru_cache(maxsize=1)
def stan_version() -> str:
    """stanc's version line, e.g. ``stanc3 v2.35.0 (Unix)``."""
    return _tool_version([str(httpstan_dir() / "stanc"), "--version"])


@lru_cache(maxsize=1)
def httpstan_version() -> str:
    """The httpstan wheel's version (its Stan Math, TBB and headers), read, not run."""
    import httpstan

    return str(getattr(httpstan, "__version__", "unknown"))


def compiler() -> str:
    """The C++ compiler (``$CXX``, default g++)."""
    return os.environ.get("CXX", "g++")


def compiler_version() -> str:
    """The compiler's version line (runs it: only when building)."""
    return _tool_version([compiler(), "--version"])


def build_key(code: str) -> dict[str, str]:
    """What determines the executable; its hash names the cache directory.

    Program text, driver source, Stan version (``stanc --version`` of the wheel, which is
    present wherever this package runs), httpstan version, compiler and linker flags and
    the entry's layout.  Deliberately *not* the C++ compiler, neither its version nor its
    path: the version can only be had by running the compiler and the path only by
    finding it on PATH, and a lookup must work where there is no compiler (a cluster node
    using programs built on the login node), which a key the node cannot compute would
    defeat.  A finished program does not depend on the compiler still being there (it is
    self-contained, see the module docstring), and programs built by different compilers
    from the same sources run the same Stan service with IEEE arithmetic (no
    ``-ffast-math``); the records are keyed by backend and Stan version, not by the
    compiler, in any case.  The compiler's command, path and version are recorded in the
    entry's ``build.json`` (and in the marker) instead; to rebuild with another compiler,
    delete the cache.
    """
    return {
        "program": content_key({"code": code}),
        "objects": "driver.o + model.o",
        "driver": content_key({"code": DRIVER_SOURCE.read_text()}),
        "stan": stan_version(),
        "httpstan": httpstan_version(),
        "flags": " ".join(CXXFLAGS + tuple("-D" + d for d in DEFINES) + LDFLAGS),
        "runtime_libs": ",".join(RUNTIME_LIBS),
    }


def write_json_file(path: Path, obj: Mapping[str, Any]) -> None:
    """A data, init or point file in Stan's JSON (NumPy values converted)."""
    path.write_text(json.dumps(dict(obj), default=json_default))


def run_compiler(cmd: list[str], what: str) -> subprocess.CompletedProcess:
    """Run the C++ compiler; RuntimeError with its error lines when it fails or cannot run."""
    try:
        out = subprocess.run(cmd, capture_output=True, text=True)
    except OSError as err:
        raise RuntimeError(
            f"compiling {what} failed: cannot run the C++ compiler {compiler()!r}: {err}"
        ) from err
    if out.returncode != 0:
        errors = [ln for ln in out.stderr.splitlines() if "error" in ln]
        raise RuntimeError(
            f"compiling {what} failed ({compiler()} exit {out.returncode}):\n"
            + "\n".join(errors[:20] or [tail(out.stderr)])
        )
    return out


def _compile_flags() -> list[str]:
    return [*CXXFLAGS, *("-D" + d for d in DEFINES), f"-I{httpstan_dir() / 'include'}"]


def driver_object() -> Path:
    """The driver compiled once into ``driver.o`` (cached, keyed by the driver's source, the
    Stan version and the flags); every program's executable links it."""
    parts = {
        "driver": content_key({"code": DRIVER_SOURCE.read_text()}),
        "stan": stan_version(),
        "httpstan": httpstan_version(),
        "flags": " ".join(CXXFLAGS + tuple("-D" + d for d in DEFINES)),
    }
    cache_dir = cache_root() / "native" / f"driver-{content_key(parts)}"
    if not entry_complete(cache_dir, DRIVER_OBJECT):
        with build_lock(cache_dir):
            if not entry_complete(cache_dir, DRIVER_OBJECT):
                work = new_build_dir(cache_dir)
                try:
                    t0 = time.perf_counter()
                    LOG.info("compiling the native driver once into %s", cache_dir)
                    cmd = [compiler(), *_compile_flags(), "-c", str(DRIVER_SOURCE)]
                    cmd += ["-o", str(work / DRIVER_OBJECT)]
                    cxx_version = compiler_version()
                    log_captured("compiler for driver.cpp", run_compiler(cmd, "driver.cpp").stderr)
                    publish_entry(work, cache_dir, {**parts, "compiler_version": cxx_version})
                    LOG.info("compiled the native driver in %.1f s", time.perf_counter() - t0)
                finally:
                    shutil.rmtree(work, ignore_errors=True)
    return cache_dir / DRIVER_OBJECT


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


class _Terminated(BaseException):
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
        raise _Terminated()

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    except _Terminated:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)
        raise  # pragma: no cover - the signal ends the process
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _kill_group(proc: subprocess.Popen) -> None:
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


def run_driver(cmd: list[str]) -> tuple[int, str]:
    """Run the driver in its own process group; return (exit code, stdout + stderr).

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
    )
    try:
        out, _ = proc.communicate()
    except BaseException:
        _kill_group(proc)
        raise
    return proc.returncode, out or ""


def _check_self_contained(exe: Path) -> None:
    """Start the new executable without ``LD_LIBRARY_PATH`` (it must stop at its usage
    check): BackendError when the loader cannot find a library beside it."""
    env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
    try:
        out = subprocess.run([str(exe)], capture_output=True, text=True, env=env, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as err:
        raise BackendError(f"the new native driver {exe} does not start: {err}") from err
    if out.returncode != EXIT_USAGE:
        raise BackendError(
            f"the new native driver {exe} does not start on its own (exit code "
            f"{out.returncode}):\n{tail(out.stderr or out.stdout)}"
        )


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


class NativeBackend:
    """Stan backend on our own driver (see the module docstring).

    Parameters
    ----------
    tmp_root : directory for the per-run data and draws files (default: system temp dir).
    discard : run the sampler but keep no draws (benchmarks of the sampler's floor);
        :meth:`sample` then returns empty arrays.
    """

    name = "native"

    def __init__(self, tmp_root: str | os.PathLike | None = None, discard: bool = False) -> None:
        self.tmp_root = Path(tmp_root or tempfile.gettempdir())
        self.discard = discard
        self._markers: dict[tuple[str, str], dict[str, Any]] = {}
        self._swept = False

    def identity(self) -> dict[str, str]:
        return {"backend": self.name, "stan_version": stan_version()}

    # ------------------------------------------------------------------ compile
    def compile(self, stan_file: str | os.PathLike) -> dict[str, Any]:
        """Build the program's executable in the cache (once); return its marker.

        Marker keys: ``backend``, ``stan_file``, ``program_sha256``, ``stan_version``,
        ``compiler`` (the version line recorded at build time), ``cache_dir``,
        ``exe_file``.  Finding a built program runs no compiler.  RuntimeError with stanc's
        or the compiler's message when the program does not build; BackendError when the
        cache cannot be written or the build cannot run (no compiler).
        """
        path = Path(stan_file).resolve()
        code = program_code(path)
        memo = (str(path), code)
        if memo in self._markers:
            return self._markers[memo]
        parts = build_key(code)
        cache_dir = cache_root() / "native" / f"{path.stem}-{content_key(parts)}"
        exe = cache_dir / EXE_NAME
        if not entry_complete(cache_dir, EXE_NAME):
            with build_lock(cache_dir):
                if not entry_complete(cache_dir, EXE_NAME):
                    self._build(path, code, cache_dir, parts)
        try:
            record = json.loads((cache_dir / BUILD_RECORD).read_text())
        except (OSError, ValueError):
            record = {}
        marker = {
            "backend": self.name,
            "stan_file": str(path),
            "program_sha256": parts["program"],
            "stan_version": parts["stan"],
            "compiler": str(record.get("compiler_version", "unknown")),
            "cache_dir": str(cache_dir),
            "exe_file": str(exe),
        }
        self._markers[memo] = marker
        return marker

    @staticmethod
    def _build(path: Path, code: str, cache_dir: Path, parts: dict[str, str]) -> None:
        """stanc + g++ into a temporary sibling directory, with the wheel's runtime
        libraries copied beside the executable, renamed to ``cache_dir``."""
        work = new_build_dir(cache_dir)
        try:
            t0 = time.perf_counter()
            LOG.info(
                "compiling %s with the native backend (%s) into %s",
                path.name,
                parts["stan"],
                cache_dir,
            )
            hdir = httpstan_dir()
            model_name = re.sub(r"\W", "_", path.stem) + "_model"
            (work / "program.stan").write_text(code)
            stanc = subprocess.run(
                [
                    str(hdir / "stanc"),
                    "--name",
                    model_name,
                    "--o",
                    str(work / "model.hpp"),
                    str(work / "program.stan"),
                ],
                capture_output=True,
                text=True,
            )
            if stanc.returncode != 0:
                msg = (stanc.stderr or stanc.stdout).replace(str(work / "program.stan"), str(path))
                raise RuntimeError(f"stanc rejected {path}:\n{msg.strip()}")
            log_captured(f"stanc warnings for {path.name}", stanc.stderr)
            cxx_version = compiler_version()  # BackendError when there is no compiler
            driver_o = driver_object()
            exe = work / EXE_NAME
            model_cmd = [compiler(), *_compile_flags(), "-x", "c++", "-c"]
            model_cmd += [str(work / "model.hpp"), "-o", str(work / "model.o")]
            log_captured(f"compiler for {path.name}", run_compiler(model_cmd, str(path)).stderr)
            link_cmd = [compiler(), str(driver_o), str(work / "model.o"), "-o", str(exe)]
            link_cmd += [f"-L{hdir / 'lib'}", "-ltbb", *LDFLAGS]
            log_captured(f"linker for {path.name}", run_compiler(link_cmd, str(path)).stderr)
            (work / "model.o").unlink()
            for lib in RUNTIME_LIBS:
                shutil.copyfile(hdir / "lib" / lib, work / lib)
                (work / lib).chmod(shared_mode())
            _check_self_contained(exe)
            (work / "program.stan").unlink()
            publish_entry(
                work,
                cache_dir,
                {
                    **parts,
                    "compiler_version": cxx_version,
                    "compiler_path": shutil.which(compiler()),
                    "stan_file": str(path),
                    "command": [model_cmd, link_cmd],
                },
            )
            LOG.info("compiled %s in %.1f s", path.name, time.perf_counter() - t0)
        finally:
            shutil.rmtree(work, ignore_errors=True)

    @contextlib.contextmanager
    def _run_dir(self, data: Mapping[str, Any]) -> Iterator[Path]:
        """A temporary directory holding ``data.json`` for one driver call, removed after
        it (and, on first use, the directories of killed earlier processes swept)."""
        if not self._swept:
            sweep_stale(self.tmp_root, TMP_PREFIX)
            self._swept = True
        tmp = Path(tempfile.mkdtemp(prefix=owned_tempdir_name(TMP_PREFIX), dir=self.tmp_root))
        try:
            write_json_file(tmp / "data.json", data)
            yield tmp
        finally:
            with contextlib.suppress(OSError):
                shutil.rmtree(tmp)

    # ------------------------------------------------------------------ log density
    def log_density(
        self, stan_file: str | os.PathLike, data: Mapping[str, Any], points: list[dict]
    ) -> LogDensities:
        """The model block's log density (no Jacobian, constants kept) and its gradient on
        the unconstrained scale at each point (constrained values, Stan's names), by the
        program's executable in its ``--log-density`` mode: one compile serves sampling and
        the model check.  ValueError when the data are rejected; BackendError otherwise."""
        marker = self.compile(stan_file)
        label = Path(marker["stan_file"]).name
        with self._run_dir(data) as tmp:
            cmd = [marker["exe_file"], "--log-density", "--data", str(tmp / "data.json")]
            for i, point in enumerate(points):
                write_json_file(tmp / f"point{i}.json", point)
                cmd += ["--init", str(tmp / f"point{i}.json")]
            cmd += ["--output", str(tmp / "values.txt"), "--parent-pid", str(os.getpid())]
            try:
                returncode, output = run_driver(cmd)
            except OSError as err:
                raise BackendError(f"{label}: cannot start {marker['exe_file']}: {err}") from err
            if returncode == EXIT_DATA_REJECTED:
                raise ValueError(f"{label}: data rejected: {tail(output, 5)}")
            if returncode != 0:
                raise BackendError(
                    f"{label}: the native driver's log-density mode failed (exit code "
                    f"{returncode}):\n{tail(output)}"
                )
            return LogDensities.parse((tmp / "values.txt").read_text())

    # ------------------------------------------------------------------ sample
    def sample(
        self,
        stan_file: str | os.PathLike,
        data: Mapping[str, Any],
        seed: int,
        settings: SamplerSettings,
        inits: list[dict] | None = None,
    ) -> Draws:
        """Run NUTS and return the post-warmup draws (the contract of the other backends).

        ``settings.workers`` chains run at once (threads of one process).  ``timings``:
        ``sample`` is the driver's wall time, ``sample_cpu`` its CPU time (user + system,
        from the child's rusage), ``convert`` reading the draws, ``total`` the method.
        SIGTERM during the call kills the driver and removes the temporaries before the
        process ends (:func:`sigterm_unwinds`).
        """
        with sigterm_unwinds():
            return self._sample(stan_file, data, seed, settings, inits)

    def _sample(
        self,
        stan_file: str | os.PathLike,
        data: Mapping[str, Any],
        seed: int,
        settings: SamplerSettings,
        inits: list[dict] | None,
    ) -> Draws:
        t_start = time.perf_counter()
        check_sample_args(seed, settings, inits)
        marker = self.compile(stan_file)
        label = Path(marker["stan_file"]).name
        with self._run_dir(data) as tmp:
            data_file = tmp / "data.json"
            cmd = [
                marker["exe_file"],
                "--data",
                str(data_file),
                "--seed",
                str(int(seed)),
                "--chains",
                str(settings.chains),
                "--warmup",
                str(settings.iter_warmup),
                "--samples",
                str(settings.iter_sampling),
                "--delta",
                repr(float(settings.adapt_delta)),
                "--max-depth",
                str(settings.max_treedepth),
                "--init-radius",
                repr(float(settings.init_radius)),
                "--threads",
                str(min(settings.workers, settings.chains)),
                "--parent-pid",
                str(os.getpid()),
            ]
            for c, init in enumerate(inits or []):
                init_file = tmp / f"init{c + 1}.json"
                write_json_file(init_file, init)
                cmd += ["--init", str(init_file)]
            out_file = tmp / "draws.bin"
            cmd += ["--discard"] if self.discard else ["--output", str(out_file)]
            before = os.times()
            t0 = time.perf_counter()
            try:
                returncode, output = run_driver(cmd)
            except OSError as err:
                raise BackendError(
                    f"{label}: cannot start the native driver {marker['exe_file']}: {err}"
                ) from err
            t_sample = time.perf_counter() - t0
            after = os.times()
            cpu = (
                after.children_user
                - before.children_user
                + after.children_system
                - before.children_system
            )
            log_captured(f"native driver {label} (seed {seed})", output)
            if returncode == EXIT_SAMPLER_FAILED:
                raise SamplingError(f"{label} (seed {seed}): {tail(output, 5)}")
            if returncode == EXIT_DATA_REJECTED:
                raise ValueError(f"{label}: data rejected: {tail(output, 5)}")
            if returncode != 0:
                meaning = {
                    EXIT_USAGE: ": bad arguments",
                    EXIT_WRITE_FAILED: ": cannot write the draws",
                    EXIT_INPUT_UNREADABLE: ": cannot open or parse a data or init file",
                }.get(returncode, "")
                why = (
                    f"killed by signal {-returncode}"
                    if returncode < 0
                    else f"exit code {returncode}{meaning}"
                )
                raise BackendError(
                    f"{label}: the native driver {marker['exe_file']} "
                    f"failed ({why}):\n{tail(output)}"
                )
            t0 = time.perf_counter()
            if self.discard:
                draws = Draws(
                    params={},
                    sample_stats={c: np.empty((settings.chains, 0)) for c in SAMPLER_COLUMNS},
                )
            else:
                draws = columns_to_draws(*read_draws_file(out_file))
            t_convert = time.perf_counter() - t0
        draws.timings = {
            "sample": t_sample,
            "sample_cpu": cpu,
            "convert": t_convert,
            "total": time.perf_counter() - t_start,
        }
        return draws
