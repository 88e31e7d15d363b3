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
Each cell is cached on its own under its content key (the cell, K, the design, joint-MAP and
exact settings and the code; :meth:`ssmobs.cache_keys.CacheKeys.map_cells`), so a grid
extended by new values or horizons computes only the new cells.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .. import io
from ..binomial import clopper_pearson
from ..config.scenario import Scenario
from ..log import Progress

logger = logging.getLogger("ssmobs")

#: keys every cached cell file must hold
CELL_KEYS = ("K_max", "K_max_frac", "exact")


def _median(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else math.nan


def cell_summary(
    scenario: Scenario,
    disturbances: str | os.PathLike,
    design_cfg: Mapping[str, Any],
    joint_settings: Mapping[str, Any],
    exact_settings: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """One cell: its design trajectories, joint MAP and (``exact_settings`` given and the
    model linear in the states) exact marginal; the row of the map's table (module
    docstring), without the map's own columns."""
    from ..design.disturbance_sets import disturbance_set
    from ..design.trajectories import make_trajectories
    from ..exact.marginal import exact_marginal
    from ..exact.settings import ExactSettings
    from ..joint_map.multi_start_summary import multi_start_of
    from ..joint_map.problem import JointMapProblem

    model = scenario.model
    matrix, attrs = disturbance_set(
        disturbances,
        scenario.disturbance_dim,
        scenario.K,
        scenario.method,
        scenario.seed,
        dict(design_cfg),
    )
    traj = make_trajectories(scenario, matrix, provenance=attrs)
    settings = scenario.joint_map_config(joint_settings)
    # every start's results and the distinct maxima; start 0 alone is the joint MAP of K^max
    problem = JointMapProblem.of_trajectories(traj, scenario.prior, settings)
    _, frame, info = multi_start_of(problem)
    K = scenario.K
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


def map_table(
    entry: Mapping[str, Any],
    cells: Sequence[tuple[Mapping[str, Any], str]],
    design_dir: str | os.PathLike,
    design_cfg: Mapping[str, Any],
    joint_settings: Mapping[str, Any],
    exact_settings: Mapping[str, Any] | None,
    cells_dir: str | os.PathLike,
) -> pd.DataFrame:
    """One row per cell of a map (``cells``: each cell's scenario entry and content key).

    A cell found in ``cells_dir/<key>.json`` is read, any other computed and written there
    at once (a rerun after a kill computes only the missing cells); every row is the one its
    file holds, its columns in :func:`cell_columns`' order, so a resumed map's table is the
    same bytes as a fresh one's."""
    from ..models import get_model

    names = get_model(entry["base"]["model"]).param_names  # every cell's model
    progress = Progress(f"observability map {entry['name']}", len(cells))
    rows = []
    for cell, key in cells:
        path = Path(cells_dir) / f"{key}.json"
        row = _read_cell(path)
        if row is None:
            sc = Scenario.from_config(cell)
            disturbances = (
                Path(design_dir) / f"q{sc.disturbance_dim}_K{sc.K}_{sc.method}_seed{sc.seed}.nc"
            )
            io.write_checked_json(
                path, cell_summary(sc, disturbances, design_cfg, joint_settings, exact_settings)
            )
            row = _read_cell(path)  # a fresh row as a cached one reads (JSON types)
            if row is None:
                raise io.CorruptFileError(f"{path}: not readable right after writing it")
        rows.append(
            {
                "map": entry["name"],
                "model": cell["model"],
                "vary": entry["vary"],
                "value": float(cell["omega"][entry["vary"]]),
                "T": int(cell["T"]),
                "K": int(cell["K"]),
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


def run_map_cells(
    entry: Mapping[str, Any],
    cells: Sequence[tuple[Mapping[str, Any], str]],
    design_dir: str | os.PathLike,
    design_cfg: Mapping[str, Any],
    joint_settings: Mapping[str, Any],
    exact_settings: Mapping[str, Any],
    cells_dir: str | os.PathLike,
    out: str | os.PathLike,
) -> pd.DataFrame:
    """Rule observability_map_cells: every cell of one map (:func:`map_table`; the exact
    settings apply where the map runs the exact stage), as one table at ``out``."""
    frame = map_table(
        entry,
        cells,
        design_dir,
        design_cfg,
        joint_settings,
        exact_settings if entry["exact"] else None,
        cells_dir,
    )
    io.write_parquet(out, frame)
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
