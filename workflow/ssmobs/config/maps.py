"""The cells of an observability map (issue 21) as scenario entries: a map's ``base`` with
its varied parameter set to each value and each ``T`` (:func:`cell_entries`); validated, as
every scenario, by :func:`ssmobs.config.validation.validate`.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

from .schema import scenario_schema, schema_problems

#: keys of a map's base that its cells set themselves
MAP_CELL_KEYS = ("name", "T", "K", "joint_map", "stan", "exact", "exact_K", "stan_batch_size")


def map_value_label(value: float) -> str:
    """A value of a map's varied parameter as cell names and captions write it."""
    return f"{value:g}"


def cell_entries(entry: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The scenario entries of every cell of one observability map, value-major then T
    (config order), with the schema's defaults filled in.

    A cell is the map's ``base`` with ``omega[vary]`` = value, its ``T`` and ``K``, the
    joint MAP on and Stan off; its name is ``<map>_<vary><value>_T<T>``."""
    base = dict(entry["base"])
    cells = []
    for value in entry["values"]:
        for T in entry["T"]:
            omega = {**base["omega"], entry["vary"]: value}
            cell = {
                **copy.deepcopy(base),
                "name": f"{entry['name']}_{entry['vary']}{map_value_label(value)}_T{T}",
                "omega": omega,
                "T": int(T),
                "K": int(entry["K"]),
                "joint_map": True,
                "stan": False,
            }
            schema_problems(cell, scenario_schema())  # fills in the defaults (checked elsewhere)
            cells.append(cell)
    return cells
