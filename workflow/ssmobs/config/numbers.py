"""Numbers in a config: numbers written as text, read as YAML 1.2 writes them, and the
non-finite numbers refused.

A quoted number of a config file (``K: '12'``) and every nested value of Snakemake's
``--config`` (which it parses with YAML's BaseLoader, as text) reach the check as strings:
:func:`numbers_from_text` reads those where the schema wants a number in the plain forms
of :mod:`ssmobs.config.schema` (:func:`~ssmobs.config.schema.plain_number`) and refuses in
one line the forms that YAML 1.1 and YAML 1.2 read differently (issue 61: ``'010'`` planned
K = 8, ``'4:00'`` T = 240).  :func:`nonfinite_problems` refuses NaN everywhere and infinite
numbers everywhere but a prior interval's bounds (issue 60).  Imports only
:mod:`ssmobs.config.schema`.
"""

from __future__ import annotations

import math
import re
from typing import Any

import yaml

from .schema import (
    MAX_REPR,
    PLAIN_DIGITS,
    YAML12_OTHER,
    _key,
    _types,
    number_form,
    plain_number,
    scenario_schema,
)

#: where a config may hold an infinite number: the bounds of a prior interval of a scenario
#: (``scenarios[i].prior.<name>[j]``) or of an observability map's base, a flat prior on a
#: half-line or the whole line (``[0, .inf]``, ``[-.inf, .inf]``)
INFINITE_ALLOWED: tuple[tuple[str | type, ...], ...] = (
    ("scenarios", int, "prior", str, int),
    ("observability_maps", int, "base", "prior", str, int),
)


def _infinite_allowed(path: tuple) -> bool:
    def fits(part: Any, form: str | type) -> bool:
        return part == form if isinstance(form, str) else isinstance(part, form)

    return any(
        len(path) == len(forms) and all(fits(p, f) for p, f in zip(path, forms))
        for forms in INFINITE_ALLOWED
    )


def nonfinite_problems(obj: Any, path: tuple = ()) -> list[str]:
    """Every NaN anywhere in the config, and every infinite number except a prior
    interval's bounds (:data:`INFINITE_ALLOWED`); JSON schema ranges let NaN pass."""
    if isinstance(obj, float) and not math.isfinite(obj):
        if math.isinf(obj) and _infinite_allowed(path):
            return []
        allowed = " (.inf or -.inf allowed as a bound)" if _infinite_allowed(path) else ""
        return [f"{_key(path)} = {obj!r}: must be a finite number{allowed}"]
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in nonfinite_problems(v, path + (k,))]
    if isinstance(obj, list):
        return [p for i, v in enumerate(obj) for p in nonfinite_problems(v, path + (i,))]
    return []


def _yaml12_number(text: str) -> int | float | None:
    """What YAML 1.2's core schema reads ``text`` as when it is a number, else None."""
    if not YAML12_OTHER.fullmatch(text):
        return plain_number(text)
    if text.startswith(("0o", "0x")):
        return int(text[2:], 8 if text[1] == "o" else 16)
    return int(text) if re.fullmatch(r"[-+]?[0-9]+", text) else float(text)


def _yaml11_number(text: str) -> int | float | None:
    """What YAML 1.1 (PyYAML, Snakemake's reader) reads ``text`` as, unquoted, when it is a
    number, else None."""
    tag = yaml.resolver.Resolver().resolve(yaml.ScalarNode, text, (True, False))
    if not tag.endswith((":int", ":float")):
        return None
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return None
    return value if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def number_text_problem(text: str) -> str:
    """Why the text ``text``, where a number is wanted, is refused: a form that YAML 1.1 or
    YAML 1.2 reads as a number but the two read differently (``010``: 8 and 10; ``4:00``: 240
    and no number); "" for plain decimal numbers and for text that is no number at all."""
    if plain_number(text) is not None:
        return ""
    v11, v12 = _yaml11_number(text), _yaml12_number(text)
    if v11 is None and v12 is None:
        return ""
    if v11 == v12:
        return (
            f"{number_form(text)} ({v11!r} in YAML 1.1 and 1.2), not a form a config takes; "
            f"allowed: {PLAIN_DIGITS}"
        )
    read11 = f"YAML 1.1 reads as {v11!r}" if v11 is not None else "YAML 1.1 reads as text"
    read12 = f"YAML 1.2 as {v12!r}" if v12 is not None else "YAML 1.2 as no number"
    read = f"{read11} and {read12}"
    return f"{number_form(text)}, which {read}; allowed: {PLAIN_DIGITS}"


def numbers_from_text(
    instance: Any, schema: dict, problems: list[str] | None = None, path: tuple = ()
) -> Any:
    """``instance`` with every string where the schema wants a number (and no string) read
    as the number it writes, in place (returns it); every string where it wants a boolean
    or null read as a YAML scalar of that type.

    Snakemake parses nested values of ``--config`` (and of a profile's ``config:``) with
    YAML's BaseLoader, i.e. as strings: ``--config 'stan={chains: 1}'`` gives
    ``{'chains': '1'}``; a quoted value of a config file (``K: '12'``) is a string too.  A
    number is read only from a plain decimal form (:func:`plain_number`, as YAML 1.2 reads
    it); a form that YAML 1.1 and 1.2 read differently (``010``, ``4:00``, ``1_0``, ``0x8``)
    is left and one line naming the key, the value and the allowed form is added to
    ``problems`` (:func:`number_text_problem`).  Other text stays and the schema names it.
    """
    problems = [] if problems is None else problems
    forms = schema.get("oneOf") or [schema]
    kinds = {k for form in forms for k in _types(form)}
    if isinstance(instance, str):
        if "string" in kinds or len(instance) > MAX_REPR:
            return instance
        if kinds & {"integer", "number"}:
            number = plain_number(instance)
            if number is not None:
                return number  # 1.0 for an integer: refused by the schema
            why = number_text_problem(instance)
            if why:
                problems.append(f"{_key(path)} = {instance!r}: {why}")
                return instance
        if kinds & {"boolean", "null"}:
            try:
                parsed = yaml.safe_load(instance)
            except yaml.YAMLError:
                return instance
            if (parsed is None and "null" in kinds) or (
                isinstance(parsed, bool) and "boolean" in kinds
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
                instance[key] = numbers_from_text(value, sub, problems, path + (key,))
    else:
        prefix = form.get("prefixItems") or []
        for i, value in enumerate(instance):
            sub = prefix[i] if i < len(prefix) else form.get("items")
            if isinstance(sub, dict):
                instance[i] = numbers_from_text(value, sub, problems, path + (i,))
    return instance


def text_number_problems(config: dict[str, Any], schema: dict[str, Any]) -> list[str]:
    """Read every string of ``config`` where the schema wants a number, boolean or null as
    that value, in place (:func:`numbers_from_text`: a quoted number
    of a config file, every nested value of Snakemake's ``--config``), an observability
    map's ``base`` as a scenario entry; one problem per number form that YAML 1.1 and 1.2
    read differently (``'010'``, ``'4:00'``)."""
    problems: list[str] = []
    numbers_from_text(config, schema, problems)
    for i, entry in enumerate(config.get("observability_maps") or []):
        if isinstance(entry, dict) and isinstance(entry.get("base"), dict):
            where = ("observability_maps", i, "base")
            numbers_from_text(entry["base"], scenario_schema(), problems, where)
    return problems
