"""Config validation: the JSON schema (with defaults) plus the checks a schema cannot express.

:func:`validate` is called by the Snakefile before the DAG is built, so a bad config
stops the run with one message naming the key, the value and what is allowed, before any
expensive work and before anything is written to ``results/``.  :func:`read_config_file`
reads a config file strictly (duplicate keys, size and YAML alias expansion are refused);
:func:`check_config_files` applies it to the files Snakemake read itself (``--configfile``).
"""

from __future__ import annotations

import copy
import functools
import json
import math
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from .models import MODELS

#: folders directly under results/ that the workflow uses itself; no scenario may take them
#: (compared case-insensitively, for case-insensitive file systems)
RESERVED_SCENARIO_NAMES = ("shared", "k_selection")

SCHEMA_PATH = Path(__file__).resolve().parents[1] / "schemas" / "config.schema.yaml"
#: the paper's values; every non-empty ``paper_ref`` must be one of its keys
PAPER_VALUES_PATH = Path(__file__).resolve().parents[2] / "config" / "paper_values.yaml"

#: largest config file read (bytes); a config has a few kB
MAX_CONFIG_BYTES = 5 * 2**20
#: most values (mappings, lists, scalars) a config may hold once YAML aliases are expanded;
#: a config has a few hundred, an alias "bomb" billions
MAX_CONFIG_VALUES = 100_000
#: longest rendering of a value in a message (characters)
MAX_REPR = 200

README = "config/README.md"


class ConfigError(ValueError):
    """The configuration is invalid; the message lists every problem found."""


def load_schema() -> dict:
    return yaml.safe_load(SCHEMA_PATH.read_text())


def _short(value: Any, limit: int = MAX_REPR) -> str:
    """``repr(value)``, cut to about ``limit`` characters so that a message stays readable."""
    return _cut(repr(value), limit)


def _cut(text: str, limit: int = MAX_REPR) -> str:
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} characters)"


def short_list(names: list[str], n: int = 20) -> str:
    """The first ``n`` of ``names`` as a list, with how many more there are."""
    shown = _short(names[:n])
    return shown if len(names) <= n else f"{shown} and {len(names) - n} more"


# ------------------------------------------------------------------------ reading files
class RefusedYAMLError(yaml.MarkedYAMLError):
    """Valid YAML that would silently mean something else (a duplicate key) or is too big."""


class ConfigLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate keys in a mapping (PyYAML keeps the last)
    and documents whose YAML aliases expand to more than :data:`MAX_CONFIG_VALUES` values."""

    def get_single_node(self) -> yaml.Node | None:
        node = super().get_single_node()
        if node is not None and _expanded_size(node, {}) > MAX_CONFIG_VALUES:
            raise RefusedYAMLError(
                problem=(
                    f"holds more than {MAX_CONFIG_VALUES} values once its YAML aliases "
                    f"(*name) are expanded; a config has a few hundred"
                ),
                problem_mark=node.start_mark,
            )
        return node

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        first: dict[Any, yaml.Node] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # '<<: *base' may be overridden
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                seen = first.get(key)
            except TypeError:  # unhashable: the base class reports it
                continue
            if seen is None:
                first[key] = key_node
            else:
                raise RefusedYAMLError(
                    problem=(
                        f"key {_short(key)} appears twice in one mapping (also line "
                        f"{seen.start_mark.line + 1}); YAML would silently keep only the "
                        f"last value: remove one"
                    ),
                    problem_mark=key_node.start_mark,
                )
        return super().construct_mapping(node, deep=deep)


def _expanded_size(node: yaml.Node, memo: dict[int, int | None]) -> int:
    """Number of values under ``node`` with every alias expanded, capped just above the
    limit (a shared node is counted once per use but visited once)."""
    key = id(node)
    if key in memo:
        size = memo[key]
        return MAX_CONFIG_VALUES + 1 if size is None else size  # None: a cycle
    memo[key] = None
    if isinstance(node, yaml.SequenceNode):
        children = list(node.value)
    elif isinstance(node, yaml.MappingNode):
        children = [n for pair in node.value for n in pair]
    else:
        children = []
    total = 1
    for child in children:
        total += _expanded_size(child, memo)
        if total > MAX_CONFIG_VALUES:
            break
    total = min(total, MAX_CONFIG_VALUES + 1)
    memo[key] = total
    return total


def _json_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ConfigError(
                f"key {_short(key)} appears twice in one JSON object; JSON readers "
                f"silently keep only the last value: remove one"
            )
        out[key] = value
    return out


def parse_config_text(text: str) -> Any:
    """The document in ``text``: JSON first, as Snakemake reads ``--configfile``, then YAML
    with :class:`ConfigLoader`.  Raises ConfigError (JSON) or a ``yaml.YAMLError``."""
    try:
        return json.loads(text, object_pairs_hook=_json_pairs)
    except json.JSONDecodeError:
        pass
    loader = ConfigLoader(text)
    try:
        return loader.get_single_data()
    finally:
        loader.dispose()


def read_config_file(path: str | os.PathLike) -> Any:
    """The document in the config file ``path`` (None when empty).

    Raises ConfigError with one line naming the file (and line and column) when it does not
    exist, cannot be read, is larger than :data:`MAX_CONFIG_BYTES`, is not valid YAML, has a
    key twice in one mapping, or expands to more than :data:`MAX_CONFIG_VALUES` values.
    """
    path = Path(path)
    if not path.is_file():
        what = "is a directory, not a file" if path.is_dir() else "does not exist"
        raise ConfigError(f"config file {path} {what}")
    try:
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError(
                f"config file {path} has {size} bytes, more than the {MAX_CONFIG_BYTES} "
                f"bytes ({MAX_CONFIG_BYTES / 2**20:g} MiB) a config file may have; a config "
                f"has a few kB"
            )
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"config file {path} cannot be read: {err}") from None
    try:
        return parse_config_text(text)
    except ConfigError as err:
        raise ConfigError(f"config file {path}: {err}") from None
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        where = f", line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = ": ".join(str(p) for p in (err.context, err.problem) if p)
        if not isinstance(err, RefusedYAMLError):
            problem = f"YAML syntax error: {problem}"
        raise ConfigError(f"config file {path}{where}: {_cut(problem, 2 * MAX_REPR)}") from None
    except yaml.YAMLError as err:
        raise ConfigError(f"config file {path}: YAML syntax error: {_cut(str(err))}") from None
    except RecursionError:
        raise ConfigError(f"config file {path}: nested too deeply to be a config") from None


def check_config_files(
    paths: Iterable[str | os.PathLike], error: type[Exception] = ConfigError
) -> None:
    """Read every file of ``paths`` as :func:`read_config_file` does; raise ``error`` with
    one line per bad file.

    Snakemake reads ``--configfile`` files itself and keeps the last of duplicate keys;
    common.smk calls this on ``workflow.configfiles`` so that they are refused there too.
    """
    problems = []
    for path in paths:
        try:
            read_config_file(path)
        except ConfigError as err:
            problems.append(str(err))
    if problems:
        raise error("\n".join(problems))


# ------------------------------------------------------------------------ the schema
def _is_integer(checker: Any, instance: Any) -> bool:
    """JSON schema's "integer" without floats: 12.0 would become the path part K12.0."""
    return isinstance(instance, int) and not isinstance(instance, bool)


_TYPE_CHECKER = jsonschema.Draft202012Validator.TYPE_CHECKER.redefine("integer", _is_integer)


