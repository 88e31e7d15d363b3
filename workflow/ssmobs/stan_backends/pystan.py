"""PyStan 3 backend (pystan 3.10 + httpstan 4.13, embedded in this process).

Compiling
    :meth:`PyStanBackend.compile` builds the program once into the *shared* httpstan
    cache (``$XDG_CACHE_HOME/httpstan/<version>/models/<id>/``, default ``~/.cache``)
    under an exclusive ``fcntl.flock`` lock, so concurrent jobs never compile the same
    program into the same directory at once.  No data is needed to compile.

Sampling
    httpstan keeps every seeded fit as ``models/<id>/fits/<fit>.jsonlines.gz`` (28 MB for
    T=20, 127 MB for T=100 with the paper's settings) and returns it from there on an
    identical repeat call.  Sampling therefore runs with a *private* ``XDG_CACHE_HOME``
    (a temporary directory, one per process) whose ``httpstan/<version>/models/<id>/``
    holds symlinks to the shared model's files (never to ``fits/``): the build finds the
    compiled model at once and the fit lands in the private directory.  After every call,
    also a failed one, its ``fits/`` are deleted, so seeded fits never accumulate; the
    directory itself goes at process exit.  httpstan's per-chain Unix socket files (which
    it never deletes) are put there too via ``tempfile.tempdir`` and deleted as well.

    Why one private directory per process and not per call: the compiled model is a
    pybind11 extension; loading the same ``.so`` through a second path initialises it
    twice and the interpreter aborts at exit ("double free or corruption").  For the same
    reason, direct PyStan use in a process that samples through this backend must go
    through :meth:`PyStanBackend.session`.

    Programs are built with httpstan's own functions, not through its HTTP server, whose
    client (PyStan's) gives up after 300 s.  httpstan gives ``stanc`` one second
    (``subprocess.run(..., timeout=1)`` in ``httpstan.compile``); on a loaded machine its
    start-up alone can take longer and the build fails with ``TimeoutExpired``.
    :func:`_patient_stanc` gives it :data:`STANC_TIMEOUT` seconds instead, for httpstan's
    module only.

    The chains run in a process pool of ``settings.workers`` processes made for the call
    (``httpstan.services_stub.executor`` is replaced and restored; there is no public
    option, pystan issue #349).

    PyStan's flat draws interleave chains (chain varies fastest); they are reshaped to
    ``(chain, draw, *shape)``.

The process-wide state touched here (environment, ``tempfile.tempdir``, the executor) makes
one call at a time per process; a lock enforces that for threads.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import logging
import multiprocessing as mp
import os
import re
import shutil
import threading
import time
from collections.abc import Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path
from typing import Any

import numpy as np

from ..io import file_lock
from .base import (
    SAMPLER_COLUMNS,
    Draws,
    SamplerSettings,
    SamplingError,
    check_sample_args,
    log_captured,
    program_code,
    quiet_loggers,
)
from .pystan_cache import private_cache, shared_cache_env

LOG = logging.getLogger("ssmobs.stan")

#: one sampling call at a time per process (environment and module globals are shared)
_CALL_LOCK = threading.RLock()
#: seconds stanc may take when httpstan translates a program (httpstan's own limit is 1 s)
STANC_TIMEOUT = 120.0


class _PatientSubprocess:
    """The ``subprocess`` module as ``httpstan.compile`` sees it, with a longer timeout."""

    def __getattr__(self, name: str) -> Any:
        import subprocess

        return getattr(subprocess, name)

    @staticmethod
    def run(*args: Any, timeout: float | None = None, **kwargs: Any) -> Any:
        import subprocess

        if timeout is not None:
            timeout = max(timeout, STANC_TIMEOUT)
        return subprocess.run(*args, timeout=timeout, **kwargs)


def _patient_stanc() -> None:
    """Give httpstan's stanc call :data:`STANC_TIMEOUT` seconds (idempotent)."""
    import httpstan.compile

    if not isinstance(httpstan.compile.subprocess, _PatientSubprocess):
        httpstan.compile.subprocess = _PatientSubprocess()  # type: ignore[assignment]


