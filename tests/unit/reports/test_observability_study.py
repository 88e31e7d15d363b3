"""The observability study table and figure from scenario summaries (synthetic inputs)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from fake_propriety import PROPER, FakePropriety, analysis
from ssmobs.config.scenario import Scenario
from ssmobs.reports import observability_study as study
from ssmobs.reports.observability_study import run_observability_study

pytestmark = pytest.mark.unit


def study_table(*args, **kwargs):
    """The study table with every posterior proper unless a test says otherwise."""
    return study.study_table(*args, **{"propriety": PROPER, **kwargs})


def _entry(T):
    return {
        "name": f"sv_T{T}",
        "model": "stoch_vol",
        "x0": 0,
        "T": T,
        "K": 4,
        "omega": {"phi": 0.9, "sigma": 0.5},
    }


def scenario(T):
    return Scenario.from_config(_entry(T))


def joint(k_max):
    return {
        "K": 4,
        "K_max": k_max,
        "ratio": k_max / 4,
        "n_ok": k_max,
        "n_boundary": 4 - k_max,
        "phi_mean": 0.8 if k_max else float("nan"),
        "sigma_mean": 0.4,
    }


def stan_frame(converged, failed):
    return pd.DataFrame(
        {
            "k": range(4),
            "converged": converged,
            "failed_checks": failed,
            "phi_map": [0.1, 0.2, 0.3, 0.9],
            "sigma_map": [0.5] * 4,
        }
    )


def test_rows_sorted_by_T_with_ratios_and_reasons():
    scs = [scenario(50), scenario(20)]
    frame = study_table(
        scs,
        {"sv_T50": joint(1), "sv_T20": joint(0)},
        {
            "sv_T50": {"n_stan": 3, "ratio": 0.75, "phi_mean": 0.85},
            "sv_T20": {"n_stan": 0, "ratio": 0.0},
        },
        {
            "sv_T50": stan_frame([True, True, True, False], ["", "", "", "rhat"]),
            "sv_T20": stan_frame([False] * 4, ["divergences,rhat", "rhat", "rhat,ebfmi", "rhat"]),
        },
    )
    assert frame["T"].tolist() == [20, 50]
    assert frame["K_max_ratio"].tolist() == [0.0, 0.25]
    assert frame["K_stan_ratio"].tolist() == [0.0, 0.75]
    assert frame.loc[0, "joint_not_ok"] == "boundary 4"
    assert frame.loc[0, "stan_failed_checks"] == "divergences 1, rhat 4, ebfmi 1"
    assert frame.loc[1, "stan_failed_checks"] == "rhat 1"
    assert frame.loc[1, "phi_mean_marginal"] == 0.85 and np.isnan(frame.loc[0, "phi_mean_marginal"])
    assert frame.loc[0, "phi_map_median_all_k"] == pytest.approx(0.25)


def test_stage_not_run_gives_nan(tmp_path):
    frame = study_table([scenario(20)], {}, {}, {})
    assert np.isnan(frame.loc[0, "K_max_ratio"]) and np.isnan(frame.loc[0, "K_stan_ratio"])


def test_run_writes_csv_md_png(tmp_path):
    (tmp_path / "j.json").write_text(json.dumps(joint(2)))
    (tmp_path / "s.json").write_text(json.dumps({"n_stan": 1, "ratio": 0.25}))
    stan_frame([True, False, False, False], ["", "rhat", "rhat", "rhat"]).to_parquet(
        tmp_path / "m.parquet"
    )
    out = {ext: tmp_path / f"ours_x_observability.{ext}" for ext in ("csv", "md", "png")}
    run_observability_study(
        {"name": "x"},
        [scenario(20)],
        {"sv_T20": tmp_path / "j.json"},
        {"sv_T20": tmp_path / "s.json"},
        {"sv_T20": tmp_path / "m.parquet"},
        out["csv"],
        out["md"],
        out["png"],
        stan_settings={"chains": 2, "iter_warmup": 3, "iter_sampling": 4},
        propriety=PROPER,
    )
    back = pd.read_csv(out["csv"])
    assert back["K_max_ratio"].tolist() == [0.5] and back["K_stan_ratio"].tolist() == [0.25]
    assert "2 chains x (3 + 4) iterations" in out["md"].read_text()
    assert out["png"].stat().st_size > 1000


def test_ratios_carry_their_binomial_interval():
    from ssmobs.binomial import clopper_pearson

    frame = study_table([scenario(20)], {"sv_T20": joint(1)}, {}, {})
    assert (frame.loc[0, "K_max_ratio_lo95"], frame.loc[0, "K_max_ratio_hi95"]) == clopper_pearson(
        1, 4
    )
    assert np.isnan(frame.loc[0, "K_stan_ratio_lo95"])  # no Stan stage


def test_multi_start_adds_k_max_unique_beside_k_max():
    from ssmobs.binomial import clopper_pearson

    single = study_table([scenario(20)], {"sv_T20": joint(3)}, {}, {})
    assert "K_max_unique" not in single.columns  # one start: the paper's columns only
    multi = {**joint(3), "n_starts": 8, "K_max_unique": 1, "K_max_undetermined": 2}
    frame = study_table([scenario(20)], {"sv_T20": multi}, {}, {})
    assert frame.loc[0, "K_max"] == 3 and frame.loc[0, "K_max_unique"] == 1
    assert frame.loc[0, "K_max_undetermined"] == 2  # one maximum, too few starts passed
    older = {**joint(3), "n_starts": 8, "K_max_unique": 1}  # a summary without the key
    assert np.isnan(
        study_table([scenario(20)], {"sv_T20": older}, {}, {}).loc[0, "K_max_undetermined"]
    )
    assert frame.loc[0, "K_max_unique_ratio"] == 0.25
    lo, hi = frame.loc[0, "K_max_unique_ratio_lo95"], frame.loc[0, "K_max_unique_ratio_hi95"]
    assert (lo, hi) == clopper_pearson(1, 4)


def test_an_estimate_off_the_support_or_from_draws_that_ran_off_is_not_a_number():
    """Issue 47: sigma has support (0, inf); a KDE mode of -9e306 (draws that ran off) or
    -0.2 (off the support), or a marginal mean off the support, is left out and named."""
    frame = stan_frame([True] * 4, [""] * 4)
    frame["sigma_map"] = [0.5, -0.2, -8.98e306, 0.7]
    stan = {"n_stan": 4, "ratio": 1.0, "phi_mean": 0.85, "sigma_mean": -1.45e307}
    row = study_table([scenario(20)], {"sv_T20": joint(2)}, {"sv_T20": stan}, {"sv_T20": frame})
    row = row.iloc[0]
    assert row["sigma_map_median_all_k"] == 0.6  # the median of 0.5 and 0.7 only
    assert np.isnan(row["sigma_mean_marginal"]) and row["phi_mean_marginal"] == 0.85
    note = row["not_shown"]
    assert "sigma_map of 1 k off the support (0, inf)" in note
    assert "sigma_map of 1 k from draws that ran off" in note
    assert "sigma_mean_marginal from draws that ran off" in note
    clean = study_table(
        [scenario(20)],
        {"sv_T20": joint(2)},
        {"sv_T20": {"n_stan": 4}},
        {"sv_T20": stan_frame([True] * 4, [""] * 4)},
    )
    assert clean.loc[0, "not_shown"] == "none"


def test_every_row_says_what_is_not_shown_even_without_a_stan_stage():
    frame = study_table([scenario(20)], {"sv_T20": joint(1)}, {}, {})
    assert frame.loc[0, "not_shown"] == "none"


def test_an_improper_posterior_shows_no_stan_number_and_says_why():
    improper = analysis(stoch_vol=FakePropriety(improper=("x0 drops out at phi = 0",)))
    stan = {"n_stan": 3, "ratio": 0.75, "K": 4, "phi_mean": 0.85}
    tables = {"sv_T20": stan_frame([True, True, True, False], ["", "", "", "rhat"])}
    frame = study_table(
        [scenario(20)], {"sv_T20": joint(2)}, {"sv_T20": stan}, tables, propriety=improper
    )
    row = frame.iloc[0]
    assert row["improper"] == "improper: x0 drops out at phi = 0"
    for column in ("K_stan", "K_stan_ratio", "K_stan_ratio_lo95", "phi_mean_marginal"):
        assert np.isnan(row[column]), column
    assert np.isnan(row["phi_map_median_all_k"])
    assert row["K_max"] == 2 and row["stan_failed_checks"] == "rhat 1"
    assert row["not_shown"].startswith("every Stan number (improper posterior)")
    proper = study_table([scenario(20)], {"sv_T20": joint(2)}, {"sv_T20": stan}, tables)
    assert proper.loc[0, "K_stan"] == 3 and "improper" not in proper.columns


def test_caption_states_what_ran(tmp_path):
    cfg = {"chains": 4, "iter_warmup": 4000, "iter_sampling": 6000}
    off = Scenario.from_config({**_entry(20), "stan": False, "name": "off_T20"})
    assert study.stan_caption([off], cfg) == "Stan: off."
    assert study.stan_caption([scenario(20)], cfg) == "Stan: 4 chains x (4000 + 6000) iterations."
    own = Scenario.from_config({**_entry(50), "stan_settings": {"iter_sampling": 500}})
    both = study.stan_caption([scenario(20), own, off], cfg)
    assert both == (
        "Stan: 4 chains x (4000 + 6000) iterations (sv_T20); "
        "4 chains x (4000 + 500) iterations (sv_T50); off (off_T20)."
    )
    (tmp_path / "j.json").write_text(json.dumps(joint(2)))
    out = {ext: tmp_path / f"o.{ext}" for ext in ("csv", "md", "png")}
    run_observability_study(
        {"name": "x"},
        [off],
        {"off_T20": tmp_path / "j.json"},
        {},
        {},
        out["csv"],
        out["md"],
        out["png"],
        stan_settings=cfg,
        propriety=PROPER,
    )
    first = out["md"].read_text().splitlines()[0]
    assert first.endswith("Stan: off.") and "4000" not in first


def test_the_projects_analysis_notes_the_edge_phi_to_zero_and_keeps_the_numbers():
    """With models.propriety itself: the SV model with phi on (0, 1) has x0 dropping out as
    phi -> 0, an end of the support: noted, numbers kept."""
    stan = {"n_stan": 3, "ratio": 0.75, "K": 4, "phi_mean": 0.85}
    frame = study.study_table([scenario(20)], {"sv_T20": joint(2)}, {"sv_T20": stan}, {})
    assert "phi -> 0" in frame.loc[0, "edge"] and "improper" not in frame.columns
    assert frame.loc[0, "K_stan"] == 3 and frame.loc[0, "phi_mean_marginal"] == 0.85


def test_the_study_figure_writes_improper_where_k_stan_is_not_shown(tmp_path, monkeypatch):
    from ssmobs.reports import figures

    seen: list[str] = []
    monkeypatch.setattr(
        figures,
        "save_figure",
        lambda fig, paths: seen.extend(t.get_text() for t in fig.axes[0].texts),
    )
    improper = analysis(stoch_vol=FakePropriety(improper=("x0 drops out at phi = 0",)))
    stan = {"sv_T20": {"n_stan": 3, "ratio": 0.75, "K": 4}}
    frame = study_table([scenario(20)], {"sv_T20": joint(2)}, stan, {}, propriety=improper)
    study.figure_study(frame, "t", tmp_path / "f.png")
    assert seen == ["improper"]
    seen.clear()
    study.figure_study(
        study_table([scenario(20)], {"sv_T20": joint(2)}, stan, {}), "t", tmp_path / "g.png"
    )
    assert seen == []
