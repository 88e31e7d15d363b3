"""Ours against the paper's in standard errors (ssmobs.reports.paper_comparison)."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from ssmobs.reports.paper_comparison import (
    paper_comparison,
    se_fraction,
    se_mean,
    se_mse,
    se_variance,
)


def test_standard_errors_match_the_spread_over_repeated_samples():
    rng = np.random.default_rng(7)
    K, bias, sd, reps = 400, 0.3, 0.5, 4000
    est = bias + sd * rng.standard_normal((reps, K))  # estimates minus the truth
    means, variances = est.mean(axis=1), est.var(axis=1, ddof=1)
    mses = (est**2).mean(axis=1)
    # each standard error within 5 % of the spread it predicts (4000 repetitions: ~1 %)
    assert se_mean(sd**2, K) == pytest.approx(means.std(), rel=0.05)
    assert se_variance(sd**2, K) == pytest.approx(variances.std(), rel=0.05)
    assert se_mse(sd**2, sd**2 + bias**2, K) == pytest.approx(mses.std(), rel=0.05)
    cover = rng.random((reps, K)) < 0.9
    assert se_fraction(0.9, K) == pytest.approx(cover.mean(axis=1).std(), rel=0.05)


def _folder(tmp_path, table2: str = "", table3: str = ""):
    pd.DataFrame(
        [
            {
                "scenario": "s",
                "T": 20,
                "K": 100,
                "K_max": 100,
                "K_stan": 80,
                "K_max_frac": 1.0,
                "K_max_frac_paper": float("nan"),
                "K_stan_frac": 0.8,
                "K_stan_frac_paper": 0.9,
            },
        ]
    ).to_csv(tmp_path / "section4_summary.csv", index=False)
    (tmp_path / "table2_joint_vs_marginal.csv").write_text(table2 or "\n")
    (tmp_path / "table3_coverage.csv").write_text(table3 or "\n")
    return tmp_path


def test_a_fraction_is_judged_by_the_binomial_error_at_the_papers_fraction(tmp_path):
    out = paper_comparison(_folder(tmp_path))
    assert out["quantity"].tolist() == ["|K^Stan|/K"]  # the paper gives no K^max here
    row = out.iloc[0]
    assert row["standard_error"] == pytest.approx(math.sqrt(0.9 * 0.1 / 100))
    assert row["z"] == pytest.approx(-0.1 / 0.03)


def test_table_ii_uses_the_estimators_own_sample_size(tmp_path):
    rows = []
    for est in ("joint MAP", "marginal MAP"):
        for stat, ours, paper in (
            ("mean", 0.9, 0.91),
            ("variance", 0.01, 0.011),
            ("MSE", 0.02, None),
        ):
            rows.append(
                {
                    "T": 20,
                    "scenario": "s",
                    "estimator": est,
                    "statistic": stat,
                    "a_ours": ours,
                    "a_paper": paper,
                    "a_rel_diff": 0.0,
                }
            )
    table3 = (
        "T,scenario,quantity,ours,paper,rel_diff,K_stan\n20,s,cover90_a,0.85,0.9,0.05,80\n"
        "20,s,mean_cover90_states,0.9,0.9,0,80\n"
    )
    out = paper_comparison(_folder(tmp_path, pd.DataFrame(rows).to_csv(index=False), table3))
    out = out.set_index("quantity")
    # the joint MAP averages K^max = 100 trajectories, the marginal MAP K^Stan = 80
    assert out.loc["joint MAP mean of a", "standard_error"] == pytest.approx(0.1 / 10)
    assert out.loc["marginal MAP mean of a", "standard_error"] == pytest.approx(0.1 / math.sqrt(80))
    assert out.loc["marginal MAP variance of a", "K"] == 80
    assert "joint MAP MSE of a" not in out.index  # the paper states no MSE here
    assert out.loc["cover90_a", "z"] == pytest.approx(-0.05 / math.sqrt(0.09 / 80))
    assert math.isnan(out.loc["mean_cover90_states", "z"])  # no simple standard error


def test_a_subsets_k_stan_is_judged_over_its_stan_runs(tmp_path):
    folder = _folder(tmp_path)
    summary = pd.read_csv(folder / "section4_summary.csv").assign(K=4000, K_stan_runs=100)
    summary.to_csv(folder / "section4_summary.csv", index=False)
    row = paper_comparison(folder).iloc[0]
    assert row["K"] == 100
    assert row["standard_error"] == pytest.approx(math.sqrt(0.9 * 0.1 / 100))


ONLY_A = {  # (Sep, d=2, p=1) with b and c on (-1, 1): x0 drops out at c = 0, inside the prior
    "name": "s",
    "model": "sep_d2_p1",
    "omega": {"a": 0.9, "b": 0.9, "c": 0.9},
    "x0": 8,
    "T": 20,
    "K": 100,
    "prior": {"a": "restricted", "b": "unrestricted", "c": "unrestricted"},
}


def _provenance(folder, scenario: dict) -> None:
    config = {"outputs_dir": "x", "scenarios": [scenario]}
    (folder / "provenance.json").write_text(json.dumps({"config": config, "commit": "0" * 40}))


def _tables_ii_iii() -> tuple[str, str]:
    rows = [
        {
            "T": 20,
            "scenario": "s",
            "estimator": est,
            "statistic": stat,
            "a_ours": 0.9,
            "a_paper": 0.91,
            "a_rel_diff": 0.01,
        }
        for est in ("joint MAP", "marginal MAP")
        for stat in ("mean", "variance", "MSE")
    ]
    table3 = "T,scenario,quantity,ours,paper,rel_diff,K_stan\n20,s,cover90_a,0.85,0.9,0.05,80\n"
    return pd.DataFrame(rows).to_csv(index=False), table3


def test_an_improper_posteriors_stan_numbers_are_not_compared(tmp_path):
    """Issue 60: a folder whose scenario is improper under its prior (by the current
    analysis of its provenance's config, whatever its tables hold) compares no |K^Stan|,
    marginal MAP or coverage; the paper's values stay beside the reason, the joint MAP's
    rows are compared as before."""
    folder = _folder(tmp_path, *_tables_ii_iii())
    _provenance(folder, ONLY_A)
    out = paper_comparison(folder).set_index("quantity")
    withheld = ["|K^Stan|/K", "marginal MAP mean of a", "marginal MAP MSE of a", "cover90_a"]
    assert out.loc[withheld, ["ours", "rel_diff", "standard_error", "z"]].isna().all().all()
    assert out.loc["|K^Stan|/K", "paper"] == 0.9
    assert out.loc["cover90_a", "paper"] == 0.9
    assert out.loc[withheld, "improper"].str.contains("c = 0, inside the prior").all()
    assert (out.loc[withheld, "K"] == 100).all()  # the runs, not the converged 80
    joint = out.loc["joint MAP mean of a"]
    assert joint["ours"] == 0.9 and joint["improper"] == ""
    assert joint["standard_error"] > 0  # compared as before


def test_a_proper_scenario_in_the_provenance_is_compared(tmp_path):
    folder = _folder(tmp_path)
    _provenance(folder, {**ONLY_A, "prior": "restricted"})  # c -> 0 at an end: edge only
    row = paper_comparison(folder).iloc[0]
    assert row["ours"] == 0.8 and row["improper"] == ""
    assert row["z"] == pytest.approx(-0.1 / 0.03)


def test_a_tables_own_improper_column_withholds_as_well(tmp_path):
    """A folder made by the current tables: |K^Stan| is empty and the reason is in the
    summary's column improper; the comparison keeps the paper's value and reads no count."""
    table2, table3 = _tables_ii_iii()
    folder = _folder(tmp_path, table2, table3.replace(",80\n", ",\n"))
    summary = pd.read_csv(folder / "section4_summary.csv")
    summary = summary.assign(K_stan=math.nan, K_stan_frac=math.nan, K_stan_runs=50)
    summary["improper"] = "improper: a reason"
    summary.to_csv(folder / "section4_summary.csv", index=False)
    out = paper_comparison(folder).set_index("quantity")
    assert out.loc["|K^Stan|/K", "improper"] == "improper: a reason"
    assert out.loc["|K^Stan|/K", "paper"] == 0.9 and math.isnan(out.loc["|K^Stan|/K", "ours"])
    assert out.loc["cover90_a", "K"] == 50 and math.isnan(out.loc["cover90_a", "z"])
    assert math.isnan(out.loc["marginal MAP variance of a", "ours"])
