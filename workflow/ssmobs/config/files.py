"""Strict reading of config files: duplicate keys, size, YAML alias expansion and numbers in
YAML 1.1 forms (``010``, ``4:00``, ``1_0``, ``0x8``) are refused.

:func:`read_config_file` reads one file; :func:`check_config_files` applies it to the files
Snakemake read itself (``--configfile``).  Imports only :mod:`ssmobs.config.schema`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import yaml

from .schema import (
    MAX_REPR,
    PLAIN_FLOAT,
    PLAIN_INF,
    PLAIN_INT,
    PLAIN_NAN,
    YAML12_ONLY,
    ConfigError,
    cut_text,
    number_form,
    short_repr,
)

#: largest config file read (bytes); a config has a few kB
MAX_CONFIG_BYTES = 5 * 2**20
#: most values (mappings, lists, scalars) a config may hold once YAML aliases are expanded;
#: a config has a few hundred, an alias "bomb" billions
MAX_CONFIG_VALUES = 100_000


#: what a config file must be, for the messages about files that are not one
CONFIG_TEXT = "a config file is YAML or JSON text (see config/README.md)"


class RefusedYAMLError(yaml.MarkedYAMLError):
    """Valid YAML that would silently mean something else (a duplicate key) or is too big."""


class ConfigLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate keys in a mapping (PyYAML keeps the last),
    documents whose YAML aliases expand to more than :data:`MAX_CONFIG_VALUES` values and
    numbers in forms only YAML 1.1 reads as numbers (:func:`_refuse_yaml11_numbers`)."""

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
        if node is not None:
            _refuse_yaml11_numbers(node, self, [], set())
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
                        f"key {short_repr(key)} appears twice in one mapping (also line "
                        f"{seen.start_mark.line + 1}); YAML would silently keep only the "
                        f"last value: remove one"
                    ),
                    problem_mark=key_node.start_mark,
                )
        return super().construct_mapping(node, deep=deep)


_INT_TAG, _FLOAT_TAG = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
_STR_TAG = "tag:yaml.org,2002:str"


def _refuse_yaml11_numbers(
    node: yaml.Node, loader: yaml.SafeLoader, path: list[str], seen: set[int]
) -> None:
    """Raise :class:`RefusedYAMLError` at the first number written in a form only YAML 1.1
    reads as a number (``010``, ``4:00``, ``1_0``, ``0x8``, ``0o7``): PyYAML reads them
    (8, 240, 10, 8, ...) where a person, or YAML 1.2, reads another value or a string."""
    if id(node) in seen:
        return
    seen.add(id(node))
    if isinstance(node, yaml.ScalarNode):
        where = f"key {'.'.join(path)!r}: " if path else ""
        if node.tag == _STR_TAG and node.style is None and YAML12_ONLY.fullmatch(node.value):
            raise RefusedYAMLError(
                problem=(
                    f"{where}{node.value} is a number in YAML 1.2 but a string here (YAML "
                    f"1.1); write the number in plain decimal digits (e.g. 1000 or 1.0e+3)"
                ),
                problem_mark=node.start_mark,
            )
        if node.tag not in (_INT_TAG, _FLOAT_TAG):
            return
        text = str(node.value)
        if PLAIN_INT.fullmatch(text) or (
            node.tag == _FLOAT_TAG
            and any(p.fullmatch(text) for p in (PLAIN_FLOAT, PLAIN_INF, PLAIN_NAN))
        ):
            return
        try:
            read = loader.construct_object(node)
        except (yaml.YAMLError, ValueError):
            read = None
        shown = f"it would run as {read!r}" if read is not None else "it is no number"
        raise RefusedYAMLError(
            problem=(
                f"{where}{text} is {number_form(text)}, a YAML 1.1 form that YAML 1.2 "
                f"reads otherwise ({shown}); write the number in plain decimal digits"
            ),
            problem_mark=node.start_mark,
        )
    if isinstance(node, yaml.SequenceNode):
        for i, child in enumerate(node.value):
            _refuse_yaml11_numbers(
                child, loader, [*path[:-1], f"{path[-1]}[{i}]"] if path else [f"[{i}]"], seen
            )
    elif isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            _refuse_yaml11_numbers(key_node, loader, path, seen)
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else "?"
            _refuse_yaml11_numbers(value_node, loader, [*path, str(key)], seen)


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
                f"key {short_repr(key)} appears twice in one JSON object; JSON readers "
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
    exist, is a directory, a device or a named pipe (never opened), cannot be read, is larger
    than :data:`MAX_CONFIG_BYTES`, is not text (not UTF-8, or with NUL bytes: a binary file),
    is not valid YAML, has a key twice in one mapping, or expands to more than
    :data:`MAX_CONFIG_VALUES` values.
    """
    path = Path(path)
    if not path.is_file():
        if path.is_dir():
            what = f"is a directory, not a file; {CONFIG_TEXT}"
        elif path.exists():  # a device (/dev/null), a named pipe or a socket: not read
            what = f"is not a regular file (a device, named pipe or socket); {CONFIG_TEXT}"
        else:
            what = "does not exist"
        raise ConfigError(f"config file {path} {what}")
    try:
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError(
                f"config file {path} has {size} bytes, more than the {MAX_CONFIG_BYTES} "
                f"bytes ({MAX_CONFIG_BYTES / 2**20:g} MiB) a config file may have; a config "
                f"has a few kB"
            )
        data = path.read_bytes()
    except OSError as err:
        raise ConfigError(f"config file {path} cannot be read: {err}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(
            f"config file {path} is not a text file (byte {data[err.start]:#04x} at "
            f"position {err.start} is not UTF-8); {CONFIG_TEXT}"
        ) from None
    if "\0" in text:
        raise ConfigError(
            f"config file {path} is not a text file (it holds a NUL byte at position "
            f"{text.index(chr(0))}); {CONFIG_TEXT}"
        )
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
        raise ConfigError(f"config file {path}{where}: {cut_text(problem, 2 * MAX_REPR)}") from None
    except yaml.YAMLError as err:  # one line: the reader's error spans two
        problem = cut_text(" ".join(str(err).split()))
        raise ConfigError(f"config file {path}: YAML syntax error: {problem}") from None
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


def count_values(obj: Any, limit: int = MAX_CONFIG_VALUES) -> int:
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
