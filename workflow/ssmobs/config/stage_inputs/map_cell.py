"""What an observability map reads (issue 21): one cell, and rule observability_map_cells,
which computes the cells of one map."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..blocks import joint_map_settings
from .frozen import ScenarioViews, design_set_path, frozen, plain

#: the folder of the cached cells of every observability map, ``<key>.json`` each (by their
#: own keys, shared by maps and profiles)
MAP_CELLS_DIR = "results/observability_map/cells"


@dataclass(frozen=True)
class MapCellInputs(ScenarioViews):
    """Everything one cell of an observability map reads: the design sets' key and
    settings (the job makes a missing set), the model, its true values (the map's base with
    one parameter set to the cell's value), T, K, the disturbance method and seed (Sec.
    III.A), the prior, the merged joint-MAP settings (Sec. III.B; the base's start and
    number of starts) and the exact stage's settings where the map runs it, else None.  Its
    content is the cell's key (:meth:`ssmobs.cache_keys.CacheKeys.map_cells`): no name, no
    map, so a cell two maps share, or that an extended grid keeps, keeps its key."""

    design: str
    design_settings: tuple[tuple[str, Any], ...]
    model: str
    #: the true parameters and initial state as the config gives them (frozen)
    omega: Any
    x0: Any
    T: int
    K: int
    method: str
    seed: int
    #: the prior as the config gives it (a variant name, or per-parameter pairs)
    prior: Any
    #: the joint-MAP settings as sorted (key, value) pairs
    settings: tuple[tuple[str, Any], ...]
    #: the ``exact_marginal`` block as sorted (key, value) pairs, or None (no exact stage)
    exact: tuple[tuple[str, Any], ...] | None

    @property
    def exact_config(self) -> dict[str, Any] | None:
        """The ``exact_marginal`` block as the config gives it, or None."""
        return None if self.exact is None else {k: plain(v) for k, v in self.exact}

    def design_set(self, q: int) -> str:
        """The design set of K disturbances of dimension ``q`` = (d + p) T the cell reads
        (the model gives d and p)."""
        return design_set_path(self.design, q, self.K, self.method, self.seed)


@dataclass(frozen=True)
class MapCellsInputs:
    """Everything rule observability_map_cells reads for one map: its name and varied
    parameter (columns of its table), the folder of the cached cells and every cell,
    value-major then T, with its key (:meth:`ssmobs.cache_keys.CacheKeys.map_cells`), which
    names its file there (:meth:`cell_file`)."""

    map: str
    vary: str
    cells_dir: str
    #: (the cell's key, its inputs), one per cell
    cells: tuple[tuple[str, MapCellInputs], ...]

    def cell_file(self, key: str) -> str:
        """The cached file of the cell of key ``key``."""
        return f"{self.cells_dir}/{key}.json"


def map_cell_inputs(
    cell: Mapping[str, Any], config: Mapping[str, Any], *, design: str, exact: bool
) -> MapCellInputs:
    """The inputs of the cell ``cell`` (a scenario entry of
    :func:`ssmobs.config.maps.cell_entries`) under the design sets of key ``design``;
    ``exact``: the map runs the exact stage."""
    return MapCellInputs(
        design=design,
        design_settings=frozen(config["design"]),
        model=str(cell["model"]),
        omega=frozen(cell["omega"]),
        x0=frozen(cell["x0"]),
        T=int(cell["T"]),
        K=int(cell["K"]),
        method=str(cell["method"]),
        seed=int(cell["seed"]),
        prior=frozen(cell.get("prior")),
        settings=frozen(joint_map_settings(cell, config["joint_map"])),
        exact=frozen(config["exact_marginal"]) if exact else None,
    )


def map_cells_inputs(
    entry: Mapping[str, Any], cells: Sequence[tuple[str, MapCellInputs]]
) -> MapCellsInputs:
    """The inputs of rule observability_map_cells for the map ``entry``, whose cells are
    ``cells`` (each cell's key and inputs, in the map's order), cached in
    :data:`MAP_CELLS_DIR`."""
    return MapCellsInputs(
        map=str(entry["name"]),
        vary=str(entry["vary"]),
        cells_dir=MAP_CELLS_DIR,
        cells=tuple(cells),
    )
