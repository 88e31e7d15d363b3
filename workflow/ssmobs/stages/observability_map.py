"""The observability map's stage (issue 21): where in (true parameter, T) a model is
observable, and how well.

A map (one entry of the config's ``observability_maps``) is a grid of *cells*: a base
scenario (model, Omega, x0, prior, method, seed) with one parameter set to each of
``values`` and the horizon set to each of ``T`` (the cells' scenario entries:
:func:`ssmobs.config.maps.cell_entries`).  Every cell gets K design trajectories
(Sec. III.A) and
- the joint MAP (Sec. III.B): |K^max|/K with its exact binomial 95 % interval and, over
  K^max, the median local variance of every Omega component; |K^max_unique|/K with its
  interval, the trajectories with exactly one distinct maximum that passes the checks over
  the cell's ``n_starts`` starts (:mod:`ssmobs.joint_map.multi_start`; the base's
  ``joint_map_n_starts``, else the ``joint_map`` block's ``n_starts``): with one start, the
  default, it equals |K^max| (no other start looked for a second maximum);
- for a model linear in the states, the exact marginal posterior p(Omega | z) (Kalman filter
  and grid, :mod:`ssmobs.exact.marginal`): the fraction of trajectories with a unique interior
  maximum (Definition 3) with its interval, and over those the median Laplace standard
  deviation and the median width of the 90 % interval of every Omega component ("how
  well"), plus the fraction whose cut-off improper spike is not negligible.
Each cell is cached on its own under its content key, what it reads
(:class:`~ssmobs.config.stage_inputs.MapCellInputs`: the cell, K, the design, joint-MAP and
exact settings) with the code (:meth:`ssmobs.cache_keys.CacheKeys.map_cells`), so a grid
extended by new values or horizons computes only the new cells.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from .. import io
from ..binomial import clopper_pearson
from ..log import Progress
from . import PathLike

if TYPE_CHECKING:
    from ..config.stage_inputs import MapCellInputs, MapCellsInputs

logger = logging.getLogger("ssmobs")

#: keys every cached cell file must hold
CELL_KEYS = ("K_max", "K_max_frac", "exact")


def _median(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else math.nan


def cell_summary(inputs: MapCellInputs) -> dict[str, Any]:
    """One cell, from its :class:`~ssmobs.config.stage_inputs.MapCellInputs` alone: its
    design trajectories, joint MAP and (the map runs the exact stage and the model is linear
    in the states) exact marginal; the row of the map's table (module docstring), without
    the map's own columns."""
    from ..design.disturbance_sets import disturbance_set
    from ..design.trajectories import trajectories_of
    from ..exact.marginal import exact_marginal
    from ..exact.settings import ExactSettings
    from ..joint_map.multi_start_summary import multi_start_of
    from ..joint_map.problem import JointMapProblem
    from ..models import get_model

    model = get_model(inputs.model)
    K = inputs.K
    q = (model.obs_dim + model.state_dim) * inputs.T
    path = inputs.design_set(q)
    matrix, attrs = disturbance_set(path, q, K, inputs.method, inputs.seed, inputs.design_config)
    traj = trajectories_of(
        model,
        np.array(model.omega_array(inputs.omega_config), dtype=float),
        np.atleast_1d(np.asarray(inputs.x0_config, dtype=float)),
        inputs.T,
        matrix,
        name="",  # a cell is keyed by what it computes, not by a name
        method=inputs.method,
        seed=inputs.seed,
        provenance=attrs,
    )
    # every start's results and the distinct maxima; start 0 alone is the joint MAP of K^max
    problem = JointMapProblem.of_trajectories(traj, inputs.prior_config, inputs.settings_config)
    _, frame, info = multi_start_of(problem)
    row: dict[str, Any] = {"K_max": int(info["K_max"])}
    row["K_max_frac"] = row["K_max"] / K
    row["K_max_frac_lo95"], row["K_max_frac_hi95"] = clopper_pearson(row["K_max"], K)
    row["n_starts"] = int(info["n_starts"])
    row["K_max_unique"] = int(info["K_max_unique"])
    row["K_max_unique_frac"] = row["K_max_unique"] / K
    row["K_max_unique_frac_lo95"] = float(info["K_max_unique_lo95"])
    row["K_max_unique_frac_hi95"] = float(info["K_max_unique_hi95"])
    ok = (frame["status"] == "ok").to_numpy()
    for name in model.param_names:
        row[f"lvar_median_{name}"] = _median(frame.loc[ok, f"lvar_{name}"].to_numpy(float))
    exact_settings = inputs.exact_config
    row["exact"] = exact_settings is not None and model.linear_in_states
    if exact_settings is not None and model.linear_in_states:
        result = exact_marginal(
            model, traj.z, problem.bounds, ExactSettings.from_mapping(exact_settings)
        )
        ex = result.to_frame(model)
        unique = int((ex["maxima"] == "unique").sum())
        used = ex["converged"].to_numpy(bool)
        row["exact_unique"] = unique
        row["exact_unique_frac"] = unique / K
        row["exact_unique_frac_lo95"], row["exact_unique_frac_hi95"] = clopper_pearson(unique, K)
        row["exact_used"] = int(used.sum())
        row["spike_frac"] = float((used & ex["spike_not_negligible"].to_numpy(bool)).sum()) / K
        for name in model.param_names:
            sd = ex.loc[used, f"laplace_sd_{name}"].to_numpy(float)
            width = (ex.loc[used, f"{name}_q95"] - ex.loc[used, f"{name}_q5"]).to_numpy(float)
            row[f"sd_median_{name}"] = _median(sd)
            row[f"width90_median_{name}"] = _median(width)
    return row


