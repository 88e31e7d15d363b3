"""Logging set-up shared by every workflow script (:func:`start_job`), and a progress reporter."""

from __future__ import annotations

import atexit
import logging
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from types import TracebackType
from typing import Protocol

from . import io, kernels

LOGGER_NAME = "ssmobs"


def setup(logfile: str | None = None, level: int = logging.INFO) -> logging.Logger:
    """Log to ``logfile`` (if given) and to stderr; uncaught exceptions land in the log.

    With a ``logfile`` (every workflow job's first call) it also checks that the job computes
    with the fixed kernels (:func:`ssmobs.kernels.require`) and logs which."""
    root = logging.getLogger()
    root.setLevel(level)
    for h in list(root.handlers):
        root.removeHandler(h)
    fmt = logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s", "%H:%M:%S")
    stream = logging.StreamHandler(sys.stderr)
    stream.setFormatter(fmt)
    root.addHandler(stream)
    if logfile:
        Path(logfile).parent.mkdir(parents=True, exist_ok=True)
        fh = logging.FileHandler(logfile, mode="w")
        fh.setFormatter(fmt)
        root.addHandler(fh)
    for noisy in ("matplotlib", "h5py", "asyncio", "httpstan", "aiohttp", "PIL"):
        logging.getLogger(noisy).setLevel(logging.WARNING)

    def _hook(exc_type: type[BaseException], exc: BaseException, tb: TracebackType | None) -> None:
        _FAILED.append(exc_type.__name__)
        logging.getLogger(LOGGER_NAME).error("uncaught exception", exc_info=(exc_type, exc, tb))
        sys.__excepthook__(exc_type, exc, tb)

    sys.excepthook = _hook
    logger = logging.getLogger(LOGGER_NAME)
    if logfile:  # a workflow job: it refuses to compute with this CPU's own kernels
        logger.info(kernels.require())
    return logger


class RuleJob(Protocol):
    """What :func:`start_job` reads of the ``snakemake`` object a rule script is given."""

    @property
    def log(self) -> Sequence[str]: ...

    @property
    def output(self) -> Iterable[str]: ...


#: an uncaught exception ended this process (set by :func:`setup`'s hook)
_FAILED: list[str] = []


def _record_outputs(outputs: list[str]) -> None:
    """At the end of a job that raised nothing: record its outputs' checksums."""
    if not _FAILED:
        io.record_checksums(outputs)


def start_job(job: RuleJob) -> logging.Logger:
    """The first call of every rule script: log to the job's log file (which checks the fixed
    kernels, :func:`setup`), then delete the temporaries a killed earlier job left beside
    its outputs (:func:`ssmobs.io.sweep_temporaries`); returns the package's logger.  When
    the script ends without an uncaught exception, the checksum of every output is recorded
    (:func:`ssmobs.io.record_checksums`), so that a later run finds an output damaged or
    edited after its job and makes it again instead of reading it."""
    logger = setup(job.log[0])
    io.sweep_temporaries(job.output)  # left by an interrupted earlier run
    atexit.register(_record_outputs, [str(f) for f in job.output])
    return logger


class Progress:
    """Logs 'label: done/total, about N s left' at most every ``every`` seconds."""

    def __init__(
        self, label: str, total: int, logger: logging.Logger | None = None, every: float = 10.0
    ) -> None:
        self.label, self.total, self.every = label, total, every
        self.logger = logger or logging.getLogger(LOGGER_NAME)
        self.start = time.monotonic()
        self.last = -float("inf")
        self.done = 0

    def update(self, n: int = 1) -> None:
        """Count ``n`` more done; log when the last line is ``every`` seconds old or all
        are done."""
        self.done += n
        now = time.monotonic()
        if self.done >= self.total or now - self.last >= self.every:
            self.last = now
            elapsed = now - self.start
            rate = self.done / elapsed if elapsed > 0 else float("inf")
            left = (self.total - self.done) / rate if rate > 0 else float("nan")
            self.logger.info(
                "%s: %d/%d done, %.0f s elapsed, about %.0f s left",
                self.label,
                self.done,
                self.total,
                elapsed,
                left,
            )
