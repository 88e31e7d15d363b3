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
    import numpy as np

    from ...config.scenario import Scenario
    from ...config.stage_inputs import KSelectionGridInputs

logger = logging.getLogger("ssmobs")


def run_k_selection_point(
    disturbances: np.ndarray,
    provenance: dict,
    scenario: Scenario,
    K: int,
    method: str,
    seed: int,
    settings: dict,
    out: PathLike,
    *,
    sets: str = "independent",
) -> dict:
    """One point of rule k_selection_grid: the joint-MAP summary of one K_i (Sec. IV.A).

    ``disturbances`` and ``provenance``: the (q x K) design set and its file's attributes,
    as :func:`ssmobs.design.disturbance_sets.disturbance_set` returns them.  ``seed`` is the run's
    seed; the set itself was drawn with :func:`ssmobs.k_selection.set_seed` (seed, K, sets).
    """
    from ...design.trajectories import make_trajectories
    from ...joint_map.driver import joint_map_of
    from ...joint_map.problem import JointMapProblem
    from ...k_selection import set_seed

    sc = scenario.replace(K=K, method=method, seed=set_seed(seed, K, sets))
    traj = make_trajectories(sc, disturbances, provenance=provenance)
    # the scenario's start of the states, the paper's one start (as the key holds them)
    settings = sc.joint_map_config(settings, single_start=True)
    _, _, info = joint_map_of(JointMapProblem.of_trajectories(traj, sc.prior, settings))
    # no scenario name: a point is keyed by what it computes, the grid names the scenario
    info.update(K_i=K, method=method, seed=seed, sets=sets, set_seed=sc.seed)
    io.write_checked_json(out, info)
    return info


def _point_scenario(inputs: KSelectionGridInputs) -> Scenario:
    """The scenario the points of a grid compute with, made from the grid's inputs alone
    (each point sets its K, method and seed)."""
    from ...config.scenario import Scenario

    return Scenario.from_config(inputs.scenario_config)


def run_k_selection_grid(inputs: KSelectionGridInputs, paths: Mapping[str, PathLike]) -> list[dict]:
    """Rule k_selection_grid: V_{K_i} for every K_i of one grid (method, set variant, seed),
    from its :class:`~ssmobs.config.stage_inputs.KSelectionGridInputs` alone; ``paths``: the
    output ``grid``, whose file name names the grid (as in :data:`ssmobs.stage_table.STAGES`).

    Each point is cached on its own in the points' folder, ``K<K_i>.json``, as soon as it is
    done (a rerun after a kill computes only the missing ones; grids of other k_selection
    entries on the same scenario find it too, and a file lock keeps two jobs from computing
    it at once), each set among the design sets
    (:func:`ssmobs.design.disturbance_sets.disturbance_set`)."""
    from ...config.stage_inputs.frozen import design_set_path
    from ...design.disturbance_sets import disturbance_set
    from ...k_selection import set_seed

    out = paths["grid"]
    method, sets, seed = inputs.grid_of(Path(out).name)
    points_dir = Path(inputs.points) / f"{method}_{sets}_seed{seed}"
    sc = _point_scenario(inputs)
    settings = inputs.settings_config
    progress = Progress(
        f"choice of K {inputs.scenario} {method} {sets} seed {seed}", len(inputs.K_grid)
    )
    rows = []
    for K in inputs.K_grid:
        point = points_dir / f"K{K}.json"
        info = None
        with io.file_lock(points_dir / ".locks" / f"K{K}.lock"):
            if point.exists():
                try:
                    info = io.read_checked_json(point, required=["K_i", "method", "seed"])
                except io.CorruptFileError as err:
                    logger.warning("recomputing: %s", err.what)
            if info is None:
                s = set_seed(seed, K, sets)
                q = sc.disturbance_dim
                path = design_set_path(inputs.design, q, K, method, s)
                matrix, attrs = disturbance_set(path, q, K, method, s, inputs.design_config)
                info = run_k_selection_point(
                    matrix, attrs, sc, K, method, seed, settings, point, sets=sets
                )
        rows.append({**info, "scenario": inputs.scenario})
        progress.update()
    io.write_json(out, {"points": rows})
    return rows