def cell_columns(param_names: Sequence[str], row: Mapping[str, Any]) -> list[str]:
    """The columns of a cell's row in the order :func:`cell_summary` makes them (a cell file
    sorts its keys), any others after them."""
    order = ["K_max", "K_max_frac", "K_max_frac_lo95", "K_max_frac_hi95", "n_starts"]
    order += ["K_max_unique", "K_max_unique_frac", "K_max_unique_frac_lo95"]
    order += ["K_max_unique_frac_hi95"]
    order += [f"lvar_median_{n}" for n in param_names]
    order += ["exact", "exact_unique", "exact_unique_frac", "exact_unique_frac_lo95"]
    order += ["exact_unique_frac_hi95", "exact_used", "spike_frac"]
    order += [f"{s}_median_{n}" for n in param_names for s in ("sd", "width90")]
    return [c for c in order if c in row] + sorted(c for c in row if c not in order)


def _read_cell(path: Path) -> dict[str, Any] | None:
    if not path.exists():
        return None
    try:
        return io.read_checked_json(path, required=list(CELL_KEYS))
    except io.CorruptFileError as err:
        logger.warning("recomputing: %s", err.what)
        return None


def map_table(inputs: MapCellsInputs) -> pd.DataFrame:
    """One row per cell of a map, from its :class:`~ssmobs.config.stage_inputs.MapCellsInputs`
    alone.

    A cell found in its file (:meth:`~ssmobs.config.stage_inputs.MapCellsInputs.cell_file`)
    is read, any other computed (:func:`cell_summary`) and written there at once (a rerun
    after a kill computes only the missing cells); every row is the one its file holds, its
    columns in :func:`cell_columns`' order, so a resumed map's table is the same bytes as a
    fresh one's."""
    from ..models import get_model

    progress = Progress(f"observability map {inputs.map}", len(inputs.cells))
    rows = []
    for key, cell in inputs.cells:
        path = Path(inputs.cell_file(key))
        row = _read_cell(path)
        if row is None:
            io.write_checked_json(path, cell_summary(cell))
            row = _read_cell(path)  # a fresh row as a cached one reads (JSON types)
            if row is None:
                raise io.CorruptFileError(f"{path}: not readable right after writing it")
        names = get_model(cell.model).param_names
        rows.append(
            {
                "map": inputs.map,
                "model": cell.model,
                "vary": inputs.vary,
                "value": float(cell.omega_config[inputs.vary]),
                "T": cell.T,
                "K": cell.K,
                **{c: row[c] for c in cell_columns(names, row)},
            }
        )
        progress.update()
    return pd.DataFrame(rows)


