"""The points of the choice of K (Sec. IV.A) and the cells of an observability map (issue 21)
are keyed by exactly what they read (issue 62): each is computed from one frozen inputs
object whose content is its key, every field of it moves the key, and the code that computes
them reads no config, scenario or rule param beside it."""

from __future__ import annotations

import ast
import dataclasses
import inspect
from pathlib import Path

import pytest
import yaml
from ssmobs import cache_keys, run_paths
from ssmobs.cache_keys import CacheKeys
from ssmobs.config.stage_inputs import (
    MAP_CELLS_DIR,
    KSelectionPointInputs,
    inputs_payload,
    k_selection_points_inputs,
    map_cell_inputs,
)
from ssmobs.config.validation import validate
from ssmobs.models import MODELS
from ssmobs.stage_table import PACKAGE_DIR, STAGES
from ssmobs.stages import observability_map as om
from ssmobs.stages.k_selection import grid

pytestmark = pytest.mark.unit

REPO = PACKAGE_DIR.parents[1]


@pytest.fixture(scope="module")
def smoke() -> dict:
    """The smoke profile: one k_selection entry and one observability map (exact on)."""
    config = validate(yaml.safe_load((REPO / "config" / "smoke.yaml").read_text()))
    assert config["k_selection"] and config["observability_maps"]
    return config


def _changed(value):
    """Another value of a field of an inputs object."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, (int, float)):
        return value + 1
    if isinstance(value, str):
        return value + "x"
    if isinstance(value, tuple):
        return (*value, ("extra", 1))
    return "changed"  # None, a nested inputs object


def _other(field: str, value):
    """Another value of ``field``; a model is a module of the package: another one."""
    return next(m for m in sorted(MODELS) if m != value) if field == "model" else _changed(value)


def _fields(inputs) -> list[str]:
    fields = [f.name for f in dataclasses.fields(inputs)]
    assert fields and set(inputs_payload(inputs)) == {"stage_inputs", *fields}
    return fields


def test_every_field_of_the_points_inputs_moves_the_points_key(smoke, monkeypatch):
    ksel = smoke["k_selection"][0]["name"]
    keys = CacheKeys(smoke, "native")
    base = keys.k_selection_points(ksel)
    inputs = k_selection_points_inputs(keys.k_selections[ksel], smoke, design=keys.design)
    assert keys.inputs("k_selection_points", ksel) == inputs  # the table's builder
    assert CacheKeys(smoke, "native").k_selection_points(ksel) == base  # same inputs, same key
    payload = keys.describe()[f"k_selection_points:{ksel}:{base}"]
    assert payload["inputs"] == inputs_payload(inputs)
    assert payload["model_code"] == keys.model_code(inputs.model)
    for field in _fields(inputs):
        other = dataclasses.replace(inputs, **{field: _other(field, getattr(inputs, field))})
        monkeypatch.setattr(keys, "inputs", lambda *a, o=other, **k: o)
        assert keys.k_selection_points(ksel) != base, field
    monkeypatch.undo()
    assert keys.k_selection_points(ksel) == base


def test_a_point_is_its_shared_inputs_and_its_file_in_their_keyed_folder(smoke):
    """Every field of one point's inputs moves its key or its file: what every point of the
    scenario reads is the folder's key, K_i, method, set variant and seed its file's name;
    the grid's job computes its points from the object that folder is keyed by."""
    ksel = smoke["k_selection"][0]["name"]
    keys = CacheKeys(smoke, "native")
    grid_inputs = keys.inputs("k_selection_grid", ksel)
    shared = grid_inputs.points_inputs
    assert Path(grid_inputs.points).name == keys.k_selection_points(ksel)
    payload = keys.describe()[f"k_selection_points:{ksel}:{keys.k_selection_points(ksel)}"]
    assert payload["inputs"] == inputs_payload(shared)  # the folder's key holds what they read
    point = shared.point(100, "random", "nested", 1)
    assert isinstance(point, KSelectionPointInputs) and point.points is shared
    assert point.file == "random_nested_seed1/K100.json"
    for field in _fields(point):
        if field == "points":
            continue  # the folder's key: the test above
        other = dataclasses.replace(point, **{field: _changed(getattr(point, field))})
        assert other.file != point.file, field
    assert point.design_set(8, 5).startswith(f"results/shared/design_disturbances/{keys.design}/")
    assert point.design_set(8, 5).endswith("/q8_K100_random_seed5.nc")


def test_grids_on_one_scenario_share_its_points_and_a_grid_key_follows_them(smoke):
    """Two k_selection entries on one scenario share the points' folder whatever their
    grids; an edit of what a point reads moves both the points' and the grids' keys."""
    entry = smoke["k_selection"][0]
    twin = {**entry, "name": "twin", "K_grid": [*entry["K_grid"], entry["K_grid"][-1] * 2]}
    config = {**smoke, "k_selection": [entry, twin]}
    keys = CacheKeys(config, "native")
    assert keys.k_selection_points("twin") == keys.k_selection_points(entry["name"])
    assert keys.k_selection_grid("twin") != keys.k_selection_grid(entry["name"])
    tighter = {**config, "joint_map": {**config["joint_map"], "grad_tol": 1e-9}}
    other = CacheKeys(tighter, "native")
    assert other.k_selection_points("twin") != keys.k_selection_points("twin")
    assert other.k_selection_grid("twin") != keys.k_selection_grid("twin")
    # a setting no point reads leaves them: the Stan block, the scenario's description
    sampled = {**config, "stan": {**config["stan"], "chains": 2}}
    assert CacheKeys(sampled, "native").k_selection_points("twin") == keys.k_selection_points(
        "twin"
    )


