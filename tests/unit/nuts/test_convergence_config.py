"""Thresholds from the config reach the convergence check and the re-evaluation of records."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from factories import same_a09
from ssmobs import io
from ssmobs.config import validation as cfg
from ssmobs.nuts.convergence import ConvergenceSettings, check_convergence, threshold_failures
from ssmobs.nuts.convergence_sensitivity import (
    converged_under,
    failure_pattern_table,
    sensitivity_table,
)
from ssmobs.stages.outputs.paper_tables import run_convergence_sensitivity
from test_convergence import make_draws  # noqa: E402  (this folder is on sys.path)

pytestmark = pytest.mark.unit


def config_with(**convergence) -> dict:
    return cfg.validate(
        {
            "scenarios": [same_a09(K=10)],
            "convergence": convergence,
        }
    )


def saturated_draws():
    """Well-mixed draws whose only fault is 7 draws at the maximum tree depth 10."""
    d = make_draws()
    d.sample_stats["treedepth__"][2, :7] = 10
    return d


@pytest.mark.parametrize("counted", [False, True])
def test_treedepth_from_config_decides_a_run_that_fails_only_on_tree_depth(counted):
    c = config_with(treedepth_fails=counted) if counted else config_with()
    settings = ConvergenceSettings(**c["convergence"])  # as rule sample_nuts builds them
    res = check_convergence(saturated_draws(), settings, max_treedepth=10)
    assert res["n_treedepth_hits"] == 7
    assert res["converged"] is (not counted)
    assert res["failed_checks"] == (["treedepth"] if counted else [])
    # the same record re-evaluated from its stored worst values agrees
    assert threshold_failures(res, settings) == res["failed_checks"]


def test_rhat_threshold_from_config_reaches_the_check():
    d = make_draws(shift=0.15)  # chains slightly apart: R-hat between 1.01 and 1.05
    res = check_convergence(d, ConvergenceSettings(**config_with()["convergence"]))
    assert 1.01 <= res["max_rhat"] < 1.05, res["max_rhat"]
    assert res["failed_checks"] == ["rhat"]
    loose = ConvergenceSettings(**config_with(rhat_max=1.05)["convergence"])
    assert check_convergence(d, loose)["converged"]


def table(rows):
    base = {
        "status": "ok",
        "converged": True,
        "failed_checks": "",
        "max_rhat": 1.001,
        "min_ess_bulk": 900.0,
        "min_ess_tail": 800.0,
        "n_divergent": 0.0,
        "n_treedepth_hits": 0.0,
        "min_ebfmi": 0.7,
    }
    return pd.DataFrame([{**base, "k": k, **r} for k, r in enumerate(rows)])


def test_converged_under_reclassifies_records_and_keeps_other_failures():
    t = table(
        [
            {},  # passes everywhere
            {"n_treedepth_hits": 12.0},  # only tree depth
            {"max_rhat": 1.03, "converged": False, "failed_checks": "rhat"},
            {"converged": False, "failed_checks": "kde"},  # not a threshold
            {
                "status": "error",
                "converged": False,
                "failed_checks": "sampling_error",
                "max_rhat": np.nan,
            },
        ]
    )
    warn = ConvergenceSettings()
    assert converged_under(t, warn).tolist() == [True, True, False, False, False]
    counted = ConvergenceSettings(treedepth_fails=True)
    assert converged_under(t, counted).tolist() == [True, False, False, False, False]
    loose = ConvergenceSettings(rhat_max=1.05)
    assert converged_under(t, loose).tolist() == [True, True, True, False, False]
    s = sensitivity_table({"x": t}, warn).iloc[0]
    assert (s["K"], s["K_stan_run"]) == (5, 2)
    assert (
        s["rhat1.01_treedepth_warns"],
        s["rhat1.01_treedepth_fails"],
        s["rhat1.05_treedepth_warns"],
        s["rhat1.05_treedepth_fails"],
    ) == (2, 1, 3, 2)


def test_sensitivity_stage_reads_tables_and_writes_the_table(tmp_path):
    t = table(
        [
            {},
            {"n_treedepth_hits": 3.0},
            {"max_rhat": 1.02, "converged": False, "failed_checks": "rhat"},
        ]
    )
    io.write_parquet(tmp_path / "a.parquet", t)
    out = run_convergence_sensitivity(
        {"a": tmp_path / "a.parquet"},
        config_with()["convergence"],
        [tmp_path / f"sens.{ext}" for ext in ("csv", "md", "tex")],
        [tmp_path / f"fails.{ext}" for ext in ("csv", "md", "tex")],
        configs={"a": same_a09(name="a")},
    )
    assert out["rhat1.05_treedepth_fails"].tolist() == [2]
    text = (tmp_path / "sens.md").read_text()
    assert "rhat1.01_treedepth_warns" in text and "| a " in text
    fails = pd.read_csv(tmp_path / "fails.csv")
    assert fails[["scenario", "failed_checks", "runs"]].values.tolist() == [["a", "rhat", 1]]
    assert fails["max_rhat_q50"].tolist() == [1.02]


def test_block_variants_check_mixing_on_the_chosen_blocks_only():
    good = {
        f"{s}_{b}": v
        for b in ("omega", "x0", "states")
        for s, v in (("max_rhat", 1.001), ("min_ess_bulk", 900.0), ("min_ess_tail", 800.0))
    }
    bad = {"max_rhat": 1.5, "converged": False, "failed_checks": "rhat"}
    t = table(
        [
            good,
            {**good, **bad, "max_rhat_states": 1.5},  # only the states mix badly
            {**good, **bad, "max_rhat_x0": 1.5, "max_rhat_states": 1.5},
            {**good, **bad, "max_rhat_omega": 1.5, "min_ess_bulk_omega": 20.0},
            {**good, "converged": False, "failed_checks": "divergences", "n_divergent": 3.0},
        ]
    )
    base = ConvergenceSettings()
    assert converged_under(t, base).tolist() == [True, False, False, False, False]
    assert converged_under(t, base, ("omega", "x0")).tolist() == [True, True, False, False, False]
    assert converged_under(t, base, ("omega",)).tolist() == [True, True, True, False, False]
    row = sensitivity_table({"x": t}, base).iloc[0]
    assert (row["omega_x0_only"], row["omega_only"]) == (2, 3)
    # a table without per-block columns (records before format 2): no block variant
    assert np.isnan(sensitivity_table({"x": table([{}])}, base).iloc[0]["omega_only"])


def test_failure_patterns_group_the_runs_that_did_not_converge():
    separated = {"converged": False, "failed_checks": "rhat,ess_bulk,ess_tail"}
    t = table(
        [
            {},
            {**separated, "max_rhat": 1.5, "failing_blocks": "omega,states"},
            {**separated, "max_rhat": 1.7, "failing_blocks": "omega,states", "n_divergent": 2.0},
            {**separated, "max_rhat": 1.6, "failing_blocks": "omega,states"},
            {"converged": False, "failed_checks": "divergences", "n_divergent": 1.0},
        ]
    ).fillna({"failing_blocks": ""})
    out = failure_pattern_table({"x": t, "all good": table([{}])})
    assert out[
        ["failed_checks", "failing_blocks", "runs", "runs_with_divergences"]
    ].values.tolist() == [
        ["rhat,ess_bulk,ess_tail", "omega,states", 3, 1],
        ["divergences", "", 1, 1],
    ]
    first = out.iloc[0]
    assert (first["max_rhat_q00"], first["max_rhat_q50"], first["max_rhat_q100"]) == (1.5, 1.6, 1.7)
    assert set(out["scenario"]) == {"x"} and set(out["K"]) == {5}
