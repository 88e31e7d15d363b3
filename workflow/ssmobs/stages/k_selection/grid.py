"""Glue of the choice of K (Sec. IV.A; rule k_selection_grid in
``workflow/rules/k_selection.smk``): the joint-MAP summaries V_{K_i} of every K_i of a grid.

The rules that read them, select_k and table_k_selection, write stamped outputs: their glue
is in :mod:`ssmobs.stages.k_selection.choice`.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

from ... import io
from ...log import Progress
from .. import PathLike

if TYPE_CHECKING:
    import numpy as np

    from ...config.scenario import Scenario

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


def run_k_selection_grid(
    design_dir: PathLike,
    scenario: Scenario,
    K_grid: list[int],
    method: str,
    seed: int,
    sets: str,
    settings: dict,
    design_cfg: dict,
    *,
    points_dir: PathLike,
    out: PathLike,
) -> list[dict]:
    """Rule k_selection_grid: V_{K_i} for every K_i of one grid (method, set variant, seed).

    Each point is cached on its own in ``points_dir/K<K_i>.json`` as soon as it is done (a
    rerun after a kill computes only the missing ones; grids of other k_selection entries on
    the same scenario find it too, and a file lock keeps two jobs from computing it at once),
    each set in ``design_dir`` (:func:`ssmobs.design.disturbance_sets.disturbance_set`)."""
    from ...design.disturbance_sets import disturbance_set
    from ...k_selection import set_seed

    progress = Progress(f"choice of K {scenario.name} {method} {sets} seed {seed}", len(K_grid))
    rows = []
    for K in K_grid:
        point = Path(points_dir) / f"K{K}.json"
        info = None
        with io.file_lock(Path(points_dir) / ".locks" / f"K{K}.lock"):
            if point.exists():
                try:
                    info = io.read_checked_json(point, required=["K_i", "method", "seed"])
                except io.CorruptFileError as err:
                    logger.warning("recomputing: %s", err.what)
            if info is None:
                s = set_seed(seed, K, sets)
                path = Path(design_dir) / f"q{scenario.disturbance_dim}_K{K}_{method}_seed{s}.nc"
                matrix, attrs = disturbance_set(
                    path, scenario.disturbance_dim, K, method, s, design_cfg
                )
                info = run_k_selection_point(
                    matrix, attrs, scenario, K, method, seed, settings, point, sets=sets
                )
        rows.append({**info, "scenario": scenario.name})
        progress.update()
    io.write_json(out, {"points": rows})
    return rows
