"""The six state space models of Section IV, by slug.

A new model is one module here (a :class:`~ssmobs.models.base.StateSpaceModel` subclass)
plus one ``stan/<slug>.stan`` program, registered in :data:`MODELS`.
"""

from __future__ import annotations

from .base import PRIOR_VARIANTS, PriorBounds, StateSpaceModel
from .same import Same
from .sep import Sep
from .sep_d1_p2 import SepD1P2
from .sep_d2_p1 import SepD2P1
from .sep_mult import SepMult
from .sep_ranwalk import SepRanWalk

MODELS: dict[str, StateSpaceModel] = {
    m.slug: m for m in (Same(), Sep(), SepD2P1(), SepD1P2(), SepRanWalk(), SepMult())
}


def get_model(slug: str) -> StateSpaceModel:
    """The model with this slug; ValueError listing the known slugs otherwise."""
    try:
        return MODELS[slug]
    except KeyError:
        raise ValueError(f"unknown model '{slug}'; known models: {sorted(MODELS)}") from None


__all__ = ["MODELS", "PRIOR_VARIANTS", "PriorBounds", "StateSpaceModel", "get_model"]