def program_sha256(code: str) -> str:
    return hashlib.sha256(code.encode()).hexdigest()


def _build_complete(directory: Path) -> bool:
    """True when httpstan finished building into ``directory``: the extension module and
    the compiler log, which httpstan writes after the module (a build killed in between
    leaves a module that httpstan loads and then fails on the missing log)."""
    try:
        names = [p for p in directory.iterdir()]
    except FileNotFoundError:
        return False
    return any(p.suffix in EXTENSION_SUFFIXES for p in names) and any(
        p.name == "stderr.log" for p in names
    )


@contextlib.contextmanager
def _captured(label: str) -> Iterator[io.StringIO]:
    """Capture stdout and stderr (PyStan's progress and stanc messages) for the log."""
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            yield buf
    finally:
        log_captured(label, buf.getvalue())


@contextlib.contextmanager
def _chain_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """Replace httpstan's module-global chain pool by one of ``workers`` processes."""
    import httpstan.services_stub as ss

    old = ss.executor
    pool = ProcessPoolExecutor(
        max_workers=workers, mp_context=mp.get_context("fork"), initializer=ss.init_worker
    )
    ss.executor = pool
    ok = False
    try:
        yield pool
        ok = True
    finally:
        ss.executor = old
        if not ok:  # chains may still run after an error or interrupt: stop them
            for proc in list(getattr(pool, "_processes", {}).values()):
                with contextlib.suppress(Exception):
                    proc.terminate()
        pool.shutdown(wait=True, cancel_futures=True)


def _to_chain_draw(
    arr: np.ndarray, shape: tuple[int, ...], n_draws: int, n_chains: int
) -> np.ndarray:
    """PyStan's ``fit[name]`` (shape + (draws*chains,), chain fastest) -> (chain, draw, *shape)."""
    arr = np.asarray(arr).reshape(shape + (n_draws, n_chains))
    return np.ascontiguousarray(np.moveaxis(arr, (-1, -2), (0, 1)))


def fit_to_draws(fit: Any, n_chains: int, n_draws: int) -> Draws:
    """Convert a ``stan.fit.Fit`` to :class:`Draws` (chain-major arrays)."""
    params = {}
    for name, dims in zip(fit.param_names, fit.dims):
        params[name] = _to_chain_draw(fit[name], tuple(int(d) for d in dims), n_draws, n_chains)
    stats = {}
    for name in SAMPLER_COLUMNS:
        if name in fit.sample_and_sampler_param_names:
            stats[name] = _to_chain_draw(fit[name], (), n_draws, n_chains)
    return Draws(params=params, sample_stats=stats)


def _failure_reason(err: BaseException) -> str:
    """Stan's own message from a PyStan/httpstan error, without httpstan's wrapping."""
    text = str(err).strip() or type(err).__name__
    text = re.sub(r",\s*traceback:\s*`\[.*\]`\s*$", "", text, flags=re.S)
    inner = re.search(r"`\w*(?:Error|Exception)\((['\"])(.*)\1\)`", text, flags=re.S)
    if inner:
        text = inner.group(2)
    return " ".join(text.replace("\\n", " ").split())


def _no_user_header(user_header: str | os.PathLike | None) -> None:
    if user_header is not None:
        raise ValueError(
            "the pystan backend takes no external C++ header (stan.gradients 'analytic' "
            "needs the native or cmdstanpy backend)"
        )


