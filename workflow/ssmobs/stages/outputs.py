"""Glue of the tables and figures (rules in ``workflow/rules/outputs.smk`` and
``workflow/rules/figures.smk``) and of every other rule that writes a stamped output into
``outputs_dir``: the table of barrier starts (joint_map_mu0_sweep, ``joint_map.smk``) and the
choice of K's figure and table (select_k, table_k_selection, ``k_selection.smk``).

All of them are keyed together by the outputs' key (:meth:`ssmobs.cache_keys.CacheKeys.output`),
so an edit here reruns the tables and figures, never the stages they read.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import io
from ..config.scenario import Scenario
from . import PathLike

if TYPE_CHECKING:
    import pandas

    from ..design.trajectories import Trajectories

logger = logging.getLogger("ssmobs")


# -------------------------------------------------------------- paper tables and figures (Sec. IV)
def _maybe_json(path: PathLike | None) -> dict | None:
    return io.read_json(path) if path else None


def _table_ii_setting(rows: list[dict]) -> str:
    """The caption's setting, "model Same, (a, x0) = (0.9, 8)", when the rows share it."""
    settings = set()
    for r in rows:
        sc = Scenario.from_config(r["config"])
        a = dict(zip(sc.model.param_names, sc.omega)).get("a", float("nan"))
        settings.add((sc.model.slug, float(a), tuple(float(v) for v in sc.x0)))
    if len(settings) != 1:
        return "the scenarios of paper_outputs.tables_2_3"
    ((slug, a, x0),) = settings
    x0_text = ", ".join(f"{v:g}" for v in x0)
    return f"model {slug.replace('_', ' ').title()}, (a, x0) = ({a:g}, {x0_text})"


