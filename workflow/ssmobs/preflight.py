"""Checks the make targets run before Snakemake: the config file, and a stale lock.

``python -m ssmobs.preflight [--unlock-stale] CONFIGFILE`` (see the Makefile)

* reads CONFIGFILE and validates it (:func:`ssmobs.config.validate`, with the size budget),
  and prints one line per problem instead of Snakemake's traceback: a file that does not
  exist or is larger than 5 MiB, a YAML syntax error or a key given twice in one mapping
  (file, line, column), aliases that expand to too many values, an empty file or one
  without the required key ``scenarios``; problems of one kind that many scenarios share
  come as one line with their number and first names, every one of them with ``--all``;
* with ``--unlock-stale``: when a killed run left Snakemake's lock in ``.snakemake/locks``
  and no Snakemake process runs in this directory, removes it with ``snakemake --unlock``
  (Snakemake would otherwise refuse to start).  Whether a process runs here is read from
  ``/proc`` (Linux); where that is not possible the lock is left and the remedy printed.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from .config import README, ConfigError, read_config_file, short_list, validate


def load_config_file(path: str | os.PathLike) -> dict[str, Any]:
    """The mapping in the config file ``path``, read strictly (:func:`read_config_file`:
    size, YAML syntax, duplicate keys, alias expansion); ConfigError with a one-line
    message otherwise."""
    config = read_config_file(path)
    if config is None:
        raise ConfigError(
            f"config file {path} is empty; it needs at least the key 'scenarios' "
            f"(a list of scenarios; see {README})"
        )
    if not isinstance(config, dict):
        raise ConfigError(
            f"config file {path}: the top level must be a mapping with the key "
            f"'scenarios', not a {type(config).__name__} (see {README})"
        )
    if "scenarios" not in config:
        raise ConfigError(
            f"config file {path} has no key 'scenarios' (required: a list of "
            f"scenarios; see {README}); its keys: {short_list(sorted(map(str, config)))}"
        )
    return config


def check_config_file(path: str | os.PathLike, every_problem: bool = False) -> dict[str, Any]:
    """Load and validate ``path``; ConfigError naming the file and its problems (problems
    of one kind that many scenarios share in one line, unless ``every_problem``)."""
    config = load_config_file(path)
    try:
        return validate(config, every_problem=every_problem, config_file=str(path))
    except ConfigError as err:
        raise ConfigError(f"config file {path}: {err}") from None


# ------------------------------------------------------------------------ stale locks
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m ssmobs.preflight",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("configfile", help="the config file Snakemake will be given")
    parser.add_argument(
        "--all",
        action="store_true",
        help="list every problem of the config one by one (else problems that many "
        "scenarios share are given in one line, with their number and first names)",
    )
    parser.add_argument(
        "--unlock-stale",
        action="store_true",
        help="remove a stale Snakemake lock when no Snakemake runs here",
    )
    args = parser.parse_args(argv)
    try:
        check_config_file(args.configfile, every_problem=args.all)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    if args.unlock_stale:
        note = unlock_if_stale(Path.cwd(), args.configfile)
        if note:
            print(f"preflight: {note}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())


def use_package_of(workflow_dir: str | os.PathLike) -> None:
    """Put ``workflow_dir`` first on the PYTHONPATH that Snakemake's jobs inherit, so they
    run this checkout's package, not the one an editable install points at elsewhere."""
    rest = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    os.environ["PYTHONPATH"] = os.pathsep.join([str(workflow_dir), *rest])
