"""The one table of the workflow's stages (issue 62): for each stage the code it runs, its
rule scripts and the files outside the import graph it depends on (read by the code
closures, :mod:`ssmobs.stage_code`), and for a stage converted to an inputs object its
keyed folder, its outputs and the builder of what it reads (read by the cache keys,
:mod:`ssmobs.cache_keys`, and by :class:`~ssmobs.run_paths.RunPaths`).

Adding a stage is one :class:`Stage` here, one module ``stages/<stage>.py`` with
``run_<stage>(inputs, paths)``, one builder in :mod:`ssmobs.config.stage_inputs`, one rule
and one script (``docs/reference/layout.md`` shows it worked through).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .config.stage_inputs import (
    design_sets_inputs,
    design_sets_payload,
    exact_inputs,
    gather_inputs,
    joint_map_inputs,
    k_selection_grid_inputs,
    k_selection_points_inputs,
    model_check_inputs,
    model_check_stan_inputs,
    nuts_batches_inputs,
    nuts_records_inputs,
    program_inputs,
    program_payload,
    trajectories_inputs,
)

#: the package's own directory (``workflow/ssmobs``)
PACKAGE_DIR = Path(__file__).resolve().parent


@dataclass(frozen=True)
class Stage:
    """One stage: its code (entries of :func:`ssmobs.stage_code.module_closure`: a package
    module, or ``"stages/<stage>.py:f,g"`` for some functions of a stage module, whose
    imports are followed at the module's top level and inside those functions only), its
    rule scripts (``workflow/scripts/<script>.py``) and extra files; where it has an inputs
    object: its builder (a validated scenario entry, the config and the keyed paths it reads
    -> the frozen inputs), its entry function, its keyed folder (``{scenario}`` and
    ``{key}`` filled in), its outputs there (name -> file) and the outputs of other stages
    it reads (passed to the builder by keyword)."""

    code: tuple[str, ...]
    scripts: tuple[str, ...]
    extra_files: tuple[str, ...] = ()
    inputs: Callable[..., Any] | None = None
    #: the function of the first code entry's module the rule runs, ``run_<stage>(inputs,
    #: paths)``
    entry: str | None = None
    folder: str | None = None
    outputs: Mapping[str, str] = field(default_factory=dict)
    #: the builder's keyword -> (stage, output) of the same scenario it reads (``""``: the
    #: stage's folder; at the same K, or batch size, where both are keyed by it)
    reads: Mapping[str, tuple[str, str]] = field(default_factory=dict)
    #: what the stage is keyed by beside the scenario (``("K",)``: once per K it runs at)
    per: tuple[str, ...] = ()
    #: of ``per``, what the builder takes by keyword (where no output it reads carries it)
    builder_per: tuple[str, ...] = ()
    #: the keys or paths of shared stages it reads (:class:`~ssmobs.cache_keys.CacheKeys`
    #: attributes: ``design``, the design sets' key; called with the scenario's name:
    #: ``program_marker``, its compiled program's marker, and ``own_program``, whether its
    #: model has a hand-written Stan program), passed to the builder by keyword
    shared: tuple[str, ...] = ()
    #: whether the stage runs the scenario's model, so its key holds the model's code
    runs_model: bool = False
    #: what the stage is keyed for: a scenario, or a ``k_selection`` entry (by its name);
    #: for a shared stage, ``config`` (once per config, its builder given the config alone)
    #: or ``model`` (once per model, its builder given the model's name, the config and, by
    #: keyword, what :class:`~ssmobs.cache_keys.CacheKeys` knows of it: the backend, ...)
    of: str = "scenario"
    #: what the key holds of the inputs where that is not
    #: :func:`~ssmobs.config.stage_inputs.inputs_payload`: a shared stage keeps the payload
    #: its key held before its inputs object, so no cache moved (the fields it leaves out
    #: name the outputs' path instead)
    payload: Callable[[Any], dict[str, Any]] | None = None

    def folder_of(self, scenario: str, key: str) -> str:
        """This stage's keyed folder for a scenario and its key."""
        assert self.folder is not None, "a stage without a keyed folder"
        return self.folder.format(scenario=scenario, key=key)

    def paths(self, scenario: str, key: str) -> dict[str, str]:
        """The outputs of this stage for a scenario and its key (name -> path)."""
        folder = self.folder_of(scenario, key)
        return {name: f"{folder}/{file}" for name, file in self.outputs.items()}

    def read_path(self, scenario: str, key: str, output: str) -> str:
        """What another stage reads of this one: its output ``output``, or its keyed folder
        where ``output`` is ``""`` (a stage whose files are not fixed outputs)."""
        return self.folder_of(scenario, key) if output == "" else self.paths(scenario, key)[output]


#: the native backend's C++ driver (samples, and evaluates the log density for the check)
NATIVE_DRIVER = "stan_backends/native_driver/driver.cpp"
#: our headers the driver and every native program compile with in place of Stan's: every
#: header below ``stan_backends/native_build.py``'s SHADOW_INCLUDE_DIR (a test checks the two
#: agree)
NATIVE_SHADOW_HEADERS = tuple(
    sorted(
        p.relative_to(PACKAGE_DIR).as_posix()
        for p in (PACKAGE_DIR / "stan_backends" / "native_include").rglob("*.hpp")
    )
)
#: the marker of a model's compiled program (rule build_stan_model's output) for a backend
#: and the program's key; it names the program and header the build job compiled, which the
#: NUTS batches run
PROGRAM_MARKER = "results/shared/stan/{backend}/{model}/{key}.json"
#: the compiled pair kernel of the LCD design sets (its flags are in lcd_native.py)
LCD_KERNEL = "design/lcd_kernel/lcd_kernel.cpp"
#: the rule scripts of the stamped tables and figures
OUTPUT_SCRIPTS = (
    "paper_tables",
    "convergence_sensitivity",
    "joint_map_mu0_sweep",
    "select_k",
    "table_k_selection",
    "observability_study",
    "observability_map",
    "figure_design_points",
    "figure_joint_vs_marginal",
    "figure_profile_posterior",
    "figure_observability",
    "figure_exact_vs_stan",
)

STAGES: dict[str, Stage] = {
    # keyed once per config (config.stage_inputs.DesignSetsInputs); a set's q, K, method
    # and seed are its file's name in the keyed folder (config.stage_inputs.DESIGN_SET);
    # the sets k_selection_grid makes (ssmobs.design.disturbance_sets) lie beside these
    "design": Stage(
        ("stages/design.py:run_design_disturbances",),
        ("design_disturbances",),
        (LCD_KERNEL,),
        inputs=design_sets_inputs,
        payload=design_sets_payload,
        of="config",
    ),
    # at K trajectories: the scenario's K and its exact_K
    "trajectories": Stage(
        ("stages/design.py:run_design_trajectories",),
        ("design_trajectories",),
        inputs=trajectories_inputs,
        entry="run_design_trajectories",
        per=("K",),
        builder_per=("K",),
        shared=("design",),
        runs_model=True,
        folder="results/{scenario}/design_trajectories/{key}",
        outputs={"trajectories": "trajectories.nc", "checksum": "trajectories.nc.sha256"},
    ),
    # the model check of the Python model alone; the command line too: it was part of the
    # check's module.  Its output is a keyed file, results/{scenario}/check_model/<key>.json
    # (RunPaths.check), not a keyed folder
    "check_model": Stage(
        ("model_check/check.py", "model_check/__main__.py"),
        ("check_model",),
        inputs=model_check_inputs,
        entry="run_check_model",
        runs_model=True,
    ),
    # ... and against the Stan program: the same code (the program, the native driver and
    # our headers are keyed beside it: cache_keys.CacheKeys.check_model)
    "check_model_stan": Stage(
        ("model_check/check.py", "model_check/__main__.py"),
        ("check_model",),
        inputs=model_check_stan_inputs,
        entry="run_check_model",
        shared=("own_program",),
        runs_model=True,
    ),
    "joint_map": Stage(
        ("stages/joint_map.py",),
        ("joint_map",),
        inputs=joint_map_inputs,
        entry="run_joint_map",
        reads={"trajectories": ("trajectories", "trajectories")},
        folder="results/{scenario}/joint_map/{key}",
        outputs={"table": "joint_map.parquet", "theta": "theta_hat.nc", "summary": "summary.json"},
    ),
    # the points V_{K_i} of the choice of K, shared by the k_selection entries on a scenario,
    # computed in rule k_selection_grid's job (its script is the grid's): keyed by what each
    # reads (config.stage_inputs.KSelectionPointsInputs), its K_i and grid in its file's name
    "k_selection_points": Stage(
        ("stages/k_selection/grid.py:run_k_selection_point",),
        (),
        inputs=k_selection_points_inputs,
        shared=("design",),
        runs_model=True,
        of="k_selection",
        folder="results/shared/k_selection_points/{key}",
    ),
    # the grids of one k_selection entry (its name in place of a scenario's)
    "k_selection_grid": Stage(
        ("stages/k_selection/grid.py",),
        ("k_selection_grid",),
        inputs=k_selection_grid_inputs,
        entry="run_k_selection_grid",
        reads={"points": ("k_selection_points", "")},
        shared=("design",),
        of="k_selection",
        folder="results/k_selection/{scenario}/{key}",
        outputs={"grid": "{method}_{sets}_seed{seed}.json"},
    ),
    # a model's compiled program (config.stage_inputs.ProgramInputs): its marker is
    # PROGRAM_MARKER (not a keyed folder), named by the inputs' backend and model and the key
    "program": Stage(
        ("stages/stan.py:run_build_stan_model",),
        ("build_stan_model",),
        (NATIVE_DRIVER, *NATIVE_SHADOW_HEADERS),
        inputs=program_inputs,
        payload=program_payload,
        of="model",
    ),
    # the records of every trajectory, one file each (resumable, shared by batchings),
    # written by rule sample_nuts, whose inputs hold these whole (no entry of their own)
    "nuts_records": Stage(
        ("stages/stan.py:run_sample_batch", "nuts/record_cache.py"),
        ("sample_nuts",),
        (NATIVE_DRIVER, *NATIVE_SHADOW_HEADERS),
        inputs=nuts_records_inputs,
        reads={
            "trajectories": ("trajectories", "trajectories"),
            "joint_map": ("joint_map", "theta"),
        },
        shared=("program_marker", "own_program"),
        runs_model=True,
        folder="results/{scenario}/sample_nuts/records/{key}",
    ),
    # the batch tables of one batch size, batch{b}.parquet
    "nuts_batches": Stage(
        ("stages/stan.py:run_sample_batch",),
        ("sample_nuts",),
        inputs=nuts_batches_inputs,
        entry="run_sample_batch",
        reads={
            "trajectories": ("trajectories", "trajectories"),
            "joint_map": ("joint_map", "theta"),
            "records": ("nuts_records", ""),
        },
        per=("batch_size",),
        builder_per=("batch_size",),
        shared=("program_marker", "own_program"),
        folder="results/{scenario}/sample_nuts/{key}",
        outputs={"table": "batch{batch}.parquet"},
    ),
    "gather": Stage(
        ("stages/stan.py:run_gather_nuts", "nuts/record_cache.py"),
        ("gather_nuts",),
        inputs=gather_inputs,
        entry="run_gather_nuts",
        reads={
            "trajectories": ("trajectories", "trajectories"),
            "batches": ("nuts_batches", ""),
            "records": ("nuts_records", ""),
        },
        per=("batch_size",),
        builder_per=("batch_size",),
        folder="results/{scenario}/gather_nuts/{key}",
        outputs={"table": "marginal_map.parquet", "summary": "summary.json"},
    ),
    # at K trajectories: the scenario's K and its exact_K
    "exact": Stage(
        ("stages/exact.py",),
        ("exact_marginal",),
        inputs=exact_inputs,
        entry="run_exact_marginal",
        reads={"trajectories": ("trajectories", "trajectories")},
        per=("K",),
        folder="results/{scenario}/exact_marginal/{key}",
        outputs={"table": "marginal_map.parquet", "summary": "summary.json"},
    ),
    # the cells of an observability map: what computes a cell, not the map's table or figure;
    # each cell keyed by what it reads (config.stage_inputs.MapCellInputs), the map's job by
    # its cells (MapCellsInputs, cache_keys.CacheKeys.map_table)
    "map_cells": Stage(
        ("stages/observability_map.py:run_map_cells",), ("observability_map_cells",)
    ),
    # the variant x row table of Section IV, read from committed reproductions
    "variant_table": Stage(("reports/stan_variants.py",), ("stan_variant_table",)),
    # every stamped table and figure; observability_study's and observability_map's scripts
    # call their modules themselves
    "outputs": Stage(
        (
            "stages/outputs/paper_tables.py",
            "stages/outputs/figures.py",
            "stages/outputs/mu0_sweep.py",
            "stages/k_selection/choice.py",
            "reports/observability_study.py",
            "stages/observability_map.py:write_map,figure_map",
            # the objects the scripts read back (their read-back properties)
            "config/stage_inputs/outputs.py",
        ),
        OUTPUT_SCRIPTS,
    ),
}
