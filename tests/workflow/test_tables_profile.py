"""The tables profile (Tables II/III and Figure 3 at the paper's settings): it plans the
paper's work, and its committed outputs hold the paper's values beside ours and a
provenance that matches the profile."""

from __future__ import annotations

import hashlib
import math
import re
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).parent))

from helpers import REPO, make_workdir, snakemake  # noqa: E402

pytestmark = pytest.mark.workflow

PROFILE = REPO / "config" / "tables.yaml"
OUT = REPO / "paper_figures" / "paper_settings"
TARGETS = [
    f"paper_figures/paper_settings/{stem}.{ext}"
    for stem in ("table2_joint_vs_marginal", "table3_coverage")
    for ext in ("csv", "md", "tex")
]
TARGETS += [f"paper_figures/paper_settings/fig3_joint_vs_marginal.{ext}" for ext in ("pdf", "png")]


def test_profile_is_the_papers_setting():
    conf = yaml.safe_load(PROFILE.read_text())
    rows = {(sc["T"], sc["K"]) for sc in conf["scenarios"]}
    assert rows == {(20, 1300), (50, 3100)}
    for sc in conf["scenarios"]:
        assert sc["model"] == "same" and sc["omega"] == {"a": 0.9} and sc["x0"] == 8
    # chains and iterations are the schema's defaults, which are the paper's
    assert not {"chains", "iter_warmup", "iter_sampling"} & set(conf.get("stan", {}))
    schema = yaml.safe_load((REPO / "workflow" / "schemas" / "config.schema.yaml").read_text())
    stan = schema["properties"]["stan"]["properties"]
    assert (
        stan["chains"]["default"],
        stan["iter_warmup"]["default"],
        stan["iter_sampling"]["default"],
    ) == (4, 4000, 6000)


@pytest.mark.slow  # `make tables` (2.2 h, run rarely) planned: its dry run in test-slow (issue 48)
def test_dry_run_plans_every_trajectory(tmp_path):
    workdir = make_workdir(tmp_path)
    proc = snakemake(workdir, "-n", "--cores", "2", *TARGETS, "--configfile", "config/tables.yaml")
    counts = dict(re.findall(r"^(\w+)\s+(\d+)$", proc.stdout, flags=re.M))
    batch = yaml.safe_load(PROFILE.read_text())["stan"]["batch_size"]
    assert int(counts["sample_nuts"]) == math.ceil(1300 / batch) + math.ceil(3100 / batch)
    assert int(counts["joint_map"]) == 2 and int(counts["gather_nuts"]) == 2


committed = pytest.mark.skipif(
    not (OUT / "provenance.json").is_file(),
    reason="no committed paper-settings outputs in this checkout",
)


@committed
def test_committed_provenance_matches_profile():
    prov = yaml.safe_load((OUT / "provenance.json").read_text())
    assert prov["config"] == yaml.safe_load(PROFILE.read_text())
    assert prov["config_sha256"] == hashlib.sha256(PROFILE.read_bytes()).hexdigest()
    assert prov["stan"]["backend"] in ("native", "cmdstanpy", "pystan")
    assert prov["wall_seconds"] > 0 and re.fullmatch(r"[0-9a-f]{40}", prov["commit"])


@committed
def test_committed_tables_hold_paper_values_beside_ours():
    t2 = pd.read_csv(OUT / "table2_joint_vs_marginal.csv")
    assert set(t2["T"]) == {20, 50}
    for comp in ("a", "x0"):
        assert {f"{comp}_ours", f"{comp}_paper", f"{comp}_rel_diff"} <= set(t2.columns)
        both = t2.dropna(subset=[f"{comp}_ours", f"{comp}_paper"])
        assert len(both) == 12  # mean, variance, MSE; joint and marginal MAP; two T
        assert (both[f"{comp}_rel_diff"] >= 0).all()
    t3 = pd.read_csv(OUT / "table3_coverage.csv")
    assert {"ours", "paper"} <= set(t3.columns) and t3["paper"].notna().any()
    for ext in ("pdf", "png"):
        assert (OUT / f"fig3_joint_vs_marginal.{ext}").stat().st_size > 1000


SECTION4 = REPO / "config" / "section4_sep_d2_p1.yaml"
SECTION4_OUT = REPO / "paper_figures" / "section4_sep_d2_p1_a_T50"


def test_section4_profile_is_the_papers_setting():
    conf = yaml.safe_load(SECTION4.read_text())
    (sc,) = conf["scenarios"]
    assert (sc["model"], sc["T"], sc["K"], sc["x0"]) == ("sep_d2_p1", 50, 4000, 8)
    assert sc["omega"] == {"a": 0.9, "b": 0.9, "c": 0.9}
    assert sc["prior"] == {"a": "restricted", "b": "unrestricted", "c": "unrestricted"}
    assert not {"chains", "iter_warmup", "iter_sampling"} & set(conf.get("stan", {}))
    assert conf["outputs_dir"] == "paper_figures/section4_sep_d2_p1_a_T50"


@pytest.mark.skipif(
    not (SECTION4_OUT / "provenance.json").is_file(),
    reason="no committed Section IV row in this checkout",
)
def test_committed_section4_row_matches_profile_and_holds_the_papers_value():
    prov = yaml.safe_load((SECTION4_OUT / "provenance.json").read_text())
    assert prov["config"] == yaml.safe_load(SECTION4.read_text())
    assert prov["config_sha256"] == hashlib.sha256(SECTION4.read_bytes()).hexdigest()
    # recorded as the Makefile runs it: `make section4 SECTION4_CONFIG=<its config>`
    assert prov["command"] == f"make section4 SECTION4_CONFIG={SECTION4.relative_to(REPO)}"
    assert prov["started_from_empty_results"] is True
    assert prov["wall_seconds"] > 0
    assert prov["stan"]["gradients_by_model"] == {"sep_d2_p1": "analytic"}
    row = pd.read_csv(SECTION4_OUT / "section4_summary.csv").iloc[0]
    assert row["K"] == 4000 and row["K_stan_paper"] == 2972  # the paper's, from paper_values
    # x0 drops out of the likelihood at c = 0, inside c's prior (-1, 1): the posterior is
    # improper, so the row says so and states no |K^Stan| (every trajectory still ran)
    assert "x0 drops out of the likelihood at c = 0" in row["improper"]
    assert pd.isna(row["K_stan"]) and pd.isna(row["K_stan_frac"])
    assert row["K_stan_runs"] == row["K"]
    assert 0 < row["K_max"] <= row["K"]
