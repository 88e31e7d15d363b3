"""cmdstanpy backend (used when a CmdStan installation exists; see :func:`have_cmdstan`).

Compiling
    cmdstanpy writes the executable next to the ``.stan`` file and decides to recompile by
    comparing timestamps only.  :meth:`CmdStanPyBackend.compile` therefore copies the
    program into a cache directory keyed by everything that determines the binary: the
    program, the CmdStan installation's path and full version (from its makefile) and its
    ``make/local``, ``<cache_root>/cmdstan/<slug>-<key>/`` (:mod:`.cache`), and compiles
    once, under an exclusive lock, in a temporary sibling directory renamed into place when
    the executable and the build record are complete: an entry under its final name is
    always finished (a half-written executable of a killed build is never taken for one).
    The executable carries a checksum written at build time and verified before each use
    (:mod:`.cache`): a replaced or damaged one is rebuilt, never run.
    The repository's ``stan/`` stays free of executables.

Sampling
    Each call writes the data JSON and CmdStan's CSV and console files into a temporary
    directory that is deleted afterwards (also on errors; a killed job's directory is swept
    by the next call), so nothing accumulates; progress bars are off and cmdstanpy's log
    goes to DEBUG.  Names map from :class:`SamplerSettings`: ``workers`` ->
    ``parallel_chains``, ``iter_warmup``, ``iter_sampling``, ``adapt_delta``,
    ``max_treedepth`` as they are.  CSV output is written at full double precision
    (``sig_figs=18``; CmdStan's default is 6 significant digits).

Failures
    CmdStan's own failure on these data (initialisation failed, an exception in the model)
    raises :class:`SamplingError`; anything else (a missing shared library, exit code 127,
    a killed process) raises :class:`BackendError` with the tail of CmdStan's console
    output, so the job fails instead of writing per-trajectory error records.
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import shutil
import tempfile
import time
from collections.abc import Mapping
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
    program_code,
    quiet_loggers,
)
from .cache import (
    cache_root,
    content_key,
    ensure_entry,
    new_build_dir,
    owned_tempdir_name,
    publish_entry,
    sweep_stale,
    tail,
    verified,
)

LOG = logging.getLogger("ssmobs.stan")

#: CSV digits: full double precision
SIG_FIGS = 18
TMP_PREFIX = "ssmobs-cmdstan-"
#: CmdStan console text that means the sampler failed on these data (not the installation)
SAMPLER_FAILURE = re.compile(
    r"Initialization failed|Rejecting initial value|"
    r"Exception:|Error evaluating the log probability",
    re.I,
)


def cmdstan_identity(path: str | os.PathLike) -> dict[str, str]:
    """Path, full version (``CMDSTAN_VERSION`` in the makefile) and ``make/local`` hash."""
    root = Path(path)
    version = "unknown"
    try:
        found = re.search(r"^CMDSTAN_VERSION\s*:?=\s*(\S+)", (root / "makefile").read_text(), re.M)
        version = found.group(1) if found else version
    except OSError:
        pass
    try:
        local = (root / "make" / "local").read_text()
    except OSError:
        local = ""
    return {
        "cmdstan_path": str(root.resolve()),
        "cmdstan_version": version,
        "make_local": hashlib.sha256(local.encode()).hexdigest()[:16],
    }


def _console_tail(directory: Path) -> str:
    """The last lines of CmdStan's console files in ``directory`` (read before deletion)."""
    texts = []
    for f in sorted(directory.rglob("*stdout*.txt")) + sorted(directory.rglob("*.err")):
        try:
            texts.append(f"[{f.name}]\n" + tail(f.read_text(errors="replace"), 8))
        except OSError:
            continue
    return "\n".join(texts)


