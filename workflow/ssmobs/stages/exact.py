"""Glue of the exact marginal stage (issue 11; rule exact_marginal in
``workflow/rules/exact_marginal.smk``): Kalman filter with a diffuse x0 and a grid over Omega,
for the scenarios whose model is linear in the states."""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import io
from . import PathLike

if TYPE_CHECKING:
    from ..config.stage_inputs import ExactInputs
    from ..models.base import StateSpaceModel

logger = logging.getLogger("ssmobs")


def exact_summary(
    frame: Any, model: StateSpaceModel, omega: Any, x0: Any, x_true: np.ndarray
) -> dict:
    """The Stan stage's statistics (:func:`ssmobs.nuts.stan_metrics.stan_summary`, over the
    trajectories with a unique interior maximum) plus Definition 3's counts and the share of
    trajectories whose posterior is improper at each boundary and, where x0 drops out inside
    the support, at that point (``improper_interior_<p>_share``, ``interior_<p>_median``)."""
    from ..exact.marginal import MAXIMA_KINDS
    from ..nuts.stan_metrics import stan_summary

    info = stan_summary(frame, model, omega, x0, x_true)
    info["n_exact"] = info["n_stan"]
    for kind in MAXIMA_KINDS:
        info[f"n_{kind}"] = int((frame["maxima"] == kind).sum())
    info["n_box_truncated"] = int(frame["box_truncated"].sum())
    info["n_spike_not_negligible"] = int((frame["converged"] & frame["spike_not_negligible"]).sum())
    for name in model.param_names:
        for side in ("lower", "upper"):
            col = frame[f"improper_{side}_{name}"]
            info[f"improper_{side}_{name}_share"] = float(col.mean()) if len(col) else math.nan
            slopes = frame[f"slope_{side}_{name}"].to_numpy(dtype=float)
            info[f"slope_{side}_{name}_median"] = (
                float(np.nanmedian(slopes)) if np.isfinite(slopes).any() else math.nan
            )
        if f"improper_interior_{name}" in frame.columns:  # x0 drops out inside the support
            info[f"improper_interior_{name}_share"] = float(
                frame[f"improper_interior_{name}"].mean()
            )
            points = frame[f"interior_{name}"].to_numpy(dtype=float)
            info[f"interior_{name}_median"] = (
                float(np.nanmedian(points)) if np.isfinite(points).any() else math.nan
            )
    return info


def run_exact_marginal(inputs: ExactInputs, paths: Mapping[str, PathLike]) -> dict:
    """Rule exact_marginal: exact marginal posteriors of every design trajectory, from its
    :class:`~ssmobs.config.stage_inputs.ExactInputs` alone; ``paths``: the outputs ``table``
    and ``summary``, as in :data:`ssmobs.stage_table.STAGES`."""
    import time

    from ..design.trajectories import read_trajectories
    from ..exact.marginal import exact_marginal
    from ..exact.settings import ExactSettings

    traj = read_trajectories(inputs.trajectories)
    model = traj.model
    name = inputs.scenario
    if not model.linear_in_states:
        raise ValueError(
            f"scenario {name}: model '{model.slug}' is not linear "
            f"in the states; the exact stage does not apply"
        )
    bounds = model.prior_bounds(traj.omega, inputs.prior_config)
    start = time.perf_counter()
    settings = ExactSettings.from_mapping(inputs.settings_config)
    result = exact_marginal(model, traj.z, bounds, settings)
    seconds = time.perf_counter() - start
    frame = result.to_frame(model)
    info = exact_summary(frame, model, traj.omega, traj.x0, traj.x)
    info.update(
        scenario=name,
        model=model.slug,
        T=traj.T,
        grid=result.info,
        prior=list(bounds.variants),
    )
    logger.info(
        "scenario %s (exact): %d of %d with a unique interior maximum, %.1f s",
        name,
        info["n_exact"],
        traj.K,
        seconds,
    )
    io.write_parquet(paths["table"], frame)
    io.write_json(paths["summary"], info)
    return info
