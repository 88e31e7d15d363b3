"""The config's ground floor: its schema, its error and the messages that name what is wrong.

:func:`load_schema` reads ``workflow/schemas/config.schema.yaml``; :func:`schema_problems`
checks a value against (part of) it, filling in its defaults, and words every problem as
key, value and what is allowed; the number forms a config takes (:func:`plain_number`) and
those that YAML 1.1 and 1.2 read differently (:func:`number_form`).  This module imports
nothing of the package, so every other module (the cross-field checks of
:mod:`ssmobs.config.validation`, :mod:`ssmobs.config.scenario`) can use it.
"""

from __future__ import annotations

import copy
import functools
import math
import re
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import jsonschema
import yaml

SCHEMA_PATH = Path(__file__).resolve().parents[2] / "schemas" / "config.schema.yaml"
#: longest rendering of a value in a message (characters)
MAX_REPR = 200

README = "config/README.md"


class ConfigError(ValueError):
    """The configuration is invalid; the message lists every problem found."""


def load_schema() -> dict:
    """The config schema (:data:`SCHEMA_PATH`), read afresh (by libyaml where PyYAML has
    it: the same tree, parsed in a tenth of the time)."""
    return yaml.load(SCHEMA_PATH.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


@functools.lru_cache(maxsize=1)
def scenario_schema() -> dict:
    """The schema of one entry of ``scenarios`` (with its defaults)."""
    return load_schema()["properties"]["scenarios"]["items"]


def short_repr(value: Any, limit: int = MAX_REPR) -> str:
    """``repr(value)``, cut to about ``limit`` characters so that a message stays readable."""
    return cut_text(repr(value), limit)


def cut_text(text: str, limit: int = MAX_REPR) -> str:
    """``text``, cut to ``limit`` characters with how long it was."""
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} characters)"


def short_list(names: list[str], n: int = 20) -> str:
    """The first ``n`` of ``names`` as a list, with how many more there are."""
    shown = short_repr(names[:n])
    return shown if len(names) <= n else f"{shown} and {len(names) - n} more"


# ------------------------------------------------------------------------ many alike
#: problems of one kind given one by one up to this many; more are summarised in one line
ALIKE_GIVEN_ONE_BY_ONE = 3
#: names of the other entries a summary line shows
ALIKE_NAMES_SHOWN = 3
#: the entry a problem is about, as the messages write it: ``scenarios[3]``, with its name
#: (``scenarios[3] ('x')``) where the check adds it, or ``scenario 'x'`` (the size budget)
_ENTRY = re.compile(
    r"^(?:(?P<section>scenarios|k_selection|observability_studies|observability_maps)"
    r"\[(?P<index>\d+)\](?: \((?P<quoted>'[^']*'|\"[^\"]*\")\))?"
    r"|(?P<owner>scenario|k_selection|observability map) '(?P<name>[^']*)')"
)
#: values inside a message: quoted text, numbers (not digits inside names), then lists
_TEXT = re.compile(r"'[^']*'|\"[^\"]*\"")
_NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?![\w])")
_LIST = re.compile(r"\[[^\[\]]*\]")
_PLURAL = {
    "scenarios": "scenarios",
    "scenario": "scenarios",
    "k_selection": "k_selection entries",
    "observability_studies": "observability studies",
    "observability_maps": "observability maps",
    "observability map": "observability maps",
}


def _entry_and_kind(problem: str, names: dict[str, list[Any]]) -> tuple[str, str, str] | None:
    """(section, the entry's name, the problem's kind) of a problem about one entry of a
    config list, None for others.  The kind is the message without its entry and with
    every value (quoted text, number, list) blanked: problems that differ only in the
    entry and its values are of one kind."""
    found = _ENTRY.match(problem)
    if found is None:
        return None
    if found["owner"]:
        section, name = found["owner"], found["name"]
    else:
        section, index = found["section"], int(found["index"])
        entries = names.get(section, [])
        if found["quoted"]:
            name = found["quoted"][1:-1]
        else:
            name = entries[index] if index < len(entries) else f"[{index}]"
    rest = _TEXT.sub("'…'", problem[found.end() :])
    rest = _LIST.sub("[…]", _NUMBER.sub("…", rest))
    return _PLURAL[section], str(name), rest


