"""Issue 21: the observability maps of the smoke run, checked against the scenario whose
trajectories one cell shares, and a user's model mapped with one config entry."""

from __future__ import annotations

import json

import pandas as pd
import pytest
import yaml
from helpers import REPO, SMOKE_OUT, only

pytestmark = pytest.mark.workflow


def test_map_cell_equals_the_scenario_with_the_same_trajectories(smoke_run):
    """Cell (a = 0.9, T = 4) of map 'same' is scenario same_T4: the same |K^max| and the same
    count of unique interior maxima of the exact marginal."""
    cells = pd.read_csv(smoke_run / SMOKE_OUT / "map_same.csv")
    assert len(cells) == 4 and set(cells["T"]) == {4, 8}
    cell = cells[(cells["value"] == 0.9) & (cells["T"] == 4)].iloc[0]
    joint = json.loads(only(smoke_run, "results/same_T4/joint_map/*/summary.json").read_text())
    exact = json.loads(only(smoke_run, "results/same_T4/exact_marginal/*/summary.json").read_text())
    assert cell["K"] == joint["K"] == 12
    assert cell["K_max"] == joint["K_max"]
    assert cell["n_starts"] == 1 and cell["K_max_unique"] == cell["K_max"]  # one start
    assert cell["exact_unique"] == exact["n_unique"]
    assert bool(cell["paper_point"]) and cells["paper_point"].sum() == 1
    for col in ("K_max_frac", "exact_unique_frac"):
        assert (cells[f"{col}_lo95"] <= cells[col]).all() and (
            cells[col] <= cells[f"{col}_hi95"]
        ).all()


def test_own_model_map_has_the_joint_map_only(smoke_run):
    """stoch_vol is not linear in the states: joint MAP columns, no exact ones."""
    cells = pd.read_csv(smoke_run / SMOKE_OUT / "map_stoch_vol.csv")
    assert list(cells["value"]) == [0.5, 0.9] and not cells["exact"].any()
    assert "exact_unique" not in cells.columns
    assert {"lvar_median_phi", "lvar_median_sigma", "K_max_frac_hi95"} <= set(cells.columns)
    assert cells["K_max_frac"].between(0, 1).all()
    for ext in ("png", "pdf", "md"):
        assert (smoke_run / SMOKE_OUT / f"map_stoch_vol.{ext}").stat().st_size > 0
    # 4 starts per trajectory (the base's joint_map_n_starts): cell phi = 0.9 has the
    # trajectories and settings of scenario stoch_vol_T5, so its |K^max_unique| (issue 36)
    joint = json.loads(only(smoke_run, "results/stoch_vol_T5/joint_map/*/summary.json").read_text())
    cell = cells[cells["value"] == 0.9].iloc[0]
    assert (cells["n_starts"] == 4).all() and joint["n_starts"] == 4
    assert cell["K_max_unique"] == joint["K_max_unique"] and cell["K_max"] == joint["K_max"]
    assert cell["K_max_unique_frac_lo95"] <= cell["K_max_unique_frac"]


MAP_PROFILE = REPO / "config" / "map.yaml"
MAP_OUT = REPO / "paper_figures" / "observability_map"
committed_map = pytest.mark.skipif(
    not (MAP_OUT / "provenance.json").is_file(), reason="no committed maps in this checkout"
)


@committed_map
def test_committed_maps_match_the_profile_and_their_scenario():
    """The committed maps come from config/map.yaml; the cell of the paper's Same (0.9, 8)
    at T = 20 has the numbers of the scenario with the same trajectories (Section IV table
    of the same run), and ranWalk at T = 4 is unobservable (Sec. IV.E)."""
    prov = yaml.safe_load((MAP_OUT / "provenance.json").read_text())
    assert prov["config"] == yaml.safe_load(MAP_PROFILE.read_text())
    conf = yaml.safe_load(MAP_PROFILE.read_text())
    for entry in conf["observability_maps"]:
        cells = pd.read_csv(MAP_OUT / f"map_{entry['name']}.csv")
        assert len(cells) == len(entry["values"]) * len(entry["T"])
        assert (MAP_OUT / f"map_{entry['name']}.png").stat().st_size > 2000
    same = pd.read_csv(MAP_OUT / "map_same.csv").set_index(["value", "T"])
    s4 = pd.read_csv(MAP_OUT / "section4_summary.csv").set_index("scenario").loc["same_a09_T20"]
    assert same.loc[(0.9, 20), "K_max"] == s4["K_max"]
    assert same.loc[(0.9, 20), "exact_unique"] == s4["exact_unique"]
    ranwalk = pd.read_csv(MAP_OUT / "map_ranwalk.csv").set_index(["value", "T"])
    assert ranwalk.loc[(0.9, 4), "K_max"] == 0
