"""Config validation: the JSON schema (with defaults) plus the checks a schema cannot express.

:func:`validate` is called by the Snakefile before the DAG is built, so a bad config
stops the run with one message naming the key, the value and what is allowed, before any
expensive work and before anything is written to ``results/``.
"""

from __future__ import annotations

import copy
import functools
import math
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from .models import MODELS

#: folders directly under results/ that the workflow uses itself; no scenario may take them
#: (compared case-insensitively, for case-insensitive file systems)
RESERVED_SCENARIO_NAMES = ("shared", "k_selection")

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
    return _key(tuple(error.absolute_path))


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


def _key(path: tuple) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _nonfinite_problems(obj: Any, path: tuple = ()) -> list[str]:
    """Every NaN or infinite number anywhere in the config (JSON schema ranges let NaN pass)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return [f"{_key(path)} = {obj!r}: must be a finite number"]
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in _nonfinite_problems(v, path + (k,))]
    if isinstance(obj, list):
        return [p for i, v in enumerate(obj) for p in _nonfinite_problems(v, path + (i,))]
    return []


def _numbers_from_command_line(config: dict) -> None:
    """Numbers of ``limits`` given as strings become numbers (in place).

    Snakemake parses nested values of ``--config`` (and of a profile's ``config:``) with
    YAML's BaseLoader, i.e. as strings; this lets a profile raise the limits.
    """
    limits = config.get("limits")
    if not isinstance(limits, dict):
        return
    for key, value in limits.items():
        if isinstance(value, str):
            try:
                parsed = yaml.safe_load(value)
            except yaml.YAMLError:
                continue
            if isinstance(parsed, (int, float)) and not isinstance(parsed, bool):
                limits[key] = parsed


@functools.lru_cache(maxsize=1)
def _validator_class() -> type:
    return _with_defaults(jsonschema.Draft202012Validator)


def schema_problems(instance: Any, schema: dict) -> list[str]:
    """Every way ``instance`` breaks ``schema`` (key, value, what is allowed), after filling
    the schema's defaults into ``instance`` (in place)."""
    errors = sorted(
        _validator_class()(schema).iter_errors(instance), key=lambda e: list(e.absolute_path)
    )
    return [_describe(e) for e in errors]


def _schema_problems(config: dict) -> list[str]:
    return schema_problems(config, load_schema())


def _scenario_problems(config: dict) -> list[str]:
    problems: list[str] = []
    seen: dict[str, int] = {}
    for i, sc in enumerate(config["scenarios"]):
        where = f"scenarios[{i}] ('{sc['name']}')"
        if sc["name"] in seen:
            problems.append(
                f"{where}.name = {sc['name']!r}: used twice (also scenarios"
                f"[{seen[sc['name']]}]); scenario names must be unique"
            )
        seen.setdefault(sc["name"], i)
        if sc["name"].lower() in RESERVED_SCENARIO_NAMES:
            problems.append(
                f"{where}.name = {sc['name']!r}: reserved (results/{sc['name']}/ "
                f"holds the workflow's own files); reserved names: "
                f"{list(RESERVED_SCENARIO_NAMES)}"
            )
        if sc["model"] not in MODELS:
            problems.append(
                f"{where}.model = {sc['model']!r}: unknown model; allowed: {sorted(MODELS)}"
            )
            continue
        model = MODELS[sc["model"]]
        for msg in model.check_true_values(sc["omega"], sc["x0"], sc.get("prior")):
            problems.append(f"{where}: {msg}")
        if sc.get("joint_map_start") == "sign_of_x0" and not model.has_sign_consistent_start:
            problems.append(
                f"{where}.joint_map_start = 'sign_of_x0': model {sc['model']!r} "
                f"has no sign-consistent start; allowed: 'observations'"
            )
    names = {sc["name"] for sc in config["scenarios"]}
    problems += _repeated_names(config.get("k_selection", []), "k_selection")
    for i, ks in enumerate(config.get("k_selection", [])):
        where = f"k_selection[{i}] ('{ks['name']}')"
        if ks["scenario"] not in names:
            problems.append(
                f"{where}.scenario = {ks['scenario']!r}: no scenario of that name; "
                f"configured: {sorted(names)}"
            )
        grid = ks["K_grid"]
        if isinstance(grid, dict):  # the paper's K_i = i * step, i = 1 .. last / step
            if grid["last"] % grid["step"] or grid["last"] < 2 * grid["step"]:
                problems.append(
                    f"{where}.K_grid = {grid}: 'last' must be a multiple of 'step' "
                    f"and at least 2 * step"
                )
                continue
            grid = ks["K_grid"] = list(range(grid["step"], grid["last"] + 1, grid["step"]))
        if any(b <= a for a, b in zip(grid, grid[1:])):
            problems.append(f"{where}.K_grid = {grid}: must be strictly increasing")
    models = {sc["name"]: sc["model"] for sc in config["scenarios"]}
    problems += _repeated_names(config.get("observability_studies", []), "observability_studies")
    for i, st in enumerate(config.get("observability_studies", [])):
        where = f"observability_studies[{i}] ('{st['name']}')"
        unknown = [n for n in st["scenarios"] if n not in names]
        if unknown:
            problems.append(
                f"{where}.scenarios: no scenario(s) named {unknown}; configured: {sorted(names)}"
            )
        elif len({models[n] for n in st["scenarios"]}) > 1:
            problems.append(
                f"{where}.scenarios = {st['scenarios']}: must all use one model, "
                f"got {sorted({models[n] for n in st['scenarios']})}"
            )
    return (
        problems
        + _keep_draws_problems(config)
        + _figure_problems(config)
        + _paper_output_problems(config)
    )


def _repeated_names(entries: list[dict], section: str) -> list[str]:
    """One problem per entry of a config list whose ``name`` an earlier entry already has."""
    seen: set[str] = set()
    problems = []
    for i, entry in enumerate(entries):
        if entry["name"] in seen:
            problems.append(
                f"{section}[{i}] ('{entry['name']}').name = {entry['name']!r}: "
                f"used twice; names must be unique"
            )
        seen.add(entry["name"])
    return problems


def _keep_draws_problems(config: dict) -> list[str]:
    """stan.keep_draws: every k must be a trajectory of at least one Stan scenario."""
    stan_K = {sc["name"]: sc["K"] for sc in config["scenarios"] if sc.get("stan", True)}
    if not stan_K:
        return []
    largest = max(stan_K.values())
    beyond = [k for k in config["stan"]["keep_draws"] if k >= largest]
    if not beyond:
        return []
    return [
        f"stan.keep_draws = {config['stan']['keep_draws']}: k = {beyond} is beyond every "
        f"Stan scenario (k counts from 0, so k < K; the largest K is {largest}); "
        f"K per Stan scenario: {stan_K}"
    ]


def _figure_problems(config: dict) -> list[str]:
    """Ranges that make the figures meaningful (Figure 2's |a| < 1 is in the schema)."""
    f4 = config["figure4"]
    problems = []
    for lo, hi in (("a_min", "a_max"), ("x0_min", "x0_max")):
        if not f4[lo] < f4[hi]:
            problems.append(
                f"figure4.{lo} = {f4[lo]!r}, figure4.{hi} = {f4[hi]!r}: "
                f"{lo} must be < {hi} (the grid of Figure 4 would be empty)"
            )
    return problems


def _paper_output_problems(config: dict) -> list[str]:
    """paper_outputs: every name is a scenario that can give that table or figure."""
    scenarios = {sc["name"]: sc for sc in config["scenarios"]}
    chosen = config["paper_outputs"]
    problems = []
    for key in ("tables_2_3", "figure3", "figure4"):
        value = chosen[key]
        names = [value] if isinstance(value, str) else list(value or [])
        unknown = [n for n in names if n not in scenarios]
        if unknown:
            problems.append(
                f"paper_outputs.{key}: no scenario(s) named {unknown}; configured: "
                f"{sorted(scenarios)}"
            )
            continue
        entries = [scenarios[n] for n in names]
        if key != "figure4":
            one_stage = [sc["name"] for sc in entries if not (sc["joint_map"] and sc["stan"])]
            if one_stage:
                problems.append(
                    f"paper_outputs.{key}: scenario(s) {one_stage} do not run both "
                    f"stages; allowed: scenarios with joint_map and stan true"
                )
        models = [MODELS.get(sc["model"]) for sc in entries]
        if key == "figure3" and entries:
            truths = {(sc["model"], repr(sc["omega"]), repr(x0_list(sc))) for sc in entries}
            if len(truths) > 1:
                problems.append(
                    f"paper_outputs.figure3 = {names}: must share one model, omega "
                    f"and x0 (one pair of true-value lines), got {sorted(truths)}"
                )
            elif models[0] is not None and models[0].state_dim != 1:
                problems.append(
                    f"paper_outputs.figure3: model {entries[0]['model']!r} has "
                    f"p = {models[0].state_dim}; Figure 3 plots a scalar x0"
                )
        if key == "figure4" and entries and models[0] is not None:
            if models[0].n_params != 1 or models[0].state_dim != 1:
                problems.append(
                    f"paper_outputs.figure4 = {value!r}: model "
                    f"{entries[0]['model']!r} has {models[0].n_params} parameter(s) "
                    f"and p = {models[0].state_dim}; Figure 4's (Omega, x0) grid "
                    f"needs one parameter and p = 1"
                )
    return problems


def _backend_problems(config: dict) -> list[str]:
    backend = config["stan"]["backend"]
    if backend != "cmdstanpy" or not any(sc.get("stan", True) for sc in config["scenarios"]):
        return []
    from .stan_backends import have_cmdstan

    if not have_cmdstan():
        return [
            "stan.backend = 'cmdstanpy': no CmdStan installation was found (set $CMDSTAN "
            "or install CmdStan under ~/.cmdstan); allowed without CmdStan: 'auto' or "
            "'native' or 'pystan'"
        ]
    return []


def validate(config: dict[str, Any]) -> dict[str, Any]:
    """Fill schema defaults into ``config`` (in place) and check it.

    Raises :class:`ConfigError` listing every problem (key, value, what is allowed).
    """
    if not isinstance(config, dict):
        raise ConfigError(
            f"invalid configuration: the top level must be a mapping with the "
            f"required key 'scenarios', got {type(config).__name__}"
        )
    _numbers_from_command_line(config)
    problems = _nonfinite_problems(config) or _schema_problems(config)
    if not problems:
        problems = _scenario_problems(config) + _backend_problems(config)
    if not problems:
        from . import budget

        problems = budget.problems(config)
    if problems:
        raise ConfigError("invalid configuration:\n  - " + "\n  - ".join(problems))
    return config


def x0_list(sc: dict) -> list[float]:
    x0 = sc["x0"]
    return [float(v) for v in (x0 if isinstance(x0, list) else [x0])]
