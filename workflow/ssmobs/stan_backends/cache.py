"""Where compiled Stan programs live, and sweeping what killed jobs leave behind.

Compiled programs go to ``$SSMOBS_CACHE`` if set, else ``$XDG_CACHE_HOME/ssmobs`` (default
``~/.cache/ssmobs``), one directory per backend and key; the key is a hash of everything
that determines the binary (program text, Stan version, compiler and flags), never of the
Python environment's path, so every virtual environment and every clone shares them.
Deleting the directory clears the cache; programs are rebuilt on the next run.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import shutil
import time
from pathlib import Path
from typing import Any

LOG = logging.getLogger("ssmobs.stan")

#: temporary directories older than this (seconds) whose owner is gone are removed
STALE_AGE_S = 3600.0


def cache_root() -> Path:
    """Root of the compiled-program cache (see the module docstring)."""
    explicit = os.environ.get("SSMOBS_CACHE")
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ssmobs"


def content_key(parts: dict[str, Any]) -> str:
    """SHA-256 (16 hex digits) of a JSON-able description of a build."""
    text = json.dumps(parts, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def owned_tempdir_name(prefix: str) -> str:
    """A temporary directory prefix that records this process's id (see :func:`sweep_stale`)."""
    return f"{prefix}{os.getpid()}-"


def sweep_stale(directory: Path, prefix: str, max_age_s: float = STALE_AGE_S) -> int:
    """Remove ``directory/<prefix><pid>-*`` left by processes that are gone (or older than
    ``max_age_s`` when the pid cannot be read); returns how many were removed."""
    removed = 0
    try:
        candidates = list(Path(directory).glob(prefix + "*"))
    except OSError:
        return 0
    now = time.time()
    for cand in candidates:
        rest = cand.name[len(prefix) :]
        pid_text = rest.split("-", 1)[0]
        try:
            stale = (
                (not _pid_alive(int(pid_text)))
                if pid_text.isdigit()
                else (now - cand.stat().st_mtime > max_age_s)
            )
        except OSError:
            continue
        if not stale:
            continue
        with contextlib.suppress(OSError):
            if cand.is_dir():
                shutil.rmtree(cand)
            else:
                cand.unlink()
            removed += 1
            LOG.info("removed %s left by a process that is gone", cand)
    return removed


def tail(text: str, lines: int = 20) -> str:
    """The last ``lines`` non-empty lines of ``text`` (for error messages)."""
    kept = [ln for ln in text.strip().splitlines() if ln.strip()]
    return "\n".join(kept[-lines:])