def _with_defaults(
    validator_class: type[jsonschema.protocols.Validator],
) -> type[jsonschema.protocols.Validator]:
    validate_props = validator_class.VALIDATORS["properties"]

    def set_defaults(
        validator: jsonschema.protocols.Validator,
        properties: dict[str, Any],
        instance: Any,
        schema: dict[str, Any],
    ) -> Iterator[jsonschema.ValidationError]:
        if isinstance(instance, dict):
            for key, sub in properties.items():
                if "default" in sub and key not in instance:
                    instance[key] = copy.deepcopy(sub["default"])
        yield from validate_props(validator, properties, instance, schema)

    return jsonschema.validators.extend(
        validator_class, {"properties": set_defaults}, type_checker=_TYPE_CHECKER
    )


def _path(error: jsonschema.ValidationError) -> str:
    return _key(tuple(error.absolute_path))


def _types(schema: Any) -> list[str]:
    kinds = schema.get("type", []) if isinstance(schema, dict) else []
    return kinds if isinstance(kinds, list) else [kinds]


def _is_type(value: Any, kind: str) -> bool:
    try:
        return bool(_TYPE_CHECKER.is_type(value, kind))
    except jsonschema.exceptions.UnknownType:
        return False


def _branch_errors(error: jsonschema.ValidationError) -> list[jsonschema.ValidationError]:
    """The errors of the one ``oneOf`` form whose type the value has (empty if none or
    several have it): ``K_grid: [0, 8]`` fails as a list, not as a mapping."""
    forms = [
        i
        for i, sub in enumerate(error.validator_value)
        if any(_is_type(error.instance, kind) for kind in _types(sub))
    ]
    if len(forms) != 1:
        return []
    return sorted(
        _without_shadowed_type_errors(
            e for e in error.context or [] if e.schema_path and e.schema_path[0] == forms[0]
        ),
        key=lambda e: list(e.absolute_path),
    )


def _describe(error: jsonschema.ValidationError) -> list[str]:
    key = _path(error)
    value = _short(error.instance)
    v = error.validator
    if v == "required":
        return [f"{key}: {_cut(error.message)}"]
    if v == "additionalProperties":
        return [f"{key}: {_cut(error.message)} (see {README} for the allowed keys)"]
    if v in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum"):
        op = {"minimum": ">=", "exclusiveMinimum": ">", "maximum": "<=", "exclusiveMaximum": "<"}[v]
        return [f"{key} = {value}: must be {op} {error.validator_value}"]
    if v == "type":
        kinds = _types(error.schema)
        whole = isinstance(error.instance, float) and error.instance.is_integer()
        if "integer" in kinds and whole:
            others = [k for k in kinds if k != "integer"]
            also = f" (or of type {' or '.join(others)})" if others else ""
            return [
                f"{key} = {value}: must be a whole number written without a decimal "
                f"point ({int(error.instance)}){also}"
            ]
        return [f"{key} = {value}: must be of type {error.validator_value}"]
    if v == "enum":
        return [f"{key} = {value}: allowed values are {error.validator_value}{_quote_hint(error)}"]
    if v == "pattern":
        return [f"{key} = {value}: must match {error.validator_value}"]
    if v == "oneOf":
        inner = _branch_errors(error)
        if inner:
            return [d for e in inner for d in _describe(e)]
        kinds = [s.get("type") for s in error.validator_value]
        return [f"{key} = {value}: must be one of the forms {kinds}"]
    return [f"{key} = {value}: {_cut(error.message)}"]


def _yaml_spelling(value: Any) -> tuple[str, str] | None:
    """How a boolean, null or number that YAML read from plain text is written, and what
    YAML took it for; None for other values."""
    if isinstance(value, bool):
        return ("true" if value else "false"), "boolean"
    if value is None:
        return "null", "null"
    if isinstance(value, (int, float)):
        return repr(value), "number"
    return None


def _quote_hint(error: jsonschema.ValidationError) -> str:
    """For an ``enum`` of strings that holds the text of a non-string value (``stan_init:
    true`` read as a boolean): how to write it as a string; else ''."""
    read = _yaml_spelling(error.instance)
    if read is None or read[0] not in error.validator_value:
        return ""
    spelling, kind = read
    return f" (write {spelling!r} in quotes: unquoted, YAML reads {spelling} as a {kind}, not text)"


