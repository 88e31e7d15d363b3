"""The stamped tables and figures read exactly what their stamps key (issue 62): one record
per output (RunPaths.stamped_outputs) holds the files its rule reads, the one object its
script reads beside them and the key built from those two; the rules pass the record
whole and the scripts read nothing else."""

from __future__ import annotations

import ast
import dataclasses
import functools
import pickle
import re

import pytest
import yaml
from ssmobs.cache_keys import PACKAGE_DIR, CacheKeys
from ssmobs.config.stage_inputs import outputs
from ssmobs.config.stage_inputs.outputs import OutputInputs, Pairs, freeze, thaw
from ssmobs.config.validation import validate
from ssmobs.run_paths import RunPaths
from ssmobs.stage_table import OUTPUT_SCRIPTS

pytestmark = pytest.mark.unit

REPO = PACKAGE_DIR.parents[1]
RULES = REPO / "workflow" / "rules"
SCRIPTS = REPO / "workflow" / "scripts"
#: the profiles whose outputs span every kind of stamped output
PROFILES = ["config", "smoke", "map", "stoch_vol"]

#: the script of each stamped output and the class of what it reads (its stamp's name is the
#: rule's, with the entry's or scenario's name after it where the rule has a wildcard)
SCRIPT_INPUTS = {
    "figure_design_points": outputs.FigureDesignPointsInputs,
    "figure_joint_vs_marginal": outputs.FigureJointVsMarginalInputs,
    "figure_profile_posterior": outputs.FigureProfilePosteriorInputs,
    "figure_observability": outputs.FigureObservabilityInputs,
    "figure_exact_vs_stan": outputs.FigureExactVsStanInputs,
    "paper_tables": outputs.PaperTablesInputs,
    "convergence_sensitivity": outputs.ConvergenceSensitivityInputs,
    "select_k": outputs.SelectKInputs,
    "table_k_selection": outputs.TableKSelectionInputs,
    "observability_map": outputs.ObservabilityMapInputs,
    "observability_study": outputs.ObservabilityStudyInputs,
    "joint_map_mu0_sweep": outputs.Mu0SweepInputs,
}


@functools.cache
def run_paths(profile: str) -> RunPaths:
    config = validate(yaml.safe_load((REPO / "config" / f"{profile}.yaml").read_text()))
    return RunPaths.from_config(config, CacheKeys(config, "native", repo=REPO), "native")


def _key(paths: RunPaths, name: str, files: list[str], inputs: OutputInputs) -> str:
    return paths.keys.output(f"{paths.outputs_dir}/{name}", files, inputs.keyed())


def _changed(value: object) -> object:
    """Another value of a field's kind."""
    if isinstance(value, str):
        return value + "x"
    if isinstance(value, Pairs):
        return Pairs((*value, ("changed", 1)))
    assert isinstance(value, tuple), type(value)
    return (*value, "changed")


@pytest.mark.parametrize("profile", PROFILES)
def test_each_stamp_keys_the_files_and_the_very_object_its_rule_passes(profile):
    paths = run_paths(profile)
    records = paths.stamped_outputs
    assert records, profile
    for name, record in records.items():
        assert isinstance(record.inputs, OutputInputs), name
        assert record.key == _key(paths, name, record.keyed_files, record.inputs), name
        # what the script gets: the object pickled (Snakemake's script directive)
        again = pickle.loads(pickle.dumps(record.inputs))
        assert again == record.inputs and again.keyed() == record.inputs.keyed(), name
        assert all(isinstance(f, str) for f in record.keyed_files), name


@pytest.mark.parametrize("profile", PROFILES)
def test_changing_any_field_of_what_an_output_reads_changes_its_key(profile):
    paths = run_paths(profile)
    for name, record in paths.stamped_outputs.items():
        fields = dataclasses.fields(record.inputs)
        assert fields, name
        for field in fields:
            value = getattr(record.inputs, field.name)
            changed = dataclasses.replace(record.inputs, **{field.name: _changed(value)})
            assert _key(paths, name, record.keyed_files, changed) != record.key, (
                name,
                field.name,
            )
        files = [*record.keyed_files, "results/another.json"]
        assert _key(paths, name, files, record.inputs) != record.key, name


def test_the_keys_hold_the_configs_values_as_it_gives_them():
    """The keyed content is the config's data itself: the stamps kept their keys' content
    when the objects replaced the rules' params (issue 62)."""
    paths = run_paths("smoke")
    config, records = paths.config, paths.stamped_outputs
    figure2 = records["figure_design_points"].inputs.keyed()
    assert figure2 == {"figure": config["figure2"], "model_code": paths.keys.model_code("same")}
    name = paths.figure4_scenario
    assert records[f"figure_profile_posterior_{name}"].inputs.keyed() == {
        "scenario": paths.scenario_entry(name),
        "grid": config["figure4"],
    }
    assert records["figure_joint_vs_marginal"].inputs.keyed() == [
        paths.scenario_entry(n) for n in paths.figure3_scenarios
    ]
    assert records["convergence_sensitivity"].inputs.keyed() == {
        "scenarios": [paths.scenario_entry(n) for n in paths.stan_scenarios],
        "convergence": config["convergence"],
    }
    for name, entry in paths.studies.items():
        study = records[f"observability_study_{name}"].inputs.keyed()
        assert study["study"] == entry and study["stan_settings"] == config["stan"]
    for name, entry in paths.maps.items():
        assert records[f"map_{name}"].inputs.keyed() == {"entry": entry}
    # an output reading another's files is keyed by that one's key
    assert records["figure_observability"].inputs.keyed() == records["paper_tables"].key
    assert records["table_k_selection"].inputs.keyed() == [
        records[f"select_k_{n}"].key for n in paths.k_selections
    ]
    mu0 = records["table_mu0_sweep"].inputs.keyed()
    assert mu0["scenarios"] == [paths.scenario_entry(n) for n in paths.mu0_scenarios]


