"""Deterministic seeds: every random stream comes from (scenario seed, stage, k).

Seeds never depend on batch number or job order, so ``--cores 1`` and ``--cores 2``
give identical results (style guide, Sec. 4).
"""

from __future__ import annotations

import zlib

import numpy as np

#: largest seed accepted (an unsigned 32-bit integer: what Stan and NumPy's legacy generators
#: take, and far inside the int64 of NetCDF attributes, where seeds are stored)
MAX_SEED = 2**32 - 1

#: fixed stage tags, so that different stages never share a stream
STAGES = {"disturbances": 1, "nuts": 2}


def _tag(text: str) -> int:
    return zlib.crc32(text.encode())


def check_seed(seed: int) -> int:
    """``seed`` as an int if it is an integer in [0, MAX_SEED]; ValueError otherwise."""
    if (
        isinstance(seed, bool)
        or not isinstance(seed, (int, np.integer))
        or not (0 <= seed <= MAX_SEED)
    ):
        raise ValueError(f"seed must be an integer in [0, {MAX_SEED}]; got {seed!r}")
    return int(seed)


def seed_sequence(seed: int, stage: str, *keys: int | str) -> np.random.SeedSequence:
    """SeedSequence for ``stage`` and keys (e.g. scenario name, trajectory index k)."""
    check_seed(seed)
    spawn = [STAGES[stage]] + [k if isinstance(k, int) else _tag(k) for k in keys]
    return np.random.SeedSequence(entropy=int(seed), spawn_key=tuple(spawn))


def int_seed(seed: int, stage: str, *keys: int | str, bits: int = 31) -> int:
    """A non-negative integer seed (e.g. for Stan, which takes a 32-bit unsigned int)."""
    value = seed_sequence(seed, stage, *keys).generate_state(1, dtype=np.uint32)[0]
    return int(value) & ((1 << bits) - 1)