def fit_to_draws(fit: Any) -> Draws:
    """Convert a ``CmdStanMCMC`` to :class:`Draws` (arrays (chain, draw, *shape)).

    Uses ``fit.draws(concat_chains=False)`` (draws, chains, columns), the program
    variables of ``fit.metadata.stan_vars`` (stanio variables, reshaped column-major as
    CmdStan writes them) and the sampler columns of ``fit.method_variables()``.
    """
    draws = np.asarray(fit.draws(concat_chains=False))
    params = {}
    for name, var in fit.metadata.stan_vars.items():
        arr = np.asarray(var.extract_reshape(draws), dtype=float)  # (draw, chain, *shape)
        params[name] = np.ascontiguousarray(np.swapaxes(arr, 0, 1))
    method = fit.method_variables()
    stats = {}
    for name in SAMPLER_COLUMNS:
        if name in method:
            arr = np.asarray(method[name], dtype=float)
            arr = arr.reshape(arr.shape[0], arr.shape[1])  # (draw, chain)
            stats[name] = np.ascontiguousarray(arr.T)
    return Draws(params=params, sample_stats=stats)


class CmdStanPyBackend:
    """Stan backend on cmdstanpy + CmdStan (see the module docstring).

    Parameters
    ----------
    tmp_root : directory for the per-call output directories (default: system temp dir).
    sig_figs : significant digits in CmdStan's CSV output (None: CmdStan's default, 6).
    """

    name = "cmdstanpy"

    def __init__(
        self, tmp_root: str | os.PathLike | None = None, sig_figs: int | None = SIG_FIGS
    ) -> None:
        self.tmp_root = str(tmp_root or tempfile.gettempdir())
        self.sig_figs = sig_figs
        self._markers: dict[tuple[str, str], dict[str, Any]] = {}
        self._swept = False

    def identity(self) -> dict[str, str]:
        import cmdstanpy

        ident = cmdstan_identity(cmdstanpy.cmdstan_path())
        return {"backend": self.name, "stan_version": f"cmdstan {ident['cmdstan_version']}"}

    def compile(
        self, stan_file: str | os.PathLike, user_header: str | os.PathLike | None = None
    ) -> dict[str, Any]:
        """Compile a copy of the program in the cache (once); return its marker.

        Marker keys: ``backend``, ``stan_file`` (the repository file), ``program_sha256``,
        ``model_name``, ``cache_dir``, ``exe_file``, ``cmdstan_path``, ``cmdstan_version``,
        ``cmdstanpy_version``.  Raises RuntimeError when the program does not compile,
        BackendError when the cache cannot be written.  ``user_header``: a C++ header
        defining the program's external functions, copied beside the program and passed as
        cmdstanpy's ``user_header`` (``--allow-undefined``); keyed with the program.
        """
        import cmdstanpy

        path = Path(stan_file).resolve()
        code = program_code(path)
        sha = hashlib.sha256(code.encode()).hexdigest()
        header_text = None if user_header is None else Path(user_header).read_text()
        header_key = (
            {}
            if header_text is None
            else {"user_header": hashlib.sha256(header_text.encode()).hexdigest()}
        )
        key = (str(path), sha + str(header_key))
        known = self._markers.get(key)
        if known is not None and verified(Path(known["exe_file"])):
            return known
        ident = cmdstan_identity(cmdstanpy.cmdstan_path())
        version_tag = ident["cmdstan_version"]
        slug = path.stem
        entry_key = content_key({"program": sha, **ident, **header_key})
        cache_dir = cache_root() / "cmdstan" / f"{slug}-{entry_key}"
        exe_name = slug + (".exe" if os.name == "nt" else "")
        exe = cache_dir / exe_name

        def build() -> None:
            LOG.info("compiling %s with CmdStan %s into %s", path.name, version_tag, cache_dir)
            t0 = time.perf_counter()
            work = new_build_dir(cache_dir)
            try:
                copy = work / f"{slug}.stan"
                copy.write_text(code)
                # user_header only with a header: the autodiff call is the one
                # of every cmdstanpy version
                header_arg: dict[str, Any] = {}
                if header_text is not None:
                    header_file = work / f"{slug}.hpp"
                    header_file.write_text(header_text)
                    header_arg["user_header"] = str(header_file)
                try:
                    with quiet_loggers(forward=("cmdstanpy",)):
                        model = cmdstanpy.CmdStanModel(stan_file=str(copy), **header_arg)
                except Exception as err:
                    raise RuntimeError(f"compiling {path} failed: {err}") from err
                if model.exe_file is None or not Path(model.exe_file).is_file():
                    raise RuntimeError(f"compiling {path} gave no executable")
                built = Path(model.exe_file)
                if built != work / exe_name:
                    shutil.move(str(built), work / exe_name)
                record = {
                    "program": sha,
                    **ident,
                    **header_key,
                    "stan_file": str(path),
                    "cmdstanpy_version": cmdstanpy.__version__,
                }
                publish_entry(work, cache_dir, record, (exe_name,))
            finally:
                shutil.rmtree(work, ignore_errors=True)
            LOG.info("compiled %s in %.1f s", path.name, time.perf_counter() - t0)

        ensure_entry(cache_dir, (exe_name,), build)
        marker = {
            "backend": self.name,
            "stan_file": str(path),
            "program_sha256": sha,
            "model_name": slug,
            "cache_dir": str(cache_dir),
            "exe_file": str(exe),
            "cmdstan_path": ident["cmdstan_path"],
            "cmdstan_version": version_tag,
            "make_local_sha256": ident["make_local"],
            "cmdstanpy_version": cmdstanpy.__version__,
            **header_key,
        }
        self._markers[key] = marker
        return marker

    def sample(
        self,
        stan_file: str | os.PathLike,
        data: Mapping[str, Any],
        seed: int,
        settings: SamplerSettings,
        inits: list[dict] | None = None,
        user_header: str | os.PathLike | None = None,
    ) -> Draws:
        """Run NUTS and return the post-warmup draws (same contract as the PyStan backend).

        ``timings``: ``sample`` is the ``CmdStanModel.sample`` call (CmdStan run and CSV
        parsing), ``convert`` the reshaping, ``total`` the whole method.
        """
        import cmdstanpy

        t_start = time.perf_counter()
        check_sample_args(seed, settings, inits)
        marker = self.compile(stan_file, user_header)
        label = Path(marker["stan_file"]).name
        if not self._swept:
            sweep_stale(Path(self.tmp_root), TMP_PREFIX)
            self._swept = True
        tmp = Path(tempfile.mkdtemp(prefix=owned_tempdir_name(TMP_PREFIX), dir=self.tmp_root))
        try:
            data_file = tmp / "data.json"
            cmdstanpy.write_stan_json(str(data_file), dict(data))
            # cmdstanpy writes one init file per chain and removes them afterwards
            init_arg: list[Mapping[str, Any]] | None = (
                None if inits is None else [dict(i) for i in inits]
            )
            with quiet_loggers(forward=("cmdstanpy",)):
                model = cmdstanpy.CmdStanModel(exe_file=marker["exe_file"])
                t0 = time.perf_counter()
                try:
                    fit = model.sample(
                        data=str(data_file),
                        chains=settings.chains,
                        parallel_chains=settings.workers,
                        seed=int(seed),
                        # explicit inits, else uniform(-r, r) on the unconstrained scale
                        inits=init_arg if init_arg is not None else settings.init_radius,
                        iter_warmup=settings.iter_warmup,
                        iter_sampling=settings.iter_sampling,
                        adapt_delta=settings.adapt_delta,
                        max_treedepth=settings.max_treedepth,
                        output_dir=str(tmp / "output"),
                        sig_figs=self.sig_figs,
                        show_progress=False,
                        show_console=False,
                    )
                except RuntimeError as err:
                    console = _console_tail(tmp / "output")
                    # cmdstanpy's message lists files that are deleted below: keep only its
                    # first line and add the console's own words
                    first = str(err).strip().splitlines()[0] if str(err).strip() else ""
                    text = f"{label} (seed {seed}): {first}\n{console}".strip()
                    if SAMPLER_FAILURE.search(console) or SAMPLER_FAILURE.search(str(err)):
                        raise SamplingError(text) from err
                    raise BackendError(text) from err
                t_sample = time.perf_counter() - t0
            t0 = time.perf_counter()
            draws = fit_to_draws(fit)
            t_convert = time.perf_counter() - t0
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        draws.timings = {
            "sample": t_sample,
            "convert": t_convert,
            "total": time.perf_counter() - t_start,
        }
        return draws
