"""Issue 5: every table and figure of the smoke run, the paper-values file, the report and
the SLURM profile."""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd
import pytest
import yaml
from helpers import REPO, SMOKE, SMOKE_OUT, slurm_profile_dry_run, snakemake

pytestmark = pytest.mark.workflow

#: the six models of the paper's Section IV
PAPER_MODELS = {"same", "sep", "sep_d2_p1", "sep_d1_p2", "sep_ranwalk", "sep_mult"}

TABLES = ["table2_joint_vs_marginal", "table3_coverage", "section4_summary", "table_k_selection"]
FIGURES = [
    "fig2_design_points",
    "fig3_joint_vs_marginal",
    "fig4_profile_posterior_ranwalk_T4",
    "fig_k_convergence_same_T4",
    "fig_observability_ratios",
    "map_same",
    "map_stoch_vol",
]


@pytest.mark.parametrize("stem", TABLES)
def test_table_files_parse(smoke_run, stem):
    base = smoke_run / SMOKE_OUT / stem
    frame = pd.read_csv(f"{base}.csv")
    assert len(frame) > 0
    md = (base.with_suffix(".md")).read_text()
    assert md.count("\n|") >= len(frame) + 1
    assert "\\begin{tabular}" in base.with_suffix(".tex").read_text()


@pytest.mark.parametrize("stem", FIGURES)
def test_figure_files(smoke_run, stem):
    for ext in ("pdf", "png"):
        assert (smoke_run / SMOKE_OUT / f"{stem}.{ext}").stat().st_size > 2000


def test_table_values_finite_where_they_must(smoke_run):
    t2 = pd.read_csv(smoke_run / SMOKE_OUT / "table2_joint_vs_marginal.csv")
    joint_mean = t2[(t2["estimator"] == "joint MAP") & (t2["statistic"] == "mean")]
    assert np.isfinite(joint_mean[["a_ours", "x0_ours"]].to_numpy()).all()
    s4 = pd.read_csv(smoke_run / SMOKE_OUT / "section4_summary.csv")
    smoke = yaml.safe_load((REPO / "config" / "smoke.yaml").read_text())
    assert list(s4["scenario"]) == [sc["name"] for sc in smoke["scenarios"]]
    for _, row in s4.iterrows():
        assert 0 <= row["K_max"] <= row["K"] or math.isnan(row["K_max"])
        if row["scenario"] != "sep_d1_p2_T3":  # stan: false there
            assert 0 <= row["K_stan"] <= row["K"]
    ranwalk = s4.set_index("scenario").loc["ranwalk_T4"]
    assert ranwalk["K_max"] == 0  # a ridge of variable height: no joint MAP (Sec. IV.E)
    assert ranwalk["K_max_paper"] == 0 and ranwalk["K_stan_paper"] == 0
    # stan_every: 2 (issue 20): Stan ran k = 0, 2, 4 of the K = 6, the joint MAP all six
    assert (ranwalk["K"], ranwalk["K_stan_runs"]) == (6, 3)
    assert ranwalk["K_stan_frac"] == ranwalk["K_stan"] / 3
    (table,) = (smoke_run / "results" / "ranwalk_T4" / "gather_nuts").glob("*/marginal_map.parquet")
    assert pd.read_parquet(table, columns=["k"])["k"].tolist() == [0, 2, 4]
    ks = pd.read_csv(smoke_run / SMOKE_OUT / "table_k_selection.csv")
    assert set(ks["method"]) == {"design", "random"}
    assert set(ks["sets"]) == {"independent", "nested"}
    # every seed of a design entry starts its own optimiser: the chosen K per seed, and how
    # often each K was chosen (issue 34)
    (ksel,) = smoke["k_selection"]
    for _, sub in ks[ks["method"] == "design"].groupby("sets"):
        assert sorted(sub["seed"]) == sorted(ksel["seeds"])
    dist = pd.read_csv(smoke_run / SMOKE_OUT / "table_k_selection_distribution.csv")
    design = dist[dist["method"] == "design"]
    assert set(design["seeds"]) == {len(ksel["seeds"])}
    assert design.groupby("sets")["n_seeds"].sum().tolist() == [len(ksel["seeds"])] * 2
    # the smoke's (c1, c2) = (0.05, 0.2) are not the paper's: no paper K beside them
    assert ks["K_paper"].isna().all() and ks["K_paper_range"].isna().all()
    sens = pd.read_csv(smoke_run / SMOKE_OUT / "table_convergence_sensitivity.csv")
    assert list(sens["scenario"]) == [
        sc["name"] for sc in smoke["scenarios"] if sc.get("stan", True)
    ]
    for _, row in sens.iterrows():  # R-hat 1.05 is looser, counting tree depth stricter
        assert row["rhat1.01_treedepth_warns"] == row["K_stan_run"]
        assert row["rhat1.01_treedepth_fails"] <= row["rhat1.01_treedepth_warns"]
        assert row["rhat1.05_treedepth_warns"] >= row["rhat1.01_treedepth_warns"]
        # fewer blocks checked for mixing: never fewer converged runs
        assert row["omega_only"] >= row["omega_x0_only"] >= row["K_stan_run"]
    # every run that did not converge is in one failure pattern of its scenario
    fails = pd.read_csv(smoke_run / SMOKE_OUT / "table_convergence_failures.csv")
    failed_runs = (sens["K"] - sens["K_stan_run"]).set_axis(sens["scenario"])
    per_scenario = fails.groupby("scenario")["runs"].sum()
    assert per_scenario.to_dict() == {k: v for k, v in failed_runs.items() if v > 0}
    assert (fails["failed_checks"] != "").all()
    assert (fails["runs_with_divergences"] <= fails["runs"]).all()


