"""The configuration reference page of the documentation, generated from the config schema.

``python -m ssmobs.config.reference`` writes ``docs/reference/configuration.md``: one
section per top-level key of ``workflow/schemas/config.schema.yaml`` and one table row per
key at any depth (type, default, allowed values, description), so the page cannot drift
from the schema.  ``--check`` writes nothing and exits 1 when the page differs from what
the schema gives (``make docs`` runs it; ``tests/unit/config/test_config_reference.py`` too).

Key paths: ``a.b`` is the key ``b`` of the mapping ``a``; ``a[].b`` the key ``b`` of every
entry of the list ``a``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from .schema import SCHEMA_PATH, load_schema

#: the repository this package belongs to
REPO_DIR = Path(__file__).resolve().parents[3]
#: the generated page
PAGE_PATH = REPO_DIR / "docs" / "reference" / "configuration.md"
#: the command that writes the page
COMMAND = "python -m ssmobs.config.reference"

_KIND_WORDS = {"object": "mapping", "array": "list"}


@dataclass(frozen=True)
class KeyRow:
    """One key of the schema as the reference table shows it.

    Attributes
    ----------
    path : the key's path, e.g. ``stan.chains`` or ``k_selection[].K_grid.step``.
    kind : its type in words (``integer or null``, ``list of string``, ...).
    default : the default, ``required``, or ``–`` (neither).
    allowed : ranges, enumerations, patterns and sizes; ``–`` when the type says it all.
    description : the schema's ``description`` on one line, ``–`` when there is none.
    """

    path: str
    kind: str
    default: str
    allowed: str
    description: str


def _value(value: Any) -> str:
    """A config value as it is written in YAML flow style (strings quoted only where YAML
    would read them as something else, e.g. ``"true"``)."""
    if isinstance(value, str):
        plain = value != "" and yaml.safe_load(value) == value and value.strip() == value
        return value if plain else json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_value(v)}" for k, v in value.items()) + "}"
    return json.dumps(value)


def _code(value: Any) -> str:
    return f"`{_value(value)}`"


def kind(schema: Mapping[str, Any]) -> str:
    """The type of the values ``schema`` admits, in words."""
    branches = schema.get("oneOf") or schema.get("anyOf")
    if branches:
        return " or ".join(kind(b) for b in branches)
    types = schema.get("type")
    if types is None:
        return "any"
    if isinstance(types, list):
        return " or ".join(kind({**schema, "type": t}) for t in types)
    if types == "array" and isinstance(schema.get("items"), Mapping):
        return f"list of {kind(schema['items'])}"
    extra = schema.get("additionalProperties")
    if types == "object" and isinstance(extra, Mapping):
        return f"mapping of names to {kind(extra)}"
    return str(_KIND_WORDS.get(types, types))


def allowed(schema: Mapping[str, Any]) -> list[str]:
    """The constraints of ``schema`` beyond its type: enumerations, bounds, patterns, sizes
    (for a ``oneOf``, each branch's, labelled by its type)."""
    parts: list[str] = []
    for branch in schema.get("oneOf") or schema.get("anyOf") or ():
        own = allowed(branch)
        if own:
            parts.append(f"{kind(branch)}: {', '.join(own)}")
    if "enum" in schema:
        parts.append("one of " + ", ".join(_code(v) for v in schema["enum"]))
    for word, sign in (
        ("minimum", "≥"),
        ("exclusiveMinimum", ">"),
        ("maximum", "≤"),
        ("exclusiveMaximum", "<"),
    ):
        if word in schema:
            parts.append(f"{sign} {_value(schema[word])}")
    if "pattern" in schema:
        parts.append(f"matches `{schema['pattern']}`")
    lo, hi = schema.get("minItems"), schema.get("maxItems")
    if lo is not None and lo == hi:
        parts.append(f"exactly {lo} item{'s' if lo != 1 else ''}")
    else:
        if lo is not None:
            parts.append(f"at least {lo} item{'s' if lo != 1 else ''}")
        if hi is not None:
            parts.append(f"at most {hi} item{'s' if hi != 1 else ''}")
    if schema.get("uniqueItems"):
        parts.append("no item twice")
    items = schema.get("items")
    if isinstance(items, Mapping) and "properties" not in items:
        own = allowed(items)
        if own:
            parts.append(f"items {', '.join(own)}")
    return parts


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _default(schema: Mapping[str, Any], required: bool) -> str:
    if "default" in schema:
        return _code(schema["default"])
    return "required" if required else "–"


def walk(schema: Mapping[str, Any], prefix: str = "") -> Iterator[KeyRow]:
    """One :class:`KeyRow` per key under ``schema``, depth first, in the schema's order.

    Parameters
    ----------
    schema : a (sub)schema of the config schema.
    prefix : the path of ``schema`` itself (``""`` for the whole config).
    """
    required = set(schema.get("required", ()))
    for name, sub in (schema.get("properties") or {}).items():
        path = f"{prefix}.{name}" if prefix else name
        yield KeyRow(
            path=path,
            kind=kind(sub),
            default=_default(sub, name in required),
            allowed=", ".join(allowed(sub)) or "–",
            description=_one_line(sub.get("description", "")) or "–",
        )
        yield from _below(sub, path)


def _below(schema: Mapping[str, Any], path: str) -> Iterator[KeyRow]:
    """The rows of the keys inside ``schema`` (its properties, its list entries' and its
    ``oneOf`` branches')."""
    yield from walk(schema, path)
    items = schema.get("items")
    if isinstance(items, Mapping):
        yield from _below(items, f"{path}[]")
    for branch in schema.get("oneOf") or schema.get("anyOf") or ():
        yield from _below(branch, path)


def _cell(text: str) -> str:
    """``text`` safe inside a Markdown table cell (no column break, no HTML tag)."""
    return text.replace("|", "\\|").replace("<", "&lt;")


def render(schema: Mapping[str, Any]) -> str:
    """The reference page for ``schema`` (Markdown)."""
    schema_file = SCHEMA_PATH.relative_to(REPO_DIR).as_posix()
    lines = [
        "# Configuration reference",
        "",
        f"<!-- Generated by `{COMMAND}` from {schema_file}. Do not edit: change the",
        "schema and rerun the command (a unit test compares this page with the schema). -->",
        "",
        f"Every key of the config schema `{schema_file}`, generated from it by `{COMMAND}`.",
        "What the keys mean together, the checks a schema cannot express and the profiles are",
        "in the [configuration guide](config-guide.md).",
        "",
        _one_line(schema.get("description", "")),
        "",
        "Key paths: `a.b` is the key `b` of the mapping `a`, `a[].b` the key `b` of every entry",
        "of the list `a`. *default*: the value filled in when the key is absent; *required*: the",
        "key must be given; *–*: neither.",
    ]
    required = set(schema.get("required", ()))
    for name, sub in (schema.get("properties") or {}).items():
        lines += [
            "",
            f"## `{name}`",
            "",
            "| key | type | default | allowed | description |",
            "|---|---|---|---|---|",
        ]
        top = {"properties": {name: sub}, "required": [name] if name in required else []}
        for row in walk(top):
            cells = (f"`{row.path}`", row.kind, row.default, row.allowed, row.description)
            lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


def schema_paths(schema: Mapping[str, Any]) -> list[str]:
    """The path of every key of ``schema``, as the page writes them."""
    return [row.path for row in walk(schema)]


def main(argv: Sequence[str] | None = None) -> int:
    """Write (or with ``--check``, compare) the configuration reference page."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--output", type=Path, default=PAGE_PATH, help="the page to write")
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if the page is not current"
    )
    args = parser.parse_args(argv)
    page = render(load_schema())
    if args.check:
        current = args.output.read_text() if args.output.exists() else None
        if current != page:
            print(f"{args.output} is not generated from the current schema: run {COMMAND}")
            return 1
        return 0
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
