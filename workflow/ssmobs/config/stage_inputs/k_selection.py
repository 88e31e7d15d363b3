"""What the choice of K reads (Sec. IV.A): every point V_{K_i} of a scenario, one point, and
rule k_selection_grid, which computes the points of one grid."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..blocks import joint_map_settings
from .frozen import ScenarioViews, design_set_path, frozen


@dataclass(frozen=True)
class KSelectionPointsInputs(ScenarioViews):
    """Everything a point V_{K_i} of a scenario reads but its place in a grid (Sec. IV.A):
    the design sets' key and settings (the job makes a missing set), the model, its true
    values, T and prior, and the merged joint-MAP settings of the paper's one start.  Its
    content is the key of the points' folder
    (:meth:`ssmobs.cache_keys.CacheKeys.k_selection_points`), which the k_selection entries
    on one scenario share; no scenario name, no grid."""

    design: str
    design_settings: tuple[tuple[str, Any], ...]
    model: str
    #: the true parameters and initial state as the config gives them (frozen)
    omega: Any
    x0: Any
    T: int
    #: the prior as the config gives it (a variant name, or per-parameter pairs)
    prior: Any
    #: the joint-MAP settings as sorted (key, value) pairs (one start)
    settings: tuple[tuple[str, Any], ...]

    def point(self, K: int, method: str, sets: str, seed: int) -> KSelectionPointInputs:
        """The inputs of the point of K_i = ``K`` of the grid (method, set variant, seed)."""
        return KSelectionPointInputs(self, int(K), str(method), str(sets), int(seed))


@dataclass(frozen=True)
class KSelectionPointInputs:
    """Everything one point V_{K_i} reads (Sec. IV.A): what every point of its scenario
    reads (``points``, the key of their folder) and its place in a grid, K_i, the
    disturbance method, the set variant and the run's seed, which its file's name in that
    folder holds (:attr:`file`)."""

    points: KSelectionPointsInputs
    K: int
    method: str
    sets: str
    seed: int

    @property
    def file(self) -> str:
        """The point's file below the points' folder: its grid's folder and ``K<K_i>.json``."""
        return f"{self.method}_{self.sets}_seed{self.seed}/K{self.K}.json"

    def design_set(self, q: int, set_seed: int) -> str:
        """The design set of K_i disturbances of dimension ``q`` = (d + p) T drawn from
        ``set_seed`` (:func:`ssmobs.k_selection.set_seed` of the run's seed, K_i and the set
        variant) that the point reads; the model gives d and p."""
        return design_set_path(self.points.design, q, self.K, self.method, set_seed)


@dataclass(frozen=True)
class KSelectionGridInputs:
    """Everything rule k_selection_grid reads (Sec. IV.A) for one k_selection entry: the
    folder of its cached points (its key is the content of ``points_inputs`` with the
    code) and what every point there reads, the scenario's name (written into the grids),
    the grid of K_i and each grid file's name with its method, set variant and seed."""

    points: str
    points_inputs: KSelectionPointsInputs
    scenario: str
    K_grid: tuple[int, ...]
    #: (grid file's name, method, set variant, seed), one per job
    grids: tuple[tuple[str, str, str, int], ...]

    def grid_of(self, file: str) -> tuple[str, str, int]:
        """The method, set variant and seed of the grid written to the file ``file``."""
        return next((m, sets, seed) for f, m, sets, seed in self.grids if f == file)


def k_selection_points_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, design: str
) -> KSelectionPointsInputs:
    """What every point of the k_selection entry ``entry`` reads, under the design sets of
    key ``design``."""
    sc = next(s for s in config["scenarios"] if s["name"] == entry["scenario"])
    return KSelectionPointsInputs(
        design=design,
        design_settings=frozen(config["design"]),
        model=str(sc["model"]),
        omega=frozen(sc["omega"]),
        x0=frozen(sc["x0"]),
        T=int(sc["T"]),
        prior=frozen(sc.get("prior")),
        # the scenario's start of the states, the paper's one start
        settings=frozen(joint_map_settings(sc, config["joint_map"], single_start=True)),
    )


def k_selection_grid_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, points: str, design: str
) -> KSelectionGridInputs:
    """The inputs of rule k_selection_grid for the k_selection entry ``entry``; ``points``:
    the points' folder, keyed by :func:`k_selection_points_inputs` of the same entry."""
    return KSelectionGridInputs(
        points=points,
        points_inputs=k_selection_points_inputs(entry, config, design=design),
        scenario=str(entry["scenario"]),
        K_grid=tuple(int(K) for K in entry["K_grid"]),
        grids=tuple(
            (f"{method}_{sets}_seed{seed}.json", str(method), str(sets), int(seed))
            for method in entry["methods"]
            for sets in entry["sets"]
            for seed in entry["seeds"]
        ),
    )
