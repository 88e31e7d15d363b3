"""Stan backends: native (our driver on httpstan's Stan sources, the embedded default),
cmdstanpy (when CmdStan is installed) and PyStan 3.

``get_backend(name)`` picks one by the config key ``stan.backend`` ("auto", "native",
"cmdstanpy", "pystan"); ``resolve_backend`` turns "auto" into the concrete name (cmdstanpy
when CmdStan is installed, else native); ``stan_file(slug)`` is the repository's
``stan/<slug>.stan``.  All backends take the data dict of
:meth:`ssmobs.models.base.StateSpaceModel.stan_data`, return
:class:`~ssmobs.stan_backends.base.Draws` and give the same draws for the same seed.

The backend modules import their Stan library lazily, so choosing one never needs the other.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from pathlib import Path

from .base import BackendError, Draws, SamplerSettings, SamplingError, StanBackend

#: values accepted for the config key ``stan.backend``
BACKEND_NAMES: tuple[str, ...] = ("auto", "native", "cmdstanpy", "pystan")

#: repository directory holding the Stan programs (workflow/ssmobs/../../stan)
STAN_DIR = Path(__file__).resolve().parents[3] / "stan"

#: the sampler columns every backend returns in ``Draws.sample_stats``
SAMPLER_COLUMNS: tuple[str, ...] = (
    "lp__",
    "accept_stat__",
    "stepsize__",
    "treedepth__",
    "n_leapfrog__",
    "divergent__",
    "energy__",
)

LOG = logging.getLogger("ssmobs.stan")


def have_cmdstan() -> bool:
    """True when cmdstanpy finds a CmdStan installation that has ``bin/stanc``.

    cmdstanpy looks at ``$CMDSTAN`` (if set and non-empty), else at the newest
    ``~/.cmdstan/cmdstan-*``; it only checks the directory and its makefile, so the
    compiler binary is checked here as well.
    """
    try:
        import cmdstanpy
    except ImportError:  # pragma: no cover - cmdstanpy is a dependency
        return False
    try:
        path = cmdstanpy.cmdstan_path()
    except ValueError:
        return False
    stanc = Path(path) / "bin" / ("stanc.exe" if os.name == "nt" else "stanc")
    return stanc.is_file()


def resolve_backend(name: str = "auto") -> str:
    """The concrete backend name for the config value ``stan.backend``.

    ``auto`` gives cmdstanpy when CmdStan is installed (:func:`have_cmdstan`), else native.
    Unknown names raise ValueError.
    """
    if name not in BACKEND_NAMES:
        raise ValueError(
            f"stan.backend: unknown value {name!r}; choose one of {list(BACKEND_NAMES)}"
        )
    if name == "auto":
        return "cmdstanpy" if have_cmdstan() else "native"
    return name


def get_backend(name: str = "auto") -> StanBackend:
    """The backend for the config value ``stan.backend`` (see :func:`resolve_backend`).

    ``cmdstanpy`` without CmdStan and unknown names raise ValueError.
    """
    name = resolve_backend(name)
    if name == "native":
        from .native import NativeBackend

        return NativeBackend()
    if name == "cmdstanpy":
        if not have_cmdstan():
            cmdstan_env = os.environ.get("CMDSTAN")
            where = (
                f"$CMDSTAN={cmdstan_env!r} is not a CmdStan installation with bin/stanc"
                if cmdstan_env
                else "$CMDSTAN is unset and ~/.cmdstan has no cmdstan-*"
            )
            raise ValueError(
                f"stan.backend: 'cmdstanpy' needs a CmdStan installation, but none was found "
                f"({where}). Install CmdStan with `python -m cmdstanpy.install_cmdstan` (needs "
                f"network access to GitHub and a C++ toolchain) or point $CMDSTAN at an "
                f"existing installation; or set stan.backend to 'native' (embedded, no CmdStan "
                f"needed) or 'auto' (cmdstanpy when CmdStan is there, else native)."
            )
        from .cmdstanpy import CmdStanPyBackend

        return CmdStanPyBackend()
    from .pystan import PyStanBackend

    return PyStanBackend()


def stan_file(slug: str) -> Path:
    """The Stan program ``stan/<slug>.stan`` of the repository (FileNotFoundError if absent)."""
    path = STAN_DIR / f"{slug}.stan"
    if "/" in slug or "\\" in slug or not path.is_file():
        known = sorted(p.stem for p in STAN_DIR.glob("*.stan"))
        raise FileNotFoundError(
            f"no Stan program for model {slug!r} at {path}; programs in {STAN_DIR}: {known}"
        )
    return path


class _ToDebug(logging.Handler):
    """Re-logs records of a chatty library logger at DEBUG on ``ssmobs.stan``."""

    def __init__(self, source: str) -> None:
        super().__init__(logging.DEBUG)
        self.source = source

    def emit(self, record: logging.LogRecord) -> None:
        try:
            LOG.debug("%s %s: %s", self.source, record.levelname, record.getMessage())
        except Exception:  # pragma: no cover - never let logging break a run
            pass


@contextlib.contextmanager
def quiet_loggers(forward: tuple[str, ...] = (), mute: tuple[str, ...] = ()) -> Iterator[None]:
    """Within the block, loggers in ``forward`` go to DEBUG on ``ssmobs.stan`` only, and
    loggers in ``mute`` (e.g. aiohttp's per-request access log) are silenced below WARNING."""
    saved = []
    for name in forward + mute:
        lg = logging.getLogger(name)
        saved.append((lg, lg.level, lg.propagate, list(lg.handlers)))
    try:
        for name in forward:
            lg = logging.getLogger(name)
            lg.handlers = [_ToDebug(name)]
            lg.propagate = False
            lg.setLevel(logging.DEBUG if LOG.isEnabledFor(logging.DEBUG) else logging.WARNING)
        for name in mute:
            logging.getLogger(name).setLevel(logging.WARNING)
        yield
    finally:
        for lg, level, propagate, handlers in saved:
            lg.setLevel(level)
            lg.propagate = propagate
            lg.handlers = handlers


def log_captured(label: str, text: str, limit: int = 20000) -> None:
    """Put captured stdout/stderr of a library call into the log at DEBUG."""
    text = text.strip()
    if text and LOG.isEnabledFor(logging.DEBUG):
        if len(text) > limit:
            text = text[:limit] + f"\n... ({len(text) - limit} more characters)"
        LOG.debug("%s output:\n%s", label, text)


__all__ = [
    "BACKEND_NAMES",
    "BackendError",
    "Draws",
    "SAMPLER_COLUMNS",
    "STAN_DIR",
    "SamplerSettings",
    "SamplingError",
    "StanBackend",
    "get_backend",
    "have_cmdstan",
    "resolve_backend",
    "stan_file",
]
