"""The table of stages (ssmobs.stage_table, issue 62): every entry names code and scripts
that exist; a stage with an inputs object is keyed by exactly what it reads: its rule passes
the inputs as the only param, its script passes nothing else, its entry takes
``(inputs, paths)``, its outputs are the table's, and changing any field of the inputs moves
the key."""

from __future__ import annotations

import ast
import copy
import dataclasses
import inspect
import re
from pathlib import Path

import pytest
import yaml
from ssmobs.cache_keys import CacheKeys
from ssmobs.config.stage_inputs import DESIGN_DIR, inputs_payload
from ssmobs.config.validation import validate
from ssmobs.models import MODELS
from ssmobs.stage_table import PACKAGE_DIR, PROGRAM_MARKER, STAGES

pytestmark = pytest.mark.unit

REPO = PACKAGE_DIR.parents[1]
#: the stages with an inputs object
WITH_INPUTS = sorted(n for n, s in STAGES.items() if s.inputs is not None)
#: ... and of them those a rule runs by an entry of their own (the NUTS records are written
#: by rule sample_nuts, whose inputs hold theirs whole)
WITH_ENTRY = [n for n in WITH_INPUTS if STAGES[n].entry is not None]
#: ... and of them the shared stages, keyed once per config (the design sets) or per
#: model (its compiled program), not per scenario
SHARED = [n for n in WITH_INPUTS if STAGES[n].of in ("config", "model")]


def smoke_keys() -> CacheKeys:
    config = validate(yaml.safe_load((REPO / "config" / "smoke.yaml").read_text()))
    return CacheKeys(config, "native", repo=REPO)


def _entry(stage: str):
    module = STAGES[stage].code[0].partition(":")[0]
    name = "ssmobs." + module.removesuffix(".py").replace("/", ".")
    return __import__(name, fromlist=["_"]), STAGES[stage].entry


def _rule(stage: str) -> str:
    """The text of the rule whose script is the stage's: the rule named as the stage where
    two rules share the script (check_model and check_model_stan), else the one rule."""
    script = STAGES[stage].scripts[0]
    found = []
    for smk in sorted((REPO / "workflow" / "rules").glob("*.smk")):
        for block in re.split(r"\n(?=rule \w+:)", smk.read_text()):
            if f'"../scripts/{script}.py"' in block:
                found.append(block)
    named = [b for b in found if b.startswith(f"rule {stage}:")]
    assert found, f"no rule runs scripts/{script}.py"
    assert len(found) == 1 or len(named) == 1, (stage, script)
    return named[0] if named else found[0]


def _key(keys: CacheKeys, stage: str, name: str, **at: int) -> str:
    """The key of a stage with an inputs object: :meth:`CacheKeys.stage_key`, or for the
    model check its own method, whose payload is the one hashed before its inputs object
    (with the Stan program, the driver and our headers beside the inputs)."""
    if stage in ("check_model", "check_model_stan"):
        return keys.check_model(name, stan=stage == "check_model_stan")
    return keys.stage_key(stage, name, **at)


def test_every_entry_names_code_and_scripts_that_exist():
    assert {"trajectories", "joint_map", "exact", "gather", "nuts_batches"} <= set(WITH_ENTRY)
    assert {"check_model", "check_model_stan"} <= set(WITH_ENTRY)
    assert "nuts_records" in WITH_INPUTS
    assert "k_selection_grid" in WITH_INPUTS
    for name, stage in STAGES.items():
        for entry in stage.code:
            assert (PACKAGE_DIR / entry.partition(":")[0]).is_file(), (name, entry)
        for script in stage.scripts:
            assert (REPO / "workflow" / "scripts" / f"{script}.py").is_file(), (name, script)
        for file in stage.extra_files:
            assert (PACKAGE_DIR / file).is_file(), (name, file)
        assert stage.folder is not None or not stage.outputs, name


