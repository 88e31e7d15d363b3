"""What rule design_trajectories reads (Sec. III.A)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .frozen import TruthViews, design_set_path, frozen


@dataclass(frozen=True)
class TrajectoriesInputs(TruthViews):
    """Everything rule design_trajectories reads (Sec. III.A, Eq. (1)): the design sets' key
    (which with q, K, method and seed names the design set read, :meth:`design_set`), the
    scenario's name, model, true values, T, K, method and seed (written into the file)."""

    design: str
    scenario: str
    model: str
    #: the true parameters and initial state as the config gives them (frozen)
    omega: Any
    x0: Any
    T: int
    K: int
    method: str
    seed: int

    def design_set(self, q: int) -> str:
        """The design set of K disturbances of dimension ``q`` = (d + p) T the stage reads
        (the model gives d and p)."""
        return design_set_path(self.design, q, self.K, self.method, self.seed)


def trajectories_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, design: str, K: int
) -> TrajectoriesInputs:
    """The inputs of rule design_trajectories for the scenario ``entry`` at K trajectories,
    under the design sets of key ``design``."""
    return TrajectoriesInputs(
        design=design,
        scenario=str(entry["name"]),
        model=str(entry["model"]),
        omega=frozen(entry["omega"]),
        x0=frozen(entry["x0"]),
        T=int(entry["T"]),
        K=int(K),
        method=str(entry["method"]),
        seed=int(entry["seed"]),
    )
