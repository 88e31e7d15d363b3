"""Content keys of the cached outputs (ssmobs.cache_keys): what each key is keyed by."""

from __future__ import annotations

import ast
import copy
import shutil
from pathlib import Path

import pytest
import yaml
from ssmobs.cache_keys import CacheKeys, UnknownKeyError
from ssmobs.code_hashing import syntax_digest
from ssmobs.config.validation import validate
from ssmobs.nuts.record_cache import program_hash
from ssmobs.stage_code import (
    MODEL_REGISTRY,
    NEUTRAL_MODULES,
    PACKAGE_DIR,
    code_digest,
    digest,
    file_digest,
    module_closure,
)
from ssmobs.stage_table import NATIVE_SHADOW_HEADERS, STAGES
from ssmobs.stan_backends.base import program_code

pytestmark = pytest.mark.unit

REPO = PACKAGE_DIR.parents[1]


def smoke(gradients: str = "autodiff") -> dict:
    """The smoke profile, validated, on NUTS path ``gradients`` (the tests below are written
    for the hand-written programs; those of the analytic path ask for it)."""
    conf = yaml.safe_load((REPO / "config" / "smoke.yaml").read_text())
    conf["stan"]["gradients"] = gradients
    return validate(conf)


def keys(conf: dict, **kw) -> CacheKeys:
    return CacheKeys(conf, "native", **kw)


def test_digest_is_canonical_and_sensitive():
    assert digest({"a": 1, "b": [1, 2]}) == digest({"b": [1, 2], "a": 1})
    assert digest({"a": 1}) != digest({"a": 1.5})
    assert len(digest({})) == 12


def test_module_closure_follows_imports_and_skips_neutral_modules():
    closure = module_closure(("joint_map/driver.py",))
    assert {"joint_map/driver.py", "banded_linalg.py", "models/log_posterior.py"} <= set(closure)
    assert "log.py" not in closure and "config/validation.py" not in closure
    assert "nuts/batch.py" not in closure


def test_code_digest_names_its_script_and_its_own_glue():
    code = code_digest("joint_map")
    assert "scripts/joint_map.py" in code and "stages/joint_map.py" in code
    assert not {"stages/outputs/paper_tables.py", "stages/stan.py", "stages/exact.py"} & set(code)


def _write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


@pytest.mark.parametrize(
    ("stage", "runs", "does_not_run"),
    [
        (
            "design",
            {"stages/design.py", "design/disturbance_sets.py", "design/disturbances.py"},
            {"design/trajectories.py"},
        ),
        (
            "trajectories",
            {"stages/design.py", "design/trajectories.py"},
            {"design/disturbances.py"},
        ),
        (
            "joint_map",
            {
                "stages/joint_map.py",
                "joint_map/driver.py",
                "joint_map/multi_start_summary.py",
                "design/trajectories.py",
            },
            {
                "stages/outputs/figures.py",
                "stages/k_selection/grid.py",
                "reports/tables.py",
                "reports/figures.py",
            },
        ),
        (
            "k_selection_points",
            {
                "stages/k_selection/grid.py",
                "design/disturbance_sets.py",
                "joint_map/driver.py",
                "joint_map/problem.py",
                "k_selection.py",
            },
            {  # one start: the multi-start's code is not the grid's
                "joint_map/multi_start.py",
                "stages/design.py",
                "stages/joint_map.py",
                "stages/k_selection/choice.py",
                "stages/outputs/mu0_sweep.py",
                "reports/tables.py",
                "reports/figures.py",
            },
        ),
        (
            "program",
            {"stages/stan.py", "nuts/stan_program.py", "stan_backends/__init__.py"},
            {
                "nuts/batch.py",
                "nuts/record_cache.py",
                "nuts/stan_metrics.py",
                "design/trajectories.py",
            },
        ),
        (
            "nuts_records",
            {"stages/stan.py", "nuts/batch.py", "nuts/record_cache.py", "design/trajectories.py"},
            {
                "nuts/stan_metrics.py",
                "stages/outputs/paper_tables.py",
                "reports/tables.py",
                "joint_map/driver.py",
            },
        ),
        (
            "gather",
            {"stages/stan.py", "nuts/record_cache.py", "nuts/stan_metrics.py"},
            {"reports/tables.py"},
        ),
        (
            "exact",
            {"stages/exact.py", "exact/marginal.py", "nuts/stan_metrics.py"},
            {"nuts/batch.py", "joint_map/driver.py", "stages/stan.py"},
        ),
        (
            "outputs",
            {
                "stages/outputs/paper_tables.py",
                "stages/outputs/figures.py",
                "stages/outputs/mu0_sweep.py",
                "stages/k_selection/choice.py",
                "reports/tables.py",
                "reports/figures.py",
                "reports/observability_study.py",
            },
            {"stages/stan.py", "stages/exact.py", "nuts/batch.py", "exact/marginal.py"},
        ),
    ],
)
def test_each_stage_closure_holds_the_code_it_runs_and_none_it_does_not(stage, runs, does_not_run):
    closure = set(module_closure(STAGES[stage].code))
    assert runs <= closure
    assert not does_not_run & closure
    assert not set(NEUTRAL_MODULES) & closure


def _script_imports(script: str) -> list[tuple[str, list[str]]]:
    """(module file relative to the package, imported names) of a rule script's imports."""
    path = REPO / "workflow" / "scripts" / f"{script}.py"
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("ssmobs"):
            parts = (node.module or "").split(".")[1:]
            if parts:
                out.append(("/".join(parts) + ".py", [a.name for a in node.names]))
            else:  # from ssmobs import io, log
                out += [(f"{a.name}.py", []) for a in node.names]
    return out


