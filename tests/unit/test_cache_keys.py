"""Content keys of the cached outputs (ssmobs.cache_keys): what each key is keyed by."""

from __future__ import annotations

import copy
import shutil
from pathlib import Path

import pytest
import yaml
from ssmobs.cache_keys import (
    PACKAGE_DIR,
    CacheKeys,
    UnknownKeyError,
    code_digest,
    digest,
    module_closure,
)
from ssmobs.config import validate

pytestmark = pytest.mark.unit

REPO = PACKAGE_DIR.parents[1]


def smoke() -> dict:
    return validate(yaml.safe_load((REPO / "config" / "smoke.yaml").read_text()))


def keys(conf: dict, **kw) -> CacheKeys:
    return CacheKeys(conf, "native", **kw)


def test_digest_is_canonical_and_sensitive():
    assert digest({"a": 1, "b": [1, 2]}) == digest({"b": [1, 2], "a": 1})
    assert digest({"a": 1}) != digest({"a": 1.5})
    assert len(digest({})) == 12


def test_module_closure_follows_imports_and_skips_neutral_modules():
    closure = module_closure(("joint_map.py",))
    assert {"joint_map.py", "banded_linalg.py", "models/log_posterior.py"} <= set(closure)
    assert "log.py" not in closure and "config.py" not in closure
    assert "nuts_stage.py" not in closure


def test_code_digest_names_its_script_and_the_glue():
    code = code_digest("joint_map")
    assert "scripts/joint_map.py" in code and "stages.py" in code


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


def test_exact_key_knows_its_K():
    k = keys(smoke())
    key = k.exact("same_T4", 30)
    assert k.lookup("exact", "same_T4", key) == {"K": 30}
    assert k.trajectories("same_T4", 30) != k.trajectories("same_T4")
    with pytest.raises(UnknownKeyError, match="not one the current config produces"):
        k.lookup("exact", "same_T4", "0123456789ab")


@pytest.mark.parametrize(
    ("edit", "changed", "unchanged"),
    [
        ("ssmobs/models/same.py", {"trajectories", "joint_map", "nuts_records", "exact"}, set()),
        ("ssmobs/exact_marginal.py", {"exact"}, {"trajectories", "joint_map", "nuts_records"}),
        ("ssmobs/joint_map.py", {"joint_map"}, {"trajectories", "nuts_records", "exact"}),
        ("ssmobs/log.py", set(), {"trajectories", "joint_map", "nuts_records", "exact"}),
    ],
)
def test_code_edits_key_the_stages_that_run_the_code(tmp_path, edit, changed, unchanged):
    """An edit of a model's module or a stage's code moves that stage's outputs (and those
    downstream); an edit of logging moves none."""
    work = tmp_path / "workflow"
    shutil.copytree(
        REPO / "workflow", work, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info")
    )
    shutil.copytree(REPO / "stan", tmp_path / "stan")
    conf = smoke()

    def all_keys():
        k = keys(conf, repo=tmp_path, package_dir=work / "ssmobs")
        return {
            "trajectories": k.trajectories("same_T4"),
            "joint_map": k.joint_map("same_T4"),
            "nuts_records": k.nuts_records("same_T4"),
            "exact": k.exact("same_T4", 12),
        }

    module_closure.cache_clear()
    before = all_keys()
    f = work / edit
    f.write_text(f.read_text() + "\n# an edit\n")
    module_closure.cache_clear()
    after = all_keys()
    assert {s for s in before if before[s] != after[s]} == changed
    assert not {s for s in unchanged if before[s] != after[s]}


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
