# Glue: config validation, target lists, input functions, wildcard constraints.
import functools
import os
import re
import time
import sys
from pathlib import Path

sys.path.insert(0, str(Path(workflow.basedir) / "workflow"))

from ssmobs import config as ssmobs_config  # noqa: E402
from ssmobs.config import ConfigError  # noqa: E402
from ssmobs.models import ModelDefinitionError  # noqa: E402
from ssmobs.scenario import Scenario  # noqa: E402
from ssmobs.stan_backends import resolve_backend  # noqa: E402
from ssmobs.cache_keys import CacheKeys, UnknownKeyError  # noqa: E402
from ssmobs.stan_backends.base import BackendError  # noqa: E402
from ssmobs.preflight import lock_holders, use_package_of, write_problem  # noqa: E402

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

try:  # "auto" is resolved here, so the concrete backend is part of the rules' params
    STAN_BACKEND = resolve_backend(config["stan"]["backend"])
except ValueError as err:
    raise WorkflowError(str(err)) from None

#: where the tables and figures go (config key outputs_dir)
OUT = config["outputs_dir"]
if OUTPUTS_DIR_UNSET and workflow.is_main_process:
    _files = ", ".join(os.path.relpath(f) for f in workflow.configfiles) or "the config"
    logger.warning(
        f"outputs_dir is not set in {_files}: "
        f"its tables and figures go to the top of {OUT}/, beside the committed profiles' "
        f"folders; set outputs_dir (e.g. {OUT}/my_study) to give them a folder of their own"
    )


def committed_outputs_guard(out, configfiles):
    """Stop when ``out`` holds the committed outputs of another profile (its provenance.json
    names another config file): no profile overwrites another one's committed results."""
    import json

    prov = Path(out) / "provenance.json"
    if not prov.is_file():
        return
    owner = json.loads(prov.read_text()).get("config_file")
    mine = [os.path.relpath(Path(f).resolve(), REPO) for f in configfiles]
    if owner and owner not in mine:
        raise WorkflowError(
            f"outputs_dir = {out!r} holds the committed outputs of {owner} "
            f"({prov}); this run's config ({', '.join(mine) or 'config/config.yaml'}) "
            f"must write its own outputs_dir (set outputs_dir in its config file)"
        )


REPO = Path(workflow.basedir)
committed_outputs_guard(OUT, workflow.configfiles or ["config/config.yaml"])
SCENARIOS = {sc["name"]: sc for sc in config["scenarios"]}
#: the same entries as typed objects (the rules pass the plain entries above as params)
SCENARIO_OBJECTS = {name: Scenario.from_config(sc) for name, sc in SCENARIOS.items()}
KSEL = {ks["name"]: ks for ks in config["k_selection"]}
STUDIES = {st["name"]: st for st in config["observability_studies"]}
MAPS = {m["name"]: m for m in config["observability_maps"]}
JOINT_SCENARIOS = [n for n, sc in SCENARIOS.items() if sc["joint_map"]]
STAN_SCENARIOS = [n for n, sc in SCENARIOS.items() if sc["stan"]]
MU0_SCENARIOS = [
    n
    for n, sc in SCENARIOS.items()
    if sc["joint_map"] and sc["model"] in config["mu0_sweep"]["models"]
]
#: the config asks for the paper's tables and figures (it names a scenario of the paper or
#: sets paper_outputs); a study of one's own model gets its own outputs only
PAPER_OUTPUTS = ssmobs_config.asks_for_paper_outputs(config)
#: the scenarios the paper's tables and figures show (config key paper_outputs)
TABLE_II_SCENARIOS = list(config["paper_outputs"]["tables_2_3"])
FIGURE3_SCENARIOS = list(config["paper_outputs"]["figure3"])
FIGURE4_SCENARIO = config["paper_outputs"]["figure4"]
EXACT_SCENARIOS = [n for n, sc in SCENARIO_OBJECTS.items() if sc.exact_applies]
EXACT_VS_STAN_SCENARIOS = [n for n in EXACT_SCENARIOS if SCENARIOS[n]["stan"]]


