"""Checks before Snakemake and its first job: the config file, writable folders, a stale lock.

``python -m ssmobs.config.preflight [--all] [--unlock-stale] CONFIGFILE`` (see the Makefile)

* reads CONFIGFILE and validates it (:func:`ssmobs.config.validation.validate`, with the size
budget),
  and prints one line per problem instead of Snakemake's traceback: a file that does not
  exist or is larger than 5 MiB, a YAML syntax error or a key given twice in one mapping
  (file, line, column), aliases that expand to too many values, an empty file or one
  without the required key ``scenarios``; problems of one kind that many scenarios share
  come as one line with their number and first names, every one of them with ``--all``;
* stops with one line when ``.snakemake/`` of the working directory cannot be written
  (Snakemake keeps its lock there and would fail with a traceback); the folders the jobs
  write (``results/``, outputs_dir, the program cache) are checked by the Snakefile once
  it knows which jobs run (:func:`write_problem`);
* with ``--unlock-stale``: when a killed run left Snakemake's lock in ``.snakemake/locks``
  and no Snakemake process runs in this directory, removes it with ``snakemake --unlock``
  (Snakemake would otherwise refuse to start; :func:`ssmobs.config.run_lock.unlock_if_stale`).
  Whether a process runs here is read from ``/proc`` (Linux); where that is not possible the
  lock is left and the remedy printed.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from ..models import ModelDefinitionError
from .run_lock import unlock_if_stale
from .validation import README, ConfigError, read_config_file, short_list, validate


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
    except (ConfigError, ModelDefinitionError) as err:  # a broken model module it uses
        raise ConfigError(f"config file {path}: {err}") from None


# ------------------------------------------------------------------------ writable folders
def _why_unwritable(folder: Path) -> str | None:
    """Why files cannot be made in the existing ``folder``; None when they can."""
    if not folder.is_dir():
        kind = "a broken link" if folder.is_symlink() and not folder.exists() else "a file"
        return f"{kind}, not a folder"
    if os.access(folder, os.W_OK | os.X_OK):
        return None
    try:
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        read_only = False
    if read_only:
        return "on a read-only file system"
    st = folder.stat()
    return f"not writable by user {os.geteuid()} (mode {st.st_mode & 0o7777:o}, owner {st.st_uid})"


def blocking_folder(folder: str | os.PathLike) -> tuple[Path, str] | None:
    """What stops this process from making files in ``folder``: the nearest existing path
    at or above it, with why (a file in the way, a read-only file system, no write
    permission); None when files can be made there.

    Asks the system (``access(2)``, which knows read-only mounts and, for root, that
    permission bits do not stop it) and writes nothing, so a dry run may ask too."""
    here = Path(os.path.abspath(folder))
    while not os.path.lexists(here) and here != here.parent:
        here = here.parent
    why = _why_unwritable(here)
    return None if why is None else (here, why)


def write_problem(
    files: Iterable[str | os.PathLike], remedies: Mapping[str, str], default: str
) -> str | None:
    """One line naming the folders that stop ``files`` from being written (see
    :func:`blocking_folder`) and what to do, or None when every file can be written.

    A folder of the working directory is named by the highest folder above it that cannot
    be written for the same reason (``results``, not each stage's folder in it).
    ``remedies`` maps a folder (``results``, the outputs_dir, the program cache) to what to
    do when it or a folder around it cannot be written; ``default`` is said otherwise."""
    cwd = Path.cwd()
    checked: set[Path] = set()
    blocked: dict[Path, str] = {}
    for file in files:
        folder = Path(os.path.abspath(file)).parent
        if folder in checked:
            continue
        checked.add(folder)
        found = blocking_folder(folder)
        if found is None:
            continue
        here, why = found
        while here != cwd and here.parent.is_relative_to(cwd):
            if _why_unwritable(here.parent) != why:
                break
            here = here.parent
        blocked.setdefault(here, why)
    if not blocked:
        return None
    blocked = {p: w for p, w in blocked.items() if not any(q in p.parents for q in blocked)}

    def shown(path: Path) -> str:
        if path == cwd:
            return "the working directory"
        return os.path.relpath(path, cwd) if path.is_relative_to(cwd) else str(path)

    named = [f"{shown(p)} ({why})" for p, why in blocked.items()]
    what = "; ".join(named[:3]) + (f"; and {len(named) - 3} more" if len(named) > 3 else "")
    todo = []
    for root, remedy in remedies.items():
        root_path = Path(os.path.abspath(root))
        hit = any(
            p == root_path or p in root_path.parents or root_path in p.parents for p in blocked
        )
        if hit and remedy not in todo:
            todo.append(remedy)
    return f"this run cannot write where its jobs write: {what}; {'; '.join(todo or [default])}"


def snakemake_folder_problem() -> str | None:
    """One line when Snakemake cannot write ``.snakemake/`` of the working directory (its
    lock, records and file cache), else None.  Snakemake fails then with a traceback of its
    own, after the Snakefile was read and even in a dry run; the Snakefile cannot tell a
    run from ``--lint`` (which needs no writing), so this check is the make targets'."""
    return write_problem(
        [f".snakemake/{part}/-" for part in ("locks", "metadata", "incomplete", "iocache")],
        {},
        default=(
            "Snakemake keeps its lock and records in .snakemake/ of the working directory: "
            "make it writable, or run in a writable copy of the workflow"
        ),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m ssmobs.config.preflight",
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
    problem = snakemake_folder_problem()
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
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
