"""Stage-level glue called by the workflow scripts: read inputs, compute, write outputs.

Each function here is what one Snakemake rule does, so a step can be rerun by hand by
calling it with the same paths; the numerics live in the modules it calls.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from . import io
from .log import Progress

logger = logging.getLogger("ssmobs")

PathLike = str | os.PathLike


# ------------------------------------------------------------------ joint MAP (Sec. III.B)
def joint_map_dataset(result: Any, model: Any, T: int, attrs: dict) -> "xarray.Dataset":  # noqa: F821
    """Full Theta_hat and local variances of every k as a labelled NetCDF dataset."""
    import xarray as xr

    names = model.theta_names(T)
    return xr.Dataset(
        {"theta_hat": (("k", "component"), result.theta_hat),
         "local_variance": (("k", "component"), result.local_variance),
         "status": (("k",), np.asarray(result.status, dtype=str))},
        coords={"k": np.arange(result.theta_hat.shape[0]), "component": names},
        attrs=attrs,
    )


def run_joint_map(trajectories: PathLike, scenario: dict, settings: dict,
                  table: PathLike, summary: PathLike, theta: PathLike | None = None) -> dict:
    """Rule joint_map: joint MAP + checks for every design trajectory of a scenario."""
    from .joint_map import JointMapSettings, joint_map, joint_map_summary
    from .trajectories import read_trajectories

    traj = read_trajectories(trajectories)
    model = traj.model
    bounds = model.prior_bounds(traj.omega, scenario.get("prior"))
    progress = Progress(f"joint MAP {scenario['name']}", traj.K, logger)
    result = joint_map(model, traj.z, bounds, traj.omega, traj.x0,
                       JointMapSettings.from_mapping(settings), progress=progress)
    frame = result.to_frame(model, traj.T)
    info = joint_map_summary(frame, model, traj.omega, traj.x0)
    info.update(scenario=scenario["name"], model=model.slug, T=traj.T,
                method=scenario.get("method", "design"), seed=scenario.get("seed"),
                prior=list(bounds.variants))
    logger.info("scenario %s: |K^max| = %d of %d", scenario["name"], info["K_max"], info["K"])
    io.write_parquet(table, frame)
    if theta is not None:
        io.write_netcdf(theta, joint_map_dataset(result, model, traj.T,
                                                 {"scenario": scenario["name"]}))
    io.write_json(summary, info)
    return info


def run_k_selection_point(disturbances: PathLike, scenario: dict, K: int, method: str,
                          seed: int, settings: dict, out: PathLike) -> dict:
    """Rule k_selection_point: joint-MAP summary of one K_i of the choice of K (Sec. IV.A)."""
    from .joint_map import JointMapSettings, joint_map, joint_map_summary
    from .config import disturbance_dim
    from .trajectories import make_trajectories

    sc = {**scenario, "K": K, "method": method, "seed": seed}
    matrix, attrs = io.read_disturbances(disturbances, q=disturbance_dim(sc), K=K)
    traj = make_trajectories(sc, matrix, provenance=attrs)
    model = traj.model
    bounds = model.prior_bounds(traj.omega, sc.get("prior"))
    result = joint_map(model, traj.z, bounds, traj.omega, traj.x0,
                       JointMapSettings.from_mapping(settings))
    info = joint_map_summary(result.to_frame(model, traj.T), model, traj.omega, traj.x0)
    info.update(K_i=K, method=method, seed=seed, scenario=scenario["name"])
    io.write_json(out, info)
    return info
