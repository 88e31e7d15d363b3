"""The private httpstan cache of one process for the PyStan backend
(:mod:`ssmobs.stan_backends.pystan`, whose docstring says why): made at the first use,
emptied of fits and socket files after every call, removed at exit; directories of dead
processes are removed when the next one is made.
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

LOG = logging.getLogger("ssmobs.stan")

#: Unix socket paths must stay below ~107 bytes; private tmp dirs longer than this keep
#: httpstan's socket files in the default temp dir
_MAX_SOCKET_DIR_LEN = 70


class _PrivateCache:
    """This process's private XDG_CACHE_HOME for httpstan (see the module docstring).

    One per process, made at the first use: the compiled model is a pybind11 extension
    module, and loading the same ``.so`` from a second path (a second private directory)
    initialises it twice, which aborts the interpreter at exit ("double free or
    corruption").  So the directory lives as long as the process; every call empties its
    ``fits/`` and socket files, and the whole directory is removed at exit.  A lock file held
    for the process lifetime marks the directory as in use; directories whose lock is free
    (their process died, e.g. killed) are removed when the next one is made.
    """

    PREFIX = "ssmobs-pystan-"

    def __init__(self, tmp_root: str | None) -> None:
        self.pid = os.getpid()
        #: XDG_CACHE_HOME values in force outside active(), innermost last
        self.outer: list[str | None] = []
        self._reap_stale(tmp_root)
        self.root = Path(tempfile.mkdtemp(prefix=self.PREFIX, dir=tmp_root))
        self._lock_fh = open(self.root / ".owner.lock", "w")
        fcntl.flock(self._lock_fh.fileno(), fcntl.LOCK_EX)
        atexit.register(self.remove)

    @classmethod
    def _reap_stale(cls, tmp_root: str | None) -> None:
        base = Path(tmp_root or tempfile.gettempdir())
        for cand in base.glob(cls.PREFIX + "*"):
            lock = cand / ".owner.lock"
            try:  # skip young ones: their owner may not hold its lock yet
                if not lock.is_file() or time.time() - cand.stat().st_mtime < 60:
                    continue
            except OSError:
                continue
            try:
                with open(lock, "a") as fh:
                    fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                    shutil.rmtree(cand, ignore_errors=True)
                    LOG.info("removed stale private httpstan cache %s", cand)
            except OSError:  # held: its process is alive
                continue

    @contextlib.contextmanager
    def active(self, shared_model_dir: Path, model_name: str) -> Iterator[Path]:
        """Within the block httpstan uses this cache, with the shared model linked in."""
        import httpstan.cache

        old_env = os.environ.get("XDG_CACHE_HOME")
        old_tempdir = tempfile.tempdir
        self.outer.append(old_env)
        try:
            os.environ["XDG_CACHE_HOME"] = str(self.root)
            model_dir = httpstan.cache.model_directory(model_name)
            if not model_dir.is_dir():
                model_dir.mkdir(parents=True)
                for item in shared_model_dir.iterdir():
                    if item.is_file():  # model .so, .cpp, stanc.log, stderr.log; not fits/
                        (model_dir / item.name).symlink_to(item)
            if len(str(self.root)) <= _MAX_SOCKET_DIR_LEN:
                tempfile.tempdir = str(self.root)  # httpstan's per-chain socket files
            yield model_dir
        finally:
            self.outer.pop()
            tempfile.tempdir = old_tempdir
            if old_env is None:
                os.environ.pop("XDG_CACHE_HOME", None)
            else:
                os.environ["XDG_CACHE_HOME"] = old_env
            self.clean()

    def clean(self) -> None:
        """Delete every fit and socket file (keeps the model links)."""
        for fits in self.root.glob("httpstan/*/models/*/fits"):
            shutil.rmtree(fits, ignore_errors=True)
        for sock in self.root.glob("httpstan_*.sock"):
            with contextlib.suppress(OSError):
                sock.unlink()

    def remove(self) -> None:
        if os.getpid() == self.pid:
            shutil.rmtree(self.root, ignore_errors=True)
            with contextlib.suppress(Exception):
                self._lock_fh.close()


_PRIVATE: dict[int, _PrivateCache] = {}


@contextlib.contextmanager
def shared_cache_env() -> Iterator[None]:
    """The environment's own XDG_CACHE_HOME, even inside an active private cache."""
    cache = _PRIVATE.get(os.getpid())
    if cache is None or not cache.outer:
        yield
        return
    saved = os.environ.get("XDG_CACHE_HOME")
    outer = cache.outer[0]
    try:
        if outer is None:
            os.environ.pop("XDG_CACHE_HOME", None)
        else:
            os.environ["XDG_CACHE_HOME"] = outer
        yield
    finally:
        if saved is None:
            os.environ.pop("XDG_CACHE_HOME", None)
        else:
            os.environ["XDG_CACHE_HOME"] = saved


def private_cache(tmp_root: str | None = None) -> _PrivateCache:
    """This process's private httpstan cache (made at the first call; ``tmp_root`` is
    used only then)."""
    pid = os.getpid()
    if pid not in _PRIVATE:
        _PRIVATE[pid] = _PrivateCache(tmp_root)
    return _PRIVATE[pid]
