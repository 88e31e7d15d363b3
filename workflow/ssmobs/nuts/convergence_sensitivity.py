"""The convergence checks' sensitivity to their thresholds (Sec. III.C, issue 13): whether a
stored run would pass under other thresholds (:func:`converged_under`, no new sampling), how
many runs converge under each variant of the R-hat threshold, of counting the tree depth and
of the blocks of Theta whose R-hat and ESS count (:func:`sensitivity_table`), and which
checks and blocks the failed runs failed (:func:`failure_pattern_table`).  The checks
themselves are :mod:`ssmobs.nuts.convergence`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .convergence import (
    BLOCKS,
    THRESHOLD_CHECKS,
    ConvergenceSettings,
    failing_blocks,
    threshold_failures,
)

if TYPE_CHECKING:
    import pandas


def converged_under(
    table: pandas.DataFrame,
    settings: ConvergenceSettings,
    blocks: Sequence[str] | None = None,
) -> np.ndarray:
    """(K,) bool: would each trajectory of a Stan-stage table pass under ``settings``?

    ``table`` is the per-trajectory table of rule gather_nuts (columns ``failed_checks``,
    comma-separated, and the worst diagnostics).  A trajectory passes when it failed no
    check outside :data:`THRESHOLD_CHECKS` (non-finite draws, KDE, sampling errors stay
    failures) and :func:`threshold_failures` finds none under the new thresholds.  With
    ``blocks`` (some of :data:`BLOCKS`), R-hat and both ESS are checked on those blocks of
    Theta only (per-block columns ``max_rhat_<block>``, ...; issue 20: which quantities the
    paper's checks covered is not stated).  No new sampling: the records keep every
    diagnostic the thresholds act on.
    """
    mixing = {"rhat", "ess_bulk", "ess_tail"}
    out = np.zeros(len(table), dtype=bool)
    for i, row in enumerate(table.to_dict("records")):
        other = [
            c
            for c in str(row.get("failed_checks") or "").split(",")
            if c and c not in THRESHOLD_CHECKS
        ]
        if other or row.get("status", "ok") != "ok":
            continue
        failed = set(threshold_failures(row, settings))
        if blocks is not None:
            failed -= mixing
            if set(failing_blocks(row, settings)) & set(blocks):
                failed.add("rhat")
        out[i] = not failed
    return out


#: the variants of the sensitivity table: (column, R-hat threshold, tree depth counted)
SENSITIVITY_VARIANTS = (
    ("rhat1.01_treedepth_warns", 1.01, False),
    ("rhat1.01_treedepth_fails", 1.01, True),
    ("rhat1.05_treedepth_warns", 1.05, False),
    ("rhat1.05_treedepth_fails", 1.05, True),
)


#: the block variants of the sensitivity table: (column, blocks whose R-hat and ESS count)
BLOCK_VARIANTS = (("omega_x0_only", ("omega", "x0")), ("omega_only", ("omega",)))


def sensitivity_table(
    tables: Mapping[str, pandas.DataFrame],
    base: ConvergenceSettings,
) -> pandas.DataFrame:
    """|K^Stan| of every scenario under R-hat 1.01 / 1.05 and tree depth warned / counted,
    and with R-hat and ESS checked on Omega and x0 only or on Omega only (the run's
    thresholds; :data:`BLOCK_VARIANTS`).

    ``tables`` maps scenario names to their gather_nuts tables; the other thresholds are
    those of ``base`` (the run's config).  Column ``K_stan_run`` is |K^Stan| as the run
    decided it, so a reader sees which variant the run used.  A table without per-block
    columns (records before format 2) gives NaN in the block columns.
    """
    import pandas as pd

    rows = []
    for name, table in tables.items():
        row: dict[str, Any] = {
            "scenario": name,
            "K": int(len(table)),
            "K_stan_run": int(np.asarray(table["converged"], bool).sum()),
        }
        for col, rhat_max, td in SENSITIVITY_VARIANTS:
            settings = ConvergenceSettings(
                **{**base.to_dict(), "rhat_max": rhat_max, "treedepth_fails": td}
            )
            row[col] = int(converged_under(table, settings).sum())
        has_blocks = all(f"max_rhat_{b}" in table.columns for b in BLOCKS)
        for col, blocks in BLOCK_VARIANTS:
            row[col] = int(converged_under(table, base, blocks).sum()) if has_blocks else math.nan
        rows.append(row)
    columns = [v[0] for v in SENSITIVITY_VARIANTS] + [v[0] for v in BLOCK_VARIANTS]
    return pd.DataFrame(rows, columns=["scenario", "K", "K_stan_run", *columns])


#: the quantiles of the largest R-hat shown per failure pattern
FAILURE_RHAT_QUANTILES = (0.0, 0.05, 0.25, 0.5, 0.75, 0.95, 1.0)


def failure_pattern_table(tables: Mapping[str, pandas.DataFrame]) -> pandas.DataFrame:
    """How the runs that did not converge failed: per scenario and pattern (the checks that
    failed and the blocks of Theta that failed them), the number of runs, how many of them
    also had divergent transitions, and quantiles of their largest R-hat.

    ``tables`` maps scenario names to their gather_nuts tables (thresholds applied, so
    ``failed_checks`` and ``failing_blocks`` are the run's).  Separated modes give a large
    R-hat with ample ESS per chain; slow mixing gives a moderate R-hat with a small ESS.
    """
    import pandas as pd

    qcols = [f"max_rhat_q{round(100 * q):02d}" for q in FAILURE_RHAT_QUANTILES]
    rows = []
    for name, table in tables.items():
        failed = table[~np.asarray(table["converged"], bool)]
        if failed.empty:
            continue
        blocks = failed["failing_blocks"] if "failing_blocks" in failed else ""
        keys = pd.DataFrame(
            {
                "failed_checks": failed["failed_checks"].fillna("").astype(str),
                "failing_blocks": pd.Series(blocks, index=failed.index).fillna("").astype(str),
            }
        )
        for (checks, blks), idx in keys.groupby(["failed_checks", "failing_blocks"]).groups.items():
            group = failed.loc[idx]
            rhat = group["max_rhat"].to_numpy(float)
            rhat = rhat[np.isfinite(rhat)]
            row: dict[str, Any] = {
                "scenario": name,
                "K": int(len(table)),
                "failed_checks": checks,
                "failing_blocks": blks,
                "runs": int(len(group)),
                "runs_with_divergences": int((group["n_divergent"].to_numpy(float) > 0).sum()),
            }
            for col, q in zip(qcols, FAILURE_RHAT_QUANTILES, strict=True):
                row[col] = float(np.quantile(rhat, q)) if rhat.size else math.nan
            rows.append(row)
    cols = ["scenario", "K", "failed_checks", "failing_blocks", "runs", "runs_with_divergences"]
    frame = pd.DataFrame(rows, columns=cols + qcols)
    return frame.sort_values(["scenario", "runs"], ascending=[True, False], kind="stable")
