"""Every path of a run (ssmobs.run_paths.RunPaths): each one is a file that a rule of
``workflow/rules/`` makes, under the key of what determines it, and the targets of ``all``
are this config's outputs."""

from __future__ import annotations

import ast
import functools
import io
import re
import tokenize
from pathlib import Path

import pytest
import yaml
from ssmobs.cache_keys import PACKAGE_DIR, CacheKeys
from ssmobs.config.validation import validate
from ssmobs.run_paths import MAP_CELLS_DIR, RunPaths

pytestmark = pytest.mark.unit

REPO = PACKAGE_DIR.parents[1]
RULES = REPO / "workflow" / "rules"


@functools.cache
def run_paths(profile: str) -> RunPaths:
    config = validate(yaml.safe_load((REPO / "config" / f"{profile}.yaml").read_text()))
    return RunPaths.from_config(config, CacheKeys(config, "native", repo=REPO), "native")


def _fstring(body: str, names: dict[str, str]) -> str | None:
    """The text of an f-string's ``body`` with ``names`` filled in (None: another expression)."""
    out = []
    for piece in re.split(r"(\{\{|\}\}|\{[^{}]*\})", body):
        if piece in ("{{", "}}"):
            out.append(piece[0])
        elif piece.startswith("{"):
            if piece[1:-1] not in names:
                return None
            out.append(names[piece[1:-1]])
        else:
            out.append(piece)
    return "".join(out)


def rule_patterns(paths: RunPaths) -> set[str]:
    """Every path pattern written out in the rule files (string literals, f-strings with
    outputs_dir and the design folder filled in), with Snakemake's {wildcards}."""
    names = {
        "OUT": paths.outputs_dir,
        "PATHS.design_dir": f"results/shared/design_disturbances/{paths.keys.design}",
    }
    found = set()
    for smk in sorted(RULES.glob("*.smk")):
        for tok in tokenize.generate_tokens(io.StringIO(smk.read_text()).readline):
            if tok.type != tokenize.STRING:
                continue
            prefix = tok.string[: tok.string.index(tok.string[-1])].lower()
            if "f" in prefix:
                text = _fstring(ast.literal_eval(tok.string[1:]), names)
            else:
                text = ast.literal_eval(tok.string)
            if isinstance(text, str) and "/" in text:
                found.add(text)
    return found


def matches_a_rule(path: str, patterns: set[str]) -> bool:
    """Whether ``path`` is an instance of a pattern (or of a multiext stem: ``.ext`` more)."""
    for pattern in patterns:
        parts = re.split(r"(\{\w+\})", pattern)
        body = "".join("[^/]+" if re.fullmatch(r"\{\w+\}", p) else re.escape(p) for p in parts)
        if re.fullmatch(rf"{body}(\.\w+)?", path):
            return True
    return False


@pytest.fixture(scope="module")
def smoke() -> RunPaths:
    return run_paths("smoke")


