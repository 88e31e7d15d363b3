"""Issue 21: the cells of an observability map, their keys and cache, and a cell known to
be unobservable."""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest
from factories import same_a09
from ssmobs.cache_keys import CacheKeys
from ssmobs.config.maps import cell_entries
from ssmobs.config.stage_inputs import DESIGN_SET, MAP_CELLS_DIR
from ssmobs.config.validation import ConfigError, validate
from ssmobs.stages import observability_map as om

pytestmark = pytest.mark.unit

SCENARIO = same_a09(K=3)
MAP = {
    "name": "m",
    "base": same_a09(name=None, prior="restricted", T=None, K=None),
    "vary": "a",
    "values": [0.5, 0.9],
    "T": [4, 10],
    "K": 20,
}


def config(*maps: dict, **blocks: dict) -> dict:
    return validate({"scenarios": [dict(SCENARIO)], "observability_maps": list(maps), **blocks})


def test_cells_are_the_base_at_every_value_and_horizon():
    conf = config(MAP)
    cells = cell_entries(conf["observability_maps"][0])
    assert [c["name"] for c in cells] == ["m_a0.5_T4", "m_a0.5_T10", "m_a0.9_T4", "m_a0.9_T10"]
    assert [c["omega"]["a"] for c in cells] == [0.5, 0.5, 0.9, 0.9]
    assert all(c["K"] == 20 and c["stan"] is False and c["joint_map"] for c in cells)
    assert all(c["method"] == "design" and c["seed"] == 1 for c in cells)  # defaults filled
    assert conf["observability_maps"][0]["base"] == MAP["base"]  # the base is not changed


@pytest.mark.parametrize(
    "change, message",
    [
        ({"vary": "b"}, r"vary = 'b': not a parameter of model 'same'; allowed: \['a'\]"),
        ({"base": {**MAP["base"], "T": 5}}, r"base: \['T'\] are set per cell"),
        ({"values": [0.5, 1.5]}, r"cell m_a1.5_T4: true value a=1.5 must satisfy \|a\| < 1"),
        ({"base": {**MAP["base"], "model": "nope"}}, r"base.model = 'nope': unknown model"),
        ({"T": [0]}, r"T\[0\]"),
    ],
)
def test_a_bad_map_is_refused_before_any_job(change, message):
    with pytest.raises(ConfigError, match=message):
        config({**MAP, **change})


def _keys(conf: dict) -> dict[str, str]:
    return {cell["name"]: key for cell, key in CacheKeys(conf, "native").map_cells("m")}


def test_an_extended_grid_keeps_the_keys_of_its_cells():
    before = _keys(config(MAP))
    after = _keys(config({**MAP, "values": [0.5, 0.9, 0.99], "T": [4, 10, 20]}))
    assert all(after[name] == key for name, key in before.items())
    assert len(set(after.values())) == 9


def test_cell_keys_follow_the_settings_that_determine_them():
    base = _keys(config(MAP))
    coarse = _keys(config(MAP, exact_marginal={"coarse_nodes": [200, 48, 16, 9]}))
    assert set(coarse.values()).isdisjoint(base.values())
    no_exact = {**MAP, "exact": False}
    assert _keys(config(no_exact)) == _keys(
        config(no_exact, exact_marginal={"coarse_nodes": [200, 48, 16, 9]})
    )
    joint = _keys(config(MAP, joint_map={"grad_tol": 1e-6}))
    assert set(joint.values()).isdisjoint(base.values())
    renamed = {**MAP, "name": "other"}
    other = CacheKeys(config(renamed), "native").map_cells("other")
    assert sorted(k for _, k in other) == sorted(base.values())  # the name is no part of it


def _inputs(conf: dict, name: str = "m"):
    """What rule observability_map_cells reads for map ``name`` (the object of its key)."""
    keys = CacheKeys(conf, "native")
    return keys.lookup("map", name, keys.map_table(name))["inputs"]


def _at(inputs, cells_dir):
    """``inputs`` with its cells cached in ``cells_dir``."""
    return dataclasses.replace(inputs, cells_dir=str(cells_dir))


