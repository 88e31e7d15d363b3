"""Convergence checks of one NUTS run (Sec. III.C of the paper; Stan's warnings guidance).

A run passes when, over its post-warmup draws,

* there are no divergent transitions (``n_divergent <= max_divergences``),
* every parameter's rank-normalised split R-hat (max of bulk and folded, Vehtari et al.
  2021, the paper's [35]; ArviZ's ``rhat(method="rank")``) is ``< rhat_max``,
* every parameter's bulk-ESS and tail-ESS (totals over chains; ArviZ's ``ess(method="bulk")``
  / ``ess(method="tail")``) are ``>= ess_bulk_min`` / ``>= ess_tail_min``,
* every chain's E-BFMI (ArviZ's ``bfmi``) is ``>= ebfmi_min``,
* all draws are finite,

and tree-depth saturation (draws with ``treedepth__ >= max_treedepth``) is reported as a
warning, or fails the run when ``treedepth_fails`` is set.  Default thresholds are those of
Stan's runtime-warnings page, the paper's reference [2] for "the exact thresholds used in
Stan" (R-hat < 1.01, bulk-/tail-ESS > 100 per chain, E-BFMI 0.3, no divergences, tree-depth
saturation an efficiency warning; quoted in config/README.md).  :func:`threshold_failures`
applies them to a run's worst diagnostics, so stored records can be re-evaluated under other
thresholds (:mod:`ssmobs.nuts.convergence_sensitivity`) without new sampling.

The array-level statistics live in :mod:`ssmobs.nuts.diagnostics` (why ours and not ArviZ's:
its docstring, with the measured numbers).  Two implementations give the same numbers
(tested to 1e-10):

* ``"vectorized"`` (default): :func:`ssmobs.nuts.diagnostics.rank_diagnostics` and
  :func:`ssmobs.nuts.diagnostics.ebfmi`, all parameters at once;
* ``"arviz"``: ArviZ's array layer (``arviz_stats.base.array_stats``: ``rhat``, ``ess``,
  ``bfmi``), one parameter at a time; the reference the vectorised code is tested against.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..stan_backends.base import Draws
from .diagnostics import ebfmi, rank_diagnostics

if TYPE_CHECKING:
    import pandas

__all__ = [
    "ARVIZ_STAT_NAMES",
    "CHECKS",
    "THRESHOLD_CHECKS",
    "ConvergenceSettings",
    "check_convergence",
    "ebfmi",
    "rank_diagnostics",
    "stack_params",
    "threshold_failures",
    "to_inference_data",
]

#: the checks a run can fail, in the order they are reported
CHECKS = ("nonfinite", "divergences", "rhat", "ess_bulk", "ess_tail", "ebfmi", "treedepth")

#: ArviZ's names for Stan's sampler columns (as ArviZ's from_pystan / from_cmdstanpy rename them)
ARVIZ_STAT_NAMES = {
    "divergent__": "diverging",
    "treedepth__": "tree_depth",
    "n_leapfrog__": "n_steps",
    "stepsize__": "step_size",
    "accept_stat__": "acceptance_rate",
    "energy__": "energy",
    "lp__": "lp",
}


@dataclass(frozen=True)
class ConvergenceSettings:
    """Thresholds of the convergence checks (Stan warnings guidance; facts sheet Sec. 1).

    Attributes
    ----------
    max_divergences : largest number of post-warmup divergent transitions that passes (0).
    rhat_max : a run fails if any rank-normalised split R-hat is >= this (1.01).
    ess_bulk_min, ess_tail_min : a run fails if any total bulk-/tail-ESS is < this
        (100 x 4 chains = 400).
    ebfmi_min : a run fails if any chain's E-BFMI is < this (0.3).
    treedepth_fails : if True, draws that hit the sampler's max tree depth fail the run;
        by default they only add a warning (an efficiency, not a validity, problem).
    implementation : ``"vectorized"`` (:mod:`ssmobs.nuts.diagnostics`) or ``"arviz"``
        (arviz-stats); same numbers, see the module doc.
    """

    max_divergences: int = 0
    rhat_max: float = 1.01
    ess_bulk_min: float = 400.0
    ess_tail_min: float = 400.0
    ebfmi_min: float = 0.3
    treedepth_fails: bool = False
    implementation: str = "vectorized"

    def __post_init__(self) -> None:
        if self.implementation not in ("vectorized", "arviz"):
            raise ValueError(
                f"ConvergenceSettings.implementation must be 'vectorized' or "
                f"'arviz', got {self.implementation!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# --------------------------------------------------------------------------- helpers
def stack_params(draws: Draws) -> tuple[list[str], np.ndarray]:
    """All scalar components of all parameters: names and an array (n, chain, draw).

    Vector parameters are flattened in C order and named ``name[i]`` / ``name[i,j]``
    (0-based), scalars keep their name.
    """
    names: list[str] = []
    blocks: list[np.ndarray] = []
    for name, arr in draws.params.items():
        arr = np.asarray(arr, dtype=float)
        if arr.ndim < 2:
            raise ValueError(
                f"parameter '{name}' has shape {arr.shape}; expected (chain, draw, ...)"
            )
        c, s = arr.shape[:2]
        shape = arr.shape[2:]
        flat = arr.reshape(c, s, -1)
        if not shape:
            names.append(name)
        else:
            names.extend(f"{name}[{','.join(map(str, idx))}]" for idx in np.ndindex(*shape))
        blocks.append(np.moveaxis(flat, 2, 0))
    if not blocks:
        raise ValueError("the draws contain no parameters")
    return names, np.concatenate(blocks, axis=0)


def to_inference_data(draws: Draws) -> Any:
    """The draws as ArviZ data: an ``xarray.DataTree`` with groups ``posterior`` and
    ``sample_stats`` (ArviZ's sampler-stat names), from ``arviz_base.from_dict``."""
    import arviz_base

    stats: dict[str, np.ndarray] = {}
    for key, arr in draws.sample_stats.items():
        new = ARVIZ_STAT_NAMES.get(key, key)
        arr = np.asarray(arr)
        stats[new] = arr.astype(bool) if new == "diverging" else arr
    return arviz_base.from_dict(
        {"posterior": {k: np.asarray(v) for k, v in draws.params.items()}, "sample_stats": stats}
    )


def _arviz_diagnostics(x: np.ndarray) -> dict[str, np.ndarray]:
    """R-hat, bulk- and tail-ESS of every row of ``x`` (P, chain, draw) by arviz-stats."""
    from arviz_stats.base import array_stats

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # 0/0 of constant rows, warnings of rows with NaN
        return {
            "rhat": array_stats.rhat(x, method="rank"),
            "ess_bulk": array_stats.ess(x, method="bulk"),
            "ess_tail": array_stats.ess(x, method="tail", prob=(0.05, 0.95)),
        }


def _worst(values: np.ndarray, names: list[str], largest: bool) -> tuple[float, str | None]:
    """Worst value (NaN counts as worst) and the component it belongs to."""
    if values.size == 0:
        return math.nan, None
    nan = np.isnan(values)
    if nan.any():
        i = int(np.flatnonzero(nan)[0])
        return math.nan, names[i]
    i = int(np.argmax(values) if largest else np.argmin(values))
    return float(values[i]), names[i]


# --------------------------------------------------------------------------- thresholds
#: the checks decided by a threshold on a run's worst diagnostic (the others - nonfinite
#: draws, a failed KDE, a sampling error - do not depend on ConvergenceSettings)
THRESHOLD_CHECKS = ("divergences", "rhat", "ess_bulk", "ess_tail", "ebfmi", "treedepth")


def threshold_failures(worst: Mapping[str, Any], settings: ConvergenceSettings) -> list[str]:
    """Names (in :data:`CHECKS` order) of the threshold checks a run fails.

    ``worst`` holds the run's worst diagnostics as :func:`check_convergence` returns them and
    every per-trajectory record keeps them: ``n_divergent``, ``max_rhat``, ``min_ess_bulk``,
    ``min_ess_tail``, ``min_ebfmi`` and ``n_treedepth_hits``.  A NaN (or missing) value fails
    its check.  Tree-depth saturation fails only when ``settings.treedepth_fails``.  Used by
    :func:`check_convergence` and to re-evaluate stored records under other thresholds
    (:func:`ssmobs.nuts.convergence_sensitivity.converged_under`).
    """

    def num(key: str) -> float:
        v = worst.get(key)
        return math.nan if v is None else float(v)

    failed = []
    if not num("n_divergent") <= settings.max_divergences:
        failed.append("divergences")
    if not num("max_rhat") < settings.rhat_max:
        failed.append("rhat")
    if not num("min_ess_bulk") >= settings.ess_bulk_min:
        failed.append("ess_bulk")
    if not num("min_ess_tail") >= settings.ess_tail_min:
        failed.append("ess_tail")
    if not num("min_ebfmi") >= settings.ebfmi_min:
        failed.append("ebfmi")
    if settings.treedepth_fails and not num("n_treedepth_hits") == 0:
        failed.append("treedepth")
    return failed


def _threshold_message(check: str, worst: Mapping[str, Any], settings: ConvergenceSettings) -> str:
    """One line for a failed threshold check (the form :func:`check_convergence` uses)."""
    names = (
        "n_divergent",
        "max_rhat",
        "min_ess_bulk",
        "min_ess_tail",
        "min_ebfmi",
        "n_treedepth_hits",
    )
    v = {k: (math.nan if worst.get(k) is None else float(worst[k])) for k in names}
    if check == "divergences":
        return (
            f"divergences: {v['n_divergent']:.0f} divergent transitions after warmup, "
            f"allowed {settings.max_divergences}"
        )
    if check == "rhat":
        return f"rhat: max rank R-hat {v['max_rhat']:.4g} >= {settings.rhat_max}"
    if check == "ess_bulk":
        return f"ess_bulk: min bulk-ESS {v['min_ess_bulk']:.4g} < {settings.ess_bulk_min}"
    if check == "ess_tail":
        return f"ess_tail: min tail-ESS {v['min_ess_tail']:.4g} < {settings.ess_tail_min}"
    if check == "ebfmi":
        return f"ebfmi: min E-BFMI over chains {v['min_ebfmi']:.4g} < {settings.ebfmi_min}"
    return f"treedepth: {v['n_treedepth_hits']:.0f} draws hit the max tree depth"


def apply_thresholds(table: pandas.DataFrame, settings: ConvergenceSettings) -> pandas.DataFrame:
    """The per-trajectory table with ``converged``, ``failed_checks`` and ``reason`` decided
    by ``settings`` from the stored worst diagnostics (:func:`threshold_failures`).

    Records are keyed without the thresholds (a threshold changes no draw), so the tables
    built from them apply the configured thresholds here; failures that are no threshold
    (non-finite draws, KDE, sampling errors, exceptions) are kept with their reasons.
    """
    out = table.copy()
    converged, failed_col, reasons = [], [], []
    for row in table.to_dict("records"):
        old = [c for c in str(row.get("failed_checks") or "").split(",") if c]
        other = [c for c in old if c not in THRESHOLD_CHECKS]
        kept = [
            part
            for part in str(row.get("reason") or "").split("; ")
            if part and part.split(":", 1)[0] not in THRESHOLD_CHECKS
        ]
        if row.get("status", "ok") != "ok":
            converged.append(False)
            failed_col.append(",".join(old))
            reasons.append(str(row.get("reason") or ""))
            continue
        thr = threshold_failures(row, settings)
        failed = [c for c in (*CHECKS, "kde", "exception") if c in other or c in thr]
        failed += [c for c in other if c not in failed]
        messages = [_threshold_message(c, row, settings) for c in thr] + [
            p for p in kept if p != "not converged"
        ]
        converged.append(not failed)
        failed_col.append(",".join(failed))
        reasons.append("" if not failed else "; ".join(messages) or "not converged")
    out["converged"] = np.array(converged, dtype=bool)
    out["failed_checks"] = failed_col
    out["reason"] = reasons
    out["failing_blocks"] = [
        ",".join(failing_blocks(row, settings)) for row in table.to_dict("records")
    ]
    return out


#: the blocks of Theta whose diagnostics every record keeps: Omega, x0, the states x_1..x_T
BLOCKS = ("omega", "x0", "states")
#: the per-block diagnostics (worst over the block's components)
BLOCK_STATS = ("max_rhat", "min_ess_bulk", "min_ess_tail")


def block_of(name: str) -> str:
    """The block of a component name of :func:`stack_params` (``a``, ``x0[1]``, ``x[3]``)."""
    base = name.split("[", 1)[0]
    return "x0" if base == "x0" else "states" if base == "x" else "omega"


def block_diagnostics(names: list[str], diag: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Worst R-hat, bulk- and tail-ESS per block of Theta (:data:`BLOCKS`), so a reader sees
    whether Omega itself, x0 or only the states failed (NaN for an empty block)."""
    kinds = np.array([block_of(n) for n in names])
    out: dict[str, Any] = {}
    for block in BLOCKS:
        sel = kinds == block
        if not sel.any():
            out[block] = dict.fromkeys(BLOCK_STATS, math.nan)
            continue
        rhat = np.asarray(diag["rhat"], float)[sel]
        bulk = np.asarray(diag["ess_bulk"], float)[sel]
        tail = np.asarray(diag["ess_tail"], float)[sel]
        out[block] = {
            "max_rhat": float(np.nan if np.isnan(rhat).any() else rhat.max()),
            "min_ess_bulk": float(np.nan if np.isnan(bulk).any() else bulk.min()),
            "min_ess_tail": float(np.nan if np.isnan(tail).any() else tail.min()),
        }
    return out


def failing_blocks(row: Mapping[str, Any], settings: ConvergenceSettings) -> list[str]:
    """The blocks whose R-hat or ESS fail ``settings`` (from a table's per-block columns)."""
    out = []
    for block in BLOCKS:
        rhat = row.get(f"max_rhat_{block}")
        bulk = row.get(f"min_ess_bulk_{block}")
        tail = row.get(f"min_ess_tail_{block}")
        if rhat is None or bulk is None or tail is None:
            continue
        rhat, bulk, tail = float(rhat), float(bulk), float(tail)
        if math.isnan(rhat) and math.isnan(bulk) and math.isnan(tail):
            continue
        if not (
            rhat < settings.rhat_max
            and bulk >= settings.ess_bulk_min
            and tail >= settings.ess_tail_min
        ):
            out.append(block)
    return out


# --------------------------------------------------------------------------- main entry
def check_convergence(
    draws: Draws, settings: ConvergenceSettings | None = None, max_treedepth: int = 10
) -> dict[str, Any]:
    """Run every check on one run's post-warmup draws.

    Parameters
    ----------
    draws : the run's :class:`~ssmobs.stan_backends.base.Draws` (all parameters checked).
    settings : thresholds; defaults to :class:`ConvergenceSettings()`.
    max_treedepth : the sampler's max tree depth (``SamplerSettings.max_treedepth``);
        draws with ``treedepth__ >= max_treedepth`` count as hits.

    Returns
    -------
    dict with ``converged`` (bool), ``failed_checks`` (list of names from :data:`CHECKS`),
    ``warnings`` (list of str), ``messages`` (one line per failed check), the worst values
    ``max_rhat``, ``min_ess_bulk``, ``min_ess_tail`` (each with ``*_param``: the component),
    ``n_divergent``, ``n_treedepth_hits``, ``min_ebfmi``, ``ebfmi`` (per chain),
    ``n_nonfinite``, ``n_chains``, ``n_draws``.  NaN diagnostics (e.g. R-hat of a constant
    parameter) count as failures.
    """
    settings = settings or ConvergenceSettings()
    names, x = stack_params(draws)
    n_chains, n_draws = x.shape[1], x.shape[2]
    failed: list[str] = []
    messages: list[str] = []
    warns: list[str] = []

    finite = np.isfinite(x)
    n_nonfinite = int(x.size - np.count_nonzero(finite))
    if n_nonfinite:
        bad = [names[i] for i in np.flatnonzero(~finite.reshape(len(names), -1).all(axis=1))]
        failed.append("nonfinite")
        messages.append(
            f"nonfinite: {n_nonfinite} non-finite draws in {bad[:5]}"
            f"{' ...' if len(bad) > 5 else ''}"
        )
        x = np.where(finite, x, np.nan)  # NaN rows get NaN diagnostics below

    stats = draws.sample_stats
    div = np.asarray(stats.get("divergent__", np.zeros((n_chains, n_draws))), dtype=float)
    n_div = int(np.nansum(div))
    if n_div > settings.max_divergences:
        failed.append("divergences")
        messages.append(
            f"divergences: {n_div} divergent transitions after warmup "
            f"({100.0 * n_div / div.size:.2f} %), allowed {settings.max_divergences}"
        )

    use_arviz = settings.implementation == "arviz"
    diag = _arviz_diagnostics(x) if use_arviz else rank_diagnostics(x)
    max_rhat, max_rhat_param = _worst(diag["rhat"], names, largest=True)
    min_bulk, min_bulk_param = _worst(diag["ess_bulk"], names, largest=False)
    min_tail, min_tail_param = _worst(diag["ess_tail"], names, largest=False)
    if not max_rhat < settings.rhat_max:
        failed.append("rhat")
        messages.append(
            f"rhat: max rank R-hat {max_rhat:.4g} ({max_rhat_param}) >= {settings.rhat_max}"
        )
    if not min_bulk >= settings.ess_bulk_min:
        failed.append("ess_bulk")
        messages.append(
            f"ess_bulk: min bulk-ESS {min_bulk:.4g} ({min_bulk_param}) < {settings.ess_bulk_min}"
        )
    if not min_tail >= settings.ess_tail_min:
        failed.append("ess_tail")
        messages.append(
            f"ess_tail: min tail-ESS {min_tail:.4g} ({min_tail_param}) < {settings.ess_tail_min}"
        )

    if "energy__" in stats:
        if use_arviz:
            from arviz_stats.base import array_stats

            bfmi = array_stats.bfmi(np.asarray(stats["energy__"], dtype=float))
        else:
            bfmi = ebfmi(stats["energy__"])
        min_bfmi = float(np.min(bfmi)) if not np.isnan(bfmi).any() else math.nan
    else:
        bfmi = np.full(n_chains, np.nan)
        min_bfmi = math.nan
        warns.append("ebfmi: no energy__ in the sampler output")
    if not min_bfmi >= settings.ebfmi_min:
        failed.append("ebfmi")
        messages.append(f"ebfmi: min E-BFMI over chains {min_bfmi:.4g} < {settings.ebfmi_min}")

    depth = np.asarray(stats.get("treedepth__", np.zeros((n_chains, n_draws))), dtype=float)
    hits = int(np.count_nonzero(depth >= max_treedepth))
    if hits:
        text = (
            f"treedepth: {hits} of {depth.size} draws ({100.0 * hits / depth.size:.2f} %) "
            f"hit max_treedepth {max_treedepth}"
        )
        if settings.treedepth_fails:
            failed.append("treedepth")
            messages.append(text)
        else:
            warns.append(text)

    blocks = block_diagnostics(names, diag)
    failed = [c for c in CHECKS if c in failed]
    # one rule for the thresholds: the same function re-evaluates stored records
    worst = {
        "n_divergent": n_div,
        "max_rhat": max_rhat,
        "min_ess_bulk": min_bulk,
        "min_ess_tail": min_tail,
        "min_ebfmi": min_bfmi,
        "n_treedepth_hits": hits,
    }
    assert [c for c in failed if c in THRESHOLD_CHECKS] == threshold_failures(worst, settings)
    return {
        "converged": not failed,
        "failed_checks": failed,
        "messages": messages,
        "warnings": warns,
        "max_rhat": max_rhat,
        "max_rhat_param": max_rhat_param,
        "min_ess_bulk": min_bulk,
        "min_ess_bulk_param": min_bulk_param,
        "min_ess_tail": min_tail,
        "min_ess_tail_param": min_tail_param,
        "n_divergent": n_div,
        "n_treedepth_hits": hits,
        "max_treedepth_seen": int(np.max(depth)) if depth.size else 0,
        "min_ebfmi": min_bfmi,
        "ebfmi": [float(v) for v in bfmi],
        "n_nonfinite": n_nonfinite,
        "n_chains": int(n_chains),
        "n_draws": int(n_draws),
        "blocks": blocks,
    }