@pytest.mark.parametrize("stage", sorted(STAGES))
def test_what_a_stage_script_calls_is_in_its_stage_key(stage):
    """Every package module a stage's script imports is hashed into the stage's key, and a
    function it imports from a stage module is one the stage's entry follows."""
    closure = set(module_closure(STAGES[stage].code))
    entries = dict(e.partition(":")[::2] for e in STAGES[stage].code)
    for script in STAGES[stage].scripts:
        for module, names in _script_imports(script):
            if module in NEUTRAL_MODULES:
                continue
            assert module in closure, f"{script}.py imports {module}, not in the {stage} key"
            functions = entries.get(module)
            if functions:  # an entry of named functions
                assert set(names) <= set(functions.split(",")), (script, names, functions)


@pytest.mark.parametrize(
    ("path", "value", "changed", "unchanged"),
    [
        ("omega", {"a": 0.8}, {"trajectories", "joint_map", "nuts_records", "exact"}, set()),
        ("prior", "unrestricted", {"joint_map", "nuts_records", "exact"}, {"trajectories"}),
        ("description", "a new text", set(), {"trajectories", "joint_map", "nuts_records"}),
        ("paper_ref", "", set(), {"trajectories", "joint_map", "nuts_records", "exact"}),
    ],
)
def test_scenario_fields_key_exactly_the_stages_they_determine(path, value, changed, unchanged):
    base = smoke()
    edited = copy.deepcopy(base)
    edited["scenarios"][0][path] = value

    def all_keys(conf):
        k = keys(conf)
        return {
            "trajectories": k.trajectories("same_T4"),
            "joint_map": k.joint_map("same_T4"),
            "nuts_records": k.nuts_records("same_T4"),
            "exact": k.exact("same_T4", 12),
        }

    a, b = all_keys(base), all_keys(edited)
    assert {s for s in a if a[s] != b[s]} == changed
    assert not {s for s in unchanged if a[s] != b[s]}


def test_thresholds_key_the_tables_not_the_records():
    base = smoke()
    edited = copy.deepcopy(base)
    edited["convergence"]["rhat_max"] = 1.05
    a, b = keys(base), keys(edited)
    assert a.nuts_records("same_T4") == b.nuts_records("same_T4")
    assert a.nuts_batches("same_T4", 4) != b.nuts_batches("same_T4", 4)
    assert a.gather("same_T4", 4) != b.gather("same_T4", 4)


def test_stan_every_keys_the_batches_not_the_records():
    base = smoke()
    every2, every1 = copy.deepcopy(base), copy.deepcopy(base)
    every2["scenarios"][0]["stan_every"] = 2
    every1["scenarios"][0]["stan_every"] = 1  # the same as absent: the keys stay
    a, b, c = keys(base), keys(every2), keys(every1)
    # a subset's runs are the full set's runs: the same records
    assert a.nuts_records("same_T4") == b.nuts_records("same_T4")
    assert a.nuts_batches("same_T4", 4) != b.nuts_batches("same_T4", 4)
    assert a.gather("same_T4", 4) != b.gather("same_T4", 4)
    assert (a.trajectories("same_T4"), a.joint_map("same_T4"), a.exact("same_T4", 12)) == (
        b.trajectories("same_T4"),
        b.joint_map("same_T4"),
        b.exact("same_T4", 12),
    )
    assert a.nuts_batches("same_T4", 4) == c.nuts_batches("same_T4", 4)


def test_init_radius_keys_the_records_only_off_stans_default():
    base = smoke()
    two, one = copy.deepcopy(base), copy.deepcopy(base)
    two["stan"]["init_radius"] = 2  # Stan's default: records made before the key stay valid
    one["stan"]["init_radius"] = 1
    a, b, c = keys(base), keys(two), keys(one)
    assert a.nuts_records("same_T4") == b.nuts_records("same_T4")
    assert a.nuts_records("same_T4") != c.nuts_records("same_T4")
    assert a.joint_map("same_T4") == c.joint_map("same_T4")


def test_a_scenarios_own_stan_settings_and_seed_key_its_records():
    base = smoke()

    def with_(**changes):
        conf = copy.deepcopy(base)
        conf["scenarios"][0].update(changes)
        return keys(conf).nuts_records("same_T4")

    plain = keys(base).nuts_records("same_T4")
    block = base["stan"]
    assert with_(stan_settings={}) == plain
    assert with_(stan_settings={"iter_warmup": block["iter_warmup"]}) == plain  # the same value
    assert with_(stan_settings={"adapt_delta": 0.95}) != plain
    assert with_(stan_settings={"init_radius": 0.5}) != plain
    assert with_(stan_seed=3) != plain != with_(stan_seed=4)


def test_chains_at_the_joint_map_key_the_records_by_it():
    base = smoke()
    at_map = copy.deepcopy(base)
    at_map["scenarios"][0]["stan_init"] = "joint_map"
    edited = copy.deepcopy(at_map)
    edited["joint_map"] = {**edited.get("joint_map", {}), "grad_tol": 2e-5}
    plain, edited_plain = copy.deepcopy(base), copy.deepcopy(base)
    edited_plain["joint_map"] = {**edited_plain.get("joint_map", {}), "grad_tol": 2e-5}
    assert keys(at_map).nuts_records("same_T4") != keys(edited).nuts_records("same_T4")
    assert keys(plain).nuts_records("same_T4") == keys(edited_plain).nuts_records("same_T4")