def summarise_problems(problems: list[str], names: dict[str, list[Any]]) -> list[str]:
    """``problems`` with every kind that more than :data:`ALIKE_GIVEN_ONE_BY_ONE` entries
    of one config list share (see :func:`_entry_and_kind`) given as one line: how many, the
    first problem in full, the names of the first few others.  Fewer stay as they are, in
    their order; a summary line takes its first problem's place.

    ``names``: the ``name`` of every entry of each config list (``scenarios``, ...), by
    position, for the schema's messages that give only the position (``scenarios[3].K``).
    """
    kinds: dict[tuple[str, str], list[tuple[int, str]]] = {}
    for i, problem in enumerate(problems):
        found = _entry_and_kind(problem, names)
        if found is not None:
            kinds.setdefault((found[0], found[2]), []).append((i, found[1]))
    out: dict[int, str] = dict(enumerate(problems))
    for (section, _), alike in kinds.items():
        if len(alike) <= ALIKE_GIVEN_ONE_BY_ONE:
            continue
        others = [repr(name) for _, name in alike[1:]]
        shown = ", ".join(others[:ALIKE_NAMES_SHOWN])
        if len(others) > ALIKE_NAMES_SHOWN:
            shown += f" and {len(others) - ALIKE_NAMES_SHOWN} more"
        first = alike[0][0]
        out[first] = (
            f"{len(alike)} {section} alike, the first: {problems[first]}; the others: {shown}"
        )
        for i, _ in alike[1:]:
            del out[i]
    return [out[i] for i in sorted(out)]


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
    value = short_repr(error.instance)
    v = error.validator
    if v == "required":
        return [f"{key}: {cut_text(error.message)}"]
    if v == "additionalProperties":
        return [f"{key}: {cut_text(error.message)} (see {README} for the allowed keys)"]
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
    if v in ("maxLength", "minLength"):
        bound = "at most" if v == "maxLength" else "at least"
        return [
            f"{key} = {value}: {len(error.instance)} characters; allowed: {bound} "
            f"{error.validator_value} (it is part of file names)"
        ]
    if v == "oneOf":
        inner = _branch_errors(error)
        if inner:
            return [d for e in inner for d in _describe(e)]
        kinds = [s.get("type") for s in error.validator_value]
        return [f"{key} = {value}: must be one of the forms {kinds}"]
    return [f"{key} = {value}: {cut_text(error.message)}"]


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


# ------------------------------------------------------------------------ number forms
#: the number forms a config takes, read alike by YAML 1.2 (core schema) and YAML 1.1:
#: decimal digits without a leading zero, a decimal fraction with an optional exponent
#: (``1e3``, a number in YAML 1.2, text in YAML 1.1, which reads no number otherwise)
PLAIN_INT = re.compile(r"[-+]?(0|[1-9][0-9]*)")
PLAIN_FLOAT = re.compile(r"[-+]?(\.[0-9]+|(0|[1-9][0-9]*)(\.[0-9]*)?)([eE][-+]?[0-9]+)?")
PLAIN_INF = re.compile(r"([-+]?)\.(inf|Inf|INF)")
PLAIN_NAN = re.compile(r"\.(nan|NaN|NAN)")
#: what else YAML 1.2's core schema reads as a number: leading zeros, octal 0o7, hex 0x8
YAML12_OTHER = re.compile(
    r"[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+|[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?"
)
#: numbers of YAML 1.2 that PyYAML (YAML 1.1) reads as text: octal 0o7, 1e3, 1.5e3
YAML12_ONLY = re.compile(r"[-+]?(0o[0-7]+|0x[0-9a-fA-F]+|[0-9]+(\.[0-9]*)?[eE][-+]?[0-9]+)")
#: how a config writes numbers, for the messages
PLAIN_DIGITS = "a number in plain decimal digits (e.g. 10, 0.5, 1.0e+3)"


def number_form(text: str) -> str:
    """What makes ``text`` a number form that YAML 1.1 and YAML 1.2 read differently."""
    body = text.lstrip("+-")
    if "_" in body:
        return "digits with underscores"
    if ":" in body:
        return "a base-60 (sexagesimal) number"
    if body[:2].lower() == "0x":
        return "a hexadecimal number"
    if body[:2].lower() in ("0o", "0b"):
        return "an octal or binary number"
    return "a number with a leading zero"


def plain_number(text: str) -> int | float | None:
    """The number ``text`` writes in a plain decimal form (:data:`PLAIN_INT`,
    :data:`PLAIN_FLOAT`, ``.inf``, ``.nan``), as YAML 1.2 reads it; None for other text."""
    if PLAIN_INT.fullmatch(text):
        return int(text)
    if PLAIN_FLOAT.fullmatch(text):
        return float(text)
    inf = PLAIN_INF.fullmatch(text)
    if inf:
        return -math.inf if inf[1] == "-" else math.inf
    return math.nan if PLAIN_NAN.fullmatch(text) else None


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
