"""Off-support and run-off marginal MAPs are marked in the per-trajectory Stan table."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from ssmobs.models import get_model
from ssmobs.nuts.off_support import mark_off_support, off_support_reasons, unusable

pytestmark = pytest.mark.unit


def frame(T: int = 2) -> pd.DataFrame:
    model = get_model("stoch_vol")
    cols: dict[str, list[float]] = {"k": [0, 1, 2], "converged": [True, False, True]}
    for name in model.theta_names(T):
        for stat in ("map", "q5", "q95"):
            cols[f"{name}_{stat}"] = [0.5, 0.5, 0.5]
    return pd.DataFrame(cols)


def test_values_off_the_support_or_run_off_are_marked_and_kept():
    model = get_model("stoch_vol")
    bounds = model.prior_bounds(
        {"phi": 0.9, "sigma": 0.5}, {"phi": "restricted", "sigma": "half_line"}
    )
    table = frame()
    table.loc[1, "sigma_map"] = -1.6e307  # a KDE artefact of draws that ran off
    table.loc[2, "phi_q95"] = 1.02  # beyond phi < 1
    table.loc[2, "x1_map"] = 3e120  # a state that ran off
    marked = mark_off_support(table, model, bounds, 2)
    assert marked.loc[0, "off_support"] == ""
    assert marked.loc[1, "off_support"].startswith("sigma_map -1.6e+307 from draws that ran off")
    assert "phi_q95 1.02 off the support (0, 1)" in marked.loc[2, "off_support"]
    assert "x1_map 3e+120 from draws that ran off" in marked.loc[2, "off_support"]
    assert marked.loc[1, "sigma_map"] == -1.6e307  # the value itself is kept
    assert "off_support" not in table.columns  # the input is left alone


def test_nan_is_not_computed_and_no_reason():
    model = get_model("stoch_vol")
    bounds = model.prior_bounds(
        {"phi": 0.9, "sigma": 0.5}, {"phi": "restricted", "sigma": "half_line"}
    )
    table = frame()
    table["sigma_map"] = np.nan
    assert off_support_reasons(table, model, bounds, 2) == ["", "", ""]
    assert unusable(float("nan"), (0.0, 1.0)) == ""
    assert unusable(1.0, (0.0, 1.0)) == ""  # the ends themselves are not beyond the support


def test_gather_writes_the_marks_into_the_per_trajectory_table(tmp_path, monkeypatch):
    """Rule gather_nuts' table (marginal_map.parquet) carries off_support; the summary
    counts the marked rows."""
    from ssmobs import io
    from ssmobs.config.scenario import Scenario
    from ssmobs.config.stage_inputs import GatherInputs
    from ssmobs.design import trajectories as design
    from ssmobs.nuts import record_cache
    from ssmobs.stages.stan import run_gather_nuts

    model = get_model("stoch_vol")
    scenario = Scenario.from_config(
        {"name": "sv", "model": "stoch_vol", "omega": {"phi": 0.9, "sigma": 0.5}, "x0": 0,
         "T": 2, "K": 3, "prior": {"phi": "restricted", "sigma": "half_line"}}
    )  # fmt: skip
    traj = design.Trajectories(
        model=model,
        omega=scenario.omega,
        x0=scenario.x0,
        x=np.zeros((3, 2, 1)),
        z=np.zeros((3, 2, 1)),
        attrs={},
    )
    monkeypatch.setattr(design, "read_trajectories", lambda path: traj)
    monkeypatch.setattr(record_cache, "check_batch_records", lambda *a, **k: None)
    table = frame()
    table.loc[1, "sigma_map"] = -1.6e307
    io.write_parquet(tmp_path / "batch0.parquet", table)
    inputs = GatherInputs(
        trajectories="unused.nc",
        batches=(str(tmp_path / "batch0.parquet"),),
        records=str(tmp_path),
        scenario="sv",
        K=3,
        stan_every=1,
        prior=(("phi", "restricted"), ("sigma", "half_line")),
        stan_init="random",
        convergence=(),
    )
    paths = {"table": tmp_path / "marginal_map.parquet", "summary": tmp_path / "summary.json"}
    info = run_gather_nuts(inputs, paths)
    back = io.read_parquet(tmp_path / "marginal_map.parquet", ["off_support"])
    assert back["off_support"].tolist()[0] == "" and back["off_support"].tolist()[2] == ""
    assert back["off_support"].tolist()[1].startswith("sigma_map -1.6e+307")
    assert info["n_off_support"] == 1