def test_exact_settings_key_the_exact_stage_only():
    base = smoke()
    edited = copy.deepcopy(base)
    edited["exact_marginal"]["coarse_nodes"] = [200, 48, 16, 9]
    a, b = keys(base), keys(edited)
    assert a.exact("same_T4", 30) != b.exact("same_T4", 30)
    assert a.trajectories("same_T4", 30) == b.trajectories("same_T4", 30)
    assert a.joint_map("same_T4") == b.joint_map("same_T4")
    assert a.nuts_records("same_T4") == b.nuts_records("same_T4")


def test_k_grid_and_scenario_name_key_the_grids_not_their_points():
    """A changed K_grid gives new grid files (found stale before: the grid files kept the old
    K_i) while the points of the K_i both grids hold are found again; the scenario's name,
    which the grid files carry, keys them too."""
    base = smoke()
    grid, renamed = copy.deepcopy(base), copy.deepcopy(base)
    grid["k_selection"][0]["K_grid"] = [8, 16, 32]
    renamed["scenarios"][0]["name"] = "same_T4_renamed"
    renamed["k_selection"][0]["scenario"] = "same_T4_renamed"
    a, b, c = keys(base), keys(grid), keys(renamed)
    assert a.k_selection_points("same_T4") == b.k_selection_points("same_T4")
    assert a.k_selection_grid("same_T4") != b.k_selection_grid("same_T4")
    assert a.k_selection_points("same_T4") == c.k_selection_points("same_T4")
    assert a.k_selection_grid("same_T4") != c.k_selection_grid("same_T4")


def test_exact_key_knows_its_K():
    k = keys(smoke())
    key = k.exact("same_T4", 30)
    assert k.lookup("exact", "same_T4", key) == {"K": 30}
    assert k.trajectories("same_T4", 30) != k.trajectories("same_T4")
    with pytest.raises(UnknownKeyError, match="not one the current config produces"):
        k.lookup("exact", "same_T4", "0123456789ab")


#: every key of one scenario of the smoke profile (outputs: the code of the tables and figures)
ALL_STAGES = {
    "design",
    "trajectories",
    "joint_map",
    "k_selection",
    "program",
    "nuts_records",
    "nuts_batches",
    "gather",
    "exact",
    "outputs",
}
#: the stages downstream of the design trajectories
FROM_TRAJECTORIES = {"trajectories", "joint_map", "nuts_records", "nuts_batches", "gather", "exact"}


@pytest.mark.parametrize(
    ("edit", "changed"),
    [
        ("ssmobs/models/same.py", FROM_TRAJECTORIES | {"k_selection"}),
        ("ssmobs/exact/marginal.py", {"exact"}),
        ("ssmobs/joint_map/driver.py", {"joint_map", "k_selection", "outputs"}),
        ("ssmobs/log.py", set()),
        ("ssmobs/stages/design.py", {"design", "k_selection"} | FROM_TRAJECTORIES),
        # the joint-MAP stage's glue: no other stage runs it (stages import no stage)
        ("ssmobs/stages/joint_map.py", {"joint_map"}),
        ("ssmobs/joint_map/problem.py", {"joint_map", "k_selection", "outputs"}),
        ("ssmobs/design/disturbance_sets.py", {"design", "k_selection"} | FROM_TRAJECTORIES),
        ("ssmobs/stages/k_selection/grid.py", {"k_selection"}),
        ("ssmobs/stages/k_selection/choice.py", {"outputs"}),
        ("ssmobs/stages/stan.py", {"program", "nuts_records", "nuts_batches", "gather"}),
        ("ssmobs/stages/exact.py", {"exact"}),
        ("ssmobs/stages/outputs/paper_tables.py", {"outputs"}),
        ("ssmobs/stages/outputs/mu0_sweep.py", {"outputs"}),
        ("ssmobs/nuts/record_cache.py", {"nuts_records", "nuts_batches", "gather"}),
        ("ssmobs/nuts/stan_metrics.py", {"gather", "exact"}),
        ("ssmobs/reports/tables.py", {"outputs"}),
        ("scripts/sample_nuts.py", {"nuts_records", "nuts_batches", "gather"}),
        ("scripts/paper_tables.py", {"outputs"}),
    ],
)
def test_code_edits_key_the_stages_that_run_the_code(tmp_path, edit, changed):
    """An edit of a model's module or a stage's code moves that stage's outputs (and those
    downstream) and no other: an edit of a table's glue (stages/outputs/) reruns no
    sampling, an edit of the Stan glue (stages/stan.py) no joint MAP; an edit of logging
    moves none."""
    work = tmp_path / "workflow"
    shutil.copytree(
        REPO / "workflow", work, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info")
    )
    shutil.copytree(REPO / "stan", tmp_path / "stan")
    conf = smoke()

    def all_keys():
        k = keys(conf, repo=tmp_path, package_dir=work / "ssmobs")
        return {
            "design": k.design,
            "trajectories": k.trajectories("same_T4"),
            "joint_map": k.joint_map("same_T4"),
            "k_selection": k.k_selection_grid("same_T4"),
            "program": k.program("same"),
            "nuts_records": k.nuts_records("same_T4"),
            "nuts_batches": k.nuts_batches("same_T4", 4),
            "gather": k.gather("same_T4", 4),
            "exact": k.exact("same_T4", 12),
            "outputs": k.output("paper_figures/smoke/table", [], {}),
        }

    module_closure.cache_clear()
    before = all_keys()
    f = work / edit
    f.write_text(f.read_text() + "\nEDITED = 1  # an edit\n")
    module_closure.cache_clear()
    after = all_keys()
    assert set(before) == ALL_STAGES
    assert {s for s in before if before[s] != after[s]} == changed


