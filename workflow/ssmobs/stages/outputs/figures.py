"""Glue of the figures (``workflow/rules/figures.smk``): Figure 3 (joint against marginal
MAPs), Figure 4 (the profile posterior), the observability ratios of the own models and the
exact marginal posteriors against Stan's.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from ... import io
from ...config.scenario import Scenario
from .. import PathLike

if TYPE_CHECKING:
    import pandas


logger = logging.getLogger("ssmobs")


def run_figure_joint_vs_marginal(
    scenarios: list[dict],
    joint_tables: dict[str, str],
    marginal_tables: dict[str, str],
    paths: list[str],
) -> None:
    """Rule figure_joint_vs_marginal: Figure 3 from the per-k tables of both stages.

    ``scenarios``: those of ``paper_outputs.figure3`` (one model, Omega and x0, checked by
    the config); the first parameter of the model is plotted against x0, with the true
    values as lines.  No scenarios: empty panels (and the paper's (a, x0) = (0.9, 8))."""
    import pandas as pd

    from ...models import get_model
    from ...reports.figures import figure_joint_vs_marginal
    from ...reports.propriety_notes import config_note

    name, truth = "a", (0.9, 8.0)
    if scenarios:
        name = get_model(scenarios[0]["model"]).param_names[0]
        truth = (float(scenarios[0]["omega"][name]), float(scenarios[0]["x0"]))
    panels = []
    for sc in sorted(scenarios, key=lambda s: s["T"]):
        j = io.read_parquet(joint_tables[sc["name"]], ["status", name, "x0"])
        m = io.read_parquet(marginal_tables[sc["name"]], ["converged", f"{name}_map", "x0_map"])
        panels.append(
            {
                "T": sc["T"],
                "joint": j[j["status"] == "ok"],
                "marginal": m[m["converged"].astype(bool)],
                # an improper posterior's marginal MAPs are no estimates: not drawn
                "improper": config_note(sc).improper,
            }
        )
    if not panels:
        panels = [
            {
                "T": "-",
                "joint": pd.DataFrame({name: [], "x0": []}),
                "marginal": pd.DataFrame({f"{name}_map": [], "x0_map": []}),
            }
        ]
    figure_joint_vs_marginal(panels, *truth, paths, name=name)


def run_figure_observability(summary_csv: PathLike, paths: list[str]) -> None:
    """Rule figure_observability: |K^max|/K and |K^Stan|/K of every scenario."""
    import pandas as pd

    from ...reports.figures import figure_observability_ratios

    figure_observability_ratios(pd.read_csv(summary_csv), paths)


def run_figure_profile_posterior(
    trajectories: PathLike, scenario: Scenario, grid: dict, paths: list[str]
) -> None:
    """Rule figure_profile_posterior: Figure 4 for trajectory k = 0 of a ranWalk scenario."""
    from ...design.trajectories import read_trajectories
    from ...reports.figures import figure_profile_posterior
    from ...reports.profile_posterior import profile_posterior

    traj = read_trajectories(trajectories)
    model = traj.model
    bounds = model.prior_bounds(traj.omega, scenario.prior)
    a = np.linspace(grid["a_min"], grid["a_max"], grid["n"])
    x0 = np.linspace(grid["x0_min"], grid["x0_max"], grid["n"])
    values = profile_posterior(model, traj.z[0], bounds, model.param_names[0], a, x0)
    figure_profile_posterior(
        a,
        x0,
        values,
        float(traj.omega[0]),
        float(traj.x0[0]),
        f"profile posterior, {model.title}, T={traj.T}, k=1",
        paths,
    )


def run_figure_exact_vs_stan(
    scenario: Scenario,
    stan_table: PathLike,
    exact_table: PathLike,
    figure_paths: list[str],
    table_paths: list[str],
) -> pandas.DataFrame:
    """Rule figure_exact_vs_stan: Stan + KDE marginal MAP against the exact one, per k: the
    figure, and the table of median and largest differences (returned).  Where the posterior
    is improper the caption says so: neither column is then an estimate of the posterior
    (the exact one is the interior maximum's basin's)."""
    from ...reports.figures import figure_exact_vs_stan
    from ...reports.propriety_notes import posterior_note
    from ...reports.tables import exact_vs_stan_table, write_table

    model = scenario.model
    names = list(model.param_names) + (
        ["x0"] if model.state_dim == 1 else [f"x0_{i + 1}" for i in range(model.state_dim)]
    )
    cols = ["k", "converged"] + [f"{n}_{s}" for n in names for s in ("map", "q5", "q95")]
    stan = io.read_parquet(stan_table, cols)
    exact = io.read_parquet(exact_table, cols)
    # the Stan stage may run every stan_every-th trajectory only; the exact stage runs all
    exact = exact.set_index("k", drop=False).reindex(stan["k"]).reset_index(drop=True)
    if exact["k"].isna().any():
        raise ValueError(
            f"scenario {scenario.name}: the Stan table holds trajectories the exact table "
            f"does not (K = {len(stan)} and {len(exact)})"
        )
    both = stan["converged"].to_numpy(bool) & exact["converged"].to_numpy(bool)
    figure_exact_vs_stan(stan[both], exact[both], names, scenario.name, figure_paths)
    table = exact_vs_stan_table(stan[both], exact[both], names)
    caption = (
        f"Stan + KDE against the exact marginal posterior, {scenario.name}: median and "
        "largest |difference| over the trajectories converged in both"
    )
    note = posterior_note(scenario)
    if note.is_improper:
        caption += (
            f". The posterior is {note.improper}; the exact values are those of the "
            "interior maximum's basin (the spike cut off), and neither column is an estimate "
            "of the posterior"
        )
    write_table(table, table_paths, caption)
    return table