#: every output's content key (ssmobs/cache_keys.py): outputs live under results/.../<key>/
# keyed by the backends' Stan versions (the model check evaluates with the native driver)
try:
    KEYS = CacheKeys.for_backend(config, STAN_BACKEND, repo=REPO)
except (ValueError, BackendError) as err:
    raise WorkflowError(f"stan.backend {STAN_BACKEND!r} cannot start here: {err}") from None


def missing_compiler_problem():
    """One line when Stan programs must be built with the native driver here (the model
    check always uses it) and no C++ compiler is found, else None: a cold cache without g++
    fails before any job, not in a build job's traceback."""
    import shutil
    from ssmobs.stan_backends.native_build import compiler

    if not STAN_SCENARIOS or shutil.which(compiler()):
        return None
    unbuilt = unbuilt_programs()
    if not unbuilt:
        return None
    return (
        f"the native Stan backend must build {len(unbuilt)} program(s) ({', '.join(unbuilt)}) "
        f"but finds no C++ compiler {compiler()!r}: install g++ (apt-get install g++), set "
        f"CXX to a C++ compiler, or point SSMOBS_CACHE at a cache that holds the programs"
    )


def write_remedies():
    """What to do when a folder the run writes cannot be written, by folder."""
    from ssmobs.stan_backends.cache import cache_root

    return {
        "results": (
            "make results/ (this working directory's cache) writable, or run in a "
            "writable copy of the workflow"
        ),
        OUT: f"make outputs_dir = {OUT} writable, or set outputs_dir to a writable folder",
        str(cache_root()): (
            "point SSMOBS_CACHE at a writable folder (the cache of compiled Stan "
            "programs; a read-only one that holds this run's programs is fine)"
        ),
    }


def unwritable_problem(files):
    """One line when a folder that ``files`` go into cannot be written, else None."""
    return write_problem(files, write_remedies(), default="make it writable")


def unbuilt_programs():
    """The models of this run whose Stan program (hand-written, else generated) the native
    backend has not built yet (the model check always evaluates with it)."""
    from ssmobs.stages.stan import stan_program
    from ssmobs.stan_backends.native import NativeBackend

    models = sorted({sc["model"] for sc in SCENARIOS.values() if sc["stan"]})
    native = NativeBackend()
    gradients = config["stan"]["gradients"]
    return [m for m in models if not native.is_built(*stan_program(m, gradients))]


def stan_source(model):
    """stan/<model>.stan, or no file for a model whose program is generated (its key holds
    the model's code: ssmobs.cache_keys.CacheKeys.stan_program)."""
    path = f"stan/{model}.stan"
    return path if (REPO / path).is_file() else []


def stop_where_jobs_cannot_write():
    """Stop with one line, before the first job, when a job of this run would write into a
    folder that cannot be written: a read-only results/ or outputs_dir, a file where a
    folder must be, a program cache that must build but cannot be written.  Called by
    ``onstart:``, so only when jobs are to run: a dry run, or a run with nothing to do,
    reads a read-only cache (an archived run, a shared copy) without complaint.  On a
    cluster the folders are shared, so the planning process's answer holds for the jobs."""
    from ssmobs.stan_backends.cache import cache_root

    jobs = list(workflow.dag.needrun_jobs())
    files = []
    for job in jobs:
        files += [str(f) for f in (*job.output, *job.log)]
        if getattr(job, "benchmark", None):
            files.append(str(job.benchmark))
    # a NUTS job builds its program too when the cache lacks it (its marker in results/
    # says only that it was built once, maybe in another cache)
    builds = {"build_stan_model", "check_model_stan", "sample_nuts"}
    if any(job.rule.name in builds for job in jobs) and unbuilt_programs():
        files.append(str(cache_root() / "native" / "-"))
    problem = unwritable_problem(files)
    if problem is not None:
        raise WorkflowError(f"{problem}; no job was started")


def stop_without_compiler():
    """Stop the run (a dry run: warn) with :func:`missing_compiler_problem`'s line."""
    problem = missing_compiler_problem()
    if problem is not None:
        if not is_dry_run():
            raise WorkflowError(problem)
        logger.warning(problem)