class PyStanBackend:
    """Stan backend on PyStan 3 (see the module docstring for cache and pool handling).

    Parameters
    ----------
    tmp_root : where this process's private httpstan cache is made (default: the system
        temp dir); only the first use in a process decides.  A fit with the paper's
        settings and T=100 takes about 130 MB there while it is read.
    refresh : Stan's progress-message interval; 0 (default) sends none.
    """

    name = "pystan"

    def identity(self) -> dict[str, str]:
        import httpstan

        return {"backend": self.name, "stan_version": f"httpstan {httpstan.__version__}"}

    def __init__(self, tmp_root: str | os.PathLike | None = None, refresh: int = 0) -> None:
        self.tmp_root = None if tmp_root is None else str(tmp_root)
        self.refresh = int(refresh)
        self._markers: dict[tuple[str, str], dict[str, Any]] = {}

    # ------------------------------------------------------------------ compile
    def compile(
        self, stan_file: str | os.PathLike, user_header: str | os.PathLike | None = None
    ) -> dict[str, Any]:
        """Build the program into the shared httpstan cache (once); return its marker.

        The marker is JSON-able and deterministic for a given program and installation:
        ``backend``, ``stan_file``, ``program_sha256``, ``model_name`` (httpstan's
        ``models/<id>``), ``cache_dir`` (the shared model directory), ``pystan_version``,
        ``httpstan_version``.  Raises RuntimeError with stanc's/the compiler's message when
        the program does not compile.  PyStan takes no external C++: a ``user_header``
        raises ValueError (config key ``stan.gradients`` must be ``autodiff`` here).
        """
        _no_user_header(user_header)
        import httpstan
        import httpstan.cache
        import httpstan.models

        import stan

        _patient_stanc()
        path = Path(stan_file).resolve()
        code = program_code(path)
        sha = program_sha256(code)
        key = (str(path), sha)
        if key in self._markers:
            return self._markers[key]
        model_name = httpstan.models.calculate_model_name(code)
        model_id = model_name.split("/")[1]
        with _CALL_LOCK, shared_cache_env():
            cache_dir = httpstan.cache.cache_directory()
            model_dir = httpstan.cache.model_directory(model_name)
            if not _build_complete(model_dir):
                with file_lock(cache_dir / "ssmobs-locks" / f"{model_id}.lock"):
                    if not _build_complete(model_dir):  # another process may have built it
                        # a killed build's leftovers would be taken for a finished one
                        shutil.rmtree(model_dir, ignore_errors=True)
                        LOG.info("compiling %s into %s (about a minute)", path.name, model_dir)
                        t0 = time.perf_counter()
                        self._build_program(code, path)
                        LOG.info("compiled %s in %.1f s", path.name, time.perf_counter() - t0)
        marker = {
            "backend": self.name,
            "stan_file": str(path),
            "program_sha256": sha,
            "model_name": model_name,
            "cache_dir": str(model_dir),
            # mypy resolves `stan` to the repository's stan/ folder (pystan has no stubs)
            "pystan_version": stan.__version__,  # type: ignore[attr-defined]
            "httpstan_version": httpstan.__version__,
        }
        self._markers[key] = marker
        return marker

    @staticmethod
    def _build_program(code: str, path: Path) -> None:
        """Build the program into httpstan's cache with httpstan's own steps (those of its
        ``POST /models`` handler: stanc, then the extension module, then the logs), called
        directly: through HTTP, PyStan's client gives up after 300 s, which a build on a
        loaded machine exceeds."""
        import asyncio

        import httpstan.cache
        import httpstan.compile
        import httpstan.models

        model_name = httpstan.models.calculate_model_name(code)
        httpstan.cache.delete_model_directory(model_name)
        out = io.StringIO()
        # stderr stays the real one: httpstan then sends the compiler's messages (which
        # g++ writes to file descriptor 2) to a file instead, and returns them
        with (
            contextlib.redirect_stdout(out),
            quiet_loggers(forward=("httpstan",), mute=("aiohttp",)),
        ):
            try:
                _, stanc_warnings = httpstan.compile.compile(
                    code, f"model_{model_name.split('/')[1]}"
                )
            except ValueError as err:  # stanc's syntax or semantic error
                raise RuntimeError(f"compiling {path} failed: {err}") from err
            httpstan.cache.dump_stanc_warnings(stanc_warnings, model_name)
            compiler_output = asyncio.run(httpstan.models.build_services_extension_module(code))
            httpstan.cache.dump_services_extension_module_compiler_output(
                compiler_output, model_name
            )
        log_captured(f"httpstan build {path.name}", out.getvalue())
        log_captured(f"stanc warnings for {path.name}", stanc_warnings or "")
        log_captured(f"compiler for {path.name}", compiler_output or "")

    # ------------------------------------------------------------------ sessions
    @contextlib.contextmanager
    def _session(self, marker: Mapping[str, Any]) -> Iterator[Path]:
        with (
            _CALL_LOCK,
            private_cache(self.tmp_root).active(
                Path(marker["cache_dir"]), marker["model_name"]
            ) as model_dir,
            quiet_loggers(forward=("httpstan",), mute=("aiohttp",)),
        ):
            yield model_dir

    @contextlib.contextmanager
    def session(self, stan_file: str | os.PathLike) -> Iterator[dict[str, Any]]:
        """Compile if needed, then make httpstan use this process's private cache.

        Use it around any direct PyStan use in a process that also samples through this
        backend (``stan.build`` and every method of the returned model, e.g. ``log_prob``):
        a compiled model must always be loaded from the same path within a process.
        Yields the compile marker.
        """
        marker = self.compile(stan_file)
        with self._session(marker):
            yield marker

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
        """Run NUTS (``hmc_nuts_diag_e_adapt``) and return the post-warmup draws.

        ``seed`` is Stan's random seed (0 <= seed < 2**32; chains get ids 1..chains).
        ``inits``: one dict per chain (partial dicts allowed; missing parameters start at
        Stan's random inits, uniform(-2, 2) on the unconstrained scale) or None (random
        inits, the paper's choice).  ``timings``: ``sample`` is the ``posterior.sample``
        call, ``build`` the cached build with the data, ``convert`` the reshaping,
        ``total`` the whole method including the private cache and pool set-up/teardown.

        Raises SamplingError when Stan cannot initialise or fails while sampling,
        ValueError when the data are rejected (missing keys, empty prior support) or the
        arguments are invalid (a ``user_header``: PyStan keeps Stan's autodiff).
        """
        _no_user_header(user_header)
        import stan

        t_start = time.perf_counter()
        check_sample_args(seed, settings, inits)
        marker = self.compile(stan_file)
        code = program_code(marker["stan_file"])
        kwargs: dict[str, Any] = dict(
            num_chains=settings.chains,
            num_warmup=settings.iter_warmup,
            num_samples=settings.iter_sampling,
            delta=settings.adapt_delta,
            max_depth=settings.max_treedepth,
            init_radius=settings.init_radius,
            refresh=self.refresh,
        )
        if inits is not None:
            kwargs["init"] = [dict(i) for i in inits]
        label = Path(marker["stan_file"]).name
        with self._session(marker):
            with _captured(f"pystan build {label}"):
                t0 = time.perf_counter()
                try:
                    # mypy resolves `stan` to the repository's stan/ folder (no pystan stubs)
                    posterior = stan.build(  # type: ignore[attr-defined]
                        code, data=dict(data), random_seed=int(seed)
                    )
                except (RuntimeError, ValueError) as err:
                    raise ValueError(f"{label}: data rejected: {_failure_reason(err)}") from err
                if posterior is None:  # pystan swallows KeyboardInterrupt
                    raise KeyboardInterrupt
                t_build = time.perf_counter() - t0
            with _chain_pool(settings.workers), _captured(f"pystan sample {label}"):
                t0 = time.perf_counter()
                try:
                    fit = posterior.sample(**kwargs)
                except RuntimeError as err:
                    raise SamplingError(f"{label} (seed {seed}): {_failure_reason(err)}") from err
                if fit is None:
                    raise KeyboardInterrupt
                t_sample = time.perf_counter() - t0
        t0 = time.perf_counter()
        draws = fit_to_draws(fit, settings.chains, settings.iter_sampling)
        del fit
        t_convert = time.perf_counter() - t0
        draws.timings = {
            "build": t_build,
            "sample": t_sample,
            "convert": t_convert,
            "total": time.perf_counter() - t_start,
        }
        return draws
