"""The paper's tables (ssmobs.reports.tables): one key convention, compact Section IV, intervals."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd
import pytest
from factories import same_a09
from fake_propriety import PROPER, FakePropriety, analysis
from ssmobs.binomial import clopper_pearson
from ssmobs.reports.tables import (
    exact_vs_stan_table,
    section_iv,
    section_iv_compact,
    table_ii,
    table_iii,
    write_table,
)

PAPER = {
    "ref": {
        "K": 4000,
        "K_max": 1956,
        "K_stan": 3680,
        "joint": {"mean": {"a": 0.95}},
        "marginal": {"mean": {"a": 0.90}},
    }
}


def rows() -> list[dict]:
    sc = same_a09(
        T=20, K=40, method="design", stan_init="random", joint_map=True, stan=True, paper_ref="ref"
    )
    joint = {
        "K": 40,
        "K_max": 20,
        "ratio": 0.5,
        "components": ["a", "x0"],
        "a_mean": 0.94,
        "x0_mean": 7.1,
        "a_var": 0.01,
        "x0_var": 0.5,
        "a_mse": 0.02,
        "x0_mse": 1.2,
    }
    marginal = {
        "K": 40,
        "n_stan": 34,
        "ratio": 0.85,
        "a_mean": 0.897,
        "x0_mean": 8.05,
        "a_cover90": 0.87,
        "x0_cover90": 0.9,
        "a_var": 0.001,
        "x0_var": 0.7,
    }
    own = {
        **sc,
        "name": "own",
        "model": "stoch_vol",
        "omega": {"phi": 0.9, "sigma": 0.5},
        "x0": 0,
        "stan": False,
        "paper_ref": "",
    }
    return [
        {
            "config": sc,
            "scenario": "s",
            "T": 20,
            "paper_ref": "ref",
            "joint": joint,
            "marginal": marginal,
            "exact": None,
        },
        {
            "config": own,
            "scenario": "own",
            "T": 20,
            "paper_ref": "",
            "joint": None,
            "marginal": None,
            "exact": None,
        },
    ]


def test_both_stages_read_with_component_stat_keys():
    t2 = table_ii(rows()[:1], PAPER, propriety=PROPER).set_index(["estimator", "statistic"])
    assert t2.loc[("joint MAP", "mean"), "a_ours"] == 0.94
    assert t2.loc[("marginal MAP", "mean"), "a_ours"] == 0.897
    assert t2.loc[("joint MAP", "mean"), "a_paper"] == 0.95


def test_wide_summary_keeps_its_columns_and_adds_intervals():
    wide = section_iv(rows(), PAPER, propriety=PROPER).set_index("scenario")
    assert {"joint_mean_a", "marginal_mean_a", "cover90_a", "K_max_frac"} <= set(wide.columns)
    assert wide.loc["s", "joint_mean_a"] == 0.94
    assert (wide.loc["s", "K_max_frac_lo95"], wide.loc["s", "K_max_frac_hi95"]) == clopper_pearson(
        20, 40
    )
    assert wide.loc["s", "K_stan_frac_paper_hi95"] - wide.loc["s", "K_stan_frac_paper_lo95"] < 0.03
    assert math.isnan(wide.loc["own", "K_stan_frac_lo95"])


def test_k_stan_counts_over_the_stan_runs_of_a_subset():
    sub = rows()[:1]
    sub[0]["config"] = {**sub[0]["config"], "stan_every": 4}
    sub[0]["marginal"] = {**sub[0]["marginal"], "K": 10, "n_stan": 8}  # k = 0, 4, ..., 36
    wide = section_iv(sub, PAPER, propriety=PROPER).iloc[0]
    assert (wide["K"], wide["K_stan_runs"], wide["K_stan"]) == (40, 10, 8)
    assert wide["K_stan_frac"] == 0.8 and wide["K_max_frac"] == 0.5  # the joint MAP ran all K
    assert (wide["K_stan_frac_lo95"], wide["K_stan_frac_hi95"]) == clopper_pearson(8, 10)
    compact = section_iv_compact(sub, PAPER, propriety=PROPER).iloc[0]
    assert compact["Stan runs"] == 10 and compact["K^Stan/K (95 % CI)"].startswith("0.80 [")


def test_compact_summary_is_one_short_row_per_scenario(tmp_path):
    compact = section_iv_compact(rows(), PAPER, propriety=PROPER)
    assert list(compact.columns) == [
        "scenario",
        "T",
        "K",
        "K^max/K (95 % CI)",
        "paper K^max/K",
        "Stan runs",
        "K^Stan/K (95 % CI)",
        "paper K^Stan/K",
        "marginal MAP mean",
        "Cover90",
    ]
    s = compact.set_index("scenario").loc["s"]
    assert s["K^max/K (95 % CI)"] == "0.50 [0.34, 0.66]"  # K = 40: about +-0.15
    assert s["paper K^max/K"] == "0.49 [0.47, 0.50]"
    assert s["marginal MAP mean"] == "a 0.897, x0 8.05" and s["Cover90"] == "a 0.87, x0 0.9"
    own = compact.set_index("scenario").loc["own"]
    assert own["K^Stan/K (95 % CI)"] == "" and own["paper K^max/K"] == ""
    paths = write_table(compact, [tmp_path / "c.md", tmp_path / "c.tex"], "caption")
    md = (tmp_path / "c.md").read_text()
    assert md.startswith("caption\n\n") and md.count("\n|") == 4  # header, rule, 2 rows
    assert len(paths) == 2 and not (tmp_path / "c.csv").exists()


def test_write_table_refuses_unknown_suffix(tmp_path):
    with pytest.raises(ValueError, match=".csv, .md or .tex"):
        write_table(pd.DataFrame({"a": [1]}), [tmp_path / "t.txt"])


def test_table_ii_caption_names_the_configured_setting():
    from ssmobs.stages.outputs.paper_tables import _table_ii_setting

    def entry(name, a, x0):
        return {
            "config": {"name": name, "model": "same", "omega": {"a": a}, "x0": x0, "T": 20, "K": 10}
        }

    assert _table_ii_setting([entry("s1", 0.9, 8), entry("s2", 0.9, 8)]) == (
        "model Same, (a, x0) = (0.9, 8)"
    )
    assert _table_ii_setting([entry("s1", 0.7, 5)]) == "model Same, (a, x0) = (0.7, 5)"
    assert "paper_outputs.tables_2_3" in _table_ii_setting(
        [entry("s1", 0.9, 8), entry("s2", 0.7, 8)]
    )
    assert "paper_outputs.tables_2_3" in _table_ii_setting([])


def test_exact_vs_stan_table_gives_median_and_largest_difference_per_statistic():
    exact = pd.DataFrame({"a_map": [0.9, 0.8, 0.7], "a_q5": [0.1, 0.2, 0.3], "a_q95": [1.0] * 3})
    stan = exact + pd.DataFrame(
        {"a_map": [0.01, -0.03, 0.02], "a_q5": [0.0, 0.0, float("nan")], "a_q95": [0.5] * 3}
    )
    out = exact_vs_stan_table(stan, exact, ["a"]).set_index("statistic")
    assert out.loc["marginal MAP", "abs_diff_median"] == pytest.approx(0.02)
    assert out.loc["marginal MAP", "abs_diff_max"] == pytest.approx(0.03)
    assert out.loc["5 % quantile", "n"] == 2  # the NaN difference is left out
    assert out.loc["95 % quantile", "abs_diff_max"] == pytest.approx(0.5)
    with pytest.raises(ValueError, match="2 Stan rows, 3 exact rows"):
        exact_vs_stan_table(stan.iloc[:2], exact, ["a"])


def test_k_selection_distribution_counts_each_chosen_k_over_the_seeds():
    from ssmobs.reports.tables import k_selection_distribution, k_selection_table

    base = {"name": "n", "scenario": "s", "method": "design", "c1": 0.01, "c2": 0.01,
            "K_grid": "100-1000 step 100", "K_paper": 300}  # fmt: skip
    chosen = {"independent": [200, 300, 200, None], "nested": [300, 300, 300, 300]}
    rows = [
        {**base, "sets": sets, "seed": seed, "K_chosen": k}
        for sets, ks in chosen.items()
        for seed, k in enumerate(ks, 1)
    ]
    dist = k_selection_distribution(k_selection_table(rows))
    indep = dist[dist["sets"] == "independent"]
    assert list(indep["K_chosen"].fillna(-1)) == [200, 300, -1]
    assert list(indep["n_seeds"]) == [2, 1, 1] and list(indep["share"]) == [0.5, 0.25, 0.25]
    nested = dist[dist["sets"] == "nested"]
    assert list(nested["n_seeds"]) == [4] and list(nested["share"]) == [1.0]
    assert set(dist["seeds"]) == {4} and set(dist["K_paper"]) == {300}


# ------------------------------------------------- improper posteriors (issue 60)
SAME_IMPROPER = analysis(same=FakePropriety(improper=("x0 drops out at a = 0",)))


def test_improper_scenario_shows_no_stan_number_in_the_wide_summary():
    wide = section_iv(rows(), PAPER, propriety=SAME_IMPROPER).set_index("scenario")
    s = wide.loc["s"]
    assert s["improper"] == "improper: x0 drops out at a = 0" and wide.loc["own", "improper"] == ""
    for column in ("K_stan", "K_stan_frac", "K_stan_frac_lo95", "marginal_mean_a", "cover90_a"):
        assert math.isnan(s[column]), column
    assert s["K_stan_runs"] == 40 and s["joint_mean_a"] == 0.94  # what ran; the joint MAP
    assert s["K_stan_frac_paper"] == 3680 / 4000  # the paper's own value stays
    assert "edge" not in wide.columns


def test_improper_scenario_says_so_in_words_in_the_compact_summary():
    compact = section_iv_compact(rows(), PAPER, propriety=SAME_IMPROPER).set_index("scenario")
    s = compact.loc["s"]
    assert s["K^Stan/K (95 % CI)"] == "not shown: improper"
    assert s["marginal MAP mean"] == "not shown: improper" and s["Cover90"] == "not shown: improper"
    assert s["improper"] == "improper: x0 drops out at a = 0"
    assert s["K^max/K (95 % CI)"] == "0.50 [0.34, 0.66]"  # the joint MAP's count stays
    assert compact.loc["own", "K^Stan/K (95 % CI)"] == ""  # Stan did not run there


def test_edge_finding_keeps_the_numbers_and_notes_it():
    edge = analysis(same=FakePropriety(edge=("x0 drops out as a -> 0 (end of the support)",)))
    compact = section_iv_compact(rows(), PAPER, propriety=edge).set_index("scenario")
    assert compact.loc["s", "marginal MAP mean"] == "a 0.897, x0 8.05"
    assert compact.loc["s", "edge"].startswith("x0 drops out as a -> 0")
    assert "improper" not in compact.columns
    t2 = table_ii(rows()[:1], PAPER, propriety=edge).set_index(["estimator", "statistic"])
    assert t2.loc[("marginal MAP", "mean"), "a_ours"] == 0.897 and "edge" in t2.columns


def test_tables_ii_and_iii_leave_the_stan_cells_of_an_improper_posterior_empty():
    t2 = table_ii(rows()[:1], PAPER, propriety=SAME_IMPROPER).set_index(["estimator", "statistic"])
    assert math.isnan(t2.loc[("marginal MAP", "mean"), "a_ours"])
    assert math.isnan(t2.loc[("marginal MAP", "mean"), "a_rel_diff"])
    assert t2.loc[("marginal MAP", "mean"), "a_paper"] == 0.90
    assert t2.loc[("joint MAP", "mean"), "a_ours"] == 0.94
    assert set(t2["improper"]) == {"improper: x0 drops out at a = 0"}
    t3 = table_iii(rows()[:1], PAPER, propriety=SAME_IMPROPER)
    assert t3["ours"].isna().all() and t3["K_stan"].isna().all()
    assert not table_iii(rows()[:1], PAPER, propriety=PROPER)["ours"].isna().all()


def test_the_projects_analysis_marks_sep_with_a_on_minus_one_one_improper():
    """With models.propriety itself: Sep with a unrestricted is improper at a = 0 inside
    the support; Same with a on (0, 1) has the documented edge a -> 0 and keeps its numbers."""
    sep = rows()[0]
    sep["config"] = {
        **sep["config"],
        "name": "sep_b",
        "model": "sep",
        "omega": {"a": 0.9, "b": 0.9},
        "prior": {"a": "unrestricted", "b": "restricted"},
    }
    same = rows()[0]
    wide = section_iv([sep, same], PAPER).set_index("scenario")
    assert (
        wide.loc["sep_b", "improper"].startswith("improper: ")
        and "a = 0" in wide.loc["sep_b", "improper"]
    )
    assert math.isnan(wide.loc["sep_b", "K_stan"]) and math.isnan(
        wide.loc["sep_b", "marginal_mean_a"]
    )
    assert wide.loc["s", "improper"] == "" and wide.loc["s", "marginal_mean_a"] == 0.897
    assert "a -> 0" in wide.loc["s", "edge"]


def test_an_undecided_propriety_is_shown_in_words_not_as_numbers():
    @dataclass(frozen=True)
    class Undecided(FakePropriety):
        undetermined: tuple[str, ...] = ("x0 may drop out where a = b, not solved",)

    wide = section_iv(rows(), PAPER, propriety=analysis(same=Undecided())).set_index("scenario")
    assert wide.loc["s", "improper"] == (
        "may be improper (not decided): x0 may drop out where a = b, not solved"
    )
    assert math.isnan(wide.loc["s", "K_stan"])


def test_convergence_sensitivity_counts_of_an_improper_posterior_are_not_shown():
    from ssmobs.stages.outputs.paper_tables import mark_improper_counts

    table = pd.DataFrame(
        {"scenario": ["sep_b", "s"], "K": [20, 40], "K_stan_run": [13, 34], "omega_only": [14, 35]}
    )
    sep_b = {**same_a09(name="sep_b", model="sep", omega={"a": 0.9, "b": 0.9})}
    sep_b["prior"] = {"a": "unrestricted", "b": "restricted"}
    out = mark_improper_counts(table, {"sep_b": sep_b, "s": same_a09()}).set_index("scenario")
    assert out.loc["sep_b", "K_stan_run"] == out.loc["sep_b", "omega_only"] == "not shown: improper"
    assert out.loc["sep_b", "K"] == 20 and "a = 0" in out.loc["sep_b", "improper"]
    assert out.loc["s", "K_stan_run"] == 34 and out.loc["s", "improper"] == ""
    proper = mark_improper_counts(table.iloc[1:], {"s": same_a09()})
    assert list(proper.columns) == list(table.columns)  # nothing to say: the table as it was