#: the design sets of this config's design settings and code
DESIGN_DIR = f"results/shared/design_disturbances/{KEYS.design}"
# Every key up front: a cluster job plans only its own job and looks its key up directly.
for _name, _sc in SCENARIO_OBJECTS.items():
    KEYS.check_model(_name)
    KEYS.joint_map(_name)
    KEYS.trajectories(_name)
    if SCENARIOS[_name]["stan"]:  # a model may have no Stan program where none runs
        KEYS.check_model(_name, stan=True)
        KEYS.program(_sc.model.slug)
        KEYS.gather(_name, _sc.batch_size(config["stan"]))  # its batches, records
    for _K in {_sc.K, _sc.exact_trajectories}:
        KEYS.exact(_name, _K)  # and the trajectories at K
for _name in KSEL:
    KEYS.k_selection_grid(_name)  # and its points
#: every cell of every observability map with its key (issue 21)
MAP_CELLS = {_name: KEYS.map_cells(_name) for _name in MAPS}
for _name in MAPS:
    KEYS.map_table(_name)
#: stamp files (results/outputs/...) of the tables and figures, with their current keys
STAMPS = {}
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


def batch_size(name):
    return SCENARIO_OBJECTS[name].batch_size(config["stan"])


def trajectories_path(name, K=None):
    """The design trajectories of a scenario at K (its own K by default)."""
    return f"results/{name}/design_trajectories/{KEYS.trajectories(name, K)}/trajectories.nc"


def check_path(name, stan=False):
    """The report of the model check of a scenario (Python alone, or against Stan)."""
    stage = "check_model_stan" if stan else "check_model"
    return f"results/{name}/{stage}/{KEYS.check_model(name, stan)}.json"


def joint_dir(name):
    return f"results/{name}/joint_map/{KEYS.joint_map(name)}"


def joint_summary(name):
    return f"{joint_dir(name)}/summary.json"


def stan_init_inputs(name):
    """The joint MAP of every trajectory when the scenario's chains start there."""
    if SCENARIOS[name]["stan_init"] == "joint_map":
        return {"joint_map": f"{joint_dir(name)}/theta_hat.nc"}
    return {}


def program_marker(model):
    return f"results/shared/stan/{STAN_BACKEND}/{model}/{KEYS.program(model)}.json"


def checked_program(model):
    """What the model check evaluates, when sampling builds it too: with the native backend,
    build_stan_model's program, so the check runs the cached executable after the one
    compile (no check job compiles, none waits on another's build lock).  An order only:
    ancient(), so the marker's file time never reruns a check (its key holds the program)."""
    return [ancient(program_marker(model))] if STAN_BACKEND == "native" else []


def records_dir(name):
    return f"results/{name}/sample_nuts/records/{KEYS.nuts_records(name)}"


def draws_dir(name):
    return f"results/{name}/draws/{KEYS.nuts_records(name)}"


def batch_dir(name):
    return f"results/{name}/sample_nuts/{KEYS.nuts_batches(name, batch_size(name))}"


def gather_dir(name):
    return f"results/{name}/gather_nuts/{KEYS.gather(name, batch_size(name))}"


def stan_summary(name):
    return f"{gather_dir(name)}/summary.json"


def stan_table(name):
    return f"{gather_dir(name)}/marginal_map.parquet"


def exact_dir(name, K):
    return f"results/{name}/exact_marginal/{KEYS.exact(name, K)}"


def exact_table(name, K):
    return f"{exact_dir(name, K)}/marginal_map.parquet"


def exact_summary_path(name):
    """Summary of the exact stage at the scenario's exact_K (the one the tables show)."""
    return f"{exact_dir(name, SCENARIO_OBJECTS[name].exact_trajectories)}/summary.json"


#: where the cells of every observability map are cached (by their own keys, shared by maps
#: and profiles)
MAP_CELLS_DIR = "results/observability_map/cells"


