"""What the workflow tidies before and after a run, as decisions on paths and data.

Before Snakemake builds its DAG, the process that plans a run removes what must not be
reused (it takes stock of the files then):

- stale stamps: a table's or figure's stamp (``results/outputs/<outputs_dir>/<rule>.key``)
  whose key is not the current one, with the files made under the old key
  (:func:`stale_stamp_changes`);
- damaged files: design trajectories that no longer match their checksum
  (:func:`damaged_trajectory_repairs`), NUTS batches whose records changed after them
  (:func:`damaged_batch_repairs`), and any output that no longer matches the checksum its
  job recorded or has lost that record (:func:`damaged_output_repairs`,
  :func:`unrecorded_files`), and program markers whose Stan program is gone from the program
  cache (:func:`orphaned_program_markers`: rule build_stan_model runs again and writes it);

all of them only while no other run holds the lock of the directory
(:func:`ssmobs.config.run_lock.lock_decision`).  After a successful run of every target,
the tables and figures that no job of this config makes are moved out of outputs_dir
(:func:`leftover_outputs`).

Every decision here is a function of paths and data that returns what to change and what
to say; the few functions that read or change files say so and decide nothing.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .io import CHECKSUM_STORE, checksum_record

#: a change to make before the DAG is built: remove the path (None) or move it there
Change = tuple[Path, Path | None]

#: a content key, as a folder or file name of ``results/`` (:mod:`ssmobs.cache_keys`)
KEY_PATTERN = re.compile("[0-9a-f]{12}")
#: suffixes of the tables and figures a run writes into outputs_dir
OUTPUT_SUFFIXES = (".csv", ".md", ".tex", ".pdf", ".png")
#: the rules whose jobs compile a model's Stan program into the program cache where it lacks
#: the executable (a partly cleared cache).  Only build_stan_model writes a generated program
#: (with a sampling backend other than the native one the model check generates its own too):
#: a marker whose program is gone is removed before the DAG (:func:`orphaned_program_markers`)
PROGRAM_BUILDING_RULES = frozenset({"build_stan_model", "check_model_stan", "sample_nuts"})


@dataclass
class Repairs:
    """What a check found: the changes to make, the intermediate outputs of this config to
    make again in this run (targets of ``all``) and the lines to warn with."""

    changes: list[Change] = field(default_factory=list)
    targets: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


# -- stale stamps ----------------------------------------------------------------------------


@dataclass(frozen=True)
class StampState:
    """What a stamp file holds (None: missing) and whether ``<stamp>.stale`` exists (a dry
    run moved the stamp aside: the next real run honours it)."""

    text: str | None
    aside_exists: bool


def read_stamps(paths: Iterable[str]) -> dict[str, StampState]:
    """The state of every stamp of ``paths`` (reads files, decides nothing)."""
    states = {}
    for path in paths:
        try:
            text: str | None = Path(path).read_text()
        except FileNotFoundError:
            text = None
        states[path] = StampState(text, Path(f"{path}.stale").exists())
    return states


def stamp_is_stale(state: StampState, key: str) -> bool:
    """A stamp of another key than ``key`` is stale, and so is a missing one moved aside."""
    return state.text.strip() != key if state.text is not None else state.aside_exists


def stale_stamp_changes(
    stamps: Mapping[str, str],
    on_request: Mapping[str, str],
    states: Mapping[str, StampState],
    dry_run: bool,
    outputs_of: Callable[[str], list[str]],
) -> list[Change]:
    """The changes for every stale stamp of ``stamps`` and ``on_request`` (stamp -> current
    key; the latter's rules are made on request only), given their ``states``.

    A run removes a stale stamp, its ``.stale`` twin and the files made under the old key
    (``outputs_of(stamp)``), so that a run asking for one of those files by name remakes
    it too; a rule made on request keeps its files (committed ones) until it is asked for.
    A dry run keeps the files: it moves the stamp aside to ``<stamp>.stale``."""
    changes: list[Change] = []
    for path, key in {**stamps, **on_request}.items():
        if not stamp_is_stale(states[path], key):
            continue
        stamp_file, aside = Path(path), Path(f"{path}.stale")
        if dry_run:
            changes.append((stamp_file, aside))
            continue
        if path not in on_request:
            changes += [(Path(f), None) for f in outputs_of(path)]
        changes += [(stamp_file, None), (aside, None)]
    return changes


# -- damaged files ---------------------------------------------------------------------------


def damaged_trajectory_repairs(problems: Mapping[str, str | None]) -> Repairs:
    """Remove every design-trajectory file of ``problems`` (path -> why it no longer
    matches its checksum, or None) that has a problem, so that it is made again."""
    repairs = Repairs()
    for path, problem in problems.items():
        if problem:
            repairs.warnings.append(f"made again: {problem}")
            repairs.changes.append((Path(path), None))
    return repairs


@dataclass(frozen=True)
class BatchState:
    """One NUTS batch table of a scenario: why its records changed after it was written
    (:func:`ssmobs.nuts.record_cache.changed_batch_records`, or None), whether it and the
    scenario's gathered summary exist, and the scenario's gathered files."""

    table: str
    records_problem: str | None
    table_exists: bool
    summary_exists: bool
    gathered: tuple[str, ...]


def damaged_batch_repairs(batches: Iterable[BatchState]) -> Repairs:
    """Remove every batch table whose records were damaged, deleted or changed after it
    was written (or deleted by hand once gathered), so that batch reruns: it recomputes
    exactly the damaged records and reuses every valid one.  Snakemake does not remake a
    missing intermediate file whose consumers are up to date: the scenario's gathered
    files go too, so both are remade."""
    repairs = Repairs()
    for batch in batches:
        problem = batch.records_problem
        if not batch.table_exists and batch.summary_exists:
            problem = f"{batch.table} was deleted"
        if problem:
            repairs.warnings.append(f"this batch reruns: {problem.split('; this batch')[0]}")
            repairs.changes += [(Path(p), None) for p in (batch.table, *batch.gathered)]
    return repairs


def path_keys(path: Path) -> list[str]:
    """The content keys in ``path``: its folders' names and its stem that are keys."""
    return [p for p in (*path.parent.parts, path.stem) if KEY_PATTERN.fullmatch(p)]


def damaged_output_repairs(
    damaged: Iterable[tuple[Path, str]], found: Iterable[Path], current_keys: Collection[str]
) -> Repairs:
    """Remove every output of ``damaged`` (path, why: it no longer matches the checksum its
    job recorded, :func:`ssmobs.io.damaged_files`), so that no job reads it; one of
    ``results/`` under keys of this config only (``current_keys``) is a target too, made
    again in this run.  The files of ``found`` (and their ``.sha256`` files), which the
    other checks found, are said there only."""
    repairs = Repairs()
    skip = set(found)
    for path, problem in damaged:
        if path in skip or path.with_suffix("") in skip and path.suffix == ".sha256":
            continue
        repairs.warnings.append(f"made again, not reused: {problem}")
        repairs.changes.append((path, None))
        keys = path_keys(path)
        if path.parts[0] == "results" and keys and all(k in current_keys for k in keys):
            repairs.targets.append(str(path))
    return repairs


def unrecorded_files(
    paths: Iterable[str | Path], store: Path = CHECKSUM_STORE
) -> list[tuple[Path, str]]:
    """Every existing file of ``paths`` (outputs later jobs read) without a readable checksum
    record of its own in ``store`` (deleted, unreadable, or results copied without
    ``results/checksums/``), with why: it is unverified, so made again, not trusted, as a
    damaged one is (:func:`damaged_output_repairs`).  A program marker whose Stan program is
    gone (:func:`orphaned_program_markers`) cannot be used either: it is among them.  Reads
    files, decides nothing."""
    files = sorted({Path(p) for p in paths})
    found = _without_checksum_record(files, store)
    listed = {p for p, _ in found}
    found += [(p, why) for p, why in orphaned_program_markers(files) if p not in listed]
    return sorted(found)


def _without_checksum_record(paths: Iterable[Path], store: Path) -> list[tuple[Path, str]]:
    """The existing files of ``paths`` without a checksum record that vouches for them."""
    found: list[tuple[Path, str]] = []
    for path in paths:
        record = checksum_record(path, store)
        try:
            expected, _, where = record.read_text().rstrip("\n").partition("  ")
        except (OSError, UnicodeDecodeError):
            expected, where = "", ""
        vouches = len(expected) == 64 and bool(where) and checksum_record(where, store) == record
        if path.is_file() and not vouches:
            found.append((path, f"{path} has no checksum record in {store}/ (unverified)"))
    return found


#: what a program marker (rule build_stan_model's output) names: the Stan program it compiled
#: and its C++ header (None: a program without one)
PROGRAM_MARKER_FILES = ("program_file", "header_file")


def orphaned_program_markers(paths: Iterable[str | Path]) -> list[tuple[Path, str]]:
    """Every program marker of ``paths`` (a ``.json`` file that names the Stan program and C++
    header rule build_stan_model compiled, :data:`PROGRAM_MARKER_FILES`) that names a file no
    longer there, with why.  The generated programs live in the program cache
    (:mod:`ssmobs.stan_backends.cache`), which a user may clear while the marker stays in
    ``results/``: removed, the marker is made again by its build job, the one job that
    writes a generated program, before a NUTS batch or the model check needs it.  Reads
    files, decides nothing."""
    found: list[tuple[Path, str]] = []
    for path in sorted({Path(p) for p in paths}):
        if path.suffix != ".json" or not path.is_file():
            continue
        try:
            marker = json.loads(path.read_text())
        except (OSError, ValueError):
            continue  # an unreadable file is the checksum checks' business
        if not isinstance(marker, dict) or not all(k in marker for k in PROGRAM_MARKER_FILES):
            continue
        gone = [
            str(marker[k])
            for k in PROGRAM_MARKER_FILES
            if marker[k] is not None and not Path(str(marker[k])).is_file()
        ]
        if gone:
            found.append(
                (
                    path,
                    f"{path} names files of its Stan program that are gone "
                    f"({', '.join(gone)}; was the program cache cleared?): its build job "
                    f"writes them again",
                )
            )
    return found


def current_keys(described: Iterable[str]) -> set[str]:
    """The keys of :meth:`ssmobs.cache_keys.CacheKeys.describe`'s names (``kind:...:key``)."""
    return {name.rsplit(":", 1)[1] for name in described}


# -- making the changes ----------------------------------------------------------------------


def pending_changes(changes: Iterable[Change], exists: Callable[[Path], bool]) -> list[Change]:
    """``changes`` without repeats, in order, whose path ``exists``."""
    unique = dict.fromkeys((Path(p), a) for p, a in changes)
    return [(p, a) for p, a in unique if exists(p)]


def changed_files(changes: Iterable[Change]) -> list[Path]:
    """Every file that ``changes`` remove, move or write (their folders must be writable)."""
    return [f for p, a in changes for f in (p, a) if f is not None]


def left_stale_message(changes: list[Change], problem: str) -> str:
    """What a dry run says when ``changes`` cannot be made (``problem``)."""
    stale = ", ".join(str(p) for p, _ in changes[:3])
    more = f" and {len(changes) - 3} more" if len(changes) > 3 else ""
    return f"this dry run leaves the stale {stale}{more}: {problem}"


def apply_changes(changes: Iterable[Change]) -> None:
    """Remove each path of ``changes`` or move it aside (changes files, decides nothing)."""
    for path, aside in changes:
        if aside is not None:
            path.replace(aside)
        else:
            path.unlink(missing_ok=True)


# -- leftovers of an earlier config ----------------------------------------------------------


def leftover_outputs(files: Iterable[Path], made: Collection[str]) -> list[Path]:
    """The tables and figures of ``files`` (outputs_dir's files) that no job of this run
    makes (``made``: every output of the DAG), sorted; README* files stay."""
    return sorted(
        p
        for p in files
        if p.suffix in OUTPUT_SUFFIXES and not p.name.startswith("README") and str(p) not in made
    )


def unknown_stamps(stamp_files: Iterable[Path], known: Collection[str]) -> list[Path]:
    """The stamps of rules this config does not have."""
    return [p for p in stamp_files if str(p) not in known]


def set_aside_folder(stamps_dir: Path, now: time.struct_time) -> Path:
    """Where the leftovers of a run finished at ``now`` go."""
    return stamps_dir / "set_aside" / time.strftime("%Y%m%dT%H%M%S", now)


def set_aside_message(left: list[Path], out: str, aside: Path) -> str:
    """The line that says which leftovers went where."""
    names = ", ".join(p.name for p in left[:6]) + (", ..." if len(left) > 6 else "")
    return (
        f"moved {len(left)} file(s) that this config does not make out of {out} "
        f"(an earlier config's) to {aside}: {names}"
    )


# -- guards ----------------------------------------------------------------------------------


def job_files(jobs: Iterable[Any]) -> list[str]:
    """Every file that Snakemake ``jobs`` write: outputs, logs and benchmarks."""
    files = []
    for job in jobs:
        files += [str(f) for f in (*job.output, *job.log)]
        if getattr(job, "benchmark", None):
            files.append(str(job.benchmark))
    return files


def committed_owner(out: str) -> str | None:
    """The config file named by ``out/provenance.json`` (committed outputs), if any."""
    prov = Path(out) / "provenance.json"
    if not prov.is_file():
        return None
    owner: str | None = json.loads(prov.read_text()).get("config_file")
    return owner


def committed_outputs_problem(out: str, owner: str | None, config_files: list[str]) -> str | None:
    """One line when outputs_dir ``out`` holds the committed outputs of another profile
    (``owner``, not one of this run's ``config_files``): no profile overwrites another
    one's committed results."""
    if not owner or owner in config_files:
        return None
    return (
        f"outputs_dir = {out!r} holds the committed outputs of {owner} "
        f"({Path(out) / 'provenance.json'}); this run's config "
        f"({', '.join(config_files) or 'config/config.yaml'}) "
        f"must write its own outputs_dir (set outputs_dir in its config file)"
    )


def outputs_dir_unset_warning(config_files: list[str], out: str) -> str:
    """What a run says when no config file names outputs_dir (its default ``out``)."""
    files = ", ".join(config_files) or "the config"
    return (
        f"outputs_dir is not set in {files}: "
        f"its tables and figures go to the top of {out}/, beside the committed profiles' "
        f"folders; set outputs_dir (e.g. {out}/my_study) to give them a folder of their own"
    )


def unbuilt_programs(programs: Mapping[str, tuple[Path, Path | None]]) -> list[str]:
    """The models of ``programs`` (model -> its Stan program and C++ header, hand-written or
    generated: :func:`ssmobs.nuts.stan_program.planned_stan_program`) that the native
    backend has not built yet in the program cache, a generated program not yet written
    among them (asks the cache, decides nothing; the model check always uses it)."""
    from .stan_backends.native import NativeBackend

    native = NativeBackend()
    return [
        m
        for m, (program, header) in programs.items()
        if not program.is_file()  # a generated program its build job has not written yet
        or (header is not None and not header.is_file())
        or not native.is_built(program, header)
    ]


def missing_compiler_problem(unbuilt: list[str], compiler: str) -> str:
    """The line when the native backend must build the programs of ``unbuilt`` and finds
    no C++ compiler ``compiler``."""
    return (
        f"the native Stan backend must build {len(unbuilt)} program(s) ({', '.join(unbuilt)}) "
        f"but finds no C++ compiler {compiler!r}: install g++ (apt-get install g++), set "
        f"CXX to a C++ compiler, or point SSMOBS_CACHE at a cache that holds the programs"
    )


def write_remedies(out: str, cache_root: str) -> dict[str, str]:
    """What to do when a folder the run writes cannot be written, by folder."""
    return {
        "results": (
            "make results/ (this working directory's cache) writable, or run in a "
            "writable copy of the workflow"
        ),
        out: f"make outputs_dir = {out} writable, or set outputs_dir to a writable folder",
        cache_root: (
            "point SSMOBS_CACHE at a writable folder (the cache of compiled Stan "
            "programs; a read-only one that holds this run's programs is fine)"
        ),
    }
