"""A design disturbance set made and written once (Sec. III.A): the file rule
design_disturbances writes, and the cached sets the choice of K and the observability maps
make in the job that scores them (:func:`disturbance_set`) instead of one job each.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING

from .. import io

if TYPE_CHECKING:
    import numpy as np

    from .disturbances import DesignResult

logger = logging.getLogger("ssmobs")


def write_disturbance_set(
    q: int, K: int, method: str, seed: int, design_cfg: dict, out: str | os.PathLike
) -> DesignResult:
    """One (q x K) disturbance matrix (LCD design, or a random baseline,
    :func:`ssmobs.design.disturbances.design_disturbances`), written to ``out``."""
    from .disturbances import design_disturbances

    logger.info("design disturbances q=%d K=%d method=%s seed=%d", q, K, method, seed)
    result = design_disturbances(
        q, K, method, seed, b_max=design_cfg["b_max"], progress=logger.info
    )
    logger.info(
        "done: %d iterations, distance %.6g (before covariance correction %.6g), %s",
        result.iterations,
        result.distance,
        result.distance_raw,
        result.covariance_correction,
    )
    io.write_disturbances(out, result)
    return result


def disturbance_set(
    path: str | os.PathLike, q: int, K: int, method: str, seed: int, design_cfg: dict
) -> tuple[np.ndarray, dict]:
    """The disturbance set cached at ``path`` (the file rule design_disturbances writes),
    made here when it is missing or damaged.  Under a file lock, so two jobs never make the
    same set, and the temporaries a killed maker left are swept."""
    path = Path(path)
    with io.file_lock(path.parent / ".locks" / f"{path.name}.lock"):
        io.sweep_temporaries([path])  # no maker runs: we hold the lock
        try:
            return io.read_disturbances(path, q=q, K=K)
        except (FileNotFoundError, io.CorruptFileError):
            pass
        write_disturbance_set(q, K, method, seed, design_cfg, path)
    return io.read_disturbances(path, q=q, K=K)
