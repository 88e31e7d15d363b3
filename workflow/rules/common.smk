# Glue: config validation, the run's paths and keys, wildcard constraints, housekeeping.
# Every path: ssmobs/run_paths.py (PATHS); every tidying decision: ssmobs/housekeeping.py.
import functools
import os
import re
import time
import sys
from pathlib import Path

sys.path.insert(0, str(Path(workflow.basedir) / "workflow"))

from ssmobs.config import validation as ssmobs_config  # noqa: E402
from ssmobs import housekeeping  # noqa: E402
from ssmobs.config.validation import ConfigError  # noqa: E402
from ssmobs.models import ModelDefinitionError  # noqa: E402
from ssmobs.run_paths import RunPaths  # noqa: E402
from ssmobs.stan_backends import resolve_backend  # noqa: E402
from ssmobs.cache_keys import CacheKeys, UnknownKeyError  # noqa: E402
from ssmobs.code_hashing import DynamicImportError  # noqa: E402
from ssmobs.stan_backends.base import BackendError  # noqa: E402
from ssmobs.config.preflight import use_package_of, write_problem  # noqa: E402
from ssmobs.config.run_lock import lock_decision, lock_holders, take_run_lock  # noqa: E402

# Snakemake reads --configfile files itself and keeps the last of two duplicate keys
ssmobs_config.check_config_files(workflow.configfiles, error=WorkflowError)

#: no config file (nor --config) names outputs_dir: the schema's default, the top of paper_figures/
OUTPUTS_DIR_UNSET = "outputs_dir" not in config

try:  # also finds and checks every model module
    _last_file = str(workflow.configfiles[-1]) if workflow.configfiles else "config/config.yaml"
    ssmobs_config.validate(config, config_file=_last_file)
except (ConfigError, ModelDefinitionError) as err:
    files = ", ".join(map(str, workflow.configfiles)) or "(none)"
    raise WorkflowError(f"config file(s) {files}: {err}") from None


def is_dry_run():
    return bool(workflow.dryrun or getattr(workflow.output_settings, "dryrun", False))


@functools.cache
def may_change_files_before_the_lock():
    """Whether this process may tidy files (stale stamps and tables, damaged files,
    leftovers) before Snakemake takes its lock: it must hold the run lock of this directory
    and no other live Snakemake its own (ssmobs.config.run_lock); a run that may not stops
    here with one line, a dry run goes on changing nothing."""
    locks = getattr(workflow.execution_settings, "lock", True)  # not with --nolock
    main = workflow.is_main_process
    other_run = take_run_lock(Path.cwd()) if main and locks else None
    holders = lock_holders(Path.cwd()) if main and locks and other_run is None else []
    decision = lock_decision(main, locks, holders, is_dry_run(), other_run)
    if decision.error is not None:
        raise WorkflowError(decision.error)
    if decision.warning is not None:
        logger.warning(decision.warning)
    return decision.may_change


# the lock first: a run refused by it has changed no file (nothing above writes one)
may_change_files_before_the_lock()

try:  # "auto" is resolved here, so the concrete backend is part of the rules' params
    STAN_BACKEND = resolve_backend(config["stan"]["backend"])
except ValueError as err:
    raise WorkflowError(str(err)) from None

#: where the tables and figures go (config key outputs_dir)
OUT = config["outputs_dir"]
if OUTPUTS_DIR_UNSET and workflow.is_main_process:
    _files = [os.path.relpath(f) for f in workflow.configfiles]
    logger.warning(housekeeping.outputs_dir_unset_warning(_files, OUT))
REPO = Path(workflow.basedir)
# no profile overwrites another one's committed outputs
_mine = [
    os.path.relpath(Path(f).resolve(), REPO) for f in workflow.configfiles or ["config/config.yaml"]
]
_problem = housekeeping.committed_outputs_problem(OUT, housekeeping.committed_owner(OUT), _mine)
if _problem is not None:
    raise WorkflowError(_problem)

#: every output's content key (ssmobs/cache_keys.py): outputs live under results/.../<key>/
# keyed by the backends' Stan versions (the model check evaluates with the native driver)
try:
    KEYS = CacheKeys.for_backend(config, STAN_BACKEND, repo=REPO)
except (ValueError, BackendError) as err:
    raise WorkflowError(f"stan.backend {STAN_BACKEND!r} cannot start here: {err}") from None
#: every path of this run, the names of the scenarios of each stage and the targets: the
#: rules ask it (ssmobs/run_paths.py), never a copy of its attributes
PATHS = RunPaths.from_config(config, KEYS, STAN_BACKEND)
# every key up front (the cells of every observability map too, issue 21)
try:  # a model whose code imports by a form that cannot be followed cannot be keyed
    PATHS.compute_every_key()
except DynamicImportError as err:
    raise WorkflowError(str(err)) from None
