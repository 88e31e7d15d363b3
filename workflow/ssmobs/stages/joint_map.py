"""Glue of the joint-MAP stage (Sec. III.B; rule joint_map in ``workflow/rules/joint_map.smk``):
the scenario's :class:`~ssmobs.joint_map.problem.JointMapProblem` from one start
(:func:`~ssmobs.joint_map.driver.joint_map_of`) or several
(:func:`~ssmobs.joint_map.multi_start_summary.multi_start_of`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from .. import io
from ..log import Progress
from . import PathLike

if TYPE_CHECKING:
    from ..config.stage_inputs import JointMapInputs

logger = logging.getLogger("ssmobs")


def run_joint_map(inputs: JointMapInputs, paths: Mapping[str, PathLike]) -> dict:
    """Rule joint_map: joint MAP + checks for every design trajectory of a scenario, from
    its :class:`~ssmobs.config.stage_inputs.JointMapInputs` alone; ``paths``: the outputs
    ``table`` (per k), ``summary`` and ``theta`` (the maxima), as in
    :data:`ssmobs.stage_table.STAGES`."""
    from ..design.trajectories import read_trajectories
    from ..joint_map.driver import joint_map_of
    from ..joint_map.multi_start_summary import multi_start_of
    from ..joint_map.problem import JointMapProblem

    traj = read_trajectories(inputs.trajectories)
    model = traj.model
    settings = inputs.settings_config
    name = inputs.scenario
    n_starts = int(settings.get("n_starts", 1))
    progress = Progress(f"joint MAP {name}", traj.K * n_starts, logger)
    problem = JointMapProblem.of_trajectories(traj, inputs.prior_config, settings)
    run = multi_start_of if n_starts > 1 else joint_map_of
    result, frame, info = run(problem, progress)
    info.update(
        scenario=name,
        model=model.slug,
        T=traj.T,
        method=inputs.method,
        seed=inputs.seed,
        prior=list(problem.bounds.variants),
        start_states=settings["start_states"],
        mu0_median=float(np.nanmedian(frame["mu0"])),
    )
    logger.info("scenario %s: |K^max| = %d of %d", name, info["K_max"], info["K"])
    if n_starts > 1:
        logger.info(
            "scenario %s: |K^max_unique| = %d of %d (%d starts per trajectory; a maximum "
            "with a twin under a symmetry: %d; a start that ran off above every maximum: %d)",
            name,
            info["K_max_unique"],
            info["K"],
            n_starts,
            info["K_symmetric_twin"],
            info["K_edge_supremum"],
        )
    io.write_parquet(paths["table"], frame)
    io.write_joint_map(paths["theta"], result, model, traj.T, {"scenario": name})
    io.write_json(paths["summary"], info)
    return info