def test_stan_program_keys_the_records_and_the_stan_check_only(tmp_path):
    shutil.copytree(REPO / "stan", tmp_path / "stan")
    conf = smoke()
    a = keys(conf, repo=tmp_path)

    def some_keys(k):
        return (
            k.trajectories("same_T4"),
            k.check_model("same_T4"),
            k.nuts_records("same_T4"),
            k.check_model("same_T4", stan=True),
        )

    before = some_keys(a)
    stan = Path(tmp_path / "stan" / "same.stan")
    stan.write_text(stan.read_text() + "\n// an edit\n")
    after = some_keys(keys(conf, repo=tmp_path))
    assert before[:2] == after[:2]  # trajectories and the Python check
    assert before[2] != after[2] and before[3] != after[3]  # NUTS records and the Stan check


def test_the_stan_version_keys_the_programs_and_what_follows():
    """Found stale before: the programs' keys held the backend's name only, so another Stan
    (a new httpstan wheel or CmdStan) left every NUTS output as it was."""
    conf = smoke()
    old, new = "native stanc3 v2.35.0 (Unix)", "native stanc3 v2.36.0 (Unix)"
    a = CacheKeys(conf, old, check_backend=old)
    b = CacheKeys(conf, new, check_backend=old)
    assert a.program("same") != b.program("same")
    assert a.nuts_records("same_T4") != b.nuts_records("same_T4")
    assert a.trajectories("same_T4") == b.trajectories("same_T4")
    assert a.joint_map("same_T4") == b.joint_map("same_T4")
    # the check evaluates with the native driver, whatever backend samples
    assert a.check_model("same_T4", stan=True) == b.check_model("same_T4", stan=True)
    c = CacheKeys(conf, old, check_backend=new)
    assert a.check_model("same_T4", stan=True) != c.check_model("same_T4", stan=True)
    assert a.check_model("same_T4") == c.check_model("same_T4")
    assert a.nuts_records("same_T4") == c.nuts_records("same_T4")


def test_the_native_driver_keys_the_stan_check_not_the_python_check(tmp_path):
    """Found stale before: the Stan check runs the driver's log-density mode, but an edit of
    the driver left the check passed."""
    work = tmp_path / "workflow"
    shutil.copytree(
        REPO / "workflow", work, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info")
    )
    conf = smoke()
    module_closure.cache_clear()
    before = keys(conf, package_dir=work / "ssmobs")
    stan_check, python_check = (
        before.check_model("same_T4", stan=True),
        before.check_model("same_T4"),
    )
    driver = work / "ssmobs" / "stan_backends" / "native_driver" / "driver.cpp"
    driver.write_text(driver.read_text() + "\n// an edit\n")
    module_closure.cache_clear()
    after = keys(conf, package_dir=work / "ssmobs")
    assert after.check_model("same_T4", stan=True) != stan_check
    assert after.check_model("same_T4") == python_check


def test_the_shadow_header_keys_the_programs_and_the_records_not_the_checks(tmp_path):
    """The header standing in for Stan's gradient.hpp is compiled into the driver and every
    native program: an edit rebuilds them (the program's key) and reruns NUTS (the records'
    key); the trajectories and the checks (the log-density mode never calls it) stay."""
    work = tmp_path / "workflow"
    shutil.copytree(
        REPO / "workflow", work, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info")
    )
    conf = smoke()
    module_closure.cache_clear()

    def some_keys() -> tuple[str, ...]:
        k = keys(conf, package_dir=work / "ssmobs")
        return (
            k.program("same"),
            k.nuts_records("same_T4"),
            k.trajectories("same_T4"),
            k.check_model("same_T4", stan=True),
        )

    assert len(NATIVE_SHADOW_HEADERS) == 2  # gradient.hpp and the slot it arms
    for header in NATIVE_SHADOW_HEADERS:
        before = some_keys()
        path = work / "ssmobs" / header
        path.write_text(path.read_text() + "\n// an edit\n")
        module_closure.cache_clear()
        after = some_keys()
        assert after[0] != before[0] and after[1] != before[1], header  # program, records
        assert after[2:] == before[2:], header  # the trajectories and the Stan check


def test_with_analytic_gradients_the_shadow_headers_key_the_stan_check(tmp_path):
    """With ``stan.gradients: analytic`` the check also compares the sampler's gradient
    (``--sampler-gradient``, through our gradient.hpp and its slot): an edit of either
    header reruns it."""
    work = tmp_path / "workflow"
    shutil.copytree(
        REPO / "workflow", work, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info")
    )
    conf = smoke()
    conf["stan"] = {**conf["stan"], "gradients": "analytic"}
    module_closure.cache_clear()
    for header in NATIVE_SHADOW_HEADERS:
        before = keys(conf, package_dir=work / "ssmobs").check_model("same_T4", stan=True)
        path = work / "ssmobs" / header
        path.write_text(path.read_text() + "\n// an edit\n")
        module_closure.cache_clear()
        after = keys(conf, package_dir=work / "ssmobs").check_model("same_T4", stan=True)
        assert after != before, header


