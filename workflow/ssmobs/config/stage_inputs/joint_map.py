"""What rule joint_map reads (Sec. III.B)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..blocks import joint_map_settings
from .frozen import JointMapViews, frozen


@dataclass(frozen=True)
class JointMapInputs(JointMapViews):
    """Everything rule joint_map reads (Sec. III.B): the scenario's design trajectories
    (their keyed path), the scenario's name, model, T, method and seed (written into the
    summary), its prior and its merged ``joint_map`` block
    (:func:`ssmobs.config.blocks.joint_map_settings`)."""

    trajectories: str
    scenario: str
    model: str
    T: int
    method: str
    seed: int
    #: the prior as the config gives it (a variant name, or per-parameter pairs)
    prior: Any
    #: the joint-MAP settings as sorted (key, value) pairs
    settings: tuple[tuple[str, Any], ...]


def joint_map_inputs(
    entry: Mapping[str, Any], config: Mapping[str, Any], *, trajectories: str
) -> JointMapInputs:
    """The inputs of rule joint_map for the scenario ``entry``."""
    return JointMapInputs(
        trajectories=trajectories,
        scenario=str(entry["name"]),
        model=str(entry["model"]),
        T=int(entry["T"]),
        method=str(entry["method"]),
        seed=int(entry["seed"]),
        prior=frozen(entry.get("prior")),
        settings=frozen(joint_map_settings(entry, config["joint_map"])),
    )
