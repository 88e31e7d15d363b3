"""Ours against the paper's in units of Monte Carlo standard error, from a run's tables.

A relative difference alone does not say whether a difference is noise. Each value that
the paper states and a run's tables (``table2_joint_vs_marginal.csv``,
``table3_coverage.csv``, ``section4_summary.csv``) hold is set beside the standard error of
the statistic over the K trajectories it averages, so that ``z = (ours - paper) / se``
reads as "how many standard errors apart". The standard errors are those of an
independent sample of the same size under normality (for the mean, variance and MSE of an
estimator) or binomial (for a coverage or a fraction): a yardstick, not a test. Design
disturbances vary less than a random sample (Sec. III.A), so the yardstick errs on the
wide side; the paper's own Monte Carlo error is not included.

A scenario whose posterior is improper under its prior
(:mod:`ssmobs.reports.propriety_notes`) has no Stan number to compare: its |K^Stan|/K,
marginal-MAP and coverage rows keep the paper's value, and ``ours``, ``rel_diff``,
``standard_error`` and ``z`` are empty, the reason in ``improper`` ("" elsewhere).  The
analysis is the current code's, run on the scenario entries of the folder's
``provenance.json``, so a folder made before it still holding the numbers compares none of
them; a table's own ``improper`` column counts as well.  The joint MAP's rows stay.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import pandas as pd

from .. import io
from .propriety_notes import ProprietyAnalysis, config_note
from .tables import rel_diff

COLUMNS = [
    "scenario",
    "T",
    "quantity",
    "K",
    "ours",
    "paper",
    "rel_diff",
    "standard_error",
    "z",
    "improper",
]


def se_mean(variance: float, K: int) -> float:
    """Standard error of a sample mean of K values with sample variance ``variance``."""
    return math.sqrt(variance / K)


def se_variance(variance: float, K: int) -> float:
    """Standard error of a sample variance of K normal values: sigma^2 sqrt(2 / (K - 1))."""
    return variance * math.sqrt(2.0 / (K - 1))


def se_mse(variance: float, mse: float, K: int) -> float:
    """Standard error of the mean squared error over K normal estimates with bias b and
    variance s^2: Var((X - theta)^2) = 2 s^4 + 4 b^2 s^2, with b^2 = MSE - s^2."""
    bias2 = max(mse - variance, 0.0)
    return math.sqrt((2.0 * variance**2 + 4.0 * bias2 * variance) / K)


def se_fraction(p: float, K: int) -> float:
    """Binomial standard error of a fraction near ``p`` over K trials."""
    return math.sqrt(p * (1.0 - p) / K)


def _row(
    scenario: str, T: int, quantity: str, K: int, ours: float, paper: float, rel: float, se: float
) -> dict:
    z = (ours - paper) / se if se > 0 and math.isfinite(se) else math.nan
    return {
        "scenario": scenario,
        "T": int(T),
        "quantity": quantity,
        "K": int(K),
        "ours": ours,
        "paper": paper,
        "rel_diff": rel,
        "standard_error": se,
        "z": z,
        "improper": "",
    }


def _withheld(scenario: str, T: int, quantity: str, runs: int, paper: float, why: str) -> dict:
    """A Stan quantity of an improper posterior: the paper's value, nothing of ours; ``K``
    counts the Stan runs (not the converged ones, which are a Stan result)."""
    row = _row(scenario, T, quantity, runs, math.nan, paper, math.nan, math.nan)
    row["improper"] = why
    return row


def _stan_runs(rec: dict) -> int:
    """The Stan runs of a Section IV summary row (every stan_every-th of K, issue 20)."""
    runs = rec.get("K_stan_runs")
    return int(rec["K"] if runs is None or pd.isna(runs) else runs)


def _table_ii_rows(
    table2: pd.DataFrame, sizes: pd.DataFrame, improper: dict[str, str]
) -> list[dict]:
    rows = []
    comps = [c[: -len("_paper")] for c in table2.columns if c.endswith("_paper")]
    for (scenario, estimator), block in table2.groupby(["scenario", "estimator"], sort=False):
        by_stat = block.set_index("statistic")
        T = int(block["T"].iloc[0])
        why = improper.get(scenario, "") if estimator != "joint MAP" else ""
        if why:  # the marginal MAP of an improper posterior: the paper's values only
            runs = _stan_runs(sizes.loc[scenario].to_dict())
            for comp in comps:
                for stat in ("mean", "variance", "MSE"):
                    paper = by_stat.loc[stat, f"{comp}_paper"]
                    if not pd.isna(paper):
                        quantity = f"{estimator} {stat} of {comp}"
                        rows.append(_withheld(scenario, T, quantity, runs, float(paper), why))
            continue
        K = int(sizes.loc[scenario, "K_max" if estimator == "joint MAP" else "K_stan"])
        for comp in comps:
            var = float(by_stat.loc["variance", f"{comp}_ours"])
            mse = float(by_stat.loc["MSE", f"{comp}_ours"])
            yardstick = {
                "mean": se_mean(var, K),
                "variance": se_variance(var, K),
                "MSE": se_mse(var, mse, K),
            }
            for stat, se in yardstick.items():
                paper = by_stat.loc[stat, f"{comp}_paper"]
                if pd.isna(paper):
                    continue
                rows.append(
                    _row(
                        scenario,
                        T,
                        f"{estimator} {stat} of {comp}",
                        K,
                        float(by_stat.loc[stat, f"{comp}_ours"]),
                        float(paper),
                        float(by_stat.loc[stat, f"{comp}_rel_diff"]),
                        se,
                    )
                )
    return rows


def _table_iii_rows(
    table3: pd.DataFrame, sizes: pd.DataFrame, improper: dict[str, str]
) -> list[dict]:
    rows = []
    for rec in table3.to_dict("records"):
        if pd.isna(rec["paper"]):
            continue
        why = improper.get(rec["scenario"], "")
        if why:  # every Table III value is a Stan result: K counts the Stan runs
            runs = _stan_runs(sizes.loc[rec["scenario"]].to_dict())
            rows.append(
                _withheld(rec["scenario"], rec["T"], str(rec["quantity"]), runs, rec["paper"], why)
            )
            continue
        K = int(rec["K_stan"])
        coverage = str(rec["quantity"]).startswith("cover90_") and "states" not in rec["quantity"]
        # an average over the states' coverages (or biases) has no simple standard error
        se = se_fraction(float(rec["paper"]), K) if coverage else math.nan
        rows.append(
            _row(
                rec["scenario"],
                rec["T"],
                str(rec["quantity"]),
                K,
                float(rec["ours"]),
                float(rec["paper"]),
                float(rec["rel_diff"]),
                se,
            )
        )
    return rows


def _section_iv_rows(summary: pd.DataFrame, improper: dict[str, str]) -> list[dict]:
    rows = []
    for rec in summary.to_dict("records"):
        for frac in ("K_max_frac", "K_stan_frac"):
            paper = rec.get(f"{frac}_paper")
            quantity = f"|{frac[:-5]}|/K".replace("K_max", "K^max").replace("K_stan", "K^Stan")
            why = improper.get(rec["scenario"], "") if frac == "K_stan_frac" else ""
            if paper is None or pd.isna(paper):
                continue
            if why:
                runs = _stan_runs(rec)
                rows.append(_withheld(rec["scenario"], rec["T"], quantity, runs, paper, why))
                continue
            if pd.isna(rec.get(frac)):
                continue
            ours, paper = float(rec[frac]), float(paper)
            # |K^Stan| counts over the Stan runs (every stan_every-th of the K, issue 20)
            trials = _stan_runs(rec) if frac == "K_stan_frac" else int(rec["K"])
            rows.append(
                _row(
                    rec["scenario"],
                    rec["T"],
                    quantity,
                    trials,
                    ours,
                    paper,
                    rel_diff(ours, paper),
                    se_fraction(paper, trials),
                )
            )
    return rows


def improper_scenarios(
    folder: str | os.PathLike,
    tables: list[pd.DataFrame],
    propriety: ProprietyAnalysis | None = None,
) -> dict[str, str]:
    """scenario -> why its posterior is improper, for the folder's improper scenarios: the
    analysis (``propriety``, the project's when None) of every scenario entry in the folder's
    ``provenance.json`` where it has one, and the ``improper`` column of ``tables``."""
    found: dict[str, str] = {}
    for table in tables:
        if "improper" in table.columns:
            marked = table[table["improper"].fillna("").astype(str) != ""]
            found.update(zip(marked["scenario"], marked["improper"], strict=True))
    provenance = Path(folder) / "provenance.json"
    if provenance.exists():
        from ..config.validation import validate

        config = validate(io.read_json(provenance, required=["config"])["config"])
        for entry in config["scenarios"]:
            note = config_note(entry, propriety)
            if note.is_improper:
                found[entry["name"]] = note.improper
    return found


def paper_comparison(
    folder: str | os.PathLike, *, propriety: ProprietyAnalysis | None = None
) -> pd.DataFrame:
    """Every value of the folder's tables that the paper states, with its standard error
    and z (module docstring); rows of Section IV first, then Tables II and III.  Where a
    scenario's posterior is improper (:func:`improper_scenarios`), its Stan quantities show
    the paper's value only and the reason in ``improper``."""
    folder = Path(folder)
    summary = pd.read_csv(folder / "section4_summary.csv")
    table2 = _read_if_any(folder / "table2_joint_vs_marginal.csv")
    table3 = _read_if_any(folder / "table3_coverage.csv")
    tables = [t for t in (summary, table2, table3) if t is not None]
    improper = improper_scenarios(folder, tables, propriety)
    rows = _section_iv_rows(summary, improper)
    sizes = summary.set_index("scenario")
    if table2 is not None:
        rows += _table_ii_rows(table2[table2["scenario"].isin(sizes.index)], sizes, improper)
    if table3 is not None:
        rows += _table_iii_rows(table3, sizes, improper)
    return pd.DataFrame(rows, columns=COLUMNS)


def _read_if_any(path: Path) -> pd.DataFrame | None:
    """The table at ``path``; None when it is missing or has no rows (Tables II and III of a
    run without the paper's Same scenarios are written empty)."""
    if not path.exists() or not path.read_text().strip():
        return None
    return pd.read_csv(path)
