"""One merge of each settings block (issue 50): the stages compute with the merged block and
the cache keys hold the same merge, nothing more and nothing less."""

from __future__ import annotations

import copy

import pytest
import yaml
from repo_paths import REPO_DIR
from ssmobs.cache_keys import CacheKeys
from ssmobs.config.blocks import joint_map_settings, stan_settings
from ssmobs.config.scenario import Scenario
from ssmobs.config.validation import validate

pytestmark = pytest.mark.unit


def smoke() -> dict:
    return validate(yaml.safe_load((REPO_DIR / "config" / "smoke.yaml").read_text()))


def test_the_scenario_and_the_keys_merge_the_joint_map_block_alike():
    conf = smoke()
    block = conf["joint_map"]
    for entry in conf["scenarios"]:
        sc = Scenario.from_config(entry)
        for single in (False, True):
            merged = joint_map_settings(entry, block, single_start=single)
            assert sc.joint_map_config(block, single_start=single) == merged
            assert merged["start_states"] == entry["joint_map_start"]
        assert "n_starts" not in joint_map_settings(entry, block, single_start=True)
    own = next(e for e in conf["scenarios"] if e.get("joint_map_n_starts"))
    assert joint_map_settings(own, block)["n_starts"] == own["joint_map_n_starts"] > 1


def test_the_scenario_and_the_keys_merge_the_stan_block_alike():
    conf = smoke()
    entry = {**conf["scenarios"][0], "stan_settings": {"adapt_delta": 0.99}}
    merged = stan_settings(entry, conf["stan"])
    assert merged == {**conf["stan"], "adapt_delta": 0.99}
    assert Scenario.from_config(entry).stan_config(conf["stan"]) == merged
    assert stan_settings(conf["scenarios"][0], conf["stan"]) == conf["stan"]


def test_the_choice_of_k_points_are_keyed_by_what_they_compute_with():
    """Its points run the paper's one start from the scenario's start of the states: the
    block's number of starts is no part of their key, the scenario's start of the states is."""
    conf = smoke()
    ksel = conf["k_selection"][0]["name"]
    base = CacheKeys(conf, "native")
    more_starts = copy.deepcopy(conf)
    more_starts["joint_map"]["n_starts"] = 3
    other = CacheKeys(more_starts, "native")
    assert other.k_selection_points(ksel) == base.k_selection_points(ksel)
    name = conf["k_selection"][0]["scenario"]
    assert other.joint_map(name) != base.joint_map(name)  # the joint MAP runs the starts
    tighter = copy.deepcopy(conf)
    tighter["joint_map"]["grad_tol"] = conf["joint_map"]["grad_tol"] / 2
    assert CacheKeys(tighter, "native").k_selection_points(ksel) != base.k_selection_points(ksel)
