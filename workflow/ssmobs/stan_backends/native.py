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
    :meth:`NativeBackend.compile` runs ``stanc`` and ``g++`` once per (program text, driver
    source, Stan version, compiler version, flags) into
    ``<cache_root>/native/<slug>-<key>/`` (:mod:`.cache`), under an exclusive lock, in a
    temporary directory renamed into place when complete.  A stanc or compiler error raises
    RuntimeError with the tool's own message; nothing is written into the repository.

Sampling
    Data and inits go as JSON into a temporary directory (deleted afterwards, and swept
    when a killed job left one), the driver writes the draws in a binary layout (a short
    text header, then float64 rows per chain) that NumPy maps without parsing.  Exit code 3
    (initialisation failed, exception in the model) raises :class:`SamplingError`, 4 (data
    rejected) ValueError, anything else (a missing library, a killed process)
    :class:`BackendError` with the tail of the driver's messages.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import shutil
import subprocess
import tempfile
import time
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ..io import file_lock, json_default
from . import SAMPLER_COLUMNS, log_captured
from .base import BackendError, Draws, SamplerSettings, SamplingError, check_sample_args
from .cache import cache_root, content_key, owned_tempdir_name, sweep_stale, tail

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
#: binary draws file: magic bytes, then uint32 header length
MAGIC = b"SSMOBSD1"
#: driver exit codes (see driver.cpp)
EXIT_SAMPLER_FAILED, EXIT_DATA_REJECTED = 3, 4
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
def compiler() -> str:
    """The C++ compiler (``$CXX``, default g++)."""
    return os.environ.get("CXX", "g++")


@lru_cache(maxsize=1)
def compiler_version() -> str:
    return _tool_version([compiler(), "--version"])


def build_key(code: str) -> dict[str, str]:
    """Everything that determines the executable (its hash names the cache directory)."""
    return {
        "program": content_key({"code": code}),
        "driver": content_key({"code": DRIVER_SOURCE.read_text()}),
        "stan": stan_version(),
        "compiler": compiler_version(),
        "flags": " ".join(CXXFLAGS + tuple("-D" + d for d in DEFINES)),
    }


def read_draws_file(path: str | os.PathLike) -> tuple[list[str], np.ndarray]:
    """Column names and an array (chain, draw, column) from the driver's output."""
    raw = Path(path).read_bytes()
    if raw[:8] != MAGIC or len(raw) < 12:
        raise BackendError(f"{path}: not a draws file of the native driver")
    n = int.from_bytes(raw[8:12], "little")
    header = dict(line.split("=", 1) for line in raw[12 : 12 + n].decode().splitlines() if line)
    chains, draws = int(header["chains"]), int(header["draws"])
    columns = header["columns"].split(",")
    values = np.frombuffer(raw, dtype="<f8", offset=12 + n)
    if values.size != chains * draws * len(columns):
        raise BackendError(
            f"{path}: {values.size} values, expected {chains} x {draws} x {len(columns)}"
        )
    return columns, values.reshape(chains, draws, len(columns))


