"""Glue of the joint-MAP stage (Sec. III.B; rule joint_map in ``workflow/rules/joint_map.smk``).

:func:`joint_map_of` is also what the choice of K (:mod:`ssmobs.stages.k_selection`) and the
table of barrier starts (:func:`ssmobs.stages.outputs.mu0_sweep.run_joint_map_mu0_sweep`) run.
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

    from ..config.scenario import Scenario
    from ..design.trajectories import Trajectories
    from ..joint_map.driver import JointMapResult
    from ..models.base import PriorBounds

logger = logging.getLogger("ssmobs")


def joint_map_of(
    traj: Trajectories, prior: Any, settings: dict, progress: Progress | None = None
) -> tuple[JointMapResult, pandas.DataFrame, dict, PriorBounds]:
    """Joint MAP of every trajectory, its per-k table, its summary and the prior bounds."""
    from ..joint_map.driver import joint_map, joint_map_summary
    from ..joint_map.settings import JointMapSettings

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


def multi_start_of(
    traj: Trajectories, prior: Any, settings: dict, progress: Progress | None = None
) -> tuple[JointMapResult, pandas.DataFrame, dict, PriorBounds]:
    """:func:`joint_map_of` from ``settings["n_starts"]`` starts
    (:mod:`ssmobs.joint_map.multi_start`):
    the paper's start's result, its table with the per-k columns of the distinct maxima
    beside, and its summary with |K^max_unique| and the other multi-start counts."""
    from ..joint_map.driver import joint_map_summary
    from ..joint_map.multi_start import multi_start_joint_map, multi_start_summary
    from ..joint_map.settings import JointMapSettings

    model = traj.model
    bounds = model.prior_bounds(traj.omega, prior)
    parsed = JointMapSettings.from_mapping(settings)
    multi = multi_start_joint_map(
        model, traj.z, bounds, traj.omega, traj.x0, parsed, progress=progress
    )
    result = multi.runs[0]
    columns = multi.columns()
    frame = result.to_frame(model, traj.T)
    frame = frame.join(columns)
    info = joint_map_summary(frame, model, traj.omega, traj.x0)
    info.update(multi_start_summary(columns, parsed))
    return result, frame, info, bounds


def run_joint_map(
    trajectories: PathLike,
    scenario: Scenario,
    settings: dict,
    table: PathLike,
    summary: PathLike,
    theta: PathLike | None = None,
) -> dict:
    """Rule joint_map: joint MAP + checks for every design trajectory of a scenario."""
    from ..design.trajectories import read_trajectories

    traj = read_trajectories(trajectories)
    model = traj.model
    settings = scenario.joint_map_config(settings)
    n_starts = int(settings.get("n_starts", 1))
    progress = Progress(f"joint MAP {scenario.name}", traj.K * n_starts, logger)
    if n_starts > 1:
        result, frame, info, bounds = multi_start_of(traj, scenario.prior, settings, progress)
    else:
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
    if n_starts > 1:
        logger.info(
            "scenario %s: |K^max_unique| = %d of %d (%d starts per trajectory; a maximum "
            "with a twin under a symmetry: %d; a start that ran off above every maximum: %d)",
            scenario.name,
            info["K_max_unique"],
            info["K"],
            n_starts,
            info["K_symmetric_twin"],
            info["K_edge_supremum"],
        )
    io.write_parquet(table, frame)
    if theta is not None:
        io.write_joint_map(theta, result, model, traj.T, {"scenario": scenario.name})
    io.write_json(summary, info)
    return info
