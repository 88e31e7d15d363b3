"""Issue 11: the smoke run produces the exact marginal stage, its column in the tables and
the Stan-vs-exact figure."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from helpers import REPO, SMOKE_OUT, only

pytestmark = pytest.mark.workflow


def _smoke():
    return yaml.safe_load((REPO / "config" / "smoke.yaml").read_text())


def test_exact_stage_outputs(smoke_run):
    from ssmobs.models import get_model

    for sc in _smoke()["scenarios"]:
        model = get_model(sc["model"])
        found = list(smoke_run.glob(f"results/{sc['name']}/exact_marginal/*/summary.json"))
        assert len(found) == int(model.linear_in_states)
        if not model.linear_in_states:
            continue
        out = found[0].parent
        frame = pd.read_parquet(out / "marginal_map.parquet")
        info = json.loads((out / "summary.json").read_text())
        assert frame["k"].tolist() == list(range(sc["K"]))
        assert info["n_unique"] + info["n_several"] + info["n_none"] == sc["K"]
        assert info["n_exact"] == int(frame["converged"].sum())
        conv = frame[frame["converged"]]
        for name in model.param_names:
            assert (conv[f"{name}_q5"] <= conv[f"{name}_map"]).all()
            assert (conv[f"{name}_map"] <= conv[f"{name}_q95"]).all()


def test_exact_column_in_the_tables(smoke_run):
    figs = smoke_run / SMOKE_OUT
    t2 = pd.read_csv(figs / "table2_joint_vs_marginal.csv")
    marg = t2[t2["estimator"] == "marginal MAP"]
    assert {"a_exact", "x0_exact"} <= set(t2.columns)
    summ = json.loads(only(smoke_run, "results/same_T4/exact_marginal/*/summary.json").read_text())
    mean_row = marg[marg["statistic"] == "mean"].iloc[0]
    assert mean_row["a_exact"] == pytest.approx(summ["a_mean"])
    assert t2.loc[t2["estimator"] == "joint MAP", "a_exact"].isna().all()
    t3 = pd.read_csv(figs / "table3_coverage.csv")
    assert "exact" in t3.columns and np.isfinite(t3["exact"]).all()
    s4 = pd.read_csv(figs / "section4_summary.csv").set_index("scenario")
    assert np.isfinite(s4.loc["same_T4", "exact_mean_a"])
    assert s4.loc["sep_d1_p2_T3", "exact_unique"] == 0  # unobservable (Sec. IV.D)
    assert s4.loc["ranwalk_T4", "K_exact"] == 6


def test_exact_vs_stan_figure(smoke_run):
    from ssmobs.models import get_model

    for sc in _smoke()["scenarios"]:
        if sc.get("stan", True) and get_model(sc["model"]).linear_in_states:
            for ext in ("pdf", "png"):
                assert (
                    smoke_run / SMOKE_OUT / f"fig_exact_vs_stan_{sc['name']}.{ext}"
                ).stat().st_size > 2000
            # the numbers of the comparison, one row per component and statistic
            diffs = pd.read_csv(smoke_run / SMOKE_OUT / f"exact_vs_stan_{sc['name']}.csv")
            names = [*get_model(sc["model"]).param_names, "x0"]
            assert list(diffs["component"].unique()) == names
            assert diffs["n"].between(0, sc["K"]).all()
            if sc["name"] == "same_T4":  # its runs converge (ranWalk's do not: Sec. IV.E)
                assert (diffs["n"] > 0).all()
            compared = diffs[diffs["n"] > 0]
            assert (compared["abs_diff_median"] <= compared["abs_diff_max"]).all()
