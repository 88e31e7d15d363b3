"""What each stage reads, as one frozen object built from the scenario and the config
(issue 62): the rule passes it as its only param, ``run_<stage>(inputs, paths)`` reads
nothing else, and its content (:func:`inputs_payload`) with the stage's code is the stage's
cache key (:mod:`ssmobs.cache_keys`), so what is keyed is exactly what is read.

Each builder takes a validated scenario entry, the validated config and the paths of the
keyed files the stage reads (they carry the upstream keys); :data:`ssmobs.stage_table.STAGES`
names each stage's builder.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .blocks import joint_map_settings


def _frozen(value: Any) -> Any:
    """Plain config data with its mappings as sorted (key, value) pairs and lists as tuples,
    so an inputs object is immutable and compares by content."""
    if isinstance(value, Mapping):
        return tuple((str(k), _frozen(v)) for k, v in sorted(value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


def _prior_config(prior: Any) -> Any:
    """A frozen prior back as the config gives it (a mapping of variants or intervals)."""
    if isinstance(prior, tuple):
        return {k: list(v) if isinstance(v, tuple) else v for k, v in prior}
    return prior


def inputs_payload(inputs: Any) -> dict[str, Any]:
    """The content of an inputs object (its fields as plain data): what its key holds."""
    return {"stage_inputs": type(inputs).__name__, **dataclasses.asdict(inputs)}


@dataclass(frozen=True)
class JointMapInputs:
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

    @property
    def prior_config(self) -> Any:
        """The prior as :meth:`StateSpaceModel.prior_bounds` takes it."""
        return _prior_config(self.prior)

    @property
    def settings_config(self) -> dict[str, Any]:
        """The merged ``joint_map`` block as a mapping."""
        return dict(self.settings)


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
        prior=_frozen(entry.get("prior")),
        settings=_frozen(joint_map_settings(entry, config["joint_map"])),
    )


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
        return _prior_config(self.prior)

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
        prior=_frozen(entry.get("prior")),
        settings=_frozen(config["exact_marginal"]),
    )