def fake_cells(tmp_path, monkeypatch, row):
    """The cells of map MAP with cell_summary replaced by ``row(cell inputs)``: the (value,
    T) of the cells it computed, the config and the map job's inputs (cells in tmp_path)."""
    calls: list[tuple[float, int]] = []

    def fake_summary(cell):
        calls.append((cell.omega_config["a"], cell.T))
        return row(cell)

    monkeypatch.setattr(om, "cell_summary", fake_summary)
    conf = config(MAP)
    return calls, conf, _at(_inputs(conf), tmp_path / "cells")


def test_only_missing_or_damaged_cells_are_computed(tmp_path, monkeypatch):
    calls, conf, inputs = fake_cells(
        tmp_path, monkeypatch, lambda cell: {"K_max": 1, "K_max_frac": 0.05, "exact": False}
    )
    frame = om.map_table(inputs)
    assert len(calls) == 4 and list(frame["T"]) == [4, 10, 4, 10]
    wider = copy.deepcopy(conf)
    wider["observability_maps"][0]["values"] = [0.5, 0.9, 0.99]
    more = _at(_inputs(wider), tmp_path / "cells")
    (tmp_path / "cells" / f"{inputs.cells[0][0]}.json").write_text("{not json")
    calls.clear()
    frame = om.map_table(more)
    assert calls == [(0.5, 4), (0.99, 4), (0.99, 10)]
    assert len(frame) == 6 and list(frame["value"]) == [0.5, 0.5, 0.9, 0.9, 0.99, 0.99]


def test_the_map_job_reads_the_cells_its_key_is_made_of():
    """The map's key is the content of what its job reads: its name, varied parameter, cells
    folder and every cell with its key; another map of the same cells shares the cells'
    keys and files but not the table's key (the table names the map)."""
    conf = config(MAP, {**MAP, "name": "other"})
    keys = CacheKeys(conf, "native")
    inputs = keys.lookup("map", "m", keys.map_table("m"))["inputs"]
    other = keys.lookup("map", "other", keys.map_table("other"))["inputs"]
    assert [k for _, k in keys.map_cells("m")] == [k for k, _ in inputs.cells]
    assert inputs.cells == other.cells and keys.map_table("m") != keys.map_table("other")
    assert inputs.cell_file(inputs.cells[0][0]).startswith(MAP_CELLS_DIR + "/")
    assert (inputs.map, inputs.vary) == ("m", "a")
    for key, cell in inputs.cells:
        assert keys.lookup("map_cell", f"m_a{cell.omega_config['a']:g}_T{cell.T}", key) == {
            "inputs": cell
        }


def test_a_table_of_cached_cells_equals_one_of_fresh_cells(tmp_path, monkeypatch):
    """A rerun after a kill reads some cells from their files: the map's table must be the
    same bytes as a fresh run's (the JSON file sorts its keys, a fresh row does not)."""

    calls, _, inputs = fake_cells(
        tmp_path,
        monkeypatch,
        lambda cell: {
            "K_max": np.int64(3),
            "K_max_frac": np.float64(cell.T / 70),
            "K_max_frac_lo95": 0.01,
            "K_max_frac_hi95": 0.3,
            "lvar_median_a": math.nan,
            "exact": False,
        },
    )
    fresh = om.map_table(inputs)
    for key, _ in inputs.cells[1:]:
        (tmp_path / "cells" / f"{key}.json").unlink()
    calls.clear()
    resumed = om.map_table(inputs)
    assert len(calls) == len(inputs.cells) - 1  # the first cell came from its file
    assert resumed.to_csv(index=False) == fresh.to_csv(index=False)
    # the order cell_summary makes, not the file's sorted one
    assert list(fresh.columns[-6:]) == [
        "K_max",
        "K_max_frac",
        "K_max_frac_lo95",
        "K_max_frac_hi95",
        "lvar_median_a",
        "exact",
    ]


def test_random_walk_at_T4_is_unobservable(tmp_path, monkeypatch):
    """ranWalk, T = 4 (Sec. IV): no joint MAP passes the checks, and few trajectories have
    a unique interior maximum of p(a | z)."""
    conf = config(
        {
            "name": "m",
            "base": {"model": "sep_ranwalk", "omega": {"a": 0.9}, "x0": 8, "prior": "half_line"},
            "vary": "a",
            "values": [0.9],
            "T": [4],
            "K": 40,
        }
    )
    ((_, cell),) = _inputs(conf).cells
    monkeypatch.chdir(tmp_path)  # its design set is made below results/shared/
    row = om.cell_summary(cell)
    made = DESIGN_SET.format(key="*", q=8, K=40, method="design", seed=1)
    assert len(list(tmp_path.glob(made))) == 1
    assert row["K_max"] == 0 and row["K_max_frac_hi95"] < 0.1
    assert row["exact"] and row["exact_unique_frac"] < 0.5