def test_the_stage_code_names_every_shadow_header_the_builds_use():
    from ssmobs.stan_backends import native_build

    used = {
        (native_build.SHADOW_INCLUDE_DIR / rel).relative_to(PACKAGE_DIR).as_posix()
        for rel in native_build.shadow_headers()
    }
    assert used == set(NATIVE_SHADOW_HEADERS)


@pytest.mark.parametrize("key", ["build_key", "driver_key"])
def test_native_build_keys_follow_the_shadow_headers_bytes(tmp_path, monkeypatch, key):
    """Cached programs and driver objects built with another shadow header (or none) are
    not found under the current key."""
    from ssmobs.stan_backends import native_build

    def current() -> dict[str, str]:
        return native_build.build_key("x") if key == "build_key" else native_build.driver_key()

    ours = current()
    copy_dir = tmp_path / "include"
    shutil.copytree(native_build.SHADOW_INCLUDE_DIR, copy_dir)
    monkeypatch.setattr(native_build, "SHADOW_INCLUDE_DIR", copy_dir)
    assert current() == ours  # the same bytes elsewhere: the same key
    for header in (
        copy_dir / "stan" / "model" / "gradient.hpp",
        copy_dir / "ssmobs" / "gradient_slot.hpp",
    ):
        original = header.read_bytes()
        header.write_bytes(original + b" ")
        edited = current()
        assert edited != ours and edited["shadow_headers"] != ours["shadow_headers"], header
        header.write_bytes(original)
        assert current() == ours
    for header in copy_dir.rglob("*.hpp"):
        header.unlink()
    without = current()
    assert "shadow_headers" not in without  # the keys entries built before it had
    assert {k: v for k, v in ours.items() if k != "shadow_headers"} == without


def test_the_stan_identity_names_the_backend_and_its_stan():
    from ssmobs.cache_keys import stan_identity

    native = stan_identity("native")
    assert native.startswith("native ") and "stanc" in native


#: a model that imports a helper module (skipped by model discovery) and subclasses Same
HELPER_MODELS = {
    "models/_mix.py": "SCALE = 1.0\n",
    "models/same_mix.py": (
        "from ._mix import SCALE\nfrom .same import Same\n\n\n"
        "class SameMix(Same):\n    slug = 'same_mix'\n    scale = SCALE\n"
    ),
}


def _workflow_copy(tmp_path: Path) -> Path:
    work = tmp_path / "workflow"
    shutil.copytree(
        REPO / "workflow", work, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info")
    )
    return work / "ssmobs"


@pytest.mark.parametrize(
    ("edit", "moves"),
    [("models/_mix.py", True), ("models/same.py", True), ("models/sep.py", False)],
)
def test_what_a_model_imports_keys_its_outputs(tmp_path, edit, moves):
    """Found stale before: a model keyed by its own module only kept its outputs when a
    helper it imports or the model it subclasses was edited."""
    package = _write(_workflow_copy(tmp_path), HELPER_MODELS)
    shutil.copytree(REPO / "stan", tmp_path / "stan")
    shutil.copy(tmp_path / "stan" / "same.stan", tmp_path / "stan" / "same_mix.stan")
    conf = smoke()
    next(sc for sc in conf["scenarios"] if sc["name"] == "same_T4")["model"] = "same_mix"

    def model_keys():
        module_closure.cache_clear()
        k = keys(conf, repo=tmp_path, package_dir=package)
        return k.model_code("same_mix"), k.trajectories("same_T4"), k.nuts_records("same_T4")

    before = model_keys()
    assert set(before[0]) == {"models/same_mix.py", "models/_mix.py", "models/same.py"}
    (package / edit).write_text((package / edit).read_text() + "\nEDITED = 1\n")
    after = model_keys()
    assert (before != after) == moves
    assert (before[1] != after[1]) == moves and (before[2] != after[2]) == moves


#: a model that imports a module of the project tree (``workflow/<name>.py``), which
#: imports one in a user's folder on PYTHONPATH, which imports a package module
OUTSIDE_MODELS = {
    "models/same5.py": (
        "import myhelper_k46\nfrom .same import Same\n\n\n"
        "class Same5(Same):\n    slug = 'same5'\n    scale = myhelper_k46.SCALE\n"
    ),
}


@pytest.mark.parametrize("edit", ["tree", "user", "package", "none"])
def test_modules_a_model_imports_from_outside_the_package_key_its_outputs(
    tmp_path, monkeypatch, edit
):
    """Found stale before (issue 46): a model importing ``myhelper`` from ``workflow/``
    kept its numbers when ``SCALE`` in the helper was edited.  Every module outside the
    package and the pinned environment that a model runs, directly or not, keys it."""
    package = _write(_workflow_copy(tmp_path), OUTSIDE_MODELS)
    tree_helper = package.parent / "myhelper_k46.py"
    user_helper = tmp_path / "userlib" / "userhelper_k46" / "__init__.py"
    _write(
        package.parent, {"myhelper_k46.py": "import numpy\nimport userhelper_k46\n\nSCALE = 1.0\n"}
    )
    _write(
        tmp_path / "userlib",
        {"userhelper_k46/__init__.py": "from ssmobs import banded_linalg\nOFFSET = 0\n"},
    )
    monkeypatch.syspath_prepend(str(package.parent))
    monkeypatch.syspath_prepend(str(tmp_path / "userlib"))
    shutil.copytree(REPO / "stan", tmp_path / "stan")
    conf = smoke()
    next(sc for sc in conf["scenarios"] if sc["name"] == "same_T4")["model"] = "same5"

    def model_keys():
        module_closure.cache_clear()
        k = keys(conf, repo=tmp_path, package_dir=package)
        return k.model_code("same5"), k.trajectories("same_T4"), k.joint_map("same_T4")

    before = model_keys()
    assert {"import:myhelper_k46", "import:userhelper_k46", "banded_linalg.py"} <= set(before[0])
    assert not any("numpy" in f for f in before[0])  # the pinned environment is not keyed
    edited = {
        "tree": (tree_helper, "SCALE = 1.0", "SCALE = 1.5"),
        "user": (user_helper, "OFFSET = 0", "OFFSET = 1"),
        "package": (package / "banded_linalg.py", "", "\nEDITED = 1\n"),
        "none": (tree_helper, "SCALE = 1.0", "SCALE = 1.0  # a comment"),
    }[edit]
    path, old, new = edited
    path.write_text(path.read_text().replace(old, new) if old else path.read_text() + new)
    after = model_keys()
    moves = edit != "none"
    assert (before[1] != after[1]) == moves and (before[2] != after[2]) == moves


