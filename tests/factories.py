"""Scenario entries the tests share, written once.

:func:`same_a09` is the paper's model Same at a = 0.9, x0 = 8 (Sec. IV.B, Table II), the
setting most tests need a small valid scenario of."""

from __future__ import annotations

from typing import Any


def same_a09(**changes: Any) -> dict[str, Any]:
    """A config entry of model Same, Omega = {a: 0.9}, x0 = 8, named ``s`` with T = 4 and
    K = 4; ``changes`` set other values or add keys, a value of None leaves the key out.
    A new dict (and Omega) at every call, so a test may change it."""
    entry: dict[str, Any] = {
        "name": "s",
        "model": "same",
        "omega": {"a": 0.9},
        "x0": 8,
        "T": 4,
        "K": 4,
    }
    entry.update(changes)
    return {k: v for k, v in entry.items() if v is not None}
