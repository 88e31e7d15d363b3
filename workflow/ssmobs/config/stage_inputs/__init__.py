"""What each stage reads, as one frozen object built from the scenario and the config
(issue 62): the rule passes it as its only param, ``run_<stage>(inputs, paths)`` reads
nothing else, and its content (:func:`inputs_payload`) with the stage's code is the stage's
cache key (:mod:`ssmobs.cache_keys`), so what is keyed is exactly what is read.

Each builder takes a validated scenario entry, the validated config and the paths of the
keyed files the stage reads (they carry the upstream keys); :data:`ssmobs.stage_table.STAGES`
names each stage's builder.

One module per stage (design, joint_map, exact, nuts, k_selection, map_cell, model_check)
and the frozen values they share (:mod:`~ssmobs.config.stage_inputs.frozen`); everything is
importable from here.
"""

from __future__ import annotations

from .design import TrajectoriesInputs, trajectories_inputs
from .design_sets import DesignSetsInputs, design_sets_inputs, design_sets_payload
from .exact import ExactInputs, exact_inputs
from .frozen import DESIGN_DIR, DESIGN_SET, design_set_path, inputs_payload
from .joint_map import JointMapInputs, joint_map_inputs
from .k_selection import (
    KSelectionGridInputs,
    KSelectionPointInputs,
    KSelectionPointsInputs,
    k_selection_grid_inputs,
    k_selection_points_inputs,
)
from .map_cell import (
    MAP_CELLS_DIR,
    MapCellInputs,
    MapCellsInputs,
    map_cell_inputs,
    map_cells_inputs,
)
from .model_check import (
    ModelCheckInputs,
    check_case,
    model_check_inputs,
    model_check_stan_inputs,
)
from .nuts import (
    DRAWS_DIR,
    NUTS_THREADS,
    SAMPLER_FIELDS,
    GatherInputs,
    NutsBatchesInputs,
    NutsRecordsInputs,
    gather_inputs,
    nuts_batches_inputs,
    nuts_records_inputs,
)
from .program import ProgramInputs, program_inputs, program_payload

__all__ = [
    "DESIGN_DIR",
    "DESIGN_SET",
    "DRAWS_DIR",
    "MAP_CELLS_DIR",
    "NUTS_THREADS",
    "SAMPLER_FIELDS",
    "DesignSetsInputs",
    "ExactInputs",
    "GatherInputs",
    "JointMapInputs",
    "KSelectionGridInputs",
    "KSelectionPointInputs",
    "KSelectionPointsInputs",
    "MapCellInputs",
    "MapCellsInputs",
    "ModelCheckInputs",
    "NutsBatchesInputs",
    "NutsRecordsInputs",
    "ProgramInputs",
    "TrajectoriesInputs",
    "check_case",
    "design_set_path",
    "design_sets_inputs",
    "design_sets_payload",
    "exact_inputs",
    "gather_inputs",
    "inputs_payload",
    "joint_map_inputs",
    "k_selection_grid_inputs",
    "k_selection_points_inputs",
    "map_cell_inputs",
    "map_cells_inputs",
    "model_check_inputs",
    "model_check_stan_inputs",
    "nuts_batches_inputs",
    "nuts_records_inputs",
    "program_inputs",
    "program_payload",
    "trajectories_inputs",
]
