"""Native backend: the Stan programs compiled with httpstan's stanc and Stan sources into a
small executable of ours (``native_driver/driver.cpp``), one process per run.

Why
    PyStan's parent process decodes every draw from JSON (two thirds of a run's CPU time at
    the paper's settings); CmdStan cannot be installed everywhere.  The httpstan wheel that
    pip installs ships ``stanc``, the Stan and Stan Math headers and a built TBB, which is
    all a driver needs.  The driver calls the same service as CmdStan and PyStan
    (``stan::services::sample::hmc_nuts_diag_e_adapt``, chain ids 1..C with one seed, the
    same defaults), so a trajectory gives the same draws, bit for bit, on all three.

Building a program (stanc, the C++ compiler, the cache entries) is in :mod:`.native_build`,
running the driver (its process group, the draws file, the log densities) in
:mod:`.native_run`; this module holds the backend that puts them together.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

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
    cache_root,
    content_key,
    ensure_entry,
    entry_complete,
    owned_tempdir_name,
    sweep_stale,
    tail,
    verified,
)
from .native_build import EXE_NAME, PROGRAM_ARTEFACTS, build_key, build_program, stan_version
from .native_run import (
    EXIT_DATA_REJECTED,
    EXIT_INPUT_UNREADABLE,
    EXIT_SAMPLER_FAILED,
    EXIT_USAGE,
    EXIT_WRITE_FAILED,
    TMP_PREFIX,
    LogDensities,
    columns_to_draws,
    read_draws_file,
    run_driver,
    sigterm_unwinds,
    write_json_file,
)


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
    def compile(
        self, stan_file: str | os.PathLike, user_header: str | os.PathLike | None = None
    ) -> dict[str, Any]:
        """Build the program's executable in the cache (once); return its marker.

        Marker keys: ``backend``, ``stan_file``, ``program_sha256``, ``stan_version``,
        ``compiler`` (the version line recorded at build time), ``cache_dir``,
        ``exe_file``.  Finding a built program runs no compiler.  Every call (each run
        calls it) verifies the executable and its libraries against their checksums
        (:mod:`.cache`): a damaged entry is rebuilt, or refused in one line where it cannot
        be.  RuntimeError with stanc's
        or the compiler's message when the program does not build; BackendError when the
        cache cannot be written or the build cannot run (no compiler).  ``user_header``: a
        C++ header defining the program's external functions (keyed with the program).
        """
        path = Path(stan_file).resolve()
        code = program_code(path)
        header = None if user_header is None else Path(user_header).resolve()
        header_text = None if header is None else header.read_text()
        memo = (str(path), code + "\n" + (header_text or ""))
        known = self._markers.get(memo)
        if known is not None and all(
            verified(Path(known["cache_dir"]) / name) for name in PROGRAM_ARTEFACTS
        ):
            return known
        parts = build_key(code, header_text)
        cache_dir = self._cache_dir(path, parts)
        exe = cache_dir / EXE_NAME
        ensure_entry(
            cache_dir,
            PROGRAM_ARTEFACTS,
            lambda: build_program(path, code, cache_dir, parts, header),
        )
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
            **({} if header is None else {"user_header": str(header)}),
        }
        self._markers[memo] = marker
        return marker

    @staticmethod
    def _cache_dir(path: Path, parts: Mapping[str, str]) -> Path:
        """The program's cache entry, named by its stem and :func:`build_key`."""
        return cache_root() / "native" / f"{path.stem}-{content_key(dict(parts))}"

    def is_built(
        self, stan_file: str | os.PathLike, user_header: str | os.PathLike | None = None
    ) -> bool:
        """Whether the program's executable is in the cache already (runs no compiler)."""
        path = Path(stan_file).resolve()
        header = None if user_header is None else Path(user_header).read_text()
        parts = build_key(program_code(path), header)
        return entry_complete(self._cache_dir(path, parts), *PROGRAM_ARTEFACTS)

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
        self,
        stan_file: str | os.PathLike,
        data: Mapping[str, Any],
        points: list[dict],
        user_header: str | os.PathLike | None = None,
        sampler: bool = False,
        twin: bool = False,
    ) -> LogDensities:
        """The model block's log density (no Jacobian, constants kept) and its gradient on
        the unconstrained scale at each point (constrained values, Stan's names), by the
        program's executable in its ``--log-density`` mode: one compile serves sampling and
        the model check.  ``sampler``: instead the log density and gradient the NUTS sampler
        takes (Jacobian included, constants dropped; for a generated program the gradient
        without the tape).  ``twin``: a program holding both model blocks
        (:func:`ssmobs.nuts.analytic_program.analytic_stan_code`) evaluates its hand-written
        one under Stan's autodiff.  ValueError when the data are rejected; BackendError
        otherwise."""
        marker = self.compile(stan_file, user_header)
        label = Path(marker["stan_file"]).name
        with self._run_dir(data) as tmp:
            cmd = [marker["exe_file"], "--log-density", "--data", str(tmp / "data.json")]
            if sampler:
                cmd.append("--sampler-gradient")
            if twin:
                cmd.append("--autodiff-twin")
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
        user_header: str | os.PathLike | None = None,
    ) -> Draws:
        """Run NUTS and return the post-warmup draws (the contract of the other backends).

        ``settings.workers`` chains run at once (threads of one process).  ``timings``:
        ``sample`` is the driver's wall time, ``sample_cpu`` its CPU time (user + system,
        from the child's rusage), ``convert`` reading the draws, ``total`` the method.
        SIGTERM during the call kills the driver and removes the temporaries before the
        process ends (:func:`sigterm_unwinds`).
        """
        with sigterm_unwinds():
            return self._sample(stan_file, data, seed, settings, inits, user_header)

    def _sample(
        self,
        stan_file: str | os.PathLike,
        data: Mapping[str, Any],
        seed: int,
        settings: SamplerSettings,
        inits: list[dict] | None,
        user_header: str | os.PathLike | None = None,
    ) -> Draws:
        t_start = time.perf_counter()
        check_sample_args(seed, settings, inits)
        marker = self.compile(stan_file, user_header)
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
