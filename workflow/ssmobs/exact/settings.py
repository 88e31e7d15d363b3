"""Grid sizes and tolerances of the exact marginal stage (:mod:`ssmobs.exact.marginal`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

#: the quantiles every exact summary reports (of Omega's components and of the states)
QUANTILES = (0.05, 0.95)


@dataclass(frozen=True)
class ExactSettings:
    """Grid sizes and tolerances of :func:`ssmobs.exact.marginal.exact_marginal`: the config
    block ``exact_marginal`` (workflow/schemas/config.schema.yaml describes every field; a
    test keeps the two equal).

    ``coarse_nodes``, ``state_nodes`` and ``state_thin`` hold one value per number m = 1..4
    of parameters; ``state_nodes`` nodes per axis carry the state mixtures (on their own
    box, :func:`ssmobs.exact.state_mixtures.state_box`) and the fine Omega grid has
    ``(state_nodes - 1) * state_thin + 1`` nodes per axis: refining the state grid refines
    the Omega grid too.
    """

    coarse_nodes: tuple = (400, 48, 16, 9)
    state_nodes: tuple = (41, 21, 11, 7)
    state_thin: tuple = (10, 3, 2, 2)
    box_sd: float = 7.0
    state_tail_mass: float = 1e-6
    face_drop: float = 20.0
    max_widen: int = 4
    margin: float = 1e-6
    half_line_range: tuple = (1e-4, 1e4)
    spline_refine: int = 16
    mixture_mass: float = 0.9999999999
    newton_iter: int = 30
    spike_distance: float = 1e-6
    spike_tol: float = 1e-3
    n_starts: int = 4
    mixture_iter: int = 200
    mode_iter: int = 12
    valley_nodes: int = 200
    chunk_elements: int = 4_000_000

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> ExactSettings:
        """From the validated config block (its lists become tuples)."""
        fields: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in values.items()
        }
        return cls(**fields)

    @property
    def max_params(self) -> int:
        """The largest m the per-m settings cover."""
        return min(len(self.coarse_nodes), len(self.state_nodes), len(self.state_thin))

    def coarse(self, m: int) -> int:
        """Coarse grid nodes per axis for m parameters."""
        return int(self.coarse_nodes[m - 1])

    def state(self, m: int) -> int:
        """Nodes per axis of the grid carrying the state mixtures for m parameters."""
        return int(self.state_nodes[m - 1])

    def thin(self, m: int) -> int:
        """The fine grid's nodes per axis are (state_nodes - 1) x this + 1, for m parameters."""
        return int(self.state_thin[m - 1])

    def fine_nodes(self, m: int) -> int:
        """Fine grid nodes per axis for m parameters."""
        return (self.state(m) - 1) * self.thin(m) + 1
