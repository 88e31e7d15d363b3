"""The table of stages (ssmobs.stage_table, issue 62): every entry names code and scripts
that exist; a stage with an inputs object is keyed by exactly what it reads: its rule passes
the inputs as the only param, its script passes nothing else, its entry takes
``(inputs, paths)``, its outputs are the table's, and changing any field of the inputs moves
the key."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import re
from pathlib import Path

import pytest
import yaml
from ssmobs.cache_keys import CacheKeys
from ssmobs.config.stage_inputs import inputs_payload
from ssmobs.config.validation import validate
from ssmobs.models import MODELS
from ssmobs.stage_table import PACKAGE_DIR, STAGES

pytestmark = pytest.mark.unit

REPO = PACKAGE_DIR.parents[1]
#: the stages with an inputs object
WITH_INPUTS = sorted(n for n, s in STAGES.items() if s.inputs is not None)


def smoke_keys() -> CacheKeys:
    config = validate(yaml.safe_load((REPO / "config" / "smoke.yaml").read_text()))
    return CacheKeys(config, "native", repo=REPO)


def _entry(stage: str):
    module = STAGES[stage].code[0].partition(":")[0]
    name = "ssmobs." + module.removesuffix(".py").replace("/", ".")
    return __import__(name, fromlist=["_"]), STAGES[stage].entry


def _rule(stage: str) -> str:
    """The text of the rule whose script is the stage's (one rule per script)."""
    script = STAGES[stage].scripts[0]
    for smk in (REPO / "workflow" / "rules").glob("*.smk"):
        for block in re.split(r"\n(?=rule \w+:)", smk.read_text()):
            if f'"../scripts/{script}.py"' in block:
                return block
    raise AssertionError(f"no rule runs scripts/{script}.py")


def test_every_entry_names_code_and_scripts_that_exist():
    assert {"trajectories", "joint_map", "exact", "gather", "nuts_batches"} <= set(WITH_INPUTS)
    assert "k_selection_grid" in WITH_INPUTS
    for name, stage in STAGES.items():
        for entry in stage.code:
            assert (PACKAGE_DIR / entry.partition(":")[0]).is_file(), (name, entry)
        for script in stage.scripts:
            assert (REPO / "workflow" / "scripts" / f"{script}.py").is_file(), (name, script)
        for file in stage.extra_files:
            assert (PACKAGE_DIR / file).is_file(), (name, file)
        assert stage.folder is not None or not stage.outputs, name


@pytest.mark.parametrize("stage", WITH_INPUTS)
def test_the_stage_reads_its_inputs_and_nothing_else(stage):
    module, function = _entry(stage)
    assert function.startswith("run_")
    assert list(inspect.signature(getattr(module, function)).parameters) == ["inputs", "paths"]
    # the entry reads no scenario object and no config: only its inputs
    body = ast.parse(inspect.getsource(getattr(module, function)))
    names = {n.id for n in ast.walk(body) if isinstance(n, ast.Name)}
    names |= {
        n.attr
        for n in ast.walk(body)
        if isinstance(n, ast.Attribute)
        and not (isinstance(n.value, ast.Name) and n.value.id == "inputs")
    }
    assert not names & {"Scenario", "scenario", "config", "snakemake"}, names
    rule = _rule(stage)
    params = rule.split("params:")[1].split("script:")[0]
    assert re.findall(r"^\s+(\w+)=", params, flags=re.M) == ["inputs"]
    assert re.search(rf'PATHS\.inputs\(\s*"{stage}", wc\.(scenario|ksel)', params)
    outputs = dict(
        re.findall(r'^\s+(\w+)="([^"]+)"', rule.split("output:")[1].split("log:")[0], re.M)
    )
    owner = "{ksel}" if STAGES[stage].of == "k_selection" else "{scenario}"
    assert outputs == STAGES[stage].paths(owner, "{key}")
    # the script passes the params' inputs and the outputs, and reads no other param
    script = REPO / "workflow" / "scripts" / f"{STAGES[stage].scripts[0]}.py"
    read = {
        node.attr
        for node in ast.walk(ast.parse(script.read_text()))
        if isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Attribute)
        and node.value.attr == "params"
    }
    assert read == {"inputs"}


def _changed(value):
    if isinstance(value, bool):
        return not value
    if isinstance(value, (int, float)):
        return value + 1
    if isinstance(value, str):
        return value + "x"
    if isinstance(value, tuple):
        return (*value, ("extra", 1))
    return "changed"