def figure_map(
    frame: pd.DataFrame, entry: Mapping[str, Any], title: str, paths: Sequence[str]
) -> None:
    """Left: the observable fraction over the varied parameter, one colour per T (exact
    marginal: solid with its 95 % band; joint MAP |K^max|/K: dashed; where a cell ran
    several starts, |K^max_unique|/K: dotted); the paper's cells ringed.  Right: how well,
    the median 90 % interval width of the varied parameter (exact) or 2 x 1.645 x
    sqrt(median local variance) (joint MAP, models without the exact stage)."""
    from ..reports.figures import _plt, save_figure

    plt = _plt()
    vary = entry["vary"]
    exact = bool(frame["exact"].any())
    # several starts: |K^max_unique|/K beside |K^max|/K (with one start the two are equal)
    multi = "n_starts" in frame and bool((frame["n_starts"] > 1).any())
    fig, (left, right) = plt.subplots(1, 2, figsize=(9.0, 3.4))
    for i, (T, cells) in enumerate(frame.groupby("T", sort=True)):
        cells = cells.sort_values("value")
        colour = f"C{i % 10}"
        x = cells["value"].to_numpy(float)
        if exact:
            left.plot(x, cells["exact_unique_frac"], "o-", color=colour, label=f"T = {T}")
            left.fill_between(
                x,
                cells["exact_unique_frac_lo95"].astype(float),
                cells["exact_unique_frac_hi95"].astype(float),
                color=colour,
                alpha=0.12,
                lw=0,
            )
            left.plot(x, cells["K_max_frac"], "x--", color=colour, lw=0.8)
            right.plot(x, cells[f"width90_median_{vary}"], "o-", color=colour, label=f"T = {T}")
        else:
            left.plot(x, cells["K_max_frac"], "x--", color=colour, label=f"T = {T}")
            width = 2 * 1.645 * np.sqrt(cells[f"lvar_median_{vary}"].to_numpy(float))
            right.plot(x, width, "x--", color=colour, label=f"T = {T}")
        if multi:
            left.plot(x, cells["K_max_unique_frac"], "+:", color=colour, lw=0.8)
        marked = cells[cells["paper_point"]]
        if len(marked):
            y = marked["exact_unique_frac"] if exact else marked["K_max_frac"]
            left.plot(marked["value"], y, "o", ms=11, mfc="none", mec="k", mew=1.2)
    left.set_ylim(-0.03, 1.03)
    left.set_xlabel(vary)
    left.set_ylabel("fraction of the K trajectories")
    fractions = (
        "unique interior maximum of p(Ω | z) (solid), |K^max|/K (dashed)"
        if exact
        else "|K^max|/K (joint MAP)"
    )
    if multi:
        fractions += ", |K^max_unique|/K (dotted)"
    left.set_title(fractions, fontsize=8)
    right.set_yscale("log")
    right.set_xlabel(vary)
    right.set_ylabel(f"median 90 % width of {vary}")
    right.set_title(
        "exact marginal posterior" if exact else "joint MAP, from the local variance",
        fontsize=8,
    )
    right.legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=9)
    save_figure(fig, paths)
    plt.close(fig)


def run_map_cells(inputs: MapCellsInputs, paths: Mapping[str, PathLike]) -> pd.DataFrame:
    """Rule observability_map_cells: every cell of one map (:func:`map_table`) from its
    :class:`~ssmobs.config.stage_inputs.MapCellsInputs` alone, as one table at the output
    ``table`` of ``paths``."""
    frame = map_table(inputs)
    io.write_parquet(paths["table"], frame)
    return frame


def write_map(
    cells: str | os.PathLike, entry: Mapping[str, Any], paths: Mapping[str, str]
) -> pd.DataFrame:
    """Rule observability_map: the map's table (CSV, Markdown) and figure (PNG, PDF) at
    ``paths`` from the table of its cells."""
    frame = io.read_parquet(cells, required_columns=["value", "T", "K_max_frac", "exact"])
    points = {(float(v), int(T)) for v, T in entry.get("paper_points", [])}
    frame["paper_point"] = [
        (float(v), int(T)) in points for v, T in zip(frame["value"], frame["T"])
    ]
    from ..config.maps import map_value_label
    from ..models import get_model
    from ..reports.tables import write_table

    model = get_model(entry["base"]["model"])
    caption = (
        f"Observability map of {model.title} ({entry['name']}, ours): {entry['vary']} over "
        f"{map_value_label(min(entry['values']))}..{map_value_label(max(entry['values']))}, T in "
        f"{list(entry['T'])}, K = {entry['K']} design trajectories per cell."
    )
    write_table(frame, [paths["csv"], paths["md"]], caption)
    title = f"{model.title}: where is it observable? ({entry['name']}, K = {entry['K']})"
    figure_map(frame, entry, title, [paths["png"], paths["pdf"]])
    return frame
