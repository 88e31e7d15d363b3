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
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import pandas as pd

from .tables import rel_diff

COLUMNS = ["scenario", "T", "quantity", "K", "ours", "paper", "rel_diff", "standard_error", "z"]


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
    }


def _table_ii_rows(table2: pd.DataFrame, sizes: pd.DataFrame) -> list[dict]:
    rows = []
    comps = [c[: -len("_paper")] for c in table2.columns if c.endswith("_paper")]
    for (scenario, estimator), block in table2.groupby(["scenario", "estimator"], sort=False):
        K = int(sizes.loc[scenario, "K_max" if estimator == "joint MAP" else "K_stan"])
        by_stat = block.set_index("statistic")
        T = int(block["T"].iloc[0])
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


def _table_iii_rows(table3: pd.DataFrame) -> list[dict]:
    rows = []
    for rec in table3.to_dict("records"):
        if pd.isna(rec["paper"]):
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


def _section_iv_rows(summary: pd.DataFrame) -> list[dict]:
    rows = []
    for rec in summary.to_dict("records"):
        for frac in ("K_max_frac", "K_stan_frac"):
            paper = rec.get(f"{frac}_paper")
            if paper is None or pd.isna(paper) or pd.isna(rec.get(frac)):
                continue
            ours, paper = float(rec[frac]), float(paper)
            # |K^Stan| counts over the Stan runs (every stan_every-th of the K, issue 20)
            runs = rec.get("K_stan_runs") if frac == "K_stan_frac" else None
            trials = int(rec["K"] if runs is None or pd.isna(runs) else runs)
            rows.append(
                _row(
                    rec["scenario"],
                    rec["T"],
                    f"|{frac[:-5]}|/K".replace("K_max", "K^max").replace("K_stan", "K^Stan"),
                    trials,
                    ours,
                    paper,
                    rel_diff(ours, paper),
                    se_fraction(paper, trials),
                )
            )
    return rows


def paper_comparison(folder: str | os.PathLike) -> pd.DataFrame:
    """Every value of the folder's tables that the paper states, with its standard error
    and z (module docstring); rows of Section IV first, then Tables II and III."""
    folder = Path(folder)
    summary = pd.read_csv(folder / "section4_summary.csv")
    rows = _section_iv_rows(summary)
    sizes = summary.set_index("scenario")
    table2 = _read_if_any(folder / "table2_joint_vs_marginal.csv")
    if table2 is not None:
        rows += _table_ii_rows(table2[table2["scenario"].isin(sizes.index)], sizes)
    table3 = _read_if_any(folder / "table3_coverage.csv")
    if table3 is not None:
        rows += _table_iii_rows(table3)
    return pd.DataFrame(rows, columns=COLUMNS)


def _read_if_any(path: Path) -> pd.DataFrame | None:
    """The table at ``path``; None when it is missing or has no rows (Tables II and III of a
    run without the paper's Same scenarios are written empty)."""
    if not path.exists() or not path.read_text().strip():
        return None
    return pd.read_csv(path)
