"""Glue of the paper's tables (rule paper_tables: Tables II and III, Sec. IV) and of the
convergence checks' sensitivity tables (rule convergence_sensitivity, Sec. III.C).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from ... import io
from ...config.scenario import Scenario
from .. import PathLike

if TYPE_CHECKING:
    import pandas


logger = logging.getLogger("ssmobs")


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
    *,
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
    from ...reports import tables

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
    *,
    configs: Mapping[str, Mapping[str, Any]],
) -> pandas.DataFrame:
    """Rule convergence_sensitivity: |K^Stan| per scenario under other R-hat / tree-depth
    rules, and how the runs that did not converge failed (``failure_paths``).

    Re-evaluates the stored per-trajectory diagnostics (no new sampling); ``tables`` maps
    scenario names to their gather_nuts tables, ``configs`` the same names to their config
    entries: a scenario whose posterior is improper shows no |K^Stan| count but
    "not shown: improper" and the reason in a column ``improper``
    (:func:`mark_improper_counts`).
    """
    from ...nuts.convergence import ConvergenceSettings
    from ...nuts.convergence_sensitivity import failure_pattern_table, sensitivity_table
    from ...reports.tables import write_table

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
    table = mark_improper_counts(sensitivity_table(frames, base), configs)
    caption = (
        "|K^Stan| under R-hat < 1.01 or < 1.05 and tree-depth saturation warned about "
        "or counted as a failure, and with R-hat and ESS checked on Omega and x0 only or on "
        f"Omega only (other thresholds as configured: divergences <= "
        f"{base.max_divergences}, ESS >= {base.ess_bulk_min:g}/{base.ess_tail_min:g}, "
        f"E-BFMI >= {base.ebfmi_min:g})"
    )
    if "improper" in table.columns:
        caption += CAPTION_IMPROPER
    write_table(table, paths, caption)
    return table


#: what the sensitivity table's caption adds when some scenario's posterior is improper
CAPTION_IMPROPER = (
    '. A scenario whose posterior is improper under its prior shows "not shown: improper" '
    "in place of its counts and the reason in the column improper (K, its runs, stays)"
)


def mark_improper_counts(
    table: pandas.DataFrame, configs: Mapping[str, Mapping[str, Any]]
) -> pandas.DataFrame:
    """The sensitivity table with the |K^Stan| counts of every scenario whose posterior is
    improper (:mod:`ssmobs.reports.propriety_notes`) replaced by "not shown: improper"
    (``K``, the runs, stays) and the reason in a column ``improper`` (where some scenario
    is; otherwise the table as it was)."""
    from ...reports.propriety_notes import NOT_SHOWN_IMPROPER, config_note

    notes = {name: config_note(configs[name]).improper for name in table["scenario"]}
    if not any(notes.values()):
        return table
    counts = [c for c in table.columns if c not in ("scenario", "K")]
    out = table.astype({c: object for c in counts})
    hidden = out["scenario"].map(notes).astype(bool).to_numpy()
    out.loc[hidden, counts] = NOT_SHOWN_IMPROPER
    out["improper"] = out["scenario"].map(notes)
    return out
