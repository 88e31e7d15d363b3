"""Figures and the exact-vs-Stan caption say "improper" where Stan numbers are not shown."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from ssmobs.reports import figures

pytestmark = pytest.mark.unit


def summary(improper: list[str]) -> pd.DataFrame:
    cols: dict[str, object] = {"scenario": ["a", "b"]}
    for frac in ("K_max_frac", "K_max_frac_paper", "K_stan_frac", "K_stan_frac_paper"):
        cols[frac] = [0.5, np.nan if frac == "K_stan_frac" else 0.5]
        cols[f"{frac}_lo95"] = [0.3, np.nan]
        cols[f"{frac}_hi95"] = [0.7, np.nan]
    cols["improper"] = improper
    return pd.DataFrame(cols)


def texts(monkeypatch, frame: pd.DataFrame) -> list[str]:
    seen: list[str] = []

    def keep(fig, paths):
        seen.extend(t.get_text() for ax in fig.axes for t in ax.texts)

    monkeypatch.setattr(figures, "save_figure", keep)
    figures.figure_observability_ratios(frame, ["unused.png"])
    return seen


def test_improper_scenario_gets_the_word_not_a_zero_bar(monkeypatch):
    assert texts(monkeypatch, summary(["", "improper: x0 drops out at a = 0"])) == ["improper"]
    assert texts(monkeypatch, summary(["", ""])) == []


def test_figure_3_draws_no_marginal_map_of_an_improper_posterior(monkeypatch):
    labels: list[list[str]] = []

    def keep(fig, paths):
        labels.extend([t.get_text() for t in ax.get_legend().get_texts()] for ax in fig.axes)

    monkeypatch.setattr(figures, "save_figure", keep)
    joint = pd.DataFrame({"a": [0.9, 0.8], "x0": [8.0, 7.5]})
    marginal = pd.DataFrame({"a_map": [0.9, 0.85], "x0_map": [8.1, 7.9]})
    panels = [
        {"T": 20, "joint": joint, "marginal": marginal, "improper": ""},
        {"T": 50, "joint": joint, "marginal": marginal, "improper": "improper: a = 0"},
    ]
    figures.figure_joint_vs_marginal(panels, 0.9, 8.0, ["unused.png"])
    assert labels[1] == ["T=20 (|K^Stan|=2)", "T=50 (improper)"]
    assert labels[0] == ["T=20 (|K^max|=2)", "T=50 (|K^max|=2)"]


def test_exact_vs_stan_caption_says_the_posterior_is_improper(tmp_path, monkeypatch):
    from ssmobs.config.scenario import Scenario
    from ssmobs.stages.outputs import figures as glue

    monkeypatch.setattr(figures, "save_figure", lambda fig, paths: None)
    cols = {"k": [0, 1], "converged": [True, True]}
    for name in ("a", "b", "x0"):
        for stat in ("map", "q5", "q95"):
            cols[f"{name}_{stat}"] = [0.9, 0.8]
    pd.DataFrame(cols).to_parquet(tmp_path / "stan.parquet")
    pd.DataFrame(cols).to_parquet(tmp_path / "exact.parquet")
    entry = {"name": "sep_b", "model": "sep", "omega": {"a": 0.9, "b": 0.9}, "x0": 8, "T": 75}
    for prior, improper in (
        ({"a": "unrestricted", "b": "restricted"}, True),
        ("restricted", False),
    ):
        sc = Scenario.from_config({**entry, "K": 2, "prior": prior})
        md = tmp_path / f"t{improper}.md"
        glue.run_figure_exact_vs_stan(
            sc, tmp_path / "stan.parquet", tmp_path / "exact.parquet", ["f.png"], [str(md)]
        )
        first = md.read_text().splitlines()[0]
        assert ("The posterior is improper: " in first) is improper, first
