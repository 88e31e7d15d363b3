"""The cluster profile and the conda environment agree with the workflow and pyproject.toml."""

from __future__ import annotations

import re

import pytest
import yaml
from repo_paths import REPO_DIR

pytestmark = pytest.mark.unit


def _rules() -> set[str]:
    text = "\n".join(p.read_text() for p in (REPO_DIR / "workflow" / "rules").glob("*.smk"))
    text += (REPO_DIR / "Snakefile").read_text()
    rules = set(re.findall(r"^rule (\w+):", text, flags=re.M))
    local = set()
    for names in re.findall(r"^localrules:\s*([\w,\s]+?)$", text, flags=re.M):
        local |= {n.strip() for n in names.split(",") if n.strip()}
    return rules - local - {"all"}


def test_every_job_rule_has_resources_and_no_stale_rule_is_named():
    profile = yaml.safe_load(
        (REPO_DIR / "config" / "profiles" / "slurm" / "config.yaml").read_text()
    )
    named = set(profile["set-resources"])
    rules = _rules()
    assert named - rules == set(), "set-resources names rules that do not exist"
    assert rules - named == set(), "rules without a runtime and memory request"


def test_conda_environment_lists_every_dependency_of_pyproject():
    import tomllib

    deps = tomllib.loads((REPO_DIR / "pyproject.toml").read_text())["project"]["dependencies"]
    env = yaml.safe_load((REPO_DIR / "envs" / "ssmobs.yaml").read_text())
    listed = [d for d in env["dependencies"] if isinstance(d, str)]
    listed += next(d["pip"] for d in env["dependencies"] if isinstance(d, dict))
    names = {re.split(r"[<>=!~ ]", d, maxsplit=1)[0].lower() for d in listed}
    wanted = {re.split(r"[<>=!~ ]", d, maxsplit=1)[0].lower() for d in deps}
    assert wanted - names == set()