#: every table and figure of this config by its stamp file (results/outputs/...): the files
#: its rule reads, what it reads beside them and its key (ssmobs.config.stage_inputs.stamped)
STAMPED = {PATHS.stamp(name): out for name, out in PATHS.stamped_outputs.items()}
#: stamp files of the tables and figures, with their current keys: a stamp of another key is
#: removed before the DAG is built, so its rule reruns even where file times and .snakemake/
#: say nothing (e.g. a config edited back to an earlier one)
STAMPS = {stamp: out.key for stamp, out in STAMPED.items()}
#: stamps of rules made on request only (not targets of `all`), with their current keys
STAMPS_ON_REQUEST = {}

# Jobs run the package of this checkout, not the one `pip install -e` pointed at elsewhere.
use_package_of(REPO / "workflow")


def expect_key(kind, name, key):
    """What the key wildcard ``key`` of ``kind`` describes; stops on a key of another config."""
    try:
        return KEYS.lookup(kind, name, key)
    except UnknownKeyError as err:
        raise WorkflowError(str(err)) from None


def keyed_input(kind, name, key, paths):
    """``paths`` after checking that ``key`` (a wildcard) is one this config produces."""
    expect_key(kind, name, key)
    return paths


def stamp_record(stamp):
    """The record of the table or figure whose stamp file is ``stamp``."""
    if stamp not in STAMPED:  # asked for by name, but not one of this config's outputs
        raise WorkflowError(
            f"{stamp}: this config does not make this table or figure (the paper's are "
            f"made for a config that names a scenario of the paper or sets paper_outputs)"
        )
    return STAMPED[stamp]


def stamped_files(name):
    """The input function of the rule of the table or figure whose stamp is named ``name``
    (a pattern with the rule's wildcards): the files its key holds, by input name."""

    def files(wildcards):
        stamp = PATHS.stamp(name.format(**dict(wildcards.items())))
        return stamp_record(stamp).input_files

    return files


def stamped_inputs(wildcards, output):
    """The ``inputs`` param of a table or figure rule: the very object its stamp's key holds
    (ssmobs.config.stage_inputs.outputs), all its script reads beside its files."""
    return stamp_record(output.stamp).inputs


def stamp_key(wildcards, output):
    """The ``key`` param of a table or figure rule (its stamp's content)."""
    return stamp_record(output.stamp).key


wildcard_constraints:
    scenario="|".join(map(re.escape, PATHS.scenarios)) or "NONE",
    ksel="|".join(map(re.escape, PATHS.k_selections)) or "NONE",
    study="|".join(map(re.escape, PATHS.studies)) or "NONE",
    map="|".join(map(re.escape, PATHS.maps)) or "NONE",
    q=r"\d+",
    K=r"\d+",
    seed=r"\d+",
    method="design|random|antithetic",
    sets="independent|nested",
    batch=r"\d+",
    backend="native|cmdstanpy|pystan",
    model="|".join(PATHS.models) or "NONE",
    key=r"[0-9a-f]{12}",


def unwritable_problem(files):
    """One line when a folder that ``files`` go into cannot be written, else None."""
    from ssmobs.stan_backends.cache import cache_root

    remedies = housekeeping.write_remedies(OUT, str(cache_root()))
    return write_problem(files, remedies, default="make it writable")


def stop_without_compiler():
    """Stop the run (a dry run: warn) when Stan programs must be built with the native
    driver here (the model check always uses it) and no C++ compiler is found: a cold cache
    without g++ fails before any job, not in a build job's traceback."""
    import shutil
    from ssmobs.stan_backends.native_build import compiler

    if not PATHS.stan_scenarios or shutil.which(compiler()):
        return
    unbuilt = housekeeping.unbuilt_programs(PATHS.stan_programs)
    if not unbuilt:
        return
    problem = housekeeping.missing_compiler_problem(unbuilt, compiler())
    if not is_dry_run():
        raise WorkflowError(problem)
    logger.warning(problem)


def stop_where_jobs_cannot_write():
    """Stop with one line, before the first job, when a job of this run would write into a
    folder that cannot be written: a read-only results/ or outputs_dir, a file where a
    folder must be, a program cache that must build but cannot be written.  Called by
    ``onstart:``, so only when jobs are to run: a dry run, or a run with nothing to do,
    reads a read-only cache (an archived run, a shared copy) without complaint.  On a
    cluster the folders are shared, so the planning process's answer holds for the jobs."""
    from ssmobs.stan_backends.cache import cache_root

    jobs = list(workflow.dag.needrun_jobs())
    files = housekeeping.job_files(jobs)
    # a NUTS job builds its program too when the cache lacks it (its marker in results/
    # says only that it was built once, maybe in another cache)
    builds = any(job.rule.name in housekeeping.PROGRAM_BUILDING_RULES for job in jobs)
    if builds and housekeeping.unbuilt_programs(PATHS.stan_programs):
        files.append(str(cache_root() / "native" / "-"))
    problem = unwritable_problem(files)
    if problem is not None:
        raise WorkflowError(f"{problem}; no job was started")


