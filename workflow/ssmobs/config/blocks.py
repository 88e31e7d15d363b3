"""The settings blocks of a scenario: the config's block with the scenario's own values over
it, merged once here for the stages that compute with them and the cache keys that hold
them (:mod:`ssmobs.cache_keys`), and the one reader of the gradient path
(:func:`stan_gradients`).  Imports nothing, so a key's code stays this module.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def joint_map_settings(
    entry: Mapping[str, Any], block: Mapping[str, Any], *, single_start: bool = False
) -> dict[str, Any]:
    """The joint-MAP settings of a scenario entry (Sec. III.B): the config's ``joint_map``
    block with the entry's own start of the states (``joint_map_start``) and, where it sets
    one, its number of starts (``joint_map_n_starts``).  ``single_start``: the paper's one
    start alone, without ``n_starts`` (the choice of K's points).  The one merge of the
    block: the stages compute with it and the cache keys hold it."""
    own = {**block, "start_states": entry["joint_map_start"]}
    if single_start:
        own.pop("n_starts", None)
    elif entry.get("joint_map_n_starts") is not None:
        own["n_starts"] = entry["joint_map_n_starts"]
    return own


def stan_settings(entry: Mapping[str, Any], block: Mapping[str, Any]) -> dict[str, Any]:
    """The NUTS settings of a scenario entry (Sec. III.C): the config's ``stan`` block with
    the entry's own ``stan_settings`` over it.  The one merge of the block: the stage
    samples with it and the cache keys hold it."""
    return {**block, **(entry.get("stan_settings") or {})}


#: the values of the config key ``stan.gradients``
GRADIENT_PATHS: tuple[str, ...] = ("autodiff", "analytic")


def stan_gradients(block: Mapping[str, Any]) -> str:
    """The config key ``stan.gradients`` of a ``stan`` block (``autodiff`` where it is not
    set, the schema's default): how NUTS gets the gradient of a model with its own
    ``stan/<model>.stan``.  The one reader of the key; ValueError for another value."""
    gradients = block.get("gradients", "autodiff")
    if gradients not in GRADIENT_PATHS:
        raise ValueError(f"stan.gradients: {gradients!r}; allowed: {', '.join(GRADIENT_PATHS)}")
    return str(gradients)


def gradient_path(block: Mapping[str, Any], own_program: bool) -> str:
    """The gradient path NUTS takes for a model: :func:`stan_gradients` for a model with its
    own Stan program (``own_program``), ``analytic`` for the program generated for a model
    without one, whatever the key."""
    return stan_gradients(block) if own_program else "analytic"
