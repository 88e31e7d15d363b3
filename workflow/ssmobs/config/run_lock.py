"""One run of the workflow at a time in a working directory, decided before it changes a file.

Before a run tidies anything (stale stamps and their tables, damaged files, leftovers), the
process that plans it takes the run lock (:func:`take_run_lock`): an exclusive ``flock`` on
``.snakemake/ssmobs_run.lock``, held for the life of the process and released by the system
when it ends, however it ends.  A second run in the same directory (the same config, or another
config with the same ``outputs_dir``, started together or later) finds it taken and stops with
one line (:func:`lock_decision`), having changed nothing; a dry run goes on, changing nothing.

Snakemake's own lock (``.snakemake/locks``) is taken only when Snakemake has built its DAG:
:func:`lock_holders` names the live Snakemake processes that may hold it (a run started
without this module, e.g. by an older checkout), and :func:`unlock_if_stale` removes one a
killed run left (``python -m ssmobs.config.preflight --unlock-stale``, every make target).
Whether a process runs here is read from ``/proc`` (Linux).
"""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

#: the run lock's file, relative to the working directory (it holds the holder's PID)
RUN_LOCK = Path(".snakemake") / "ssmobs_run.lock"

#: the open run lock of this process (kept open: closing it would release the lock)
_HELD: list[int] = []


def take_run_lock(workdir: str | os.PathLike) -> str | None:
    """Take the run lock of ``workdir`` for the life of this process: None when this process
    holds it (taken now or before), else one line naming the run that holds it.  Where
    ``.snakemake/`` cannot be written (a read-only copy) no run can change a file there
    either: None."""
    import fcntl

    if _HELD:
        return None
    path = Path(workdir) / RUN_LOCK
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
        os.close(fd)
        who = f"PID {holder}" if holder.isdigit() else "its PID not yet written"
        return f"another run of this workflow works in this directory ({who})"
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    _HELD.append(fd)
    return None


@dataclass(frozen=True)
class LockDecision:
    """Whether this process may change files before Snakemake takes its lock, and what to
    say: a ``warning`` (a dry run goes on, changing nothing) or an ``error`` (a run stops)."""

    may_change: bool
    warning: str | None = None
    error: str | None = None


def lock_decision(
    main_process: bool,
    locks: bool,
    holders: list[int] | None,
    dry_run: bool,
    other_run: str | None = None,
) -> LockDecision:
    """May the process remove stale files before Snakemake's lock?  Only the process that
    plans the run (``main_process``; not a cluster job), while no other run holds the run
    lock (``other_run``: :func:`take_run_lock`'s line) and no other live Snakemake holds
    Snakemake's (``holders``: [] none, else their PIDs, None where a lock exists and /proc
    cannot tell); both are ignored with ``locks`` off (``--nolock``).  While one does, a run
    stops with one line before it removes or writes anything (Snakemake would refuse it
    later with its own exception, advising an --unlock that would break the live run); a
    dry run goes on."""
    if not main_process:
        return LockDecision(False)
    if not locks or (holders == [] and other_run is None):
        return LockDecision(True)
    if other_run is not None:
        msg = other_run
    elif holders:
        msg = (
            f"another Snakemake run holds the lock of this directory "
            f"(Snakemake process(es) {holders} run here)"
        )
    else:
        msg = (
            "another Snakemake run holds the lock of this directory (if no other run uses "
            "this directory, remove the lock with `snakemake --unlock`)"
        )
    if dry_run:
        return LockDecision(False, warning=f"{msg}: this dry run moves no stale stamp aside")
    return LockDecision(
        False,
        error=(
            f"{msg}: this run stops before it removes or writes anything; "
            f"start it again when that run has finished"
        ),
    )


# ------------------------------------------------------------------------ Snakemake's lock
def lock_files(workdir: str | os.PathLike) -> list[Path]:
    """Snakemake's lock files in ``workdir`` (left behind when Snakemake was killed)."""
    locks = Path(workdir) / ".snakemake" / "locks"
    return sorted(p for p in locks.iterdir() if p.is_file()) if locks.is_dir() else []


def _ancestors() -> set[int]:
    pids, pid = {os.getpid()}, os.getppid()
    while pid > 1 and pid not in pids:
        pids.add(pid)
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
            pid = int(stat.rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            break
    return pids


def snakemake_processes(workdir: str | os.PathLike) -> list[int] | None:
    """PIDs of processes whose command line mentions snakemake and that run in ``workdir``
    (or whose directory cannot be read); None where /proc is not available."""
    proc = Path("/proc")
    if not (proc / "self" / "cmdline").exists():
        return None
    workdir = Path(workdir).resolve()
    skip = _ancestors()
    found = []
    for entry in proc.iterdir():
        if not entry.name.isdigit() or int(entry.name) in skip:
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if not any(b"snakemake" in arg for arg in cmdline):
            continue
        try:
            cwd = Path(os.readlink(entry / "cwd")).resolve()
        except OSError:  # another user's process, or one that just ended: assume it is here
            if entry.exists():
                found.append(int(entry.name))
            continue
        if cwd == workdir:
            found.append(int(entry.name))
    return sorted(found)


def lock_holders(workdir: str | os.PathLike) -> list[int] | None:
    """The Snakemake processes that may hold the lock of ``workdir``: [] when there is no
    lock or it is stale (no Snakemake process runs there), else their PIDs (None where a
    lock exists and /proc cannot tell)."""
    return snakemake_processes(workdir) if lock_files(workdir) else []


def unlock_if_stale(workdir: str | os.PathLike, configfile: str | None) -> str | None:
    """Remove a stale Snakemake lock of ``workdir``; returns what was done (None: no lock)."""
    if not lock_files(workdir):
        return None
    remedy = (
        "if no other Snakemake run uses this directory, remove it with "
        "`snakemake --unlock` (with the same --configfile), then rerun"
    )
    running = snakemake_processes(workdir)
    if running is None:
        return f"a Snakemake lock exists in {workdir}/.snakemake/locks; {remedy}"
    if running:
        return (
            f"a Snakemake lock exists and Snakemake processes run in {workdir} "
            f"(PIDs {running}); left as it is"
        )
    cmd = [sys.executable, "-m", "snakemake", "--unlock"]
    if configfile:
        cmd += ["--configfile", str(configfile)]
    proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True)
    if proc.returncode != 0:
        return f"could not remove the stale lock ({proc.stderr.strip()[-500:]}); {remedy}"
    return (
        f"removed a stale Snakemake lock in {workdir} (left by a killed run; no "
        f"Snakemake process runs there)"
    )
