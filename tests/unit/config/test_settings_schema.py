"""Settings defined once: every key of a config block that has a settings dataclass is a
field of it with the same default, type and allowed values, and every field is a key of its
block or named as fixed in the dataclass's docstring (workflow/schemas/config.schema.yaml
against JointMapSettings, SamplerSettings, ConvergenceSettings and ExactSettings)."""

from __future__ import annotations

import dataclasses
import re
from typing import Any

import pytest
from factories import same_a09
from ssmobs.config import validation as cfg
from ssmobs.config.stage_inputs import SAMPLER_FIELDS
from ssmobs.exact.settings import ExactSettings
from ssmobs.joint_map.settings import JointMapSettings
from ssmobs.nuts.convergence import ConvergenceSettings
from ssmobs.stages.stan import sampler_settings
from ssmobs.stan_backends.base import SamplerSettings

pytestmark = pytest.mark.unit

SCHEMA = cfg.load_schema()["properties"]
#: config block -> (its dataclass, the block's keys that are not settings of it: what they
#: are for instead)
BLOCKS: dict[str, tuple[type, dict[str, str]]] = {
    "joint_map": (JointMapSettings, {}),
    "stan": (
        SamplerSettings,
        {
            "backend": "which backend samples (stan_backends.resolve_backend)",
            "gradients": "which program samples (nuts.stan_program.stan_program)",
            "batch_size": "trajectories per Snakemake job (groups the records)",
            "keep_draws": "which draws are written (groups the records)",
        },
    ),
    "convergence": (ConvergenceSettings, {}),
    "exact_marginal": (ExactSettings, {}),
}
#: JSON schema type -> the annotation of the dataclass field
TYPES = {"integer": "int", "number": "float", "string": "str", "boolean": "bool", "array": "tuple"}


def _fields(cls: type) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls)}


def _settings(block: str, values: dict[str, Any]) -> Any:
    cls = BLOCKS[block][0]
    if cls in (JointMapSettings, ExactSettings):
        return cls.from_mapping(values)
    return cls(**values)


def _keys(block: str) -> dict[str, dict]:
    """The block's schema keys that are settings of its dataclass."""
    own = BLOCKS[block][1]
    return {k: v for k, v in SCHEMA[block]["properties"].items() if k not in own}


@pytest.mark.parametrize("block", sorted(BLOCKS))
def test_every_schema_key_is_a_field_with_the_same_default_and_type(block):
    cls, own = BLOCKS[block]
    fields = _fields(cls)
    assert set(own) <= set(SCHEMA[block]["properties"]), "a workflow key left the schema"
    for key, spec in _keys(block).items():
        assert key in fields, f"{block}.{key} is in the schema but not a field of {cls.__name__}"
        field = fields[key]
        default = tuple(spec["default"]) if spec["type"] == "array" else spec["default"]
        assert default == field.default, (
            f"{block}.{key}: schema default {spec['default']!r}, "
            f"{cls.__name__}.{key} default {field.default!r}"
        )
        assert TYPES[spec["type"]] == field.type, f"{block}.{key}: {spec['type']} vs {field.type}"


def _fixed_in_docstring(cls: type) -> set[str]:
    """The fields the docstring of ``cls`` names after "Fixed fields"."""
    _, marker, fixed = (cls.__doc__ or "").partition("Fixed fields")
    return set(re.findall(r"``(\w+)``", fixed)) & set(_fields(cls)) if marker else set()


@pytest.mark.parametrize("block", sorted(BLOCKS))
def test_every_field_is_a_schema_key_or_named_fixed_in_the_docstring(block):
    """The other way round: a field the config cannot set is named in the docstring's
    "Fixed fields" (with why), and a field named there is not in the schema."""
    cls = BLOCKS[block][0]
    not_in_schema = set(_fields(cls)) - set(_keys(block))
    assert not_in_schema == _fixed_in_docstring(cls), (
        f"{cls.__name__}: fields the config cannot set {sorted(not_in_schema)}, "
        f"named fixed in its docstring {sorted(_fixed_in_docstring(cls))}"
    )