def test_a_model_without_package_imports_is_keyed_by_its_module_alone():
    """The registry's code (models/base.py, ...) keys every stage that takes a model."""
    assert CacheKeys(smoke(), "native").model_code("same") == {
        "models/same.py": syntax_digest(PACKAGE_DIR / "models" / "same.py")
    }
    registry = set(module_closure((MODEL_REGISTRY,)))
    assert "models/base.py" in registry
    for stage in ("trajectories", "check_model", "nuts_records", "k_selection_points", "map_cells"):
        assert registry <= set(module_closure(STAGES[stage].code)), stage
    assert registry <= set(module_closure(STAGES["outputs"].code))  # Figure 2's model


def test_a_stan_programs_includes_key_it(tmp_path):
    """Found stale before: a program keyed by its own file kept its records when a file it
    ``#include``s was edited; every backend compiles the included text."""
    data, body = (REPO / "stan" / "same.stan").read_text().split("parameters {", 1)
    stan = _write(
        tmp_path / "stan",
        {
            "same.stan": "// Same, from its parts\n#include <_same_body.stan>\n",
            "_same_body.stan": '#include "_same_data.stan"\n' + body,
            "_same_data.stan": data + "parameters {",
        },
    )
    code = program_code(stan / "same.stan")
    assert "#include" not in code and "z ~ normal(a * x, s);" in code
    assert code.replace("\n", "") == "// Same, from its parts" + (
        data + "parameters {" + body
    ).replace("\n", "")

    def stan_keys():
        k = keys(smoke(), repo=tmp_path)
        return k.program("same"), k.nuts_records("same_T4"), program_hash(stan / "same.stan")

    before = stan_keys()
    (stan / "_same_data.stan").write_text((stan / "_same_data.stan").read_text() + "\n")
    after = stan_keys()
    assert all(b != a for b, a in zip(before, after))
    (stan / "_same_data.stan").write_text("#include same.stan\n")
    with pytest.raises(ValueError, match="includes itself"):
        program_code(stan / "same.stan")
    (stan / "_same_data.stan").unlink()
    with pytest.raises(FileNotFoundError, match="_same_data.stan"):
        program_code(stan / "same.stan")


def test_a_program_without_includes_keeps_its_key():
    for path in sorted((REPO / "stan").glob("*.stan")):
        assert program_code(path) == path.read_text()
        # the key programs had before includes were expanded: their file's bytes
        assert CacheKeys(smoke(), "native").stan_program(path.stem) == file_digest(path)


def test_a_model_is_keyed_by_what_it_computes_not_its_comments(tmp_path):
    """Found before (issue 35): a comment-only edit of a model reran all of its stages."""
    package = _workflow_copy(tmp_path)
    same = package / "models" / "same.py"
    conf = smoke()

    def model_keys():
        k = keys(conf, package_dir=package)
        return k.model_code("same"), k.trajectories("same_T4"), k.nuts_records("same_T4")

    before = model_keys()
    text = same.read_text()
    docstring = '"""Model (Same, d=p=1)'
    assert docstring in text
    same.write_text(
        "# a comment\n" + text.replace(docstring, '"""An edited docstring. ' + docstring[3:])
    )
    assert model_keys() == before
    same.write_text(text.replace("\n\n\n", "\n\n\n\n") + "\n# a comment at the end\n")
    assert model_keys() == before
    same.write_text(text + "\nEDITED = 1\n")
    assert all(b != a for b, a in zip(before, model_keys()))


def test_analytic_gradients_key_every_nuts_output_and_autodiff_keys_nothing():
    base = smoke()  # validated, stan.gradients autodiff: the schema's default
    analytic, absent = copy.deepcopy(base), copy.deepcopy(base)
    analytic["stan"]["gradients"] = "analytic"
    del absent["stan"]["gradients"]  # a config made before the key: the same keys
    a, b, c = keys(base), keys(analytic), keys(absent)
    assert a.program("same") != b.program("same")
    assert a.nuts_records("same_T4") != b.nuts_records("same_T4")
    assert a.gather("same_T4", 4) != b.gather("same_T4", 4)
    assert a.check_model("same_T4", stan=True) != b.check_model("same_T4", stan=True)
    assert a.check_model("same_T4") == b.check_model("same_T4")
    assert a.trajectories("same_T4") == b.trajectories("same_T4")
    assert a.joint_map("same_T4") == b.joint_map("same_T4")
    assert (a.program("same"), a.gather("same_T4", 4)) == (
        c.program("same"),
        c.gather("same_T4", 4),
    )
    assert a.check_model("same_T4", stan=True) == c.check_model("same_T4", stan=True)


