"""What rule design_disturbances reads beside the set it makes (Sec. III.A)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class DesignSetsInputs:
    """Everything rule design_disturbances reads of the config (Sec. III.A): the ``design``
    block, the LCD optimiser's kernel-width bound ``b_max`` (``None``: the toolbox rule of
    :func:`ssmobs.design.lcd_distance.b_max_rule`).  A set's q, K, method and seed are its
    file's name in the folder these inputs key (:data:`~ssmobs.config.stage_inputs.DESIGN_SET`);
    the sets the choice of K and the maps make read the same block (their inputs'
    ``design_settings``) and lie beside."""

    #: as the config gives it (a ``2`` and a ``2.0`` are keyed apart, as before this object)
    b_max: float | None

    @property
    def design_config(self) -> dict[str, Any]:
        """The ``design`` block as the config gives it (what the optimiser is given)."""
        return {"b_max": self.b_max}


def design_sets_inputs(config: Mapping[str, Any]) -> DesignSetsInputs:
    """The inputs of rule design_disturbances of the validated ``config`` (one per config:
    the sets are shared by every scenario)."""
    return DesignSetsInputs(b_max=config["design"]["b_max"])


def design_sets_payload(inputs: DesignSetsInputs) -> dict[str, Any]:
    """What the design sets' key holds of ``inputs``: the ``design`` block, as the key held
    it before this object (so no design set, nor anything made from one, is made again)."""
    return {"design": inputs.design_config}
