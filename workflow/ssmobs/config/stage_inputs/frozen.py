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