@pytest.mark.parametrize("block", sorted(BLOCKS))
def test_every_allowed_value_of_the_schema_is_one_the_dataclass_accepts(block):
    for key, spec in _keys(block).items():
        for value in spec.get("enum", []):
            assert getattr(_settings(block, {key: value}), key) == value
        if "enum" in spec:
            with pytest.raises(ValueError, match=key):
                _settings(block, {key: "not-a-choice"})


def test_the_joint_map_settings_refuse_what_the_schema_refuses():
    """JointMapSettings checks its values itself (it is also built outside the workflow):
    a value just outside a schema bound is refused there too."""
    for key, spec in _keys("joint_map").items():
        if "exclusiveMinimum" in spec:
            outside = spec["exclusiveMinimum"]
        elif "minimum" in spec:
            outside = spec["minimum"] - 1
        else:
            continue
        with pytest.raises(ValueError, match=key):
            JointMapSettings.from_mapping({key: outside})


def test_the_default_config_gives_the_default_settings():
    conf = cfg.validate({"scenarios": [same_a09(K=3)]})
    assert JointMapSettings.from_mapping(conf["joint_map"]) == JointMapSettings()
    assert ConvergenceSettings(**conf["convergence"]) == ConvergenceSettings()
    assert sampler_settings(conf["stan"]) == SamplerSettings()
    assert ExactSettings.from_mapping(conf["exact_marginal"]) == ExactSettings()


def test_the_exact_settings_from_a_config_block_are_the_values_written():
    scenario = same_a09(K=3)
    conf = cfg.validate(
        {
            "scenarios": [scenario],
            "exact_marginal": {"coarse_nodes": [100, 20, 10, 5], "box_sd": 5.0},
        }
    )
    settings = ExactSettings.from_mapping(conf["exact_marginal"])
    assert settings.coarse(1) == 100 and settings.coarse(4) == 5
    assert settings.box_sd == 5.0 and settings.face_drop == ExactSettings().face_drop
    short = {"scenarios": [scenario], "exact_marginal": {"coarse_nodes": [9, 9, 9]}}
    with pytest.raises(cfg.ConfigError, match="coarse_nodes"):
        cfg.validate(short)
    upside_down = {"scenarios": [scenario], "exact_marginal": {"half_line_range": [10.0, 0.1]}}
    with pytest.raises(cfg.ConfigError, match=r"half_line_range = \[10.0, 0.1\]: the lower"):
        cfg.validate(upside_down)


def test_the_scenario_start_of_the_joint_map_is_the_settings_start():
    """``start_states`` is set per scenario (``joint_map_start``, Sec. III.B), not in the
    joint_map block: same default and the same choices."""
    spec = SCHEMA["scenarios"]["items"]["properties"]["joint_map_start"]
    assert "start_states" not in SCHEMA["joint_map"]["properties"]
    assert spec["default"] == JointMapSettings().start_states
    for value in spec["enum"]:
        assert JointMapSettings(start_states=value).start_states == value


def test_the_records_are_keyed_by_every_sampler_setting_but_the_workers():
    """Cache keys (ssmobs.cache_keys) and record keys leave out only ``workers``, which
    schedules chains and changes no draw."""
    assert set(SAMPLER_FIELDS) == set(_fields(SamplerSettings)) - {"workers"}
    assert set(SAMPLER_FIELDS) <= set(SCHEMA["stan"]["properties"])


def test_the_schema_reads_the_same_with_and_without_libyaml():
    """load_schema parses with libyaml where PyYAML has it; its tree is the pure-Python
    parser's."""
    import yaml
    from ssmobs.config.schema import SCHEMA_PATH, load_schema

    assert load_schema() == yaml.safe_load(SCHEMA_PATH.read_text())
