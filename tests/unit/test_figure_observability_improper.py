"""The observability-ratio figure says "improper" where Stan numbers are not shown."""

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
