"""Glue of the choice of K (Sec. IV.A; rule k_selection_grid in
``workflow/rules/k_selection.smk``): the joint-MAP summaries V_{K_i} of every K_i of a grid.

The rules that read them, select_k and table_k_selection, write stamped outputs: their glue
is in :mod:`ssmobs.stages.k_selection.choice`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from ... import io
from ...log import Progress
from .. import PathLike

if TYPE_CHECKING:
    from ...config.stage_inputs import KSelectionGridInputs, KSelectionPointInputs

logger = logging.getLogger("ssmobs")


def run_k_selection_point(inputs: KSelectionPointInputs, paths: Mapping[str, PathLike]) -> dict:
    """One point of rule k_selection_grid: the joint-MAP summary V_{K_i} of one K_i (Sec.
    IV.A), from its :class:`~ssmobs.config.stage_inputs.KSelectionPointInputs` alone;
    ``paths``: the output ``point``.

    Its design set of K_i disturbances is drawn from :func:`ssmobs.k_selection.set_seed` of
    the run's seed, K_i and the set variant, among the design sets
    (:func:`ssmobs.design.disturbance_sets.disturbance_set`: made where it is missing)."""
    import numpy as np

    from ...design.disturbance_sets import disturbance_set
    from ...design.trajectories import trajectories_of
    from ...joint_map.driver import joint_map_of
    from ...joint_map.problem import JointMapProblem
    from ...k_selection import set_seed
    from ...models import get_model

    shared = inputs.points
    model = get_model(shared.model)
    s = set_seed(inputs.seed, inputs.K, inputs.sets)
    q = (model.obs_dim + model.state_dim) * shared.T
    path = inputs.design_set(q, s)
    matrix, attrs = disturbance_set(path, q, inputs.K, inputs.method, s, shared.design_config)
    traj = trajectories_of(
        model,
        np.array(model.omega_array(shared.omega_config), dtype=float),
        np.atleast_1d(np.asarray(shared.x0_config, dtype=float)),
        shared.T,
        matrix,
        # no scenario name: a point is keyed by what it computes, the grid names the scenario
        name="",
        method=inputs.method,
        seed=s,
        provenance=attrs,
    )
    # the scenario's start of the states, the paper's one start (as the key holds them)
    problem = JointMapProblem.of_trajectories(traj, shared.prior_config, shared.settings_config)
    _, _, info = joint_map_of(problem)
    info.update(K_i=inputs.K, method=inputs.method, seed=inputs.seed, sets=inputs.sets, set_seed=s)
    io.write_checked_json(paths["point"], info)
    return info


def run_k_selection_grid(inputs: KSelectionGridInputs, paths: Mapping[str, PathLike]) -> list[dict]:
    """Rule k_selection_grid: V_{K_i} for every K_i of one grid (method, set variant, seed),
    from its :class:`~ssmobs.config.stage_inputs.KSelectionGridInputs` alone; ``paths``: the
    output ``grid``, whose file name names the grid (as in :data:`ssmobs.stage_table.STAGES`).

    Each point (:func:`run_k_selection_point`) is cached on its own in the points' folder,
    ``<grid>/K<K_i>.json``, as soon as it is done (a rerun after a kill computes only the
    missing ones; grids of other k_selection entries on the same scenario find it too, and a
    file lock keeps two jobs from computing it at once)."""
    out = paths["grid"]
    method, sets, seed = inputs.grid_of(Path(out).name)
    progress = Progress(
        f"choice of K {inputs.scenario} {method} {sets} seed {seed}", len(inputs.K_grid)
    )
    rows = []
    for K in inputs.K_grid:
        point_inputs = inputs.points_inputs.point(K, method, sets, seed)
        point = Path(inputs.points) / point_inputs.file
        info = None
        with io.file_lock(point.parent / ".locks" / f"K{K}.lock"):
            if point.exists():
                try:
                    info = io.read_checked_json(point, required=["K_i", "method", "seed"])
                except io.CorruptFileError as err:
                    logger.warning("recomputing: %s", err.what)
            if info is None:
                info = run_k_selection_point(point_inputs, {"point": point})
        rows.append({**info, "scenario": inputs.scenario})
        progress.update()
    io.write_json(out, {"points": rows})
    return rows