def stamped_outputs(path):
    """The other outputs of the rule whose stamp is ``path`` (its wildcards applied)."""
    from snakemake.io import apply_wildcards

    for candidate in workflow.rules:
        pattern = getattr(candidate.output, "stamp", None)
        found = pattern.match(path) if pattern is not None else None
        if found:
            return [
                apply_wildcards(str(f), found.groupdict())
                for f in candidate.output
                if str(f) != str(pattern)
            ]
    return []


#: the intermediate outputs of this config found damaged: targets of this run (rule all)
DAMAGED_TARGETS = []


def repairs_before_the_dag():
    """The stale stamps (with the files made under their old keys) and the damaged files
    (trajectories, NUTS batches, outputs that no longer match the checksum their job
    recorded) to remove before the DAG is built (ssmobs.housekeeping), each said once."""
    from ssmobs.io import checksum_problem, damaged_files
    from ssmobs.nuts.record_cache import changed_batch_records

    if not may_change_files_before_the_lock():
        return []
    stamps = {**STAMPS, **STAMPS_ON_REQUEST}
    states = housekeeping.read_stamps(stamps)
    changes = housekeeping.stale_stamp_changes(
        STAMPS, STAMPS_ON_REQUEST, states, is_dry_run(), stamped_outputs
    )
    found = housekeeping.damaged_trajectory_repairs(
        {path: checksum_problem(path) for path in PATHS.every_trajectories()}
    )
    batches = housekeeping.damaged_batch_repairs(
        housekeeping.BatchState(
            table,
            changed_batch_records(
                table,
                PATHS.records_dir(n),
                PATHS.draws_dir(n),
                PATHS.nuts_inputs(n).keep_draws,
            ),
            Path(table).exists(),
            Path(PATHS.stan_summary(n)).exists(),
            (PATHS.stan_summary(n), PATHS.stan_table(n)),
        )
        for n in PATHS.stan_scenarios
        for table in PATHS.nuts_batches(n)
    )
    changes += found.changes + batches.changes
    # outputs without their checksum record are unverified: made again (a dry run says so)
    current = [s for s, key in STAMPS.items() if (states[s].text or "").strip() == key]
    cached = PATHS.cached_outputs() + [f for s in current for f in (s, *stamped_outputs(s))]
    unverified = housekeeping.unrecorded_files(cached)
    if is_dry_run():
        for _, problem in unverified:
            logger.warning(f"would be made again by a run, not reused: {problem}")
        unverified = []
    outputs = housekeeping.damaged_output_repairs(
        damaged_files() + unverified,
        [p for p, _ in changes],
        housekeeping.current_keys(KEYS.describe()),
    )
    for line in found.warnings + batches.warnings + outputs.warnings:
        logger.warning(line)
    DAMAGED_TARGETS.extend(outputs.targets)
    return changes + outputs.changes


def remove_stale(changes):
    """Remove the stale files of ``changes`` (pairs of a path and None), or move them
    (pairs of a path and where to), before the DAG is built.  Where one cannot be changed
    (its folder cannot be written) nothing is: a run stops with one line (its jobs would
    write there too), a dry run says so and goes on."""
    changes = housekeeping.pending_changes(changes, os.path.lexists)
    problem = unwritable_problem(housekeeping.changed_files(changes))
    if problem is None:
        housekeeping.apply_changes(changes)
    elif not is_dry_run():
        raise WorkflowError(f"{problem}; no job was started")
    else:
        logger.warning(housekeeping.left_stale_message(changes, problem))


def set_aside_leftovers():
    """After a successful run of every target (the target ``all``), move the tables and figures in
    outputs_dir that no job of this config makes (an earlier config's) to
    ``results/outputs/<outputs_dir>/set_aside/<time>/`` with one line saying so, and remove
    the stamps of rules this config does not have, so that outputs_dir holds exactly this
    config's outputs (README* files stay).  A run of chosen targets moves nothing."""
    out, stamps_dir = Path(OUT), Path(PATHS.stamps_dir)
    if is_dry_run() or not workflow.is_main_process or not out.is_dir():
        return
    dag = workflow.dag
    if dag is None or not any(job.rule.name == "all" for job in dag.targetjobs):
        return
    made = {str(Path(f)) for job in dag.jobs for f in job.output}
    left = housekeeping.leftover_outputs([p for p in out.iterdir() if p.is_file()], made)
    if stamps_dir.is_dir():
        known = {*STAMPS, *STAMPS_ON_REQUEST}
        for key_file in housekeeping.unknown_stamps(stamps_dir.glob("*.key"), known):
            key_file.unlink()
    if not left:
        return
    aside = housekeeping.set_aside_folder(stamps_dir, time.localtime())
    aside.mkdir(parents=True, exist_ok=True)
    for p in left:
        p.replace(aside / p.name)
    logger.warning(housekeeping.set_aside_message(left, OUT, aside))