MULT = {
    "name": "m",
    "base": {"model": "sep_mult", "omega": {"a": 0.9}, "x0": 8, "prior": "half_line"},
    "vary": "a",
    "values": [0.9],
    "T": [10],
    "K": 10,
}


def test_cell_keys_follow_the_number_of_starts():
    """Multi-start is turned on for a map by its base (joint_map_n_starts) or by the
    joint_map block (n_starts); either moves the keys of its cells (issue 36)."""
    base = _keys(config(MAP))
    assert _keys(config(MAP, joint_map={"n_starts": 1})) == base  # the default
    by_block = _keys(config(MAP, joint_map={"n_starts": 4}))
    by_base = _keys(config({**MAP, "base": {**MAP["base"], "joint_map_n_starts": 4}}))
    for other in (by_block, by_base):
        assert set(other) == set(base) and set(other.values()).isdisjoint(base.values())


def test_a_cell_counts_unique_maxima_as_the_joint_map_stage_does(tmp_path, monkeypatch):
    """|K^max_unique| of a cell is the joint-MAP stage's count (trajectories with exactly one
    distinct maximum that passes the checks, ssmobs.joint_map.multi_start) on the same trajectories:
    with one start it equals |K^max|; from 4 starts (the base's joint_map_n_starts) it is
    the count over 4 starts, and |K^max| stays the paper's start's (issue 36)."""
    from ssmobs.config.scenario import Scenario
    from ssmobs.design.disturbance_sets import disturbance_set
    from ssmobs.design.trajectories import make_trajectories
    from ssmobs.joint_map.driver import JointMapSettings
    from ssmobs.joint_map.multi_start import multi_start_joint_map
    from ssmobs.joint_map.multi_start_summary import multi_start_summary
    from ssmobs.joint_map.problem import JointMapProblem

    monkeypatch.chdir(tmp_path)  # the cells make their design sets below results/shared/
    rows = {}
    for n in (1, 4):
        entry = {**MULT, "base": {**MULT["base"], "joint_map_n_starts": n}}
        conf = config(entry)
        ((cell, _),) = CacheKeys(conf, "native").map_cells("m")
        ((_, inputs),) = _inputs(conf).cells
        sc = Scenario.from_config(cell)
        rows[n] = om.cell_summary(dataclasses.replace(inputs, exact=None))
        path = tmp_path / inputs.design_set(sc.disturbance_dim)  # the set the cell made
        matrix, attrs = disturbance_set(path, sc.disturbance_dim, sc.K, sc.method, sc.seed, {})
        traj = make_trajectories(sc, matrix, provenance=attrs)
        settings = JointMapSettings.from_mapping({**conf["joint_map"], "n_starts": n})
        bounds = sc.model.prior_bounds(sc.omega, sc.prior)
        multi = multi_start_joint_map(
            JointMapProblem(sc.model, traj.z, bounds, sc.omega, sc.x0, settings)
        )
        expected = multi_start_summary(multi.columns(), settings)
        assert rows[n]["n_starts"] == n
        assert rows[n]["K_max_unique"] == expected["K_max_unique"]
        assert rows[n]["K_max"] == int((multi.runs[0].status == "ok").sum())
        assert rows[n]["K_max_unique_frac"] == expected["K_max_unique"] / 10
        lo, hi = expected["K_max_unique_lo95"], expected["K_max_unique_hi95"]
        assert (rows[n]["K_max_unique_frac_lo95"], rows[n]["K_max_unique_frac_hi95"]) == (lo, hi)
    assert rows[1]["K_max_unique"] == rows[1]["K_max"]
    assert rows[4]["K_max"] == rows[1]["K_max"]
    # the Multiplicative model's wrong-sign maxima: every trajectory passes from the paper's
    # start (10 of 10 here), but the other starts find a second maximum (0 of 10 unique)
    assert rows[4]["K_max_unique"] < rows[4]["K_max"]
