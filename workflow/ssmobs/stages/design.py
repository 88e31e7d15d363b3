"""Glue of the design stage (Sec. III.A; rules in ``workflow/rules/design.smk``): the design
disturbances, shared by scenarios, and each scenario's design trajectories."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from .. import io
from . import PathLike

if TYPE_CHECKING:
    from ..config.stage_inputs import TrajectoriesInputs
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
    inputs: TrajectoriesInputs, paths: Mapping[str, PathLike]
) -> Trajectories:
    """Rule design_trajectories: design states and observations x~(k), z~(k) of one scenario
    (Eq. (1)) from its design set, from its
    :class:`~ssmobs.config.stage_inputs.TrajectoriesInputs` alone; ``paths``: the outputs
    ``trajectories`` and ``checksum`` (beside it), as in :data:`ssmobs.stage_table.STAGES`."""
    from ..design.trajectories import trajectories_of, write_trajectories
    from ..models import get_model

    model = get_model(inputs.model)
    q = (model.obs_dim + model.state_dim) * inputs.T
    matrix, attrs = io.read_disturbances(inputs.design_set(q), q=q, K=inputs.K)
    traj = trajectories_of(
        model,
        np.array(model.omega_array(inputs.omega_config), dtype=float),
        np.atleast_1d(np.asarray(inputs.x0_config, dtype=float)),
        inputs.T,
        matrix,
        name=inputs.scenario,
        method=inputs.method,
        seed=inputs.seed,
        provenance=attrs,
    )
    logger.info("scenario %s: %d trajectories of length %d", inputs.scenario, traj.K, traj.T)
    out = paths["trajectories"]
    assert str(paths["checksum"]) == f"{out}.sha256", "the checksum lies beside the file"
    write_trajectories(out, traj)
    io.write_checksum(out)
    return traj
