"""Glue of the joint-MAP stage (Sec. III.B; rule joint_map in ``workflow/rules/joint_map.smk``).

:func:`joint_map_of` is also what the choice of K (:mod:`ssmobs.stages.k_selection`) and the
table of barrier starts (:func:`ssmobs.stages.outputs.run_joint_map_mu0_sweep`) run.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import io
from ..log import Progress
from . import PathLike

if TYPE_CHECKING:
    import pandas

    from ..joint_map import JointMapResult
    from ..models.base import PriorBounds
    from ..scenario import Scenario
    from ..trajectories import Trajectories

logger = logging.getLogger("ssmobs")


def joint_map_of(
    traj: Trajectories, prior: Any, settings: dict, progress: Progress | None = None
) -> tuple[JointMapResult, pandas.DataFrame, dict, PriorBounds]:
    """Joint MAP of every trajectory, its per-k table, its summary and the prior bounds."""
    from ..joint_map import JointMapSettings, joint_map, joint_map_summary

    model = traj.model
    bounds = model.prior_bounds(traj.omega, prior)
    result = joint_map(
        model,
        traj.z,
        bounds,
        traj.omega,
        traj.x0,
        JointMapSettings.from_mapping(settings),
        progress=progress,
    )
    frame = result.to_frame(model, traj.T)
    return result, frame, joint_map_summary(frame, model, traj.omega, traj.x0), bounds


def run_joint_map(
    trajectories: PathLike,
    scenario: Scenario,
    settings: dict,
    table: PathLike,
    summary: PathLike,
    theta: PathLike | None = None,
) -> dict:
    """Rule joint_map: joint MAP + checks for every design trajectory of a scenario."""
    from ..trajectories import read_trajectories

    traj = read_trajectories(trajectories)
    model = traj.model
    progress = Progress(f"joint MAP {scenario.name}", traj.K, logger)
    settings = {**settings, "start_states": scenario.joint_map_start}
    result, frame, info, bounds = joint_map_of(traj, scenario.prior, settings, progress)
    info.update(
        scenario=scenario.name,
        model=model.slug,
        T=traj.T,
        method=scenario.method,
        seed=scenario.seed,
        prior=list(bounds.variants),
        start_states=settings["start_states"],
        mu0_median=float(np.nanmedian(frame["mu0"])),
    )
    logger.info("scenario %s: |K^max| = %d of %d", scenario.name, info["K_max"], info["K"])
    io.write_parquet(table, frame)
    if theta is not None:
        io.write_netcdf(
            theta, io.joint_map_dataset(result, model, traj.T, {"scenario": scenario.name})
        )
    io.write_json(summary, info)
    return info