@pytest.mark.parametrize("stage", WITH_ENTRY)
def test_the_stage_reads_its_inputs_and_nothing_else(stage):
    module, function = _entry(stage)
    assert function.startswith("run_")
    assert list(inspect.signature(getattr(module, function)).parameters) == ["inputs", "paths"]
    # the entry reads no scenario object and no config: only its inputs
    body = ast.parse(inspect.getsource(getattr(module, function)))
    names = {n.id for n in ast.walk(body) if isinstance(n, ast.Name)}
    names |= {
        n.attr for n in ast.walk(body) if isinstance(n, ast.Attribute) and _root(n) != "inputs"
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
    if STAGES[stage].folder is None:  # a keyed file, not a folder: the model check's report
        output = rule.split("output:")[1].split("log:")[0].strip()
        assert output == f'"results/{owner}/{stage}/{{key}}.json",'
    else:
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


def _root(node: ast.Attribute) -> str | None:
    """The name an attribute chain starts at (``inputs`` of ``inputs.record.scenario``)."""
    value = node.value
    while isinstance(value, ast.Attribute):
        value = value.value
    return value.id if isinstance(value, ast.Name) else None


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
    if stage in SHARED:
        _every_field_of_a_shared_stages_inputs_moves_its_output(stage, monkeypatch)
        return
    keys = smoke_keys()
    owners = keys.k_selections if STAGES[stage].of == "k_selection" else keys.scenarios
    name = next(iter(owners))
    at = {p: {"K": int(owners[name].get("K", 0)), "batch_size": 4}[p] for p in STAGES[stage].per}
    inputs = keys.inputs(stage, name, **at)
    base = _key(keys, stage, name, **at)
    assert _key(keys, stage, name, **at) == base  # the same inputs, the same key
    fields = [f.name for f in dataclasses.fields(inputs)]
    assert fields and set(inputs_payload(inputs)) == {"stage_inputs", *fields}
    for field in fields:
        value = getattr(inputs, field)
        # a model is a module of the package: another one (its code is keyed too)
        new = next(m for m in sorted(MODELS) if m != value) if field == "model" else _changed(value)
        other = dataclasses.replace(inputs, **{field: new})
        monkeypatch.setattr(keys, "inputs", lambda s, n, other=other, **at: other)
        assert _key(keys, stage, name, **at) != base, field
    monkeypatch.undo()
    assert _key(keys, stage, name, **at) == base


def _shared_output(keys: CacheKeys, stage: str, inputs, monkeypatch) -> str:
    """Where shared stage ``stage`` puts its outputs when it reads ``inputs``: the design
    sets' keyed folder, or a program's marker (named by its backend, model and key)."""
    if stage == "design":
        keys.__dict__.pop("design", None)  # a cached key
        keys.__dict__["design_inputs"] = inputs
        return DESIGN_DIR.format(key=keys.design)
    monkeypatch.setattr(keys, "program_inputs", lambda model: inputs)
    key = keys.program(inputs.model)
    return PROGRAM_MARKER.format(backend=inputs.backend, model=inputs.model, key=key)


def _every_field_of_a_shared_stages_inputs_moves_its_output(stage, monkeypatch):
    """A shared stage's key keeps the payload it held before its inputs object
    (``Stage.payload``), which leaves out the fields its outputs' path holds: any field
    changed moves the key or that path."""
    keys = smoke_keys()
    model = next(iter(keys.scenarios.values()))["model"]
    inputs = keys.design_inputs if stage == "design" else keys.program_inputs(model)
    assert hash(inputs) == hash(dataclasses.replace(inputs))  # frozen, compared by content
    base = _shared_output(keys, stage, inputs, monkeypatch)
    assert _shared_output(keys, stage, inputs, monkeypatch) == base
    fields = [f.name for f in dataclasses.fields(inputs)]
    assert fields and STAGES[stage].payload is not None
    for field in fields:
        value = getattr(inputs, field)
        new = next(m for m in sorted(MODELS) if m != value) if field == "model" else _changed(value)
        other = dataclasses.replace(inputs, **{field: new})
        assert _shared_output(keys, stage, other, monkeypatch) != base, field
    assert _shared_output(keys, stage, inputs, monkeypatch) == base


@pytest.mark.parametrize("stage", SHARED)
def test_a_shared_stages_rule_passes_what_its_key_is_made_of(stage):
    """The rule of a shared stage reads no config: its params come from the inputs object
    its key is made of (for a program, the one of the key in its marker's path)."""
    params = _rule(stage).split("params:")[1].split("script:")[0]
    read = re.findall(r"^\s+(\w+)=(.*)$", params, flags=re.M)
    assert read and not any(re.search(r"\bconfig\b", source) for _, source in read), read
    made_of = {
        "design": "KEYS.design_inputs.",
        "program": 'expect_key("program", wc.model, wc.key)["inputs"].',
    }[stage]
    assert all(made_of in source for _, source in read), read


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
        assert inputs.stan_trajectories == paths.scenarios[name].stan_trajectories
        assert inputs.convergence_config == keys.config["convergence"]
    name = paths.stan_scenarios[0]
    assert keys.gather(name, 4) != keys.gather(name, 2)
    assert len(keys.inputs("gather", name, batch_size=1).batches) == len(
        paths.scenarios[name].stan_trajectories
    )


def test_the_nuts_inputs_name_the_batches_rule_sample_nuts_writes():
    """Each batch table of a scenario's batch size with its trajectories, the records' and
    the draws' folders and the program marker, as RunPaths gives them to the other rules."""
    from ssmobs.run_paths import RunPaths

    keys = smoke_keys()
    paths = RunPaths.from_config(keys.config, keys, "native")
    for name in paths.stan_scenarios:
        sc = paths.scenarios[name]
        inputs = paths.nuts_inputs(name)
        tables = [f"{paths.batch_dir(name)}/{file}" for file, _ in inputs.tables]
        assert tables == paths.nuts_batches(name)
        ks = [tuple(r) for r in sc.stan_batches(paths.batch_size(name))]
        assert [inputs.batch_of(file) for file, _ in inputs.tables] == ks
        assert (inputs.records, inputs.draws) == (paths.records_dir(name), paths.draws_dir(name))
        assert inputs.record.program == keys.program_marker(name)
        assert keys.program_marker(name).startswith(f"results/shared/stan/native/{sc.model.slug}/")
        assert (inputs.record.joint_map is None) == (sc.stan_init != "joint_map")
    name = paths.stan_scenarios[0]
    assert keys.nuts_batches(name, 4) != keys.nuts_batches(name, 2)


def test_the_nuts_batches_read_the_records_inputs_whole():
    """What determines a NUTS record (the records' key) is what the batch job samples with:
    the batches' inputs hold the records' inputs object itself, and their records folder is
    the one keyed by it."""
    keys = smoke_keys()
    for name, sc in keys.scenarios.items():
        if not sc["stan"]:
            continue
        record = keys.inputs("nuts_records", name)
        batches = keys.inputs("nuts_batches", name, batch_size=4)
        assert batches.record == record
        assert batches.records == STAGES["nuts_records"].folder_of(name, keys.nuts_records(name))
        assert Path(batches.draws).name == keys.nuts_records(name)
        assert record.trajectories == keys.inputs("joint_map", name).trajectories
        assert record.model == sc["model"] and record.scenario == name
        assert "implementation" not in dict(batches.thresholds)
        assert batches.convergence_config["implementation"] == record.diagnostics
        payload = keys.describe()[f"nuts_records:{name}:{keys.nuts_records(name)}"]
        assert payload["model_code"] == keys.model_code(sc["model"])


def test_every_field_of_the_records_inputs_moves_the_batches_key(monkeypatch):
    """A record's inputs changed in any field give other batch tables as well as other
    records (the batches read them whole)."""
    keys = smoke_keys()
    name = next(n for n, sc in keys.scenarios.items() if sc["stan"])
    batches = keys.inputs("nuts_batches", name, batch_size=4)
    base = keys.stage_key("nuts_batches", name, batch_size=4)
    for field in dataclasses.fields(batches.record):
        value = getattr(batches.record, field.name)
        new = "other" if field.name == "model" else _changed(value)
        other = dataclasses.replace(
            batches, record=dataclasses.replace(batches.record, **{field.name: new})
        )
        monkeypatch.setattr(keys, "inputs", lambda s, n, other=other, **at: other)
        assert keys.stage_key("nuts_batches", name, batch_size=4) != base, field.name
        monkeypatch.undo()


def test_the_records_key_holds_what_the_old_field_lists_held():
    """The records' inputs hold each setting the records' key was made of before its inputs
    object, normalised the same way (Stan's default init radius left out), and nothing of
    the scenario that determines no record (its description, batch size, kept draws)."""
    keys = smoke_keys()
    name = next(n for n, sc in keys.scenarios.items() if sc["stan"])
    sc, stan = keys.scenarios[name], keys.config["stan"]
    record = keys.inputs("nuts_records", name)
    assert dict(record.sampler) == {
        f: stan[f]
        for f in ("chains", "iter_warmup", "iter_sampling", "adapt_delta", "max_treedepth")
    }
    assert (record.seed, record.stan_init, record.prior) == (
        sc["seed"],
        sc["stan_init"],
        sc["prior"],
    )
    assert record.gradients == stan.get("gradients", "autodiff")
    assert record.diagnostics == keys.config["convergence"].get("implementation", "vectorized")
    edited = copy.deepcopy(keys.config)
    entry = next(e for e in edited["scenarios"] if e["name"] == name)
    entry.update(description="another text", stan_batch_size=1)
    edited["stan"]["keep_draws"] = [0, 1]
    edited["stan"]["batch_size"] = 1
    assert CacheKeys(edited, "native", repo=REPO).nuts_records(name) == keys.nuts_records(name)
    edited["stan"]["init_radius"] = 0.5
    assert CacheKeys(edited, "native", repo=REPO).nuts_records(name) != keys.nuts_records(name)