# ---------------------------------------------------------------- the model check (issue 61)
#: an edit of each input the model check reads (stan.gradients: against Stan only)
CHECK_INPUT_EDITS = [
    ("model", "sep_ranwalk"),
    ("omega", {"a": 0.8}),
    ("x0", 7),
    ("prior", {"a": [0, 1.5]}),  # an interval prior is checked as configured
]
#: fields the model check does not read: the key stays
CHECK_UNREAD_EDITS = [
    ("T", 5),
    ("K", 16),
    ("seed", 3),
    ("method", "random"),
    ("description", "a new text"),
    ("prior", "unrestricted"),  # every named variant is checked whichever the scenario picks
]


@pytest.mark.parametrize("stan", [False, True])
@pytest.mark.parametrize(("field", "value"), CHECK_INPUT_EDITS)
def test_each_input_of_the_model_check_keys_it(stan, field, value):
    """Found stale before (issue 61): the check's key had no prior, so a finished run then
    ``prior: {a: [0, 1.5]}`` reran no check while a fresh clone refused the config."""
    base = smoke()
    edited = copy.deepcopy(base)
    edited["scenarios"][0][field] = value
    a, b = keys(base), keys(edited)
    stage = "check_model_stan" if stan else "check_model"
    assert a.inputs(stage, "same_T4") != b.inputs(stage, "same_T4")
    assert a.check_model("same_T4", stan) != b.check_model("same_T4", stan)


@pytest.mark.parametrize("stan", [False, True])
@pytest.mark.parametrize(("field", "value"), CHECK_UNREAD_EDITS)
def test_a_field_the_model_check_does_not_read_leaves_its_key(stan, field, value):
    base = smoke()
    edited = copy.deepcopy(base)
    edited["scenarios"][0][field] = value
    assert keys(base).check_model("same_T4", stan) == keys(edited).check_model("same_T4", stan)


def test_the_gradient_path_keys_the_stan_check_only():
    analytic = smoke("analytic")
    a, b = keys(smoke()), keys(analytic)
    assert b.inputs("check_model_stan", "same_T4").gradients == "analytic"
    assert b.inputs("check_model", "same_T4").gradients == "autodiff"
    assert a.check_model("same_T4", stan=True) != b.check_model("same_T4", stan=True)
    assert a.check_model("same_T4") == b.check_model("same_T4")


@pytest.mark.parametrize(
    "prior", [None, "restricted", "unrestricted", {"a": [0, 1.5]}, {"a": "half_line"}]
)
def test_the_model_check_reads_the_same_cases_from_its_inputs_as_from_the_scenario(prior):
    """The rule passes the check's inputs object only: the cases the check builds from it
    are those it would build from the whole scenario entry, so what is keyed is what is
    read."""
    from ssmobs.models import get_model
    from ssmobs.models.check_cases import cases_from_scenarios, prior_variant_cases

    conf = smoke()
    sc = conf["scenarios"][0]
    if prior is None:
        sc.pop("prior", None)
    else:
        sc["prior"] = prior
    model = get_model("same")

    def cases(entries):
        found = cases_from_scenarios(entries, "same")
        return [c for case in found for c in prior_variant_cases(model, case)]

    inputs = keys(conf).inputs("check_model", "same_T4")
    assert inputs.model == "same" and cases([inputs.case_config]) == cases([sc])


@pytest.mark.parametrize(
    ("prior", "x0"),
    [
        (None, 8),
        ("restricted", [8.0]),
        ({"a": [0, 1.5]}, 8),
        ({"a": "half_line"}, 8.5),
        ({"a": [0.1, 0.95], "b": "half_line"}, 8),
    ],
)
def test_the_model_check_key_hashes_the_case_as_the_scenario_gives_it(prior, x0):
    """The check's inputs object is frozen, and its payload is the dict the check's key held
    before it (issue 62): the scenario's model, omega, x0 and interval prior as the config
    gives them, so no key moved for the change of what the rule passes."""
    from ssmobs.config.stage_inputs import ModelCheckInputs, check_case

    conf = smoke()
    sc = conf["scenarios"][0]
    sc.pop("prior", None)
    if prior is not None:
        sc["prior"] = prior
    sc["x0"] = x0
    k = keys(conf)
    for stan in (False, True):
        stage = "check_model_stan" if stan else "check_model"
        inputs = k.inputs(stage, "same_T4")
        assert isinstance(inputs, ModelCheckInputs) and inputs.against_stan is stan
        assert hash(inputs) == hash(k.inputs(stage, "same_T4"))  # frozen: hashable
        assert inputs.case_config == check_case(sc)
        interval = isinstance(prior, dict) and not all(isinstance(v, str) for v in prior.values())
        assert ("prior" in inputs.case_config) is interval
        key = k.check_model("same_T4", stan)
        payload = k.describe()[f"{stage}:same_T4:{key}"]
        assert payload["case"] == check_case(sc)
        assert ("stan" in payload) is stan


