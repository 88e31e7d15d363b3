"""Glue of the design stage (Sec. III.A; rules in ``workflow/rules/design.smk``): the design
disturbances, shared by scenarios, and each scenario's design trajectories."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

from .. import io
from . import PathLike

if TYPE_CHECKING:
    import numpy as np

    from ..config.scenario import Scenario
    from ..design.disturbances import DesignResult
    from ..design.trajectories import Trajectories

logger = logging.getLogger("ssmobs")


def run_design_disturbances(
    q: int, K: int, method: str, seed: int, design_cfg: dict, out: PathLike
) -> DesignResult:
    """Rule design_disturbances: one (q x K) disturbance matrix (LCD design, or a random
    baseline), written to ``out`` (:func:`ssmobs.design.disturbances.design_disturbances`)."""
    from ..design.disturbances import design_disturbances

    logger.info("design disturbances q=%d K=%d method=%s seed=%d", q, K, method, seed)
    result = design_disturbances(
        q, K, method, seed, b_max=design_cfg["b_max"], progress=logger.info
    )
    logger.info(
        "done: %d iterations, distance %.6g (before covariance correction %.6g), %s",
        result.iterations,
        result.distance,
        result.distance_raw,
        result.covariance_correction,
    )
    io.write_disturbances(out, result)
    return result


def disturbance_set(
    path: PathLike, q: int, K: int, method: str, seed: int, design_cfg: dict
) -> tuple[np.ndarray, dict]:
    """The disturbance set cached at ``path`` (the file rule design_disturbances writes),
    made here when it is missing or damaged: the choice of K makes its many small sets in
    the job that scores them instead of one Snakemake job each.  Under a file lock, so two
    jobs never make the same set, and the temporaries a killed maker left are swept."""
    path = Path(path)
    with io.file_lock(path.parent / ".locks" / f"{path.name}.lock"):
        io.sweep_temporaries([path])  # no maker runs: we hold the lock
        try:
            return io.read_disturbances(path, q=q, K=K)
        except (FileNotFoundError, io.CorruptFileError):
            pass
        run_design_disturbances(q, K, method, seed, design_cfg, path)
    return io.read_disturbances(path, q=q, K=K)


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