def test_every_stage_path_is_a_rules_output_under_its_key(smoke):
    patterns = rule_patterns(smoke)
    keys = smoke.keys

    def rule_path(pattern: str, **wildcards: object) -> str:
        assert pattern in patterns, f"no rule writes {pattern}"
        return pattern.format(**wildcards)

    stan = smoke.stan_scenarios
    assert stan and smoke.joint_scenarios and smoke.exact_scenarios
    for name, sc in smoke.scenarios.items():
        for K in {sc.K, sc.exact_trajectories}:
            assert smoke.trajectories(name, K) == rule_path(
                "results/{scenario}/design_trajectories/{key}/trajectories.nc",
                scenario=name,
                key=keys.trajectories(name, K),
            )
        assert smoke.trajectories(name) == smoke.trajectories(name, sc.K)
        assert smoke.check(name) == rule_path(
            "results/{scenario}/check_model/{key}.json",
            scenario=name,
            key=keys.check_model(name),
        )
        assert smoke.disturbances(sc.disturbance_dim, sc.K, sc.method, sc.seed) == rule_path(
            f"results/shared/design_disturbances/{keys.design}/q{{q}}_K{{K}}_{{method}}_seed{{seed}}.nc",
            q=sc.disturbance_dim,
            K=sc.K,
            method=sc.method,
            seed=sc.seed,
        )
    for name in smoke.joint_scenarios:
        joint = {"scenario": name, "key": keys.joint_map(name)}
        assert smoke.joint_summary(name) == rule_path(
            "results/{scenario}/joint_map/{key}/summary.json", **joint
        )
        assert smoke.joint_table(name) == rule_path(
            "results/{scenario}/joint_map/{key}/joint_map.parquet", **joint
        )
    for name in stan:
        model = smoke.scenarios[name].model.slug
        size = smoke.batch_size(name)
        assert smoke.check(name, stan=True) == rule_path(
            "results/{scenario}/check_model_stan/{key}.json",
            scenario=name,
            key=keys.check_model(name, True),
        )
        assert keys.program_marker(name) == rule_path(
            "results/shared/stan/{backend}/{model}/{key}.json",
            backend="native",
            model=model,
            key=keys.program(model),
        )
        assert smoke.checked_program(model) == [keys.program_marker(name)]
        batches = smoke.nuts_batches(name)
        assert len(batches) == -(-len(smoke.scenarios[name].stan_trajectories) // size)
        assert batches == [
            rule_path(
                "results/{scenario}/sample_nuts/{key}/batch{batch}.parquet",
                scenario=name,
                key=keys.nuts_batches(name, size),
                batch=b,
            )
            for b in range(len(batches))
        ]
        gather = {"scenario": name, "key": keys.gather(name, size)}
        assert smoke.stan_summary(name) == rule_path(
            "results/{scenario}/gather_nuts/{key}/summary.json", **gather
        )
        assert smoke.stan_table(name) == rule_path(
            "results/{scenario}/gather_nuts/{key}/marginal_map.parquet", **gather
        )
        assert keys.nuts_records(name) in smoke.records_dir(name)
        assert smoke.draws_dir(name) == f"results/{name}/draws/{keys.nuts_records(name)}"
    for name in smoke.exact_scenarios:
        K = smoke.scenarios[name].exact_trajectories
        assert smoke.exact_summary(name) == rule_path(
            "results/{scenario}/exact_marginal/{key}/summary.json",
            scenario=name,
            key=keys.exact(name, K),
        )
        assert smoke.exact_table(name, K) == rule_path(
            "results/{scenario}/exact_marginal/{key}/marginal_map.parquet",
            scenario=name,
            key=keys.exact(name, K),
        )


def test_the_choice_of_k_and_the_maps_paths_are_their_rules_outputs(smoke):
    patterns = rule_patterns(smoke)
    assert smoke.k_selections and smoke.maps
    for name, ks in smoke.k_selections.items():
        grids = smoke.k_selection_grids(name)
        assert len(grids) == len(ks["methods"]) * len(ks["sets"]) * len(ks["seeds"])
        assert len(set(grids)) == len(grids)
        pattern = "results/k_selection/{ksel}/{key}/{method}_{sets}_seed{seed}.json"
        assert pattern in patterns
        key = smoke.keys.k_selection_grid(name)
        assert all(g.startswith(f"results/k_selection/{name}/{key}/") for g in grids)
        assert all(matches_a_rule(g, {pattern}) for g in grids)
        selection = "results/k_selection/{ksel}/selection.json"
        assert selection in patterns
        assert smoke.selection(name) == selection.format(ksel=name)
        # the points are shared by every entry of the same scenario: keyed without the entry
        points = smoke.ksel_points_dir(name, "design", "nested", 3)
        assert name not in points and smoke.keys.k_selection_points(name) in points
    for name in smoke.maps:
        cells = "results/observability_map/{map}/{key}/cells.parquet"
        assert cells in patterns
        assert smoke.map_cells_table(name) == cells.format(map=name, key=smoke.keys.map_table(name))
    assert MAP_CELLS_DIR.startswith("results/observability_map/")


@pytest.mark.parametrize("profile", ["smoke", "stoch_vol", "map"])
def test_every_target_is_made_by_a_rule(profile):
    paths = run_paths(profile)
    stamps = [paths.stamp("paper_tables"), paths.stamp("map_x")]
    targets = paths.targets(stamps)
    assert len(set(targets)) == len(targets)
    patterns = rule_patterns(paths)
    strays = [t for t in targets if t not in stamps and not matches_a_rule(t, patterns)]
    assert strays == []


def test_the_targets_are_every_stage_and_output_of_the_config(smoke):
    damaged = ["results/sc/joint_map/0123456789ab/theta_hat.nc"]
    stamps = [smoke.stamp("paper_tables")]
    targets = smoke.targets(stamps, damaged)
    assert set(stamps + damaged) <= set(targets)
    assert {smoke.trajectories(n) for n in smoke.scenarios} <= set(targets)
    assert {smoke.joint_summary(n) for n in smoke.joint_scenarios} <= set(targets)
    assert {smoke.stan_summary(n) for n in smoke.stan_scenarios} <= set(targets)
    assert {smoke.exact_summary(n) for n in smoke.exact_scenarios} <= set(targets)
    # every model check, also where what it gates is cached (issue 61: a changed prior)
    assert {smoke.check(n) for n in smoke.scenarios} <= set(targets)
    assert {smoke.check(n, stan=True) for n in smoke.stan_scenarios} <= set(targets)
    out = smoke.outputs_dir
    for name in smoke.maps:
        assert f"{out}/map_{name}.png" in targets
    for name in smoke.studies:
        assert f"{out}/ours_{name}_observability.csv" in targets
    assert smoke.paper_outputs and f"{out}/table2_joint_vs_marginal.tex" in targets


def test_a_study_of_ones_own_model_gets_no_paper_outputs():
    paths = run_paths("stoch_vol")
    assert not paths.paper_outputs
    targets = paths.targets([])
    assert not [t for t in targets if "table2" in t or "fig2_" in t or "table3" in t]
    assert all(t.startswith(("results/", f"{paths.outputs_dir}/")) for t in targets)


def test_stamps_and_outputs_follow_outputs_dir():
    paths = run_paths("smoke")
    assert (
        paths.stamp("select_k_{ksel}")
        == f"results/outputs/{paths.outputs_dir}/select_k_{{ksel}}.key"
    )
    assert Path(paths.stamp("x")).parent == Path(paths.stamps_dir)


def test_study_inputs_and_exact_comparison_name_their_scenarios_files(smoke):
    for name, study in smoke.studies.items():
        inputs = smoke.study_inputs(name)
        members = study["scenarios"]
        assert inputs["stan"] == [
            smoke.stan_summary(n) for n in members if n in smoke.stan_scenarios
        ]
        assert inputs["joint"] == [
            smoke.joint_summary(n) for n in members if n in smoke.joint_scenarios
        ]
    for name in smoke.exact_vs_stan_scenarios:
        inputs = smoke.exact_vs_stan_inputs(name)
        assert inputs["stan"] == smoke.stan_table(name)
        assert inputs["exact"] == smoke.exact_table(name, smoke.scenarios[name].K)


def test_every_key_is_computed_up_front_and_map_cells_are_returned(smoke):
    config = smoke.config
    fresh = RunPaths.from_config(config, CacheKeys(config, "native", repo=REPO), "native")
    before = set(fresh.keys.describe())
    cells = fresh.compute_every_key()
    assert set(cells) == set(fresh.maps) and all(cells.values())
    described = set(fresh.keys.describe()) - before

    def computed(kind: str, name: str, path: str) -> bool:
        return any(
            d.startswith(f"{kind}:{name}:") and d.rsplit(":", 1)[1] in path for d in described
        )

    # the paths of another object: this one computed its keys in compute_every_key only
    for name in smoke.stan_scenarios:
        assert computed("gather", name, smoke.stan_summary(name))
        assert computed("check_model_stan", name, smoke.check(name, stan=True))
    for name, sc in smoke.scenarios.items():
        assert computed("joint_map", name, smoke.joint_summary(name))
        assert computed("exact", name, smoke.exact_table(name, sc.exact_trajectories))
    for name in smoke.k_selections:
        assert computed("k_selection_grid", name, smoke.ksel_grids_dir(name))
    assert fresh.every_trajectories() == [
        fresh.trajectories(n, K)
        for n, sc in fresh.scenarios.items()
        for K in {sc.K, sc.exact_trajectories}
    ]


def test_the_stan_models_are_those_of_the_stan_scenarios_once_each():
    paths = run_paths("config")  # several scenarios of each model
    models = {paths.scenarios[n].slug for n in paths.stan_scenarios}
    assert paths.stan_models == sorted(models)
    assert len(paths.stan_models) < len(paths.stan_scenarios)


def test_a_model_without_a_stan_program_has_no_source_file(tmp_path):
    """stan/<model>.stan where it exists; no file (an empty input) where the program is
    generated from the model (issue 49: a model in one file)."""
    paths = run_paths("smoke")
    assert paths.stan_source("same") == "stan/same.stan"
    config = paths.config
    elsewhere = RunPaths.from_config(config, CacheKeys(config, "native", repo=tmp_path), "native")
    assert elsewhere.stan_source("same") == []


def test_rule_params_come_from_the_entries():
    """The choice of K's and the study's params, the model check's program and the
    trajectories' inputs, as the rules read them from RunPaths."""
    paths = run_paths("config")
    name = next(iter(paths.k_selections))
    inputs = paths.stamped_outputs[f"select_k_{name}"].inputs
    assert inputs.ksel_entry == paths.k_selections[name]
    assert inputs.scenario_entry == paths.scenario_entry(inputs.ksel_entry["scenario"])
    model = paths.stan_models[0]
    name = next(n for n in paths.stan_scenarios if paths.scenarios[n].slug == model)
    assert paths.checked_program(model) == [paths.keys.program_marker(name)]
    cmdstan = RunPaths.from_config(paths.config, paths.keys, "cmdstanpy")
    assert cmdstan.checked_program(model) == []
    sc = paths.scenarios[paths.stan_scenarios[0]]
    read = paths.design_set(sc.name, sc.K)
    assert read == paths.disturbances(sc.disturbance_dim, sc.K, sc.method, sc.seed)
    assert f"_K{sc.K}_" in read and read.startswith(paths.design_dir + "/")


@pytest.mark.parametrize("profile", ["smoke", "stoch_vol", "map"])
def test_the_outputs_that_must_carry_their_record_are_rule_outputs(profile):
    """What the Snakefile verifies before a run (issue 61): every cached output of the
    config's stages, each one a rule's output (not a log), under the config's keys."""
    paths = run_paths(profile)
    cached = paths.cached_outputs()
    assert cached == sorted(set(cached))
    patterns = rule_patterns(paths)
    assert [p for p in cached if not matches_a_rule(p, patterns) or p.endswith(".log")] == []
    for name in paths.scenarios:
        assert {paths.check(name), paths.trajectories(name)} <= set(cached)
    for name in paths.joint_scenarios:
        assert paths.joint_summary(name) in cached
    for name in paths.stan_scenarios:
        assert {paths.stan_summary(name), *paths.nuts_batches(name)} <= set(cached)
    for name in paths.k_selections:
        assert set(paths.k_selection_grids(name)) <= set(cached)


def test_run_paths_write_no_generated_program(tmp_path, monkeypatch):
    """Issue 62: RunPaths computes paths only; a generated program is written by its build
    job (nuts.stan_program.stan_program), not while a run is planned; until then it counts
    as unbuilt."""
    from ssmobs import housekeeping
    from ssmobs.nuts.stan_program import stan_program

    monkeypatch.setenv("SSMOBS_CACHE", str(tmp_path / "cache"))
    config = validate(yaml.safe_load((REPO / "config" / "smoke.yaml").read_text()))
    config["stan"]["gradients"] = "analytic"
    paths = RunPaths.from_config(config, CacheKeys(config, "native", repo=REPO), "native")
    assert paths.stan_gradients == "analytic"
    planned = paths.stan_programs
    assert planned and all(header is not None for _, header in planned.values())
    paths.compute_every_key()
    for name in paths.stan_scenarios:  # what a NUTS batch reads: the build job's marker
        assert paths.nuts_inputs(name).record.program in paths.cached_outputs()
    assert not (tmp_path / "cache").exists()  # nothing written
    assert housekeeping.unbuilt_programs(planned) == sorted(planned)
    model = sorted(planned)[0]
    assert stan_program(model, "analytic") == planned[model]  # the build job writes there
    assert all(f is not None and f.is_file() for f in planned[model])


#: what the rule files may bind at their top level: RunPaths, the keys and outputs_dir
#: (what the rules ask), and the glue of common.smk and of the table made on request from
#: committed files (stan_variants.smk); never a copy of one of RunPaths' answers
RULE_GLOBALS = {"PATHS", "KEYS", "OUT", "REPO", "STAN_BACKEND", "OUTPUTS_DIR_UNSET"}
RULE_GLOBALS |= {"STAMPED", "STAMPS", "STAMPS_ON_REQUEST", "DAMAGED_TARGETS"}
RULE_GLOBALS |= {"VARIANT_TABLE", "VARIANT_TABLE_SPEC", "VARIANT_TABLE_INPUTS"}
RULE_GLOBALS |= {"VARIANT_TABLE_STAMP"}


def test_the_rules_speak_one_vocabulary():
    """Issue 62: the rules ask PATHS for the scenarios of each stage, paths and targets;
    no rule file copies an answer of RunPaths into a global of its own."""
    files = [REPO / "Snakefile", *sorted(RULES.glob("*.smk"))]
    bound = {
        (f.name, m.group(1))
        for f in files
        for m in re.finditer(r"^([A-Za-z_][A-Za-z0-9_, ]*?)\s*=(?!=)", f.read_text(), re.M)
    }
    names = {(file, n.strip()) for file, found in bound for n in found.split(",")}
    assert {n for _, n in names if n.isupper()} <= RULE_GLOBALS
    assert not [n for _, n in names if not n.isupper() and not n.startswith("_")]
    text = "".join(f.read_text() for f in files)
    assert "PATHS.compute_every_key()" in text
    for gone in ["SCENARIOS", "STAN_SCENARIOS", "DESIGN_DIR", "MAP_CELLS", "PAPER_OUTPUTS"]:
        assert not re.search(rf"\b{gone}\b", text), gone


def test_the_scenarios_are_typed_and_each_entry_is_the_configs():
    paths = run_paths("config")
    entries = paths.config["scenarios"]
    assert list(paths.scenarios) == [e["name"] for e in entries]
    for entry in entries:
        sc = paths.scenarios[entry["name"]]
        assert (sc.slug, sc.K, sc.stan) == (entry["model"], entry["K"], entry["stan"])
        assert paths.scenario_entry(entry["name"]) is entry  # what a script's params carry
    assert paths.models == sorted({e["model"] for e in entries})


def test_the_paper_outputs_scenarios_and_tables_inputs_come_from_run_paths():
    paths = run_paths("config")
    wanted = paths.config["paper_outputs"]
    assert paths.table_ii_scenarios == list(wanted["tables_2_3"]) != []
    assert paths.figure3_scenarios == list(wanted["figure3"]) != []
    assert set(paths.table_ii_scenarios + paths.figure3_scenarios) <= set(paths.scenarios)
    tables = paths.stamped_outputs["paper_tables"]
    inputs, params = tables.input_files, tables.inputs
    assert inputs == paths.paper_tables_inputs()
    assert inputs["joint"] == [paths.joint_summary(n) for n in params.joint_names]
    assert inputs["marginal"] == [paths.stan_summary(n) for n in params.marginal_names]
    assert inputs["exact"] == [paths.exact_summary(n) for n in params.exact_names]
    assert list(params.marginal_names) == paths.stan_scenarios
    assert list(params.tables_2_3) == list(wanted["tables_2_3"])
    assert params.scenario_entries == paths.config["scenarios"]
    mu0 = paths.stamped_outputs["table_mu0_sweep"].inputs.keyed()
    assert mu0["scenarios"] == [paths.scenario_entry(n) for n in paths.mu0_scenarios] != []
    assert mu0["mu0_per_T"] == paths.config["mu0_sweep"]["mu0_per_T"]
