"""Glue of the table of barrier starts (rule joint_map_mu0_sweep in ``joint_map.smk``):
|K^max|/K of the joint MAP over a range of mu_0 (Sec. III.B, IV.B, IV.C).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from ...config.scenario import Scenario
from .. import PathLike

if TYPE_CHECKING:
    import pandas

    from ...design.trajectories import Trajectories

logger = logging.getLogger("ssmobs")


def mu0_sweep_rows(
    traj: Trajectories, prior: Any, settings: dict, mu0_per_T: list[float]
) -> list[dict]:
    """|K^max|/K of one scenario's joint MAP for mu_0 = f * T (f in ``mu0_per_T``) and for the
    gradient-balance rule (:func:`ssmobs.joint_map.barrier.initial_mu_values`)."""
    from ...joint_map.driver import joint_map_of
    from ...joint_map.problem import JointMapProblem

    rows = []
    variants: list[tuple[str, dict[str, Any]]] = [
        ("gradient balance", {"mu0_rule": "gradient_balance"})
    ]
    variants += [
        (f"{f:g} T", {"mu0_rule": "per_step", "mu0": f * traj.T, "mu0_per_step": 0.0})
        for f in mu0_per_T
    ]
    for label, extra in variants:
        problem = JointMapProblem.of_trajectories(traj, prior, {**settings, **extra})
        result, _, info = joint_map_of(problem)
        assert result.mu_start is not None  # joint_map sets every trajectory's start
        rows.append(
            {
                "mu0": label,
                "mu0_over_T_median": float(np.median(result.mu_start)) / traj.T,
                "ratio": info["ratio"],
                "K_max": info["K_max"],
                "K": info["K"],
                "n_boundary": info["n_boundary"],
            }
        )
    return rows


def run_joint_map_mu0_sweep(
    trajectories: dict[str, PathLike],
    scenarios: dict[str, Scenario],
    settings: dict,
    mu0_per_T: list[float],
    paper_values: PathLike,
    paths: list[PathLike],
) -> pandas.DataFrame:
    """Rule joint_map_mu0_sweep: |K^max|/K of the Sep models over a range of barrier starts.

    One row per mu_0 setting (the gradient-balance rule first, with its median mu_0 / T),
    one column per scenario with its exact binomial 95 % interval (``lo95``, ``hi95``), and
    a last row with the paper's |K^max| / K where stated; written to ``paths`` (.csv, .md,
    .tex).
    """
    import pandas as pd

    from ...binomial import clopper_pearson
    from ...design.trajectories import read_trajectories
    from ...reports.tables import load_paper_values, write_table

    paper = load_paper_values(paper_values)
    table: dict[str, dict] = {}
    paper_row: dict[str, Any] = {"mu0": "paper"}
    for name, path in trajectories.items():
        sc = scenarios[name]
        traj = read_trajectories(path)
        for row in mu0_sweep_rows(traj, sc.prior, settings, mu0_per_T):
            entry = table.setdefault(row["mu0"], {"mu0": row["mu0"]})
            entry[f"{name} K^max/K"] = row["ratio"]
            entry[f"{name} K^max/K lo95"], entry[f"{name} K^max/K hi95"] = clopper_pearson(
                row["K_max"], row["K"]
            )
            if row["mu0"] == "gradient balance":
                entry[f"{name} mu0/T"] = row["mu0_over_T_median"]
        ref = paper.get(sc.paper_ref, {}) or {}
        stated = ref.get("K_max") is not None and ref.get("K")
        paper_row[f"{name} K^max/K"] = ref["K_max"] / ref["K"] if stated else None
        paper_row[f"{name} K^max/K lo95"], paper_row[f"{name} K^max/K hi95"] = (
            clopper_pearson(ref["K_max"], ref["K"]) if stated else (None, None)
        )
        logger.info("mu0 sweep: %s done", name)
    frame = pd.DataFrame([*table.values(), paper_row])
    cols = ["mu0"] + [c for c in frame.columns if " K^max/K" in c]
    cols += [c for c in frame.columns if c.endswith("mu0/T")]
    frame = frame[cols]
    write_table(
        frame,
        paths,
        "Joint MAP, |K^max|/K of the Sep models for barrier starts mu_0 = f T and for "
        "the gradient-balance rule (mu0/T: its median over k), with the paper's",
    )
    return frame