def map_cells_table(name):
    """The table of every cell of one observability map."""
    return f"results/observability_map/{name}/{KEYS.map_table(name)}/cells.parquet"


def ksel_grids_dir(ksel):
    """The grid files of one k_selection entry (keyed by its points' key and the grid)."""
    return f"results/k_selection/{ksel}/{KEYS.k_selection_grid(ksel)}"


def ksel_points_dir(ksel, method, sets, seed):
    """The cached points V_{K_i} of one grid, one file per K_i, keyed without the grid and
    the entry: every k_selection entry on the same scenario finds them."""
    key = KEYS.k_selection_points(ksel)
    return f"results/shared/k_selection_points/{key}/{method}_{sets}_seed{seed}"


def stamp(name):
    """The stamp file of a table or figure rule, ``name`` possibly a pattern with wildcards.

    A stamp holds the key of what made the rule's files in outputs_dir (keyed inputs, the
    content of other inputs, params, code; registered with :func:`register_stamp`).  A
    stamp of another key is removed before the DAG is built, so the rule reruns even where
    file times and .snakemake/ say nothing (e.g. a config edited back to an earlier one)."""
    return f"results/outputs/{OUT}/{name}.key"


def register_stamp(name, inputs, params):
    STAMPS[stamp(name)] = KEYS.output(f"{OUT}/{name}", inputs, params)


def stamp_key(wildcards, output):
    """The ``key`` param of a table or figure rule (its stamp's content)."""
    if output.stamp not in STAMPS:  # asked for by name, but not one of this config's outputs
        raise WorkflowError(
            f"{output.stamp}: this config does not make this table or figure (the paper's "
            f"are made for a config that names a scenario of the paper or sets paper_outputs)"
        )
    return STAMPS[output.stamp]


def keyed_input(kind, name, key, paths):
    """``paths`` after checking that ``key`` (a wildcard) is one this config produces."""
    expect_key(kind, name, key)
    return paths


wildcard_constraints:
    scenario="|".join(map(re.escape, SCENARIOS)) or "NONE",
    ksel="|".join(map(re.escape, KSEL)) or "NONE",
    study="|".join(map(re.escape, STUDIES)) or "NONE",
    map="|".join(map(re.escape, MAPS)) or "NONE",
    q=r"\d+",
    K=r"\d+",
    seed=r"\d+",
    method="design|random|antithetic",
    sets="independent|nested",
    batch=r"\d+",
    backend="native|cmdstanpy|pystan",
    model="|".join(sorted({sc["model"] for sc in config["scenarios"]})) or "NONE",
    key=r"[0-9a-f]{12}",


def disturbance_path(q, K, method, seed):
    return f"{DESIGN_DIR}/q{q}_K{K}_{method}_seed{seed}.nc"


def study_scenarios(name):
    """The scenario entries of one observability study, in config order."""
    return [SCENARIOS[n] for n in STUDIES[name]["scenarios"]]


def trajectory_inputs(wildcards):
    """The design disturbances and the model check behind one set of design trajectories."""
    K = expect_key("trajectories", wildcards.scenario, wildcards.key)["K"]
    sc = SCENARIO_OBJECTS[wildcards.scenario]
    return {
        "disturbances": disturbance_path(sc.disturbance_dim, K, sc.method, sc.seed),
        "checked": check_path(wildcards.scenario),
    }


def k_selection_grids(name):
    """Every (method, sets, seed) grid of one k_selection entry: every seed of every
    method (a design set's seed starts its optimiser, so its K is a distribution too)."""
    ks = KSEL[name]
    out = []
    for method in ks["methods"]:
        for sets in ks["sets"]:
            for seed in ks["seeds"]:
                out.append(f"{ksel_grids_dir(name)}/{method}_{sets}_seed{seed}.json")
    return out


def nuts_batches(name):
    """The batch tables of a scenario's Stan stage."""
    from ssmobs.stages.stan import batches

    ranges = batches(SCENARIO_OBJECTS[name].stan_trajectories, batch_size(name))
    return [f"{batch_dir(name)}/batch{b}.parquet" for b in range(len(ranges))]