@pytest.mark.parametrize("stage", WITH_INPUTS)
def test_every_field_of_the_inputs_moves_the_key(stage, monkeypatch):
    keys = smoke_keys()
    owners = keys.k_selections if STAGES[stage].of == "k_selection" else keys.scenarios
    name = next(iter(owners))
    at = {p: {"K": int(owners[name].get("K", 0)), "batch_size": 4}[p] for p in STAGES[stage].per}
    inputs = keys.inputs(stage, name, **at)
    base = keys.stage_key(stage, name, **at)
    assert keys.stage_key(stage, name, **at) == base  # the same inputs, the same key
    fields = [f.name for f in dataclasses.fields(inputs)]
    assert fields and set(inputs_payload(inputs)) == {"stage_inputs", *fields}
    for field in fields:
        value = getattr(inputs, field)
        # a model is a module of the package: another one (its code is keyed too)
        new = next(m for m in sorted(MODELS) if m != value) if field == "model" else _changed(value)
        other = dataclasses.replace(inputs, **{field: new})
        monkeypatch.setattr(keys, "inputs", lambda s, n, other=other, **at: other)
        assert keys.stage_key(stage, name, **at) != base, field
    monkeypatch.undo()
    assert keys.stage_key(stage, name, **at) == base


def test_the_joint_map_inputs_hold_what_the_stage_read_before():
    """The scenario fields and the merged block the joint MAP's key held before its inputs
    object (prior, the joint_map block with the scenario's start), and its trajectories."""
    keys = smoke_keys()
    name = next(iter(keys.scenarios))
    inputs = keys.inputs("joint_map", name)
    assert Path(inputs.trajectories).parent.name == keys.trajectories(name)
    assert inputs.settings_config["start_states"] == keys.scenarios[name]["joint_map_start"]
    assert inputs.prior_config == keys.scenarios[name].get("prior")


def test_the_trajectories_inputs_are_keyed_per_K_and_by_the_model_code():
    keys = smoke_keys()
    name = next(iter(keys.scenarios))
    sc = keys.scenarios[name]
    own = keys.inputs("trajectories", name, K=int(sc["K"]))
    assert keys.trajectories(name) == keys.trajectories(name, int(sc["K"]))
    other = keys.inputs("trajectories", name, K=int(sc["K"]) + 1)
    assert own.design_set(6) != other.design_set(6) and own.K + 1 == other.K
    assert f"/{keys.design}/" in own.design_set(6) and own.x0_config == sc["x0"]
    assert keys.lookup("trajectories", name, keys.trajectories(name)) == {"K": int(sc["K"])}
    payload = keys.describe()[f"trajectories:{name}:{keys.trajectories(name)}"]
    assert payload["model_code"] == keys.model_code(sc["model"])


def test_the_exact_inputs_are_keyed_per_K():
    keys = smoke_keys()
    name = next(iter(keys.scenarios))
    small, large = keys.inputs("exact", name, K=4), keys.inputs("exact", name, K=8)
    assert Path(small.trajectories).parent.name == keys.trajectories(name, 4)
    assert small != large and keys.exact(name, 4) != keys.exact(name, 8)
    assert keys.lookup("exact", name, keys.exact(name, 8)) == {"K": 8}
    assert small.settings_config == keys.config["exact_marginal"]


def test_the_gather_inputs_read_every_batch_table_and_the_records():
    """What rule gather_nuts reads is what rule sample_nuts writes: every batch table of the
    scenario's batch size, in order, and the records' folder."""
    from ssmobs.run_paths import RunPaths

    keys = smoke_keys()
    paths = RunPaths.from_config(keys.config, keys, "native")
    for name in paths.stan_scenarios:
        inputs = paths.gather_inputs(name)
        assert list(inputs.batches) == paths.nuts_batches(name) and len(inputs.batches) > 0
        assert inputs.records == paths.records_dir(name)
        assert inputs.stan_trajectories == paths.scenario_objects[name].stan_trajectories
        assert inputs.convergence_config == keys.config["convergence"]
    name = paths.stan_scenarios[0]
    assert keys.gather(name, 4) != keys.gather(name, 2)
    assert len(keys.inputs("gather", name, batch_size=1).batches) == len(
        paths.scenario_objects[name].stan_trajectories
    )


def test_the_nuts_inputs_name_the_batches_rule_sample_nuts_writes():
    """Each batch table of a scenario's batch size with its trajectories, the records' and
    the draws' folders and the program marker, as RunPaths gives them to the other rules."""
    from ssmobs.run_paths import RunPaths

    keys = smoke_keys()
    paths = RunPaths.from_config(keys.config, keys, "native")
    for name in paths.stan_scenarios:
        sc = paths.scenario_objects[name]
        inputs = paths.nuts_inputs(name)
        tables = [f"{paths.batch_dir(name)}/{file}" for file, _ in inputs.tables]
        assert tables == paths.nuts_batches(name)
        ks = [tuple(r) for r in sc.stan_batches(paths.batch_size(name))]
        assert [inputs.batch_of(file) for file, _ in inputs.tables] == ks
        assert (inputs.records, inputs.draws) == (paths.records_dir(name), paths.draws_dir(name))
        assert inputs.program == paths.program_marker(sc.model.slug)
        assert (inputs.joint_map is None) == (sc.stan_init != "joint_map")
    name = paths.stan_scenarios[0]
    assert keys.nuts_batches(name, 4) != keys.nuts_batches(name, 2)