def test_paper_values_hold_every_stated_number():
    pv = yaml.safe_load((REPO / "config" / "paper_values.yaml").read_text())
    t20, t50 = pv["same_a09_T20"], pv["same_a09_T50"]
    # Table II
    assert t20["joint"]["mean"] == {"a": 0.941, "x0": 7.15}
    assert t20["joint"]["var"] == {"a": 0.000196, "x0": 0.468}
    assert t20["joint"]["mse"] == {"a": 0.00184, "x0": 1.18}
    assert t50["joint"]["mean"] == {"a": 0.949, "x0": 6.99}
    assert t50["joint"]["var"] == {"a": 0.0000756, "x0": 0.374}
    assert t50["joint"]["mse"] == {"a": 0.00248, "x0": 1.40}
    assert t20["marginal"]["mean"] == {"a": 0.896, "x0": 8.07}
    assert t20["marginal"]["var"] == {"a": 0.000605, "x0": 0.728}
    assert t20["marginal"]["mse"] == {"a": 0.000621, "x0": 0.733}
    assert t50["marginal"]["mean"] == {"a": 0.898, "x0": 8.05}
    assert t50["marginal"]["var"] == {"a": 0.000355, "x0": 0.602}
    assert t50["marginal"]["mse"] == {"a": 0.000360, "x0": 0.605}
    # Table III
    assert t20["coverage"] == {
        "cover90": {"a": 0.870, "x0": 0.895},
        "mean_cover90_states": 0.910,
        "mean_abs_bias_states": 0.00892,
        "mean_mse_states": 0.116,
    }
    assert t50["coverage"] == {
        "cover90": {"a": 0.893, "x0": 0.905},
        "mean_cover90_states": 0.909,
        "mean_abs_bias_states": 0.00335,
        "mean_mse_states": 0.105,
    }
    # Section IV counts
    counts = {
        "same_a07_T100": (3600, 3600, 2910),
        "sep_ab_T75": (4000, 1956, 3680),
        "sep_b_T75": (4000, None, 2109),
        "sep_d2_p1_abc_T50": (4000, 1833, 3995),
        "sep_d2_p1_a_T50": (4000, None, 2972),
        "ranwalk_T4": (2000, 0, 0),
        "ranwalk_T100": (4000, 0, 1575),
        "mult_T50": (4000, 3995, 2598),
    }
    for key, (K, kmax, kstan) in counts.items():
        assert pv[key]["K"] == K and pv[key].get("K_max") == kmax and pv[key]["K_stan"] == kstan
    assert pv["sep_d1_p2"]["K_stan"] == 0
    ksel = {
        k: pv[k]["k_selection"]["design"]["K"]
        for k in ("same_a09_T4", "same_a09_T20", "same_a09_T50", "same_a07_T100")
    }
    assert ksel == {
        "same_a09_T4": 300,
        "same_a09_T20": 1300,
        "same_a09_T50": 3100,
        "same_a07_T100": 3600,
    }
    assert pv["same_a09_T4"]["k_selection"]["random"]["K_min"] == 2500


def test_every_paper_ref_exists():
    pv = yaml.safe_load((REPO / "config" / "paper_values.yaml").read_text())
    for profile in ("config.yaml", "smoke.yaml", "paper.yaml"):
        conf = yaml.safe_load((REPO / "config" / profile).read_text())
        for sc in conf["scenarios"]:
            if sc["model"] in PAPER_MODELS:  # a model of the paper: its values are needed
                assert sc.get("paper_ref", "") in pv, (profile, sc["name"])
            else:  # our own models (e.g. stoch_vol) have none, or a key that exists
                assert sc.get("paper_ref", "") in ("", *pv), (profile, sc["name"])


def test_report_lists_every_table_and_figure(smoke_run):
    snakemake(smoke_run, "--report", "report.zip", *SMOKE)
    import zipfile

    names = "\n".join(zipfile.ZipFile(smoke_run / "report.zip").namelist())
    for stem in TABLES + FIGURES:
        assert stem in names, stem


@pytest.mark.slow  # the SLURM profile (a rare path: clusters): test-slow (issue 48)
def test_slurm_profile_dry_run():
    proc = slurm_profile_dry_run("--configfile", "config/paper.yaml")
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout + proc.stderr
    assert "sample_nuts" in out and "This was a dry-run" in out
    # the paper profile plans its own trajectories, joint MAPs and Stan runs (issue 19: it
    # once found the default profile's results under the same scenario names up to date)
    for rule in ("design_trajectories", "joint_map", "sample_nuts"):
        assert re.search(rf"^{rule}\s+\d+$", out, flags=re.M), rule
