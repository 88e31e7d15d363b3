"""Where compiled Stan programs live, and sweeping what killed jobs leave behind.

Compiled programs go to ``$SSMOBS_CACHE`` if set, else ``$XDG_CACHE_HOME/ssmobs`` (default
``~/.cache/ssmobs``), one directory per backend and key; the key is a hash of what
determines the binary (program text, Stan version, flags; see each backend), never of the
Python environment's path, so every virtual environment and every clone shares them.
Deleting the directory clears the cache; programs are rebuilt on the next run.

An entry is built in a temporary sibling directory (:func:`new_build_dir`) and renamed into
place when complete (:func:`publish_entry`), so a directory under its final name is always
finished: a killed build leaves only a temporary directory, swept by a later build.  The
cache is meant to be shared: entries get the mode the umask allows (not ``mkdtemp``'s
0700), and a cache that cannot be written raises :class:`~.base.BackendError` naming the
directory (:func:`cache_writes`); a read-only cache that already holds the entries works.

Every compiled file of an entry (an executable, the libraries beside it, an object file it
is linked from) gets a checksum ``<file>.sha256`` (:func:`ssmobs.io.write_checksum`) written
at build time, before the rename, and is verified before each use (:func:`entry_problem`,
:func:`verified`): a file that does not match its checksum (replaced, truncated, one byte
flipped) or has none (an entry of an older layout) is rebuilt, never run, and where it
cannot be rebuilt (a read-only cache, no compiler) refused in one line naming it
(:func:`unusable_entry`).  A file is hashed once per process; before each later use a
``stat`` (inode, size, modification and change times) says whether it is still the file
that was hashed.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from ..io import checksum_path, checksum_problem, file_lock, write_checksum
from .base import BackendError

LOG = logging.getLogger("ssmobs.stan")

#: temporary directories older than this (seconds) whose owner is gone are removed
STALE_AGE_S = 3600.0
#: the file every finished cache entry holds (written last, before the rename)
BUILD_RECORD = "build.json"
#: errno values meaning "this directory cannot be written" (read-only, permissions, full)
UNWRITABLE = (errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EDQUOT)


def cache_root() -> Path:
    """Root of the compiled-program cache (see the module docstring)."""
    explicit = os.environ.get("SSMOBS_CACHE")
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ssmobs"


def current_umask() -> int:
    """The process's umask (from /proc on Linux, else set and restored)."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def shared_mode(executable: bool = True) -> int:
    """Mode of a new directory or executable (0o777) or file (0o666) under the umask."""
    return (0o777 if executable else 0o666) & ~current_umask()


@contextlib.contextmanager
def cache_writes(directory: Path) -> Iterator[None]:
    """Turn "cannot write here" errors of the block into a BackendError that names
    ``directory`` and says how to use another cache."""
    try:
        yield
    except OSError as err:
        if err.errno not in UNWRITABLE:
            raise
        raise BackendError(
            f"cannot write the compiled-program cache {directory} "
            f"({err.strerror or err}: {err.filename or directory}); point SSMOBS_CACHE "
            f"elsewhere, at a writable directory (e.g. export SSMOBS_CACHE=/scratch/$USER/"
            f"ssmobs-cache), or build the programs once where this cache is writable"
        ) from err


#: file -> its ``stat`` fingerprint when this process last found it matching its checksum
_VERIFIED: dict[Path, tuple[int, ...]] = {}


