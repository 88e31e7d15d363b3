"""A stand-in for ssmobs.models.propriety's answer, for tests of the tables that show it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class FakePropriety:
    """The contract's ``Propriety``: reasons inside the support (improper) and at its ends."""

    improper: tuple[str, ...] = ()
    edge: tuple[str, ...] = ()

    @property
    def is_improper(self) -> bool:
        return bool(self.improper)

    def label(self) -> str:
        return "improper: " + "; ".join(self.improper) if self.improper else ""


def analysis(**by_model: FakePropriety) -> Callable[[Any, Any], FakePropriety]:
    """(model, bounds) -> the answer given for the model's slug (proper for the others)."""
    return lambda model, bounds: by_model.get(model.slug, FakePropriety())


#: every posterior proper, no edge finding
PROPER = analysis()
