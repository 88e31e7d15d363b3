"""What rule k_selection_grid reads (Sec. IV.A)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..blocks import joint_map_settings
from .frozen import frozen, plain, prior_config_of


@dataclass(frozen=True)
class KSelectionGridInputs:
    """Everything rule k_selection_grid reads (Sec. IV.A) for one k_selection entry: the
    folder of its cached points V_{K_i} (keyed without the grid and the entry, so entries
    on the same scenario share them), the design sets' key and settings (the job makes its
    sets), the scenario's name (written into the grids), model, true values, T and prior,
    the merged joint-MAP settings of the paper's one start, the grid of K_i and each grid
    file's name with its method, set variant and seed."""

    points: str
    design: str
    design_settings: tuple[tuple[str, Any], ...]
    scenario: str
    model: str
    omega: Any
    x0: Any
    T: int
    prior: Any
    #: the joint-MAP settings as sorted (key, value) pairs (one start)
    settings: tuple[tuple[str, Any], ...]
    K_grid: tuple[int, ...]
    #: (grid file's name, method, set variant, seed), one per job
    grids: tuple[tuple[str, str, str, int], ...]

    @property
    def settings_config(self) -> dict[str, Any]:
        """The merged ``joint_map`` block as a mapping."""
        return dict(self.settings)

    @property
    def design_config(self) -> dict[str, Any]:
        """The ``design`` block as the config gives it."""
        return {k: plain(v) for k, v in self.design_settings}

    @property
    def scenario_config(self) -> dict[str, Any]:
        """The scenario entry the points compute with (its K, method and seed are set per
        point)."""
        prior = prior_config_of(self.prior)
        return {
            "name": self.scenario,
            "model": self.model,
            "omega": plain(self.omega),
            "x0": plain(self.x0),
            "T": self.T,
            "K": self.K_grid[0],
            **({} if prior is None else {"prior": prior}),
            "joint_map_start": self.settings_config["start_states"],
        }

    def grid_of(self, file: str) -> tuple[str, str, int]:
        """The method, set variant and seed of the grid written to the file ``file``."""
        return next((m, sets, seed) for f, m, sets, seed in self.grids if f == file)


def k_selection_grid_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, points: str, design: str
) -> KSelectionGridInputs:
    """The inputs of rule k_selection_grid for the k_selection entry ``entry``."""
    sc = next(s for s in config["scenarios"] if s["name"] == entry["scenario"])
    return KSelectionGridInputs(
        points=points,
        design=design,
        design_settings=frozen(config["design"]),
        scenario=str(sc["name"]),
        model=str(sc["model"]),
        omega=frozen(sc["omega"]),
        x0=frozen(sc["x0"]),
        T=int(sc["T"]),
        prior=frozen(sc.get("prior")),
        settings=frozen(joint_map_settings(sc, config["joint_map"], single_start=True)),
        K_grid=tuple(int(K) for K in entry["K_grid"]),
        grids=tuple(
            (f"{method}_{sets}_seed{seed}.json", str(method), str(sets), int(seed))
            for method in entry["methods"]
            for sets in entry["sets"]
            for seed in entry["seeds"]
        ),
    )