def damaged_batches():
    """The table of every batch whose records were damaged, deleted or changed after it
    was written (or whose kept draws no longer match their checksum), to be removed before
    the DAG is built (Snakemake takes stock of the files then; :func:`remove_stale`), so
    that batch reruns: it recomputes exactly the damaged records and reuses every valid
    one.  A batch table deleted by hand reruns too."""
    from ssmobs.record_cache import changed_batch_records

    if not may_change_files_before_the_lock():
        return []
    changes = []
    keep = config["stan"]["keep_draws"]
    for name in STAN_SCENARIOS:
        for table in nuts_batches(name):
            problem = changed_batch_records(table, records_dir(name), draws_dir(name), keep)
            if not Path(table).exists() and Path(stan_summary(name)).exists():
                problem = f"{table} was deleted"
            if problem:
                logger.warning(f"this batch reruns: {problem.split('; this batch')[0]}")
                # Snakemake does not remake a missing intermediate file whose consumers are
                # up to date: the scenario's gathered table goes too, so both are remade
                changes += [(path, None) for path in (table, stan_summary(name), stan_table(name))]
    return changes


def select_k_params(name):
    return {"ksel": KSEL[name], "scenario": SCENARIOS[KSEL[name]["scenario"]]}


def exact_vs_stan_inputs(name):
    return {"stan": stan_table(name), "exact": exact_table(name, SCENARIOS[name]["K"])}


def study_inputs(name):
    scs = study_scenarios(name)
    return {
        "joint": [joint_summary(sc["name"]) for sc in scs if sc["joint_map"]],
        "stan": [stan_summary(sc["name"]) for sc in scs if sc["stan"]],
        "stan_tables": [stan_table(sc["name"]) for sc in scs if sc["stan"]],
    }


def study_params(name):
    scs = study_scenarios(name)
    return {
        "study": STUDIES[name],
        "scenarios": scs,
        "joint_names": [sc["name"] for sc in scs if sc["joint_map"]],
        "stan_names": [sc["name"] for sc in scs if sc["stan"]],
        "stan_settings": config["stan"],
    }


def figure2_disturbances(wildcards=None):
    f2 = config["figure2"]
    return disturbance_path(2, f2["K"], "design", f2["seed"])


def damaged_trajectories():
    """Every design-trajectory file that no longer matches its checksum or has lost it
    (damage that kept its time), to be removed before the DAG is built, so it is made
    again."""
    from ssmobs.io import checksum_problem

    if not may_change_files_before_the_lock():
        return []
    changes = []
    for name, sc in SCENARIO_OBJECTS.items():
        for K in {sc.K, sc.exact_trajectories}:
            path = trajectories_path(name, K)
            problem = checksum_problem(path)
            if problem:
                logger.warning(f"made again: {problem}")
                changes.append((path, None))
    return changes


#: the intermediate outputs of this config found damaged: targets of this run (rule all)
DAMAGED_TARGETS = []


def damaged_outputs(found):
    """Every output of an earlier job that no longer matches the checksum its job recorded
    (``results/checksums/``, :func:`ssmobs.io.record_checksums`): truncated, edited or
    damaged, whatever its time.  Removed before the DAG is built, so that no job reads it:
    a requested output (a table, a summary) is made again in this run, and so is an
    intermediate one of this config's keys when the run makes every target (``all``).  The files of ``found`` (changes the other checks found)
    are said there only."""
    from ssmobs.io import damaged_files

    if not may_change_files_before_the_lock():
        return []
    changes = []
    skip = {Path(p) for p, _ in found}
    current = {name.rsplit(":", 1)[1] for name in KEYS.describe()}
    for path, problem in damaged_files():
        if path in skip or path.with_suffix("") in skip and path.suffix == ".sha256":
            continue
        logger.warning(f"made again, not reused: {problem}")
        changes.append((path, None))
        keys = [p for p in (*path.parent.parts, path.stem) if re.fullmatch("[0-9a-f]{12}", p)]
        if path.parts[0] == "results" and keys and all(k in current for k in keys):
            DAMAGED_TARGETS.append(str(path))  # an intermediate output of this config
    return changes


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