def test_a_generated_programs_keys_do_not_follow_the_gradient_switch(tmp_path, monkeypatch):
    """Issue 60: a model without ``stan/<model>.stan`` runs the same generated program
    whatever ``stan.gradients`` says, so switching it reruns none of its Stan jobs; a model
    with its own program has another program under ``analytic``."""
    import ssmobs.nuts.stan_program as program_choice
    from ssmobs.nuts.stan_program import stan_program

    made = []

    class Program:
        stan_file, header = Path("generated.stan"), Path("generated.hpp")

    def write(model, path):
        made.append((model.slug, path))
        return Program

    monkeypatch.setattr(program_choice, "write_analytic_program", write)
    monkeypatch.setattr(program_choice, "has_stan_file", lambda slug: False)
    assert stan_program("same", "autodiff") == stan_program("same", "analytic")
    assert made == [("same", None), ("same", None)]  # the one generated program, both ways

    (tmp_path / "stan").mkdir()  # no stan/same.stan: its program is generated
    a, b = keys(smoke(), repo=tmp_path), keys(smoke("analytic"), repo=tmp_path)
    assert a.program("same") == b.program("same")
    assert a.nuts_records("same_T4") == b.nuts_records("same_T4")
    assert a.check_model("same_T4", stan=True) == b.check_model("same_T4", stan=True)
    own = keys(smoke()), keys(smoke("analytic"))  # stan/same.stan of the repository
    assert own[0].nuts_records("same_T4") != own[1].nuts_records("same_T4")


# ---------------------------------------------------------------- dynamic imports (issue 61)
#: a one-file model (no stan/<model>.stan) whose helper, outside the package, is imported by
#: each form a model may use: the helper's edit must move its keys
DYNAMIC_IMPORTS = {
    "import_module": "import importlib\nhelper = importlib.import_module('dynhelper_k61')\n",
    "from_importlib": (
        "from importlib import import_module\nhelper = import_module('dynhelper_k61')\n"
    ),
    "__import__": "helper = __import__('dynhelper_k61')\n",
    "inside_a_function": (
        "def helper_scale():\n    import dynhelper_k61\n    return dynhelper_k61.SCALE\n"
    ),
    "__import__fromlist": "pkg = __import__('dynpkg_k61', fromlist=['dynhelper_k61'])\n",
}


def _dynamic_model(header: str) -> dict[str, str]:
    return {
        "models/dyn61.py": header
        + "from .same import Same\n\n\nclass Dyn61(Same):\n    slug = 'dyn61'\n"
    }


@pytest.mark.parametrize("form", sorted(DYNAMIC_IMPORTS))
def test_a_helper_imported_by_any_form_keys_the_model(tmp_path, monkeypatch, form):
    """Found stale before (issue 61): a model loading its helper with
    ``importlib.import_module("myhelper")`` kept its numbers after the helper was edited."""
    package = _write(_workflow_copy(tmp_path), _dynamic_model(DYNAMIC_IMPORTS[form]))
    user = tmp_path / "userlib"
    helper = "dynpkg_k61/dynhelper_k61.py" if "fromlist" in form else "dynhelper_k61.py"
    _write(user, {helper: "SCALE = 1.0\n", "dynpkg_k61/__init__.py": ""})
    monkeypatch.syspath_prepend(str(user))
    (tmp_path / "stan").mkdir()  # a one-file model: its program is generated
    conf = smoke()
    next(sc for sc in conf["scenarios"] if sc["name"] == "same_T4")["model"] = "dyn61"

    def model_keys():
        module_closure.cache_clear()
        k = keys(conf, repo=tmp_path, package_dir=package)
        return k.model_code("dyn61"), k.trajectories("same_T4"), k.nuts_records("same_T4")

    before = model_keys()
    name = "dynpkg_k61.dynhelper_k61" if "fromlist" in form else "dynhelper_k61"
    assert f"import:{name}" in before[0]
    (user / helper).write_text("SCALE = 1.5\n")
    after = model_keys()
    assert before[1] != after[1] and before[2] != after[2]


def test_a_package_helper_imported_relative_to_the_model_keys_it(tmp_path):
    package = _write(
        _workflow_copy(tmp_path),
        {
            **_dynamic_model(
                "import importlib\nmix = importlib.import_module('._mix', __package__)\n"
            ),
            "models/_mix.py": "SCALE = 1.0\n",
        },
    )
    conf = smoke()
    next(sc for sc in conf["scenarios"] if sc["name"] == "same_T4")["model"] = "dyn61"
    module_closure.cache_clear()
    assert "models/_mix.py" in keys(conf, repo=tmp_path, package_dir=package).model_code("dyn61")


@pytest.mark.parametrize(
    "header",
    [
        "import importlib\nNAME = 'dynhelper_k61'\nhelper = importlib.import_module(NAME)\n",
        "import os\nhelper = __import__(os.environ.get('HELPER', 'dynhelper_k61'))\n",
        "import runpy\nhelper = runpy.run_path('dynhelper_k61.py')\n",
    ],
)
def test_an_import_that_cannot_be_followed_is_refused_naming_the_module_and_line(tmp_path, header):
    from ssmobs.code_hashing import DynamicImportError

    package = _write(_workflow_copy(tmp_path), _dynamic_model(header))
    conf = smoke()
    next(sc for sc in conf["scenarios"] if sc["name"] == "same_T4")["model"] = "dyn61"
    module_closure.cache_clear()
    line = header.count("\n")  # the call is on the header's last line
    with pytest.raises(DynamicImportError) as err:
        keys(conf, repo=tmp_path, package_dir=package).model_code("dyn61")
    message = str(err.value)
    assert "ssmobs.models.dyn61" in message and f"line {line})" in message
    assert "\n" not in message
