"""Glue of the design stage (Sec. III.A; rules in ``workflow/rules/design.smk``): the design
disturbances, shared by scenarios, and each scenario's design trajectories."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from .. import io
from . import PathLike

if TYPE_CHECKING:
    from ..config.scenario import Scenario
    from ..design.disturbances import DesignResult
    from ..design.trajectories import Trajectories

logger = logging.getLogger("ssmobs")


def run_design_disturbances(
    q: int, K: int, method: str, seed: int, design_cfg: dict, out: PathLike
) -> DesignResult:
    """Rule design_disturbances: one (q x K) disturbance matrix (LCD design, or a random
    baseline), written to ``out`` (:func:`ssmobs.design.disturbance_sets.write_disturbance_set`)."""
    from ..design.disturbance_sets import write_disturbance_set

    return write_disturbance_set(q, K, method, seed, design_cfg, out)


def run_design_trajectories(
    disturbances: PathLike, scenario: Scenario, out: PathLike
) -> Trajectories:
    """Rule design_trajectories: design states and observations x~(k), z~(k) of one scenario
    (Eq. (1)) from its disturbance set, written to ``out`` with a checksum beside it."""
    from ..design.trajectories import make_trajectories, write_trajectories

    matrix, attrs = io.read_disturbances(disturbances, q=scenario.disturbance_dim, K=scenario.K)
    traj = make_trajectories(scenario, matrix, provenance=attrs)
    logger.info("scenario %s: %d trajectories of length %d", scenario.name, traj.K, traj.T)
    write_trajectories(out, traj)
    io.write_checksum(out)
    return traj
