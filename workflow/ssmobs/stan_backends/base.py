"""The interface every Stan backend implements (native, cmdstanpy with CmdStan, PyStan 3),
and the names they share: the sampler columns and the logging of their libraries' output.

Every backend compiles the same ``stan/<model>.stan`` program, takes the same data dict
(:meth:`ssmobs.models.base.StateSpaceModel.stan_data`) and returns the same :class:`Draws`.
The backend modules import this module, never the package (:mod:`ssmobs.stan_backends`,
which imports them).
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

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

#: an ``#include`` line of a Stan program: ``#include file``, ``"file"`` or ``<file>``
STAN_INCLUDE = re.compile(r'^[ \t]*#include[ \t]+(?:"([^"\n]+)"|<([^>\n]+)>|(\S+))[ \t]*$', re.M)


def program_code(stan_file: str | os.PathLike) -> str:
    """The text of a Stan program with every ``#include`` replaced by the included file's
    text, recursively (files found in the program's directory, as CmdStan's default include
    path): what every backend compiles and what keys the program, so an edit of an included
    file is an edit of the program.  A program without includes is its file's text.
    FileNotFoundError for a missing include, ValueError for one that includes itself."""
    top = Path(stan_file)

    def expand(path: Path, within: tuple[Path, ...]) -> str:
        def include(found: re.Match[str]) -> str:
            name = next(g for g in found.groups() if g is not None)
            target = (top.parent / name).resolve()
            if target in within:
                raise ValueError(f"{path}: #include {name} includes itself")
            if not target.is_file():
                raise FileNotFoundError(f"{path}: #include {name}: no file {target}")
            return expand(target, (*within, target))

        return STAN_INCLUDE.sub(include, path.read_text())

    return expand(top, (top.resolve(),))


def program_digest(stan_file: str | os.PathLike) -> str:
    """SHA-256 (16 hex digits) of :func:`program_code`: a Stan program's key."""
    return hashlib.sha256(program_code(stan_file).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class SamplerSettings:
    """NUTS settings; the defaults are the paper's (Sec. IV): 4 chains, 10 000 iterations,
    4 000 of them warmup.  The config's ``stan`` block sets every field but one.

    Fixed fields, not in the config: ``workers``, which is the job's threads
    (:func:`ssmobs.stages.stan.sampler_settings`): it schedules chains and changes no draw.
    """

    chains: int = 4
    iter_warmup: int = 4000
    iter_sampling: int = 6000
    adapt_delta: float = 0.8
    max_treedepth: int = 10
    #: random inits uniform on (-init_radius, init_radius), unconstrained (Stan's default 2)
    init_radius: float = 2.0
    #: parallel chain processes of one sampling call (PyStan pool, cmdstanpy parallel_chains)
    workers: int = 1


#: sampler settings whose default value is left out of record and cache keys, so that the
#: keys of records made before the setting existed stay valid (the value is the same)
KEYED_ONLY_OFF_DEFAULT = {"init_radius": 2.0}


def sampler_key(settings: dict[str, Any]) -> dict[str, Any]:
    """``settings`` (sampler fields) without those at a default of
    :data:`KEYED_ONLY_OFF_DEFAULT`: what a record's key holds of the sampler."""
    return {
        k: v
        for k, v in settings.items()
        if not (k in KEYED_ONLY_OFF_DEFAULT and float(v) == KEYED_ONLY_OFF_DEFAULT[k])
    }


@dataclass
class Draws:
    """Post-warmup draws of one run, chain-major.

    ``params`` maps a Stan parameter name to an array of shape (chain, draw, *param_shape);
    ``sample_stats`` maps the sampler columns ``divergent__``, ``treedepth__``, ``energy__``,
    ``accept_stat__``, ``stepsize__``, ``n_leapfrog__``, ``lp__`` to arrays (chain, draw).
    ``timings`` holds seconds spent in the backend call (``sample``) and, where the backend
    can tell, in its own transfer/parsing (``transfer``).
    """

    params: dict[str, np.ndarray]
    sample_stats: dict[str, np.ndarray]
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def n_chains(self) -> int:
        return next(iter(self.sample_stats.values())).shape[0]

    @property
    def n_draws(self) -> int:
        return next(iter(self.sample_stats.values())).shape[1]


def check_sample_args(seed: int, settings: SamplerSettings, inits: list[dict] | None) -> None:
    """ValueError for arguments no backend can run with (seed range, inits per chain, workers)."""
    if not 0 <= int(seed) < 2**32:
        raise ValueError(f"seed must be in [0, 2**32), got {seed}")
    if inits is not None and len(inits) != settings.chains:
        raise ValueError(
            f"inits must have one dict per chain ({settings.chains}), got {len(inits)}"
        )
    if settings.workers < 1:
        raise ValueError(f"settings.workers must be >= 1, got {settings.workers}")


class SamplingError(RuntimeError):
    """The sampler failed on *these data* (initialisation failure, exception in the model).

    Only this error (and a data set the model rejects, ValueError) may be stored as a
    per-trajectory result; anything else is a broken installation or environment.
    """


class BackendError(RuntimeError):
    """The backend itself cannot run (missing library, compiler, killed process): never a
    property of one trajectory, so it fails the job instead of becoming a record."""


class StanBackend(Protocol):
    """What the Stan stage needs from a backend."""

    name: str

    def identity(self) -> dict[str, str]:
        """What determines the draws besides program, data and settings: backend name and
        Stan version (part of every record's key)."""

    def compile(
        self, stan_file: str | os.PathLike, user_header: str | os.PathLike | None = None
    ) -> dict[str, Any]:
        """Compile (or find compiled) the program; return a JSON-able marker (backend,
        program hash, paths).  ``user_header``: a C++ header defining the program's external
        functions (``stanc --allow-undefined``; native and cmdstanpy only)."""

    def sample(
        self,
        stan_file: str | os.PathLike,
        data: Mapping[str, Any],
        seed: int,
        settings: SamplerSettings,
        inits: list[dict] | None = None,
        user_header: str | os.PathLike | None = None,
    ) -> Draws:
        """Run NUTS; raise SamplingError with the reason when no draws can be had."""


# --------------------------------------------------------------------------- logging
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