def test_every_field_of_a_cells_inputs_moves_its_key(smoke, monkeypatch):
    name = smoke["observability_maps"][0]["name"]
    keys = CacheKeys(smoke, "native")
    (cell, base), *_ = keys.map_cells(name)
    inputs = keys.lookup("map_cell", cell["name"], base)["inputs"]
    entry = smoke["observability_maps"][0]
    assert inputs == map_cell_inputs(cell, smoke, design=keys.design, exact=entry["exact"])
    assert inputs.exact is not None  # the smoke map runs the exact stage
    payload = keys.describe()[f"map_cell:{cell['name']}:{base}"]
    assert payload["inputs"] == inputs_payload(inputs)
    for field in _fields(inputs):
        other = dataclasses.replace(inputs, **{field: _other(field, getattr(inputs, field))})
        monkeypatch.setattr(cache_keys, "map_cell_inputs", lambda *a, o=other, **k: o)
        assert CacheKeys(smoke, "native").map_cells(name)[0][1] != base, field
    monkeypatch.undo()
    assert CacheKeys(smoke, "native").map_cells(name)[0][1] == base


def test_every_field_of_the_map_jobs_inputs_moves_its_key(smoke, monkeypatch):
    """The map's table is keyed by what its job reads (the rule's only param is the object
    its key was made of), so a cell's key, the folder of the cells, the map's name and its
    varied parameter each move it."""
    name = smoke["observability_maps"][0]["name"]
    keys = CacheKeys(smoke, "native")
    base = keys.map_table(name)
    inputs = keys.lookup("map", name, base)["inputs"]
    assert inputs.cells_dir == MAP_CELLS_DIR and inputs.map == name
    assert run_paths.MAP_CELLS_DIR is MAP_CELLS_DIR  # one constant: where RunPaths looks
    assert [key for _, key in keys.map_cells(name)] == [key for key, _ in inputs.cells]
    real = cache_keys.map_cells_inputs
    for field in _fields(inputs):
        other = dataclasses.replace(inputs, **{field: _changed(getattr(inputs, field))})
        monkeypatch.setattr(cache_keys, "map_cells_inputs", lambda *a, o=other, **k: o)
        assert CacheKeys(smoke, "native").map_table(name) != base, field
    monkeypatch.setattr(cache_keys, "map_cells_inputs", real)
    assert CacheKeys(smoke, "native").map_table(name) == base


def test_a_cell_is_keyed_by_what_it_computes_not_by_its_map():
    """A cell's key holds no name and no field the cell does not read: the base's
    description, Stan settings or paper reference do not move it."""
    from factories import same_a09

    base = same_a09(name=None, prior="restricted", T=None, K=None)
    maps = [
        {"name": "m", "base": base, "vary": "a", "values": [0.5], "T": [4], "K": 6},
        {
            "name": "n",
            "base": {**base, "description": "another", "stan_every": 2, "paper_ref": "x"},
            "vary": "a",
            "values": [0.5],
            "T": [4],
            "K": 6,
        },
    ]
    keys = CacheKeys(validate({"scenarios": [same_a09()], "observability_maps": maps}), "native")
    (_, m), (_, n) = keys.map_cells("m")[0], keys.map_cells("n")[0]
    assert m == n and keys.map_table("m") != keys.map_table("n")


def _read_names(function) -> set[str]:
    """The names and attributes a function reads, but those of its inputs object."""
    body = ast.parse(inspect.getsource(function))
    names = {n.id for n in ast.walk(body) if isinstance(n, ast.Name)}
    return names | {
        n.attr
        for n in ast.walk(body)
        if isinstance(n, ast.Attribute)
        and not (isinstance(n.value, ast.Name) and n.value.id in {"inputs", "shared", "cell"})
    }


@pytest.mark.parametrize(
    "function",
    [grid.run_k_selection_point, grid.run_k_selection_grid, om.cell_summary, om.map_table]
    + [om.run_map_cells],
    ids=lambda f: f.__name__,
)
def test_the_point_and_cell_code_reads_its_inputs_alone(function):
    params = list(inspect.signature(function).parameters)
    assert params in (["inputs", "paths"], ["inputs"]), params
    assert not _read_names(function) & {"Scenario", "scenario", "config", "snakemake"}


def test_the_rules_pass_the_inputs_alone():
    """Rule observability_map_cells passes the object its key was made of; its script and
    rule k_selection_grid's pass the params' inputs and the outputs, nothing else."""
    rules = REPO / "workflow" / "rules"
    cells = (rules / "observability_map.smk").read_text().split("rule observability_map_cells:")[1]
    params = cells.split("params:")[1].split("script:")[0]
    assert [line.strip() for line in params.strip().splitlines()][-1] == (
        'inputs=lambda wc: expect_key("map", wc.map, wc.key)["inputs"],'
    )
    for script in ("observability_map_cells", "k_selection_grid"):
        tree = ast.parse((REPO / "workflow" / "scripts" / f"{script}.py").read_text())
        read = {
            n.attr
            for n in ast.walk(tree)
            if isinstance(n, ast.Attribute)
            and isinstance(n.value, ast.Attribute)
            and n.value.attr == "params"
        }
        assert read == {"inputs"}, script
    assert STAGES["k_selection_points"].code == (
        "stages/k_selection/grid.py:run_k_selection_point",
    )