def run_paper_tables(
    scenarios: list[dict],
    tables_2_3: list[str],
    joint: dict[str, str],
    marginal: dict[str, str],
    paper_values: PathLike,
    table2: list[PathLike],
    table3: list[PathLike],
    section4_csv: PathLike,
    section4: list[PathLike],
    exact: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Rule paper_tables: Table II, Table III and the Section IV summary, paper values beside.

    ``tables_2_3``: names of the scenarios of Tables II and III (``paper_outputs``);
    ``joint`` / ``marginal`` / ``exact`` map scenario names to their summary JSON paths.
    ``table2``, ``table3``, ``section4``: the paths to write (.csv, .md, .tex by suffix);
    the Section IV summary goes whole to ``section4_csv`` and as the compact table a
    person reads (:func:`ssmobs.reports.tables.section_iv_compact`) to ``section4``.
    """
    exact = exact or {}
    from ..reports import tables

    paper = tables.load_paper_values(paper_values)
    rows = []
    for sc in scenarios:
        j = _maybe_json(joint.get(sc["name"]))
        m = _maybe_json(marginal.get(sc["name"]))
        rows.append(
            {
                "config": sc,
                "scenario": sc["name"],
                "T": sc["T"],
                "paper_ref": sc.get("paper_ref", ""),
                "joint": j,
                "marginal": m,
                "exact": _maybe_json(exact.get(sc["name"])),
                "prior": (j or {}).get("prior", sc.get("prior", "")),
            }
        )
    by_name = {r["scenario"]: r for r in rows}
    t2_rows = [by_name[n] for n in tables_2_3]
    frames = {
        "table2_joint_vs_marginal": (
            tables.table_ii(t2_rows, paper),
            table2,
            "Table II: empirical mean, variance and MSE of (a, x0), "
            f"{_table_ii_setting(t2_rows)}; ours (Stan + KDE), exact "
            "and the paper's",
        ),
        "table3_coverage": (
            tables.table_iii(t2_rows, paper),
            table3,
            "Table III: coverage of the 90% intervals, mean |bias| and MSE of "
            "the states (marginal MAP); ours (Stan + KDE), exact and the "
            "paper's",
        ),
        "section4_summary": (tables.section_iv(rows, paper), [section4_csv], ""),
        "section4_compact": (
            tables.section_iv_compact(rows, paper),
            section4,
            "Section IV: every scenario, the observability fractions "
            "|K^max|/K (joint MAP) and |K^Stan|/K (Stan) with their exact "
            "binomial 95 % intervals, ours beside the paper's (at the paper's "
            "K), and the marginal MAP's mean and Cover90 over K^Stan; every "
            "other column is in section4_summary.csv",
        ),
    }
    for frame, paths, caption in frames.values():
        tables.write_table(frame, paths, caption)
    return {k: v[0] for k, v in frames.items()}


def run_convergence_sensitivity(
    tables: dict[str, PathLike],
    convergence_cfg: dict,
    paths: list[PathLike],
    failure_paths: list[PathLike],
) -> pandas.DataFrame:
    """Rule convergence_sensitivity: |K^Stan| per scenario under other R-hat / tree-depth
    rules, and how the runs that did not converge failed (``failure_paths``).

    Re-evaluates the stored per-trajectory diagnostics (no new sampling); ``tables`` maps
    scenario names to their gather_nuts tables.
    """
    from ..nuts.convergence import ConvergenceSettings
    from ..nuts.convergence_sensitivity import failure_pattern_table, sensitivity_table
    from ..reports.tables import write_table

    frames = {
        name: io.read_parquet(
            path,
            required_columns=["k", "converged", "failed_checks", "max_rhat", "n_divergent"],
        )
        for name, path in tables.items()
    }
    write_table(
        failure_pattern_table(frames),
        failure_paths,
        "The runs that did not converge, by the checks they failed and the blocks of "
        "Theta that failed them (omega, x0, states): how many, how many also had divergent "
        "transitions, and quantiles of their largest R-hat",
    )
    base = ConvergenceSettings(**convergence_cfg)
    table = sensitivity_table(frames, base)
    write_table(
        table,
        paths,
        "|K^Stan| under R-hat < 1.01 or < 1.05 and tree-depth saturation warned about "
        "or counted as a failure, and with R-hat and ESS checked on Omega and x0 only or on "
        f"Omega only (other thresholds as configured: divergences <= "
        f"{base.max_divergences}, ESS >= {base.ess_bulk_min:g}/{base.ess_tail_min:g}, "
        f"E-BFMI >= {base.ebfmi_min:g})",
    )
    return table


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

    from ..models import get_model
    from ..reports.figures import figure_joint_vs_marginal

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

    from ..reports.figures import figure_observability_ratios

    figure_observability_ratios(pd.read_csv(summary_csv), paths)


def run_figure_profile_posterior(
    trajectories: PathLike, scenario: Scenario, grid: dict, paths: list[str]
) -> None:
    """Rule figure_profile_posterior: Figure 4 for trajectory k = 0 of a ranWalk scenario."""
    from ..design.trajectories import read_trajectories
    from ..reports.figures import figure_profile_posterior
    from ..reports.profile_posterior import profile_posterior

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
    figure, and the table of median and largest differences (returned)."""
    from ..reports.figures import figure_exact_vs_stan
    from ..reports.tables import exact_vs_stan_table, write_table

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
    write_table(
        table,
        table_paths,
        f"Stan + KDE against the exact marginal posterior, {scenario.name}: median and "
        "largest |difference| over the trajectories converged in both",
    )
    return table


# ---------------------------------------------------- barrier starts of the joint MAP (Sec. III.B)
def mu0_sweep_rows(
    traj: Trajectories, prior: Any, settings: dict, mu0_per_T: list[float]
) -> list[dict]:
    """|K^max|/K of one scenario's joint MAP for mu_0 = f * T (f in ``mu0_per_T``) and for the
    gradient-balance rule (:func:`ssmobs.joint_map.barrier.initial_mu_values`)."""
    from .joint_map import joint_map_of

    rows = []
    variants: list[tuple[str, dict[str, Any]]] = [
        ("gradient balance", {"mu0_rule": "gradient_balance"})
    ]
    variants += [
        (f"{f:g} T", {"mu0_rule": "per_step", "mu0": f * traj.T, "mu0_per_step": 0.0})
        for f in mu0_per_T
    ]
    for label, extra in variants:
        result, _, info, _ = joint_map_of(traj, prior, {**settings, **extra})
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

    from ..binomial import clopper_pearson
    from ..design.trajectories import read_trajectories
    from ..reports.tables import load_paper_values, write_table

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


# ------------------------------------------------------------------------- choice of K (Sec. IV.A)
def run_select_k(
    ksel: dict,
    scenario: Scenario,
    grids: list[PathLike],
    paper_values: PathLike,
    out_json: PathLike,
    out_csv: PathLike,
    figure_paths: list[str],
) -> dict:
    """Rule select_k: the RD rule over K_grid for every method, set variant and seed
    (:func:`ssmobs.k_selection.choose_k`); the V components as CSV and the figure."""
    import pandas as pd

    from ..k_selection import choose_k
    from ..reports.figures import figure_k_convergence
    from ..reports.tables import load_paper_values

    summaries = [row for p in grids for row in io.read_json(p, required=["points"])["points"]]
    paper = load_paper_values(paper_values).get(scenario.paper_ref, {}) or {}
    long_rows, choices = choose_k(summaries, scenario.model, ksel, scenario.name, paper)
    frame = pd.DataFrame(long_rows)
    io.write_text(out_csv, frame.to_csv(index=False, float_format="%.10g"))
    chosen = pd.DataFrame(choices)
    # one line per method, set variant and seed in the figure
    figure_k_convergence(
        frame.assign(method=frame["method"] + " " + frame["sets"]),
        chosen.assign(
            K_chosen=chosen["K_chosen"].astype(float),
            method=chosen["method"] + " " + chosen["sets"],
        ),
        f"choice of K: {ksel['name']} (c1={ksel['c1']}, c2={ksel['c2']})",
        figure_paths,
    )
    io.write_json(out_json, {"choices": choices})
    return {"choices": choices}


def run_table_k_selection(
    selections: list[PathLike], paths: list[PathLike], distribution: list[PathLike]
) -> None:
    """Rule table_k_selection: chosen K per k_selection entry, method and seed (``paths``),
    and how often each K was chosen over the seeds (``distribution``)."""
    from ..reports.tables import k_selection_distribution, k_selection_table, write_table

    rows = [c for p in selections for c in io.read_json(p, required=["choices"])["choices"]]
    table = k_selection_table(rows)
    write_table(
        table,
        paths,
        "Choice of K by relative differences (Sec. IV.A): ours per method, set variant "
        "(independent sets per K_i, or nested: one seed for all K_i) and seed, beside "
        "the paper's",
    )
    write_table(
        k_selection_distribution(table),
        distribution,
        "Choice of K over seeds (Sec. IV.A): per entry, method, set variant and (c1, c2), "
        "how many of its seeds chose each K (empty K_chosen: none on the grid), beside the "
        "paper's K",
    )
