"""What rule exact_marginal reads (issue 11)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .frozen import frozen, prior_config_of


@dataclass(frozen=True)
class ExactInputs:
    """Everything rule exact_marginal reads (issue 11): a scenario's design trajectories at
    K (their keyed path), the scenario's name, its prior and the config block
    ``exact_marginal``."""

    trajectories: str
    scenario: str
    #: the prior as the config gives it (a variant name, or per-parameter pairs)
    prior: Any
    #: the ``exact_marginal`` block as sorted (key, value) pairs
    settings: tuple[tuple[str, Any], ...]

    @property
    def prior_config(self) -> Any:
        """The prior as :meth:`StateSpaceModel.prior_bounds` takes it."""
        return prior_config_of(self.prior)

    @property
    def settings_config(self) -> dict[str, Any]:
        """The ``exact_marginal`` block as the config gives it (its lists as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self.settings}


def exact_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, trajectories: str
) -> ExactInputs:
    """The inputs of rule exact_marginal for the scenario ``entry`` (at the K of
    ``trajectories``)."""
    return ExactInputs(
        trajectories=trajectories,
        scenario=str(entry["name"]),
        prior=frozen(entry.get("prior")),
        settings=frozen(config["exact_marginal"]),
    )