def is_dry_run():
    return bool(workflow.dryrun or getattr(workflow.output_settings, "dryrun", False))


@functools.cache
def may_change_files_before_the_lock():
    """Whether this process may remove stale files before Snakemake takes its lock (the
    repairs below): the process that plans the run (not cluster jobs), while no other
    live Snakemake run holds the lock of this directory.  While one does, a run stops
    here, before it removes or writes anything (Snakemake would refuse it after the
    removals, advising an --unlock that would break the live run); a dry run goes on,
    changing nothing."""
    if not workflow.is_main_process:
        return False
    locks = getattr(workflow.execution_settings, "lock", True)  # not with --nolock
    holders = lock_holders(Path.cwd()) if locks else []
    if holders == []:
        return True
    who = (
        f"Snakemake process(es) {holders} run here"
        if holders
        else "if no other run uses this directory, remove the lock with `snakemake --unlock`"
    )
    msg = f"another Snakemake run holds the lock of this directory ({who})"
    if is_dry_run():
        logger.warning(f"{msg}: this dry run moves no stale stamp aside")
        return False
    raise WorkflowError(
        f"{msg}: this run stops before it removes or writes anything; "
        f"start it again when that run has finished"
    )


def remove_stale(changes):
    """Remove the stale files of ``changes`` (pairs of a path and None), or move them
    (pairs of a path and where to), before the DAG is built.  Where one cannot be changed
    (its folder cannot be written) nothing is: a run stops with one line (its jobs would
    write there too), a dry run says so and goes on."""
    unique = dict.fromkeys((Path(p), a) for p, a in changes)
    changes = [(p, a) for p, a in unique if os.path.lexists(p)]
    problem = unwritable_problem([f for p, a in changes for f in (p, a) if f is not None])
    if problem is not None:
        if not is_dry_run():
            raise WorkflowError(f"{problem}; no job was started")
        stale = ", ".join(str(p) for p, _ in changes[:3])
        more = f" and {len(changes) - 3} more" if len(changes) > 3 else ""
        logger.warning(f"this dry run leaves the stale {stale}{more}: {problem}")
        return
    for path, aside in changes:
        if aside is not None:
            path.replace(aside)
        else:
            path.unlink(missing_ok=True)


def stale_stamps():
    """Every stamp whose key is not the current one (see :func:`stamp`), with the files
    made under the old key, to be removed by :func:`remove_stale`, so that a run asking
    for one of those files by name (``make tables``) remakes it too, not only a run of every
    target.  In the process that plans the run (not again in cluster jobs).  A dry run
    keeps the files: it moves the stamp aside to ``<stamp>.stale``, which the next real run
    honours."""
    if not may_change_files_before_the_lock():
        return []
    changes = []
    for path, key in {**STAMPS, **STAMPS_ON_REQUEST}.items():
        stamp_file, aside = Path(path), Path(f"{path}.stale")
        try:
            stale = stamp_file.read_text().strip() != key
        except FileNotFoundError:
            stale = aside.exists()
        if not stale:
            continue
        if is_dry_run():
            changes.append((stamp_file, aside))
            continue
        # a rule made on request keeps its files (committed, e.g. the variant table) until
        # it is asked for: its missing stamp makes it rerun then
        if path not in STAMPS_ON_REQUEST:
            changes += [(Path(f), None) for f in stamped_outputs(path)]
        changes += [(stamp_file, None), (aside, None)]
    return changes


#: suffixes of the tables and figures a run writes into outputs_dir
OUTPUT_SUFFIXES = (".csv", ".md", ".tex", ".pdf", ".png")


