"""Config validation: the JSON schema (with defaults) plus the checks a schema cannot express.

:func:`validate` is called by the Snakefile before the DAG is built, so a bad config
stops the run with one message naming the key, the value and what is allowed, before any
expensive work and before anything is written to ``results/``.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from .models import MODELS

SCHEMA_PATH = Path(__file__).resolve().parents[1] / "schemas" / "config.schema.yaml"


class ConfigError(ValueError):
    """The configuration is invalid; the message lists every problem found."""


def load_schema() -> dict:
    return yaml.safe_load(SCHEMA_PATH.read_text())


def _with_defaults(validator_class):
    validate_props = validator_class.VALIDATORS["properties"]

    def set_defaults(validator, properties, instance, schema):
        if isinstance(instance, dict):
            for key, sub in properties.items():
                if "default" in sub and key not in instance:
                    instance[key] = copy.deepcopy(sub["default"])
        yield from validate_props(validator, properties, instance, schema)

    return jsonschema.validators.extend(validator_class, {"properties": set_defaults})


def _path(error: jsonschema.ValidationError) -> str:
    out = ""
    for part in error.absolute_path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _describe(error: jsonschema.ValidationError) -> str:
    key = _path(error)
    value = error.instance
    v = error.validator
    if v == "required":
        return f"{key}: {error.message}"
    if v == "additionalProperties":
        return f"{key}: {error.message} (see config/README.md for the allowed keys)"
    if v in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum"):
        op = {"minimum": ">=", "exclusiveMinimum": ">", "maximum": "<=", "exclusiveMaximum": "<"}[v]
        return f"{key} = {value!r}: must be {op} {error.validator_value}"
    if v == "type":
        return f"{key} = {value!r}: must be of type {error.validator_value}"
    if v == "enum":
        return f"{key} = {value!r}: allowed values are {error.validator_value}"
    if v == "pattern":
        return f"{key} = {value!r}: must match {error.validator_value}"
    if v == "oneOf":
        kinds = [s.get("type") for s in error.validator_value]
        return f"{key} = {value!r}: must be one of the forms {kinds}"
    return f"{key} = {value!r}: {error.message}"


def _schema_problems(config: dict) -> list[str]:
    schema = load_schema()
    Validator = _with_defaults(jsonschema.Draft202012Validator)
    errors = sorted(Validator(schema).iter_errors(config), key=lambda e: list(e.absolute_path))
    return [_describe(e) for e in errors]


def _scenario_problems(config: dict) -> list[str]:
    problems: list[str] = []
    seen: dict[str, int] = {}
    for i, sc in enumerate(config["scenarios"]):
        where = f"scenarios[{i}] ('{sc['name']}')"
        if sc["name"] in seen:
            problems.append(f"{where}.name = {sc['name']!r}: used twice (also scenarios"
                            f"[{seen[sc['name']]}]); scenario names must be unique")
        seen.setdefault(sc["name"], i)
        if sc["model"] not in MODELS:
            problems.append(f"{where}.model = {sc['model']!r}: unknown model; allowed: "
                            f"{sorted(MODELS)}")
            continue
        model = MODELS[sc["model"]]
        for msg in model.check_true_values(sc["omega"], sc["x0"], sc.get("prior")):
            problems.append(f"{where}: {msg}")
    names = {sc["name"] for sc in config["scenarios"]}
    ksel_seen: set[str] = set()
    for i, ks in enumerate(config.get("k_selection", [])):
        where = f"k_selection[{i}] ('{ks['name']}')"
        if ks["name"] in ksel_seen:
            problems.append(f"{where}.name = {ks['name']!r}: used twice; names must be unique")
        ksel_seen.add(ks["name"])
        if ks["scenario"] not in names:
            problems.append(f"{where}.scenario = {ks['scenario']!r}: no scenario of that name; "
                            f"configured: {sorted(names)}")
        grid = ks["K_grid"]
        if any(b <= a for a, b in zip(grid, grid[1:])):
            problems.append(f"{where}.K_grid = {grid}: must be strictly increasing")
    models = {sc["name"]: sc["model"] for sc in config["scenarios"]}
    study_seen: set[str] = set()
    for i, st in enumerate(config.get("observability_studies", [])):
        where = f"observability_studies[{i}] ('{st['name']}')"
        if st["name"] in study_seen:
            problems.append(f"{where}.name = {st['name']!r}: used twice; names must be unique")
        study_seen.add(st["name"])
        unknown = [n for n in st["scenarios"] if n not in names]
        if unknown:
            problems.append(f"{where}.scenarios: no scenario(s) named {unknown}; configured: "
                            f"{sorted(names)}")
        elif len({models[n] for n in st["scenarios"]}) > 1:
            problems.append(f"{where}.scenarios = {st['scenarios']}: must all use one model, "
                            f"got {sorted({models[n] for n in st['scenarios']})}")
    return problems


def _backend_problems(config: dict) -> list[str]:
    backend = config["stan"]["backend"]
    if backend != "cmdstanpy" or not any(sc.get("stan", True) for sc in config["scenarios"]):
        return []
    from .stan_backends import have_cmdstan

    if not have_cmdstan():
        return ["stan.backend = 'cmdstanpy': no CmdStan installation was found (set $CMDSTAN "
                "or install CmdStan under ~/.cmdstan); allowed without CmdStan: 'auto' or "
                "'pystan'"]
    return []


def validate(config: dict[str, Any]) -> dict[str, Any]:
    """Fill schema defaults into ``config`` (in place) and check it.

    Raises :class:`ConfigError` listing every problem (key, value, what is allowed).
    """
    problems = _schema_problems(config)
    if not problems:
        problems = _scenario_problems(config) + _backend_problems(config)
    if problems:
        raise ConfigError("invalid configuration:\n  - " + "\n  - ".join(problems))
    return config


def scenario(config: dict, name: str) -> dict:
    """The scenario entry called ``name``."""
    for sc in config["scenarios"]:
        if sc["name"] == name:
            return sc
    raise KeyError(name)


def x0_list(sc: dict) -> list[float]:
    x0 = sc["x0"]
    return [float(v) for v in (x0 if isinstance(x0, list) else [x0])]


def disturbance_dim(sc: dict) -> int:
    """q = (d + p) T: the dimension of one design disturbance vector (Sec. III.A)."""
    model = MODELS[sc["model"]]
    return (model.obs_dim + model.state_dim) * sc["T"]
