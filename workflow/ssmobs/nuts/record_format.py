"""The NUTS stage's record of one trajectory k, and the table built from records.

Record format (JSON, one file per k; :data:`ssmobs.nuts.record_cache.RECORD_VERSION`, written by
:mod:`ssmobs.nuts.batch`, stored and read back by :mod:`ssmobs.nuts.record_cache`)::

    record_version   int
    key              {scenario, k, seed, stan_seed, program_hash, settings_hash, backend
                     ("<name> <Stan version>"), data_hash}
    k, scenario, model, T
    status           "ok" (draws were checked) | "error" (an exception before that)
    converged        bool: all convergence checks passed and the marginal summary exists
    failed_checks    list of names: convergence.CHECKS, "kde", "sampling_error", "exception"
    reason           None when converged, else one line per failed check / the exception
    diagnostics      worst values (max_rhat, min_ess_bulk, min_ess_tail, n_divergent,
                     n_treedepth_hits, min_ebfmi, ebfmi per chain, ...; see
                     check_convergence) with ``blocks``: R-hat and both ESS per block
                     (omega, x0, states), or None when sampling failed
    theta_names      model.theta_names(T)
    map, q5, q95     lists in theta_names order (marginal MAP, Eq. (11); quantiles, Eq. (12)),
                     or None when they could not be computed
    init             "random" | "true"
    draws_sha256     SHA-256 of the kept draws file (only when the draws were kept)
    record_sha256    SHA-256 of the rest of the record (record_cache.write_record)
    backend          backend name
    timings          seconds: sample_call (wall time of backend.sample), backend (the
                     backend's own breakdown, e.g. transfer), prepare, diagnostics, marginal,
                     keep_draws, overhead (all of ours except writing this file) and
                     overhead_cpu (its CPU time in this process: robust to other load)

Timings are the only field that differs between reruns; :func:`records_to_frame` leaves
them out, so tables built from records are byte-identical across reruns.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .convergence import BLOCK_STATS, BLOCKS

if TYPE_CHECKING:
    import pandas

    from ..models.base import StateSpaceModel

#: diagnostics columns copied into the per-k table
DIAGNOSTIC_COLUMNS = (
    "max_rhat",
    "min_ess_bulk",
    "min_ess_tail",
    "n_divergent",
    "n_treedepth_hits",
    "min_ebfmi",
)


def records_to_frame(
    records: Sequence[dict[str, Any]], model: StateSpaceModel, T: int
) -> pandas.DataFrame:
    """One row per trajectory k (sorted by k): wide table of status, diagnostics and Theta.

    Columns: ``k`` (int), ``scenario``, ``stan_seed``, ``status``, ``converged`` (bool),
    ``failed_checks`` (comma-separated names, "" when none), ``reason`` ("" when none),
    the worst diagnostics :data:`DIAGNOSTIC_COLUMNS` (NaN when sampling failed), the same
    per block ``max_rhat_omega``, ``min_ess_bulk_x0``, ... (:data:`~ssmobs.nuts.convergence.BLOCKS`;
    the tables add ``failing_blocks``), then for
    every component of ``model.theta_names(T)`` (Omega, x0, x1..xT): ``<name>_map``,
    ``<name>_q5``, ``<name>_q95`` (NaN when not computed).  We chose wide columns (3 |Theta|
    of them, 306 for T = 100) because every metric reads whole columns and Parquet stores
    them compactly; timings are left out so the table is identical across reruns.
    """
    import pandas as pd

    names = model.theta_names(T)
    n = len(names)
    recs = sorted(records, key=lambda r: int(r["k"]))
    m = len(recs)
    cols: dict[str, Any] = {
        "k": np.array([int(r["k"]) for r in recs], dtype=np.int64),
        "scenario": [str(r.get("scenario", r["key"].get("scenario", ""))) for r in recs],
        "stan_seed": np.array([int(r["key"].get("stan_seed", -1)) for r in recs], dtype=np.int64),
        "status": [str(r["status"]) for r in recs],
        "converged": np.array([bool(r["converged"]) for r in recs], dtype=bool),
        "failed_checks": [",".join(r["failed_checks"]) for r in recs],
        "reason": [r["reason"] or "" for r in recs],
    }
    for c in DIAGNOSTIC_COLUMNS:
        vals = []
        for r in recs:
            d = r.get("diagnostics") or {}
            v = d.get(c)
            vals.append(math.nan if v is None else float(v))
        cols[c] = np.array(vals, dtype=float)
    for part in BLOCKS:  # R-hat and ESS per block of Theta (Omega, x0, states)
        for stat in BLOCK_STATS:
            vals = []
            for r in recs:
                v = ((r.get("diagnostics") or {}).get("blocks") or {}).get(part, {}).get(stat)
                vals.append(math.nan if v is None else float(v))
            cols[f"{stat}_{part}"] = np.array(vals, dtype=float)
    block = {s: np.full((m, n), np.nan) for s in ("map", "q5", "q95")}
    for i, r in enumerate(recs):
        if r.get("theta_names") is not None and list(r["theta_names"]) != names:
            raise ValueError(
                f"record k={r['k']} has Theta names {r['theta_names'][:4]}..., "
                f"expected {names[:4]}... (model {model.slug}, T={T})"
            )
        for s in ("map", "q5", "q95"):
            if r[s] is not None:
                block[s][i] = np.asarray(r[s], dtype=float)
    for j, name in enumerate(names):
        for s in ("map", "q5", "q95"):
            cols[f"{name}_{s}"] = block[s][:, j]
    return pd.DataFrame(cols)