def _without_shadowed_type_errors(
    errors: Iterable[jsonschema.ValidationError],
) -> list[jsonschema.ValidationError]:
    """``errors`` less each ``type`` error of a value whose ``enum`` error (same value, same
    schema) is there too: the list of allowed values says all, in one message."""
    errors = list(errors)
    enums = {(tuple(e.absolute_path), id(e.schema)) for e in errors if e.validator == "enum"}
    return [
        e
        for e in errors
        if not (e.validator == "type" and (tuple(e.absolute_path), id(e.schema)) in enums)
    ]


def _key(path: tuple) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _count_values(obj: Any, limit: int = MAX_CONFIG_VALUES) -> int:
    """Number of values in ``obj`` (a shared list counts at every use), stopping above
    ``limit``: a YAML alias bomb is refused before anything walks it."""
    count, stack = 0, [obj]
    while stack and count <= limit:
        item = stack.pop()
        count += 1
        if isinstance(item, dict):
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item[: limit + 1])
    return count


def _nonfinite_problems(obj: Any, path: tuple = ()) -> list[str]:
    """Every NaN or infinite number anywhere in the config (JSON schema ranges let NaN pass)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return [f"{_key(path)} = {obj!r}: must be a finite number"]
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in _nonfinite_problems(v, path + (k,))]
    if isinstance(obj, list):
        return [p for i, v in enumerate(obj) for p in _nonfinite_problems(v, path + (i,))]
    return []


def _scalars_from_command_line(instance: Any, schema: dict) -> Any:
    """``instance`` with every string where the schema wants no string, but a number,
    boolean or null, read as a YAML scalar of that type (in place; returns it).

    Snakemake parses nested values of ``--config`` (and of a profile's ``config:``) with
    YAML's BaseLoader, i.e. as strings: ``--config 'stan={chains: 1}'`` gives
    ``{'chains': '1'}``.  A string that is no such scalar stays and the schema names it.
    """
    forms = schema.get("oneOf") or [schema]
    kinds = {k for form in forms for k in _types(form)}
    if isinstance(instance, str):
        if "string" in kinds or not kinds & {"integer", "number", "boolean", "null"}:
            return instance
        if len(instance) > MAX_REPR:
            return instance
        try:
            parsed = yaml.safe_load(instance)
        except yaml.YAMLError:
            return instance
        number = isinstance(parsed, (int, float)) and not isinstance(parsed, bool)
        if (
            (parsed is None and "null" in kinds)
            or (isinstance(parsed, bool) and "boolean" in kinds)
            or (number and kinds & {"integer", "number"})  # 1.0 for an integer: refused later
        ):
            return parsed
        return instance
    kind = "object" if isinstance(instance, dict) else "array" if isinstance(instance, list) else ""
    form = next((f for f in forms if kind and kind in _types(f)), None)
    if form is None:
        return instance
    if isinstance(instance, dict):
        props, extra = form.get("properties", {}), form.get("additionalProperties")
        for key, value in list(instance.items()):
            sub = props.get(key, extra)
            if isinstance(sub, dict):
                instance[key] = _scalars_from_command_line(value, sub)
    elif isinstance(form.get("items"), dict):
        for i, value in enumerate(instance):
            instance[i] = _scalars_from_command_line(value, form["items"])
    return instance


@functools.lru_cache(maxsize=1)
def _validator_class() -> type:
    return _with_defaults(jsonschema.Draft202012Validator)


def schema_problems(instance: Any, schema: dict) -> list[str]:
    """Every way ``instance`` breaks ``schema`` (key, value, what is allowed), after filling
    the schema's defaults into ``instance`` (in place)."""
    errors = sorted(
        _without_shadowed_type_errors(_validator_class()(schema).iter_errors(instance)),
        key=lambda e: list(e.absolute_path),
    )
    return [d for e in errors for d in _describe(e)]


def _explicit_exact(config: dict) -> set[int]:
    """Indices of the scenarios that write ``exact: true`` themselves (read before the
    schema's defaults are filled in, so that a default could never count as written)."""
    scenarios = config.get("scenarios")
    if not isinstance(scenarios, list):
        return set()
    return {i for i, sc in enumerate(scenarios) if isinstance(sc, dict) and sc.get("exact") is True}


def _where(section: str, i: int, name: Any) -> str:
    return f"{section}[{i}] ({_cut(repr(name), 60)})"


def _scenario_problems(config: dict, explicit_exact: frozenset[int] = frozenset()) -> list[str]:
    problems = _name_problems(config["scenarios"], "scenarios")
    for i, sc in enumerate(config["scenarios"]):
        where = _where("scenarios", i, sc["name"])
        if sc["name"].lower() in RESERVED_SCENARIO_NAMES:
            problems.append(
                f"{where}.name = {sc['name']!r}: reserved (results/{sc['name']}/ "
                f"holds the workflow's own files); reserved names: "
                f"{list(RESERVED_SCENARIO_NAMES)}"
            )
        if sc["model"] not in MODELS:
            problems.append(
                f"{where}.model = {_short(sc['model'])}: unknown model; allowed: {sorted(MODELS)}"
            )
            continue
        model = MODELS[sc["model"]]
        for msg in model.check_true_values(sc["omega"], sc["x0"], sc.get("prior"), T=sc["T"]):
            problems.append(f"{where}: {_cut(msg, 2 * MAX_REPR)}")
        if sc.get("joint_map_start") == "sign_of_x0" and not model.has_sign_consistent_start:
            problems.append(
                f"{where}.joint_map_start = 'sign_of_x0': model {sc['model']!r} "
                f"has no sign-consistent start; allowed: 'observations'"
            )
        if i in explicit_exact and not model.linear_in_states:
            problems.append(
                f"{where}.exact = True: model {sc['model']!r} is not linear in the states, "
                f"so the exact marginal stage cannot run for it; allowed: exact: false, or "
                f"leaving exact out"
            )
    names = {sc["name"] for sc in config["scenarios"]}
    problems += _name_problems(config.get("k_selection", []), "k_selection")
    for i, ks in enumerate(config.get("k_selection", [])):
        where = _where("k_selection", i, ks["name"])
        if ks["scenario"] not in names:
            problems.append(
                f"{where}.scenario = {_short(ks['scenario'])}: no scenario of that name; "
                f"configured: {short_list(sorted(names))}"
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
            problems.append(f"{where}.K_grid = {_short(grid)}: must be strictly increasing")
    models = {sc["name"]: sc["model"] for sc in config["scenarios"]}
    problems += _name_problems(config.get("observability_studies", []), "observability_studies")
    for i, st in enumerate(config.get("observability_studies", [])):
        where = _where("observability_studies", i, st["name"])
        unknown = [n for n in st["scenarios"] if n not in names]
        if unknown:
            problems.append(
                f"{where}.scenarios: no scenario(s) named {short_list(unknown)}; configured: "
                f"{short_list(sorted(names))}"
            )
        elif len({models[n] for n in st["scenarios"]}) > 1:
            problems.append(
                f"{where}.scenarios = {_short(st['scenarios'])}: must all use one model, "
                f"got {sorted({models[n] for n in st['scenarios']})}"
            )
    return (
        problems
        + _map_problems(config)
        + _keep_draws_problems(config)
        + _figure_problems(config)
        + _paper_output_problems(config)
        + _paper_ref_problems(config)
        + _mu0_sweep_problems(config)
        + _outputs_dir_problems(config)
    )


#: keys of a map's base that its cells set themselves
MAP_CELL_KEYS = ("name", "T", "K", "joint_map", "stan", "exact", "exact_K", "stan_batch_size")


def _map_problems(config: dict) -> list[str]:
    """Every cell of every observability map is a valid scenario (its true values too)."""
    from .observability_map import cell_entries
    from .scenario import Scenario

    maps = config.get("observability_maps", [])
    problems = _name_problems(maps, "observability_maps")
    for i, entry in enumerate(maps):
        where = _where("observability_maps", i, entry["name"])
        own = [k for k in MAP_CELL_KEYS if k in entry["base"]]
        if own:
            problems.append(
                f"{where}.base: {short_list(own)} are set per cell (name, T and K by the map); "
                f"leave them out of base"
            )
            continue
        model = MODELS.get(entry["base"]["model"])
        if model is None:
            problems.append(
                f"{where}.base.model = {_short(entry['base']['model'])}: unknown model; "
                f"allowed: {sorted(MODELS)}"
            )
            continue
        if entry["vary"] not in model.param_names:
            problems.append(
                f"{where}.vary = {_short(entry['vary'])}: not a parameter of model "
                f"{model.slug!r}; allowed: {list(model.param_names)}"
            )
            continue
        for cell in cell_entries(entry):
            try:
                Scenario.from_config(cell)
            except ConfigError as err:
                problems.append(f"{where}, cell {cell['name']}: {_cut(str(err), 2 * MAX_REPR)}")
                break  # one bad cell says what is wrong with the map
    return problems


def _name_problems(entries: list[dict], section: str) -> list[str]:
    """One problem per ``name`` of a config list that an earlier entry has already (also in
    another case: names are folders and files, and case-insensitive file systems mix them
    up), and per name ending in '.' (some file systems drop it)."""
    seen: dict[str, int] = {}
    problems = []
    for i, entry in enumerate(entries):
        name = entry["name"]
        where = f"{_where(section, i, name)}.name = {_short(name)}"
        j = seen.get(name.lower())
        if j is not None and entries[j]["name"] == name:
            problems.append(f"{where}: used twice (also {section}[{j}]); names must be unique")
        elif j is not None:
            problems.append(
                f"{where}: differs from {section}[{j}] ({_short(entries[j]['name'])}) only in "
                f"case; names must differ in more than case (they name folders and files, "
                f"which case-insensitive file systems such as macOS's and Windows' mix up)"
            )
        seen.setdefault(name.lower(), i)
        if name.endswith("."):
            problems.append(
                f"{where}: ends with '.', which some file systems (Windows) drop from "
                f"folder and file names; allowed: a name ending in a letter, digit, '_' or '-'"
            )
    return problems


def _paper_ref_problems(config: dict) -> list[str]:
    """paper_ref: empty, or a key of config/paper_values.yaml (else the paper's columns
    would silently stay empty)."""
    refs = [(i, sc) for i, sc in enumerate(config["scenarios"]) if sc["paper_ref"]]
    if not refs or not PAPER_VALUES_PATH.is_file():
        return []
    known = sorted(yaml.safe_load(PAPER_VALUES_PATH.read_text()) or {})
    return [
        f"{_where('scenarios', i, sc['name'])}.paper_ref = {_short(sc['paper_ref'])}: no "
        f"such key in config/paper_values.yaml (the paper's columns would stay empty); "
        f"allowed: '' (none) or one of {short_list(known)}"
        for i, sc in refs
        if sc["paper_ref"] not in known
    ]


def _mu0_sweep_problems(config: dict) -> list[str]:
    """mu0_sweep.models: known model slugs (a known model no joint-MAP scenario uses only
    adds no rows, as for profiles without Sep scenarios)."""
    unknown = [m for m in config["mu0_sweep"]["models"] if m not in MODELS]
    if not unknown:
        return []
    return [
        f"mu0_sweep.models = {_short(config['mu0_sweep']['models'])}: unknown model(s) "
        f"{_short(unknown)}; the sweep takes model slugs (workflow/ssmobs/models/<slug>.py), "
        f"not scenario names, and a known model that no joint-MAP scenario uses adds no "
        f"rows; allowed: {sorted(MODELS)}"
    ]


def _outputs_dir_problems(config: dict) -> list[str]:
    """outputs_dir: a relative path that stays inside the working directory."""
    value = config["outputs_dir"]
    if value.startswith("/") or ".." in value.split("/"):
        return [
            f"outputs_dir = {_short(value)}: must be a relative path inside the working "
            f"directory; allowed: no leading '/' and no '..' part (e.g. paper_figures/mine)"
        ]
    return []


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
        f"stan.keep_draws = {_short(config['stan']['keep_draws'])}: k = {_short(beyond)} is "
        f"beyond every Stan scenario (k counts from 0, so k < K; the largest K is {largest}); "
        f"K per Stan scenario: {_short(stan_K)}"
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
                f"paper_outputs.{key}: no scenario(s) named {short_list(unknown)}; configured: "
                f"{short_list(sorted(scenarios))}"
            )
            continue
        entries = [scenarios[n] for n in names]
        if key != "figure4":
            one_stage = [sc["name"] for sc in entries if not (sc["joint_map"] and sc["stan"])]
            if one_stage:
                problems.append(
                    f"paper_outputs.{key}: scenario(s) {short_list(one_stage)} do not run both "
                    f"stages; allowed: scenarios with joint_map and stan true"
                )
        models = [MODELS.get(sc["model"]) for sc in entries]
        if key == "figure3" and entries:
            truths = {(sc["model"], repr(sc["omega"]), repr(x0_list(sc))) for sc in entries}
            if len(truths) > 1:
                problems.append(
                    f"paper_outputs.figure3 = {_short(names)}: must share one model, omega "
                    f"and x0 (one pair of true-value lines), got {_short(sorted(truths))}"
                )
            elif models[0] is not None and models[0].state_dim != 1:
                problems.append(
                    f"paper_outputs.figure3: model {entries[0]['model']!r} has "
                    f"p = {models[0].state_dim}; Figure 3 plots a scalar x0"
                )
        if key == "figure4" and entries and models[0] is not None:
            if models[0].n_params != 1 or models[0].state_dim != 1:
                problems.append(
                    f"paper_outputs.figure4 = {_short(value)}: model "
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


def _exact_settings_problems(config: dict[str, Any]) -> list[str]:
    """What the exact_marginal block's schema cannot say: its range is an interval."""
    lo, hi = config["exact_marginal"]["half_line_range"]
    if lo < hi:
        return []
    return [
        f"exact_marginal.half_line_range = [{lo!r}, {hi!r}]: the lower end must be below the upper"
    ]


def validate(config: dict[str, Any]) -> dict[str, Any]:
    """Fill schema defaults into ``config`` (in place) and check it.

    Raises :class:`ConfigError` listing every problem (key, value, what is allowed).
    """
    if not isinstance(config, dict):
        raise ConfigError(
            f"invalid configuration: the top level must be a mapping with the "
            f"required key 'scenarios', got {type(config).__name__}"
        )
    if _count_values(config) > MAX_CONFIG_VALUES:
        raise ConfigError(
            f"invalid configuration: more than {MAX_CONFIG_VALUES} values (YAML aliases "
            f"expanded); a config has a few hundred"
        )
    schema = load_schema()
    _scalars_from_command_line(config, schema)
    explicit_exact = frozenset(_explicit_exact(config))
    problems = _nonfinite_problems(config) or schema_problems(config, schema)
    if not problems:
        problems = (
            _scenario_problems(config, explicit_exact)
            + _backend_problems(config)
            + _exact_settings_problems(config)
        )
    if not problems:
        from . import budget

        problems = budget.problems(config)
    if problems:
        raise ConfigError("invalid configuration:\n  - " + "\n  - ".join(problems))
    return config


def x0_list(sc: dict) -> list[float]:
    x0 = sc["x0"]
    return [float(v) for v in (x0 if isinstance(x0, list) else [x0])]