def set_aside_leftovers():
    """After a successful run of every target (the target ``all``), move the tables and figures in
    outputs_dir that no job of this config makes (an earlier config's) to
    ``results/outputs/<outputs_dir>/set_aside/<time>/`` with one line saying so, and remove
    the stamps of rules this config does not have, so that outputs_dir holds exactly this
    config's outputs (README* files stay).  A run of chosen targets moves nothing."""
    out, stamps_dir = Path(OUT), Path(f"results/outputs/{OUT}")
    if is_dry_run() or not workflow.is_main_process or not out.is_dir():
        return
    dag = workflow.dag
    if dag is None or not any(job.rule.name == "all" for job in dag.targetjobs):
        return
    made = {str(Path(f)) for job in dag.jobs for f in job.output}
    left = sorted(
        p
        for p in out.iterdir()
        if p.is_file()
        and p.suffix in OUTPUT_SUFFIXES
        and not p.name.startswith("README")
        and str(p) not in made
    )
    known = {*STAMPS, *STAMPS_ON_REQUEST}
    if stamps_dir.is_dir():
        for key_file in stamps_dir.glob("*.key"):
            if str(key_file) not in known:
                key_file.unlink()
    if not left:
        return
    aside = stamps_dir / "set_aside" / time.strftime("%Y%m%dT%H%M%S")
    aside.mkdir(parents=True, exist_ok=True)
    for p in left:
        p.replace(aside / p.name)
    names = ", ".join(p.name for p in left[:6]) + (", ..." if len(left) > 6 else "")
    logger.warning(
        f"moved {len(left)} file(s) that this config does not make out of {OUT} "
        f"(an earlier config's) to {aside}: {names}"
    )


def all_targets():
    targets = [trajectories_path(name) for name in SCENARIOS] + DAMAGED_TARGETS
    targets += [joint_summary(name) for name, sc in SCENARIOS.items() if sc["joint_map"]]
    targets += [stan_summary(name) for name, sc in SCENARIOS.items() if sc["stan"]]
    for name in KSEL:
        targets += expand(f"{OUT}/fig_k_convergence_{name}.{{ext}}", ext=["pdf", "png"])
    if KSEL or PAPER_OUTPUTS:
        targets += expand(
            f"{OUT}/table_k_selection{{part}}.{{ext}}",
            part=["", "_distribution"],
            ext=["csv", "md", "tex"],
        )
    targets += [exact_summary_path(name) for name in EXACT_SCENARIOS]
    targets += expand(
        f"{OUT}/fig_exact_vs_stan_{{name}}.{{ext}}",
        name=EXACT_VS_STAN_SCENARIOS,
        ext=["pdf", "png"],
    )
    targets += expand(
        f"{OUT}/exact_vs_stan_{{name}}.{{ext}}", name=EXACT_VS_STAN_SCENARIOS, ext=["csv", "md"]
    )
    if FIGURE4_SCENARIO:
        targets += expand(
            f"{OUT}/fig4_profile_posterior_{FIGURE4_SCENARIO}.{{ext}}", ext=["pdf", "png"]
        )
    for name in STUDIES:
        targets += expand(f"{OUT}/ours_{name}_observability.{{ext}}", ext=["csv", "md", "png"])
    for name in MAPS:
        targets += expand(f"{OUT}/map_{name}.{{ext}}", ext=["csv", "md", "png", "pdf"])
    targets += list(STAMPS)
    if not PAPER_OUTPUTS:
        return targets
    targets += [f"{OUT}/fig2_design_points.pdf", f"{OUT}/fig2_design_points.png"]
    targets += expand(
        f"{OUT}/{{stem}}.{{ext}}",
        ext=["csv", "md", "tex"],
        stem=["table2_joint_vs_marginal", "table3_coverage", "section4_summary"],
    )
    targets += expand(
        f"{OUT}/{{stem}}.{{ext}}",
        ext=["pdf", "png"],
        stem=["fig3_joint_vs_marginal", "fig_observability_ratios"],
    )
    if MU0_SCENARIOS:
        targets += expand(f"{OUT}/table_mu0_sweep.{{ext}}", ext=["csv", "md", "tex"])
    if STAN_SCENARIOS:
        targets += expand(
            f"{OUT}/{{stem}}.{{ext}}",
            stem=["table_convergence_sensitivity", "table_convergence_failures"],
            ext=["csv", "md", "tex"],
        )
    return targets