def columns_to_draws(columns: list[str], values: np.ndarray) -> Draws:
    """Group Stan's flat columns (``x.1``, ``m.2.3``, column-major) into named arrays."""
    groups: dict[str, list[tuple[tuple[int, ...], int]]] = {}
    for j, col in enumerate(columns):
        name, *idx = col.split(".")
        groups.setdefault(name, []).append((tuple(int(i) for i in idx), j))
    params: dict[str, np.ndarray] = {}
    stats: dict[str, np.ndarray] = {}
    lead = values.shape[:2]
    for name, entries in groups.items():
        if name in SAMPLER_COLUMNS:
            stats[name] = np.ascontiguousarray(values[:, :, entries[0][1]])
            continue
        if not entries[0][0]:
            params[name] = np.ascontiguousarray(values[:, :, entries[0][1]])
            continue
        shape = tuple(max(e[0][d] for e in entries) for d in range(len(entries[0][0])))
        cols = [j for _, j in entries]  # Stan writes arrays column-major
        flat = values[:, :, cols].reshape(lead + shape[::-1])
        axes = tuple(range(2)) + tuple(range(len(shape) + 1, 1, -1))
        params[name] = np.ascontiguousarray(np.transpose(flat, axes))
    return Draws(params=params, sample_stats=stats)


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
        ``compiler``, ``cache_dir``, ``exe_file``.  RuntimeError with stanc's or the
        compiler's message when the program does not build.
        """
        path = Path(stan_file).resolve()
        code = path.read_text()
        memo = (str(path), code)
        if memo in self._markers:
            return self._markers[memo]
        parts = build_key(code)
        cache_dir = cache_root() / "native" / f"{path.stem}-{content_key(parts)}"
        exe = cache_dir / "driver"
        if not exe.is_file():
            cache_dir.parent.mkdir(parents=True, exist_ok=True)
            with file_lock(cache_dir.parent / f".{cache_dir.name}.lock"):
                if not exe.is_file():
                    self._build(path, code, cache_dir, parts)
        marker = {
            "backend": self.name,
            "stan_file": str(path),
            "program_sha256": parts["program"],
            "stan_version": parts["stan"],
            "compiler": parts["compiler"],
            "cache_dir": str(cache_dir),
            "exe_file": str(exe),
        }
        self._markers[memo] = marker
        return marker

    @staticmethod
    def _build(path: Path, code: str, cache_dir: Path, parts: dict[str, str]) -> None:
        """stanc + g++ into a temporary sibling directory, renamed to ``cache_dir``."""
        sweep_stale(cache_dir.parent, f".{cache_dir.name}.tmp-")
        work = Path(
            tempfile.mkdtemp(
                prefix=owned_tempdir_name(f".{cache_dir.name}.tmp-"), dir=cache_dir.parent
            )
        )
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
            cmd = [
                compiler(),
                *CXXFLAGS,
                *("-D" + d for d in DEFINES),
                f'-DSSMOBS_MODEL_HPP="{work / "model.hpp"}"',
                f"-I{hdir / 'include'}",
                "-o",
                str(work / "driver"),
                str(DRIVER_SOURCE),
                f"-L{hdir / 'lib'}",
                "-ltbb",
                f"-Wl,-rpath,{hdir / 'lib'}",
            ]
            try:
                cxx = subprocess.run(cmd, capture_output=True, text=True)
            except OSError as err:
                raise RuntimeError(
                    f"compiling {path} failed: cannot run the C++ compiler {compiler()!r}: {err}"
                ) from err
            if cxx.returncode != 0:
                errors = [ln for ln in cxx.stderr.splitlines() if "error" in ln]
                raise RuntimeError(
                    f"compiling {path} failed ({compiler()} exit "
                    f"{cxx.returncode}):\n" + "\n".join(errors[:20] or [tail(cxx.stderr)])
                )
            log_captured(f"compiler for {path.name}", cxx.stderr)
            (work / "build.json").write_text(
                json.dumps({**parts, "stan_file": str(path), "command": cmd}, indent=1)
            )
            (work / "program.stan").unlink()
            if cache_dir.exists():  # an incomplete directory without the executable
                shutil.rmtree(cache_dir)
            os.replace(work, cache_dir)
            LOG.info("compiled %s in %.1f s", path.name, time.perf_counter() - t0)
        finally:
            shutil.rmtree(work, ignore_errors=True)

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
        """
        t_start = time.perf_counter()
        check_sample_args(seed, settings, inits)
        marker = self.compile(stan_file)
        label = Path(marker["stan_file"]).name
        if not self._swept:
            sweep_stale(self.tmp_root, TMP_PREFIX)
            self._swept = True
        tmp = Path(tempfile.mkdtemp(prefix=owned_tempdir_name(TMP_PREFIX), dir=self.tmp_root))
        try:
            data_file = tmp / "data.json"
            data_file.write_text(json.dumps(dict(data), default=json_default))
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
                "--threads",
                str(min(settings.workers, settings.chains)),
            ]
            for c, init in enumerate(inits or []):
                init_file = tmp / f"init{c + 1}.json"
                init_file.write_text(json.dumps(dict(init), default=json_default))
                cmd += ["--init", str(init_file)]
            out_file = tmp / "draws.bin"
            cmd += ["--discard"] if self.discard else ["--output", str(out_file)]
            before = os.times()
            t0 = time.perf_counter()
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True)
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
            log_captured(f"native driver {label} (seed {seed})", proc.stderr)
            if proc.returncode == EXIT_SAMPLER_FAILED:
                raise SamplingError(f"{label} (seed {seed}): {tail(proc.stderr, 5)}")
            if proc.returncode == EXIT_DATA_REJECTED:
                raise ValueError(f"{label}: data rejected: {tail(proc.stderr, 5)}")
            if proc.returncode != 0:
                why = (
                    f"killed by signal {-proc.returncode}"
                    if proc.returncode < 0
                    else f"exit code {proc.returncode}"
                )
                raise BackendError(
                    f"{label}: the native driver {marker['exe_file']} "
                    f"failed ({why}):\n{tail(proc.stderr)}"
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
        finally:
            with contextlib.suppress(OSError):
                shutil.rmtree(tmp)
        draws.timings = {
            "sample": t_sample,
            "sample_cpu": cpu,
            "convert": t_convert,
            "total": time.perf_counter() - t_start,
        }
        return draws