def _fingerprint(path: Path) -> tuple[int, ...]:
    """What changes when a file or its checksum file is replaced, truncated, written to or
    removed, whatever times one sets afterwards: device, inode, size, modification and
    change times (ns) of both."""
    out: tuple[int, ...] = ()
    for item in (path, checksum_path(path)):
        st = item.stat()
        out += (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    return out


def file_problem(path: Path) -> str | None:
    """Why ``path`` cannot be used as built (missing, no checksum, a mismatch), or None.
    Hashes the file only when its ``stat`` differs from the last check in this process."""
    try:
        before = _fingerprint(path)
    except OSError:
        _VERIFIED.pop(path, None)
        return f"{path} is missing" if not path.is_file() else checksum_problem(path)
    if _VERIFIED.get(path) == before:
        return None
    problem = checksum_problem(path)
    if problem is None:
        _VERIFIED[path] = before
    else:
        _VERIFIED.pop(path, None)
    return problem


def entry_problem(cache_dir: Path, *files: str) -> str | None:
    """Why ``cache_dir`` is not a finished, intact entry (no build record, a file of
    ``files`` missing or not matching its checksum), or None."""
    if not (cache_dir / BUILD_RECORD).is_file():
        return f"{cache_dir} is unfinished (no {BUILD_RECORD})" if cache_dir.exists() else None
    for name in files:
        problem = file_problem(cache_dir / name)
        if problem is not None:
            return problem
    return None


def entry_complete(cache_dir: Path, *files: str) -> bool:
    """True when ``cache_dir`` is a finished entry whose ``files`` match their checksums."""
    return (cache_dir / BUILD_RECORD).is_file() and entry_problem(cache_dir, *files) is None


def verified(path: Path) -> bool:
    """Whether the compiled file ``path`` still matches the checksum written when it was
    built (a ``stat`` when it was hashed before in this process)."""
    return file_problem(path) is None


def unusable_entry(problem: str | None, err: BaseException) -> BackendError:
    """One line for a damaged entry that cannot be rebuilt (``err``: why not)."""
    first = (str(err).strip().splitlines() or [type(err).__name__])[0]
    return BackendError(f"{problem}; it is not used, and it cannot be rebuilt: {first}")


def ensure_entry(cache_dir: Path, files: tuple[str, ...], build: Callable[[], None]) -> None:
    """Make ``cache_dir`` a finished entry whose ``files`` match their checksums: nothing
    when it is one; else, under the build lock, ``build()`` (which publishes the entry).
    An entry that exists but is damaged and cannot be rebuilt raises
    :func:`unusable_entry`; it is never used."""
    if entry_complete(cache_dir, *files):
        return
    damage = entry_problem(cache_dir, *files)
    if damage is not None:
        LOG.warning("%s: rebuilding it", damage)
    try:
        with build_lock(cache_dir):
            if not entry_complete(cache_dir, *files):
                build()
    except (BackendError, RuntimeError, OSError) as err:
        if damage is not None:
            raise unusable_entry(damage, err) from err
        raise
    problem = entry_problem(cache_dir, *files)
    if problem is not None:  # the build published something that does not verify
        raise BackendError(f"{problem} right after its build")


@contextlib.contextmanager
def build_lock(cache_dir: Path) -> Iterator[None]:
    """Hold the exclusive lock for building ``cache_dir`` (``.<name>.lock`` beside it)."""
    with contextlib.ExitStack() as stack:
        with cache_writes(cache_dir.parent):
            cache_dir.parent.mkdir(parents=True, exist_ok=True)
            stack.enter_context(file_lock(cache_dir.parent / f".{cache_dir.name}.lock"))
        yield


def new_build_dir(cache_dir: Path) -> Path:
    """A fresh temporary sibling of ``cache_dir`` to build into (stale ones are swept)."""
    prefix = f".{cache_dir.name}.tmp-"
    with cache_writes(cache_dir.parent):
        cache_dir.parent.mkdir(parents=True, exist_ok=True)
        sweep_stale(cache_dir.parent, prefix)
        return Path(tempfile.mkdtemp(prefix=owned_tempdir_name(prefix), dir=cache_dir.parent))


def publish_entry(
    work: Path, cache_dir: Path, record: dict[str, Any], artefacts: tuple[str, ...] = ()
) -> None:
    """Write the checksums of the compiled files ``artefacts`` and the build record into
    ``work``, give it the umask's mode and rename it to ``cache_dir`` (replacing an
    unfinished or damaged directory of that name; a process running a file of the old one
    keeps its copy)."""
    with cache_writes(cache_dir.parent):
        for name in artefacts:
            write_checksum(work / name)
        (work / BUILD_RECORD).write_text(json.dumps(record, indent=1, default=str))
        work.chmod(shared_mode())
        if cache_dir.exists():  # an unfinished or damaged entry, e.g. of an old layout
            shutil.rmtree(cache_dir)
        os.replace(work, cache_dir)


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
