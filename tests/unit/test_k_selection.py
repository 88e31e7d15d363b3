"""Choice of K by relative differences (Sec. IV.A)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from factories import same_a09
from ssmobs.config.scenario import Scenario
from ssmobs.joint_map.driver import joint_map_summary
from ssmobs.k_selection import VVector, relative_difference, select_k, v_vector
from ssmobs.models import get_model

pytestmark = pytest.mark.unit


def test_relative_difference_values():
    assert relative_difference(1.0, 1.0) == 0.0
    assert np.isclose(relative_difference(1.0, 1.1), 0.1 / 1.1)
    assert np.isclose(relative_difference(-2.0, -1.0), 0.5)
    assert relative_difference(0.0, 0.0) == 0.0  # defined as 0
    assert relative_difference(0.0, 3.0) == 1.0
    assert relative_difference(1.0, -1.0) == 2.0
    assert np.isnan(relative_difference(np.nan, 1.0))
    x, y = np.array([1.0, 0.0, 5.0]), np.array([2.0, 0.0, 4.0])
    assert np.allclose(relative_difference(x, y), relative_difference(y, x))
    assert np.allclose(relative_difference(x, y), [0.5, 0.0, 0.2])


def test_select_k_on_a_hand_made_sequence():
    k_values = [100, 200, 300, 400, 500, 600]
    # component 0 (c1 = 0.01) settles from K = 300 on, component 1 (c2 = 0.05) from K = 200
    V = np.array(
        [
            [0.50, 1.00],
            [0.90, 2.00],
            [1.000, 2.02],
            [1.005, 2.05],
            [1.002, 2.01],
            [0.998, 2.04],
        ]
    )
    thr = np.array([0.01, 0.05])
    assert select_k(k_values, V, thr) == 2
    # a looser c1 moves the choice earlier; component 0 then allows i = 1 too
    assert select_k(k_values, V, np.array([0.2, 0.05])) == 1
    # one late outlier in j > i rules out every earlier i
    V2 = V.copy()
    V2[5, 0] = 1.5
    assert select_k(k_values, V2, thr) is None


def test_select_k_never_picks_the_last_and_handles_nan():
    k_values = [100, 200, 300]
    V = np.array([[1.0], [2.0], [3.0]])
    # only the last K_i would satisfy the condition (vacuously): not chosen
    assert select_k(k_values, V, np.array([0.01])) is None
    # the second-to-last can be chosen when it agrees with the last
    V[2] = 2.001
    assert select_k(k_values, V, np.array([0.01])) == 1
    # a single K_i: nothing to compare with
    assert select_k([100], np.array([[1.0]]), np.array([0.5])) is None
    # NaN (e.g. |K^max| = 0) never counts as converged
    Vn = np.array([[np.nan], [np.nan], [np.nan]])
    assert select_k(k_values, Vn, np.array([0.5])) is None
    # RD(0, 0) = 0: a ratio |K^max|/K that stays 0 converges
    assert select_k(k_values, np.zeros((3, 1)), np.array([0.01])) == 0


def test_select_k_input_checks():
    with pytest.raises(ValueError, match="increasing"):
        select_k([200, 100], np.ones((2, 1)), np.ones(1))
    with pytest.raises(ValueError, match="one V row per K_i"):
        select_k([100, 200], np.ones((3, 1)), np.ones(1))
    with pytest.raises(ValueError, match="thresholds"):
        select_k([100, 200], np.ones((2, 2)), np.ones(3))


def summary_for(slug, omega, x0, seed):
    model = get_model(slug)
    names = model.theta_names(0)
    rng = np.random.default_rng(seed)
    frame = pd.DataFrame({"status": ["ok"] * 5 + ["ridge"]})
    for c in names:
        frame[c] = rng.normal(size=6)
        frame[f"lvar_{c}"] = rng.uniform(size=6)
    return model, joint_map_summary(frame, model, omega, x0)


def test_v_vector_layout_same():
    model, s = summary_for("same", [0.9], 8.0, seed=0)
    v = v_vector(s, model)
    assert v.labels == (
        "ratio",
        "a_mean",
        "x0_mean",
        "a_var",
        "x0_var",
        "a_lvar_mean",
        "x0_lvar_mean",
    )  # the paper's V in R^7 (Sec. IV.A)
    assert v.kinds == ("c1", "c1", "c1", "c2", "c2", "c2", "c2")
    assert np.isclose(v.values[0], 5 / 6)
    assert np.isclose(v.values[1], s["a_mean"]) and np.isclose(v.values[4], s["x0_var"])
    assert np.allclose(v.thresholds(0.01, 0.03), [0.01] * 3 + [0.03] * 4)


def test_v_vector_layout_multivariate_and_missing():
    model, s = summary_for("sep_d1_p2", [0.6, 0.5, 0.9, 0.9], [8.0, 8.0], seed=1)
    v = v_vector(s, model)
    assert len(v.values) == 1 + 3 * 6
    assert v.labels[1:7] == tuple(f"{c}_mean" for c in ["a", "b", "c", "d", "x0_1", "x0_2"])
    assert v.labels[-1] == "x0_2_lvar_mean"
    del s["b_var"]
    with pytest.raises(ValueError, match="b_var"):
        v_vector(s, model)


def test_selection_from_summaries_end_to_end():
    """V vectors built from summaries feed select_k with their c1/c2 thresholds."""
    model = get_model("same")
    vs = []
    for K, shift in [(100, 0.05), (200, 0.001), (300, 0.0), (400, 0.0005)]:
        frame = pd.DataFrame(
            {
                "status": ["ok"] * 4,
                "a": [0.9 + shift, 0.92, 0.94, 0.96],
                "x0": [7.0 + shift, 7.5, 8.0, 8.5],
                "lvar_a": [0.1] * 4,
                "lvar_x0": [1.0] * 4,
            }
        )
        vs.append(v_vector(joint_map_summary(frame, model, [0.9], 8.0), model))
    V = np.stack([v.values for v in vs])
    assert isinstance(vs[0], VVector)
    assert select_k([100, 200, 300, 400], V, vs[0].thresholds(0.01, 0.03)) == 1


# ------------------------------------------------------------------ set variants (issue 12)
def test_nested_random_sets_share_points_and_independent_sets_do_not():
    from ssmobs.design.disturbances import design_disturbances
    from ssmobs.k_selection import set_seed

    q = 8
    small = {
        s: design_disturbances(q, 100, "random", set_seed(1, 100, s)).points
        for s in ("nested", "independent")
    }
    large = {
        s: design_disturbances(q, 200, "random", set_seed(1, 200, s)).points
        for s in ("nested", "independent")
    }
    assert set_seed(1, 100, "nested") == set_seed(1, 200, "nested") == 1
    assert np.array_equal(large["nested"][:100], small["nested"])  # the K=100 set is a prefix
    assert set_seed(1, 100, "independent") != set_seed(1, 200, "independent")
    # independent sets: no shared point, and their first columns are uncorrelated draws
    assert not np.isin(small["independent"], large["independent"]).any()
    r = np.corrcoef(small["independent"].ravel(), large["independent"][:100].ravel())[0, 1]
    assert abs(r) < 0.1
    assert set_seed(2, 100, "independent") != set_seed(1, 100, "independent")
    with pytest.raises(ValueError, match="sets"):
        set_seed(1, 100, "shared")


def test_select_k_stage_scores_each_set_variant_separately(tmp_path, monkeypatch):
    from ssmobs import io
    from ssmobs.config.stage_inputs import k_selection_points_inputs
    from ssmobs.k_selection import set_seed
    from ssmobs.stages.k_selection.choice import run_select_k
    from ssmobs.stages.k_selection.grid import run_k_selection_point

    entry = same_a09(
        x0=8.0, K=40, prior="restricted", paper_ref="same_a09_T4", joint_map_start="observations"
    )
    sc = Scenario.from_config(entry)
    config = {"scenarios": [entry], "joint_map": {}, "design": {"b_max": None}}
    shared = k_selection_points_inputs({"scenario": "s"}, config, design="d0")
    paper_values = Path("config/paper_values.yaml").resolve()
    monkeypatch.chdir(tmp_path)  # the points make their design sets below results/shared/
    points = []
    for sets in ("independent", "nested"):
        for K in (40, 80, 120):
            point = shared.point(K, "random", sets, 3)
            out = tmp_path / f"{sets}_K{K}.json"
            info = run_k_selection_point(point, {"point": out})
            assert (info["sets"], info["seed"], info["set_seed"]) == (sets, 3, set_seed(3, K, sets))
            assert (tmp_path / point.design_set(8, info["set_seed"])).is_file()
            assert io.read_checked_json(out, required=["K_i"]) == info
            points.append(info)
    grid = tmp_path / "grid.json"  # what rule k_selection_grid writes
    io.write_json(grid, {"points": points})
    ksel = {"name": "t", "c1": 0.5, "c2": 2.0}
    res = run_select_k(
        ksel,
        sc,
        [grid],
        paper_values,
        tmp_path / "sel.json",
        tmp_path / "v.csv",
        [str(tmp_path / "f.png")],
    )
    rows = {c["sets"]: c for c in res["choices"]}
    assert set(rows) == {"independent", "nested"}
    for c in rows.values():  # loose thresholds: the first K_i is chosen in both variants
        assert c["K_chosen"] == 40 and c["K_grid"] == "40-120 step 40"
        assert c["K_paper_range"] == ""  # not the paper's (0.01, 0.03): no comparison
    v = pd.read_csv(tmp_path / "v.csv")
    # the two variants differ: at K = 40 the nested and independent sets are other draws
    ratio = v[v["component"] == "a_mean"].pivot_table(index="K", columns="sets", values="value")
    assert not np.allclose(ratio["independent"], ratio["nested"])


def test_paper_grid_is_i_times_100_up_to_500_above_the_papers_k():
    import yaml
    from ssmobs.config import validation as cfg

    c = cfg.validate(yaml.safe_load(open("config/paper.yaml")))
    paper = yaml.safe_load(open("config/paper_values.yaml"))
    refs = {sc["name"]: sc["paper_ref"] for sc in c["scenarios"]}
    for ks in c["k_selection"]:
        grid = ks["K_grid"]
        assert grid == list(range(100, grid[-1] + 1, 100))
        top = (
            4500
            if "random" in ks["methods"]
            else paper[refs[ks["scenario"]]]["k_selection"]["design"]["K"]
        )
        assert grid[-1] == -(-(top + 500) // 500) * 500, ks["name"]
        assert ks["sets"] == (
            ["independent", "nested"] if ks["scenario"] == "same_a09_T4" else ["independent"]
        )
    names = {ks["name"]: ks for ks in c["k_selection"]}
    assert (names["same_a09_T4_random"]["c1"], names["same_a09_T4_random"]["c2"]) == (0.01, 0.03)
    assert names["same_a07_T100"]["c2"] == 0.06


def test_papers_k_is_shown_only_beside_the_papers_thresholds(tmp_path):
    from ssmobs import io
    from ssmobs.stages.k_selection.choice import run_select_k

    sc = Scenario.from_config(same_a09(x0=8.0, K=100, paper_ref="same_a09_T4"))
    model = get_model("same")
    pts = []
    for K in (100, 200, 300):
        info = {"K_i": K, "method": "random", "seed": 1, "sets": "independent", "ratio": 1.0}
        for c in model.theta_names(0):
            info.update({f"{c}_mean": 1.0, f"{c}_var": 1.0, f"{c}_lvar_mean": 1.0})
        pts.append(info)
    io.write_json(tmp_path / "grid.json", {"points": pts})
    for (c1, c2), shown in (((0.01, 0.03), "2500-4500"), ((0.01, 0.01), "")):
        res = run_select_k(
            {"name": "t", "c1": c1, "c2": c2},
            sc,
            [tmp_path / "grid.json"],
            "config/paper_values.yaml",
            tmp_path / "s.json",
            tmp_path / "v.csv",
            [str(tmp_path / "f.png")],
        )
        row = res["choices"][0]
        assert row["K_paper_range"] == shown and row["K_chosen"] == 100
        assert row["c_paper"] == ("(0.01, 0.03)" if shown else "")


def test_grid_job_makes_its_sets_and_reuses_finished_points(tmp_path, monkeypatch):
    """Rule k_selection_grid: the sets are made in the job (as rule design_disturbances would
    write them), every point is cached as it finishes, and a rerun reuses them."""
    import json

    from ssmobs.config.stage_inputs import k_selection_grid_inputs, k_selection_points_inputs
    from ssmobs.stages.k_selection.grid import run_k_selection_grid

    config = {
        "scenarios": [same_a09(x0=8.0, K=8, joint_map_start="observations")],
        "joint_map": {},
        "design": {"b_max": None},
    }
    entry = {"scenario": "s", "K_grid": [8, 16], "methods": ["random"], "sets": ["nested"]}
    inputs = k_selection_grid_inputs(
        {**entry, "seeds": [1]}, config, points=str(tmp_path / "points"), design="d0"
    )
    assert inputs.grid_of("random_nested_seed1.json") == ("random", "nested", 1)
    assert inputs.points_inputs == k_selection_points_inputs(entry, config, design="d0")
    monkeypatch.chdir(tmp_path)
    rows = run_k_selection_grid(inputs, {"grid": tmp_path / "random_nested_seed1.json"})
    assert [r["K_i"] for r in rows] == [8, 16]
    design = tmp_path / "results" / "shared" / "design_disturbances" / "d0"
    assert len(list(design.glob("q8_K*_random_seed*.nc"))) == 2
    assert json.loads((tmp_path / "random_nested_seed1.json").read_text())["points"] == rows
    points = tmp_path / "points" / "random_nested_seed1"
    stamp = {p: p.stat().st_mtime_ns for p in points.glob("K*.json")}
    assert len(stamp) == 2
    again_path = tmp_path / "again" / "random_nested_seed1.json"
    again_path.parent.mkdir()
    again = run_k_selection_grid(inputs, {"grid": again_path})
    assert again == rows
    assert {p: p.stat().st_mtime_ns for p in stamp} == stamp
