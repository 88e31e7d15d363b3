"""Config values frozen into an inputs object and back (sorted pairs, tuples), the content
an inputs object is keyed by, and the paths of the design sets the stages read."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any


def frozen(value: Any) -> Any:
    """Plain config data with its mappings as sorted (key, value) pairs and lists as tuples,
    so an inputs object is immutable and compares by content."""
    if isinstance(value, Mapping):
        return tuple((str(k), frozen(v)) for k, v in sorted(value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(frozen(v) for v in value)
    return value


def prior_config_of(prior: Any) -> Any:
    """A frozen prior back as the config gives it (a mapping of variants or intervals)."""
    if isinstance(prior, tuple):
        return {k: list(v) if isinstance(v, tuple) else v for k, v in prior}
    return prior


def plain(value: Any) -> Any:
    """A frozen value back as plain config data: (name, value) pairs as a mapping, other
    tuples as lists."""
    if isinstance(value, tuple):
        if value and all(
            isinstance(v, tuple) and len(v) == 2 and isinstance(v[0], str) for v in value
        ):
            return {k: plain(v) for k, v in value}
        return [plain(v) for v in value]
    return value


class TruthViews:
    """The frozen true values of an inputs object back as the config gives them."""

    omega: Any
    x0: Any

    @property
    def omega_config(self) -> Any:
        """The true parameters as the config gives them (a mapping or a list)."""
        return plain(self.omega)

    @property
    def x0_config(self) -> Any:
        """The true initial state as the config gives it (a number or a list)."""
        return plain(self.x0)


class JointMapViews:
    """The frozen prior and joint-MAP settings of an inputs object back as the config gives
    them."""

    prior: Any
    settings: tuple[tuple[str, Any], ...]

    @property
    def prior_config(self) -> Any:
        """The prior as :meth:`StateSpaceModel.prior_bounds` takes it."""
        return prior_config_of(self.prior)

    @property
    def settings_config(self) -> dict[str, Any]:
        """The merged ``joint_map`` block as a mapping."""
        return dict(self.settings)


class ScenarioViews(TruthViews, JointMapViews):
    """The frozen design block, true values, prior and joint-MAP settings of an inputs object
    that holds a scenario's values (a point of the choice of K, a cell of a map) back as the
    config gives them."""

    design_settings: tuple[tuple[str, Any], ...]

    @property
    def design_config(self) -> dict[str, Any]:
        """The ``design`` block as the config gives it."""
        return {k: plain(v) for k, v in self.design_settings}


#: the folder of the design sets of one design key (rule design_disturbances)
DESIGN_DIR = "results/shared/design_disturbances/{key}"
#: one design set there
DESIGN_SET = DESIGN_DIR + "/q{q}_K{K}_{method}_seed{seed}.nc"


def design_set_path(design: str, q: int, K: int, method: str, seed: int) -> str:
    """The design set of q x K disturbances by ``method`` from ``seed`` under design key
    ``design``."""
    return DESIGN_SET.format(key=design, q=q, K=K, method=method, seed=seed)


def inputs_payload(inputs: Any) -> dict[str, Any]:
    """The content of an inputs object (its fields as plain data): what its key holds."""
    return {"stage_inputs": type(inputs).__name__, **dataclasses.asdict(inputs)}