def test_frozen_config_data_reads_back_as_the_config_gives_it():
    data = {"b": [1, {"x": []}, {}], "a": {}, "c": [["s", 1]], "d": 2.0}
    frozen = freeze(data)
    assert thaw(frozen) == data and list(thaw(frozen)) == ["b", "a", "c", "d"]
    assert isinstance(frozen, Pairs) and isinstance(frozen[0][1], tuple)
    assert thaw(freeze({})) == {} and thaw(freeze([])) == []
    assert pickle.loads(pickle.dumps(frozen)) == frozen
    assert isinstance(pickle.loads(pickle.dumps(frozen)), Pairs)
    with pytest.raises(dataclasses.FrozenInstanceError):
        outputs.ObservabilityMapInputs(entry=frozen).entry = Pairs()  # type: ignore[misc]


def _rules() -> dict[str, str]:
    """Rule name -> its text, of every rule file."""
    out = {}
    for smk in sorted(RULES.glob("*.smk")):
        for block in re.split(r"^rule ", smk.read_text(), flags=re.M)[1:]:
            name, _, body = block.partition(":")
            out[name.strip()] = re.split(r"^\S", body, maxsplit=1, flags=re.M)[0]
    return out


def _section(rule: str, name: str) -> str:
    match = re.search(rf"^    {name}:\n((?:        .*\n|\n)*)", rule, flags=re.M)
    return match.group(1) if match else ""


def test_every_stamped_rule_passes_its_record_whole():
    """Its input is the record's files, its params the record's object and key: one place,
    no second list that could drift from what the stamp keys."""
    rules = _rules()
    stamped = {n: r for n, r in rules.items() if "stamp=PATHS.stamp(" in r}
    assert set(stamped) == set(OUTPUT_SCRIPTS) == set(SCRIPT_INPUTS)
    for name, rule in stamped.items():
        stamp = re.search(r'stamp=PATHS\.stamp\("([^"]+)"\)', rule).group(1)
        params = re.findall(r"^\s+(\w+)=", _section(rule, "params"), flags=re.M)
        assert _section(rule, "input").split() == [f'unpack(stamped_files("{stamp}")),'], name
        assert params == ["inputs", "key"], name
        assert "inputs=stamped_inputs," in rule and "key=stamp_key," in rule, name
        assert "config[" not in rule, name
    # every record a config makes is a rule's stamp
    patterns = [re.search(r'stamp=PATHS\.stamp\("([^"]+)"\)', r).group(1) for r in stamped.values()]
    for profile in PROFILES:
        for record in run_paths(profile).stamped_outputs:
            assert any(re.fullmatch(re.sub(r"\{\w+\}", ".+", p), record) for p in patterns)


def _reads_of_inputs(tree: ast.AST) -> tuple[set[str], set[str]]:
    """The params a script reads (``snakemake.params.<name>``) and the attributes it reads
    of ``snakemake.params.inputs``, directly or through a name bound to it."""
    params: set[str] = set()
    bound: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and "snakemake.params.inputs" in ast.unparse(node.value):
            targets = node.targets[0]
            values = node.value.elts if isinstance(node.value, ast.Tuple) else [node.value]
            names = targets.elts if isinstance(targets, ast.Tuple) else [targets]
            for target, value in zip(names, values, strict=True):
                if ast.unparse(value) == "snakemake.params.inputs":
                    bound.add(ast.unparse(target))
    read: set[str] = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        owner = ast.unparse(node.value)
        if owner == "snakemake.params":
            params.add(node.attr)
        elif owner == "snakemake.params.inputs" or owner in bound:
            read.add(node.attr)
    return params, read


@pytest.mark.parametrize("script", sorted(SCRIPT_INPUTS))
def test_a_stamped_outputs_script_reads_only_its_object(script):
    tree = ast.parse((SCRIPTS / f"{script}.py").read_text())
    params, read = _reads_of_inputs(tree)
    assert params <= {"inputs", "key"}, script
    cls = SCRIPT_INPUTS[script]
    members = {f.name for f in dataclasses.fields(cls)}
    members |= {n for n in dir(cls) if isinstance(getattr(cls, n), property)}
    assert read <= members, (script, read - members)


def test_the_records_name_the_classes_of_the_scripts():
    names = {type(r.inputs) for p in PROFILES for r in run_paths(p).stamped_outputs.values()}
    assert names == set(SCRIPT_INPUTS.values())
