"""Convergence checks of one NUTS run (Sec. III.C of the paper; Stan's warnings guidance).

A run passes when, over its post-warmup draws,

* there are no divergent transitions (``n_divergent <= max_divergences``),
* every parameter's rank-normalised split R-hat (max of bulk and folded, Vehtari et al.
  2021, the paper's [35]; ArviZ ``az.rhat(method="rank")``) is ``< rhat_max``,
* every parameter's bulk-ESS and tail-ESS (totals over chains; ``az.ess(method="bulk")`` /
  ``az.ess(method="tail")``) are ``>= ess_bulk_min`` / ``>= ess_tail_min``,
* every chain's E-BFMI (``az.bfmi``) is ``>= ebfmi_min``,
* all draws are finite,

and tree-depth saturation (draws with ``treedepth__ >= max_treedepth``) is reported as a
warning, or fails the run when ``treedepth_fails`` is set.  Default thresholds are those of
Stan's runtime-warnings page, the paper's reference [2] for "the exact thresholds used in
Stan" (R-hat < 1.01, bulk-/tail-ESS > 100 per chain, E-BFMI 0.3, no divergences, tree-depth
saturation an efficiency warning; quoted in config/README.md).  :func:`threshold_failures`
applies them to a run's worst diagnostics, so stored records can be re-evaluated under other
thresholds (:func:`converged_under`, :func:`sensitivity_table`) without new sampling.

Two implementations give the same numbers (tested to 1e-10):

* ``"vectorized"`` (default): the same formulas as ArviZ 0.23's ``_rhat_rank``,
  ``_ess_bulk``, ``_ess_tail`` and ``_bfmi``, evaluated for all parameters at once with
  NumPy (one sort per parameter and transform instead of SciPy's ``rankdata`` and a Python
  loop per parameter).  Measured on PyStan draws of model same, T = 100 (102 parameters
  x 4 x 6 000 draws): about 0.36 s against 1.3 s for ArviZ (``BENCHMARKS.md``, section
  "Stan stage (issue 4)"), which matters because the stage's own overhead must stay below
  10 % of the sampling call (about 10 s there).
* ``"arviz"``: ``az.rhat`` / ``az.ess`` / ``az.bfmi`` on ``az.from_dict`` of the draws;
  the reference the vectorised code is tested against.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass
from typing import Any, Mapping

import numpy as np
from scipy import special

from .stan_backends.base import Draws

#: the checks a run can fail, in the order they are reported
CHECKS = ("nonfinite", "divergences", "rhat", "ess_bulk", "ess_tail", "ebfmi", "treedepth")

#: ArviZ's names for Stan's sampler columns (as az.from_pystan / az.from_cmdstanpy rename them)
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
    implementation : ``"vectorized"`` or ``"arviz"`` (same numbers; see module doc).
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
            raise ValueError(f"ConvergenceSettings.implementation must be 'vectorized' or "
                             f"'arviz', got {self.implementation!r}")

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
            raise ValueError(f"parameter '{name}' has shape {arr.shape}; expected (chain, draw, ...)")
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
    """An ``arviz.InferenceData`` of the draws (ArviZ's sampler-stat names)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=FutureWarning)
        import arviz as az

    stats: dict[str, np.ndarray] = {}
    for key, arr in draws.sample_stats.items():
        new = ARVIZ_STAT_NAMES.get(key, key)
        arr = np.asarray(arr)
        stats[new] = arr.astype(bool) if new == "diverging" else arr
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=FutureWarning)
        return az.from_dict(posterior={k: np.asarray(v) for k, v in draws.params.items()},
                            sample_stats=stats)


def _z_scale_rows(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rank-normalise every row: Phi^-1((rank - 3/8) / (n + 1/4)) (ArviZ ``_z_scale``).

    Rows without ties are a permutation of the ranks 1..n, so their z-values come from one
    table of n normal quantiles; only rows with ties need their own ``ndtri``.  Also
    returns the sorted rows (for medians and quantiles without another sort).
    """
    n = m.shape[1]
    order = np.argsort(m, axis=1)
    table = special.ndtri((np.arange(1.0, n + 1.0) - 0.375) / (n + 0.25))
    z = np.empty(m.shape, dtype=float)
    np.put_along_axis(z, order, np.broadcast_to(table, m.shape), axis=1)
    srt = np.take_along_axis(m, order, axis=1)
    eq = srt[:, 1:] == srt[:, :-1]
    rows = np.flatnonzero(eq.any(axis=1))
    if rows.size:
        # tied values (common: PyStan transfers draws as ~6 significant digits) get the
        # mean rank of their group; only their z-values change.  A group is a run
        # eq[a..b-1] of equal neighbours: sorted positions a..b, ranks a+1..b+1.
        edges = np.zeros((rows.size, n + 1), dtype=np.int8)
        edges[:, 1:n] = eq[rows]
        d = np.diff(edges, axis=1)
        r_a, a = np.nonzero(d == 1)
        _, b = np.nonzero(d == -1)  # same row-major order: pairs with the starts
        size = b - a + 1
        first = np.repeat(np.cumsum(size) - size, size)
        pos = np.repeat(a, size) + (np.arange(size.sum()) - first)
        r_i = rows[np.repeat(r_a, size)]
        avg = np.repeat((a + b) / 2.0 + 1.0, size)
        z[r_i, order[r_i, pos]] = special.ndtri((avg - 0.375) / (n + 0.25))
    return z, srt


def _sorted_quantile(srt: np.ndarray, prob: float) -> np.ndarray:
    """Type-7 quantile of every row of the row-sorted array ``srt`` (as ``np.quantile``)."""
    n = srt.shape[1]
    h = (n - 1) * prob
    lo = int(math.floor(h))
    hi = min(lo + 1, n - 1)
    frac = h - lo
    # np.quantile's lerp: a + (b - a) * t, switched to b - (b - a) * (1 - t) for t >= 0.5
    a, b = srt[:, lo], srt[:, hi]
    diff = b - a
    return np.where(frac >= 0.5, b - diff * (1 - frac), a + diff * frac)


def _split(a: np.ndarray) -> np.ndarray:
    """(P, C, N) -> (P, 2C, N//2): first and last halves of each chain (ArviZ ``_split_chains``)."""
    half = a.shape[2] // 2
    return np.concatenate([a[:, :, :half], a[:, :, a.shape[2] - half:]], axis=1)


def _rhat_rows(z: np.ndarray) -> np.ndarray:
    """Split R-hat of (P, M, n) already-split chains (ArviZ ``_rhat``)."""
    n = z.shape[2]
    chain_mean = z.mean(axis=2)
    chain_var = z.var(axis=2, ddof=1)
    between = n * chain_mean.var(axis=1, ddof=1)
    within = chain_var.mean(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt((between / within + n - 1) / n)


def _ess_rows(a: np.ndarray) -> np.ndarray:
    """ESS of (P, M, n) chains with Geyer's initial monotone sequence (ArviZ ``_ess``)."""
    p_rows, m_chains, n = a.shape
    a = np.asarray(a, dtype=float)
    out = np.full(p_rows, np.nan)
    flat = a.reshape(p_rows, -1)
    nan_rows = np.isnan(flat.sum(axis=1))  # cheap: a NaN (or +-inf mix) poisons the sum
    const = (flat.max(axis=1) - flat.min(axis=1)) < np.finfo(float).resolution
    out[const & ~nan_rows] = m_chains * n
    todo = np.flatnonzero(~const & ~nan_rows)
    if todo.size == 0:
        return out
    x = a[todo]
    # autocovariance (biased, / n) by FFT, as arviz.stats.stats_utils.autocov
    from scipy.fft import next_fast_len

    nfft = next_fast_len(2 * n)
    chain_mean = x.mean(axis=2)
    f = np.fft.rfft(x - chain_mean[:, :, None], n=nfft, axis=2)
    # |F|^2 averaged over chains before the one inverse FFT
    power = (np.einsum("rck,rck->rk", f.real, f.real)
             + np.einsum("rck,rck->rk", f.imag, f.imag)) / m_chains
    acov_mean = np.fft.irfft(power, n=nfft, axis=1)[:, :n] / n  # mean over chains of acov
    mean_var = acov_mean[:, 0] * n / (n - 1.0)
    var_plus = mean_var * (n - 1.0) / n
    if m_chains > 1:
        var_plus = var_plus + chain_mean.var(axis=1, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = 1.0 - (mean_var[:, None] - acov_mean) / var_plus[:, None]
    rho[:, 0] = 1.0
    jmax = max((n - 3) // 2, 0)  # last pair (2j, 2j+1) ArviZ's loop can reach (n >= 2)
    n_pairs = jmax + 1
    ps = rho[:, 0:2 * n_pairs:2] + rho[:, 1:2 * n_pairs:2]  # pair sums, j = 0..jmax
    nonpos = ps <= 0
    first = np.where(nonpos.any(axis=1), nonpos.argmax(axis=1), n_pairs)
    jc = np.minimum(jmax, first)  # pairs computed by the loop (j = 1..jc)
    rows = np.arange(todo.size)
    # Geyer's initial monotone sequence: cumulative minimum of the pair sums 0..jc-1
    ps_mono = np.minimum.accumulate(ps, axis=1)
    keep = np.arange(n_pairs)[None, :] < jc[:, None]
    head = np.where(keep, ps_mono, 0.0).sum(axis=1)
    even_last = rho[rows, 2 * jc]
    ps_last = ps[rows, jc]
    tail = np.where(jc >= 1, np.where((ps_last >= 0) | (even_last > 0), even_last, 0.0), 1.0)
    tau = -1.0 + 2.0 * head + tail
    total = m_chains * n
    tau = np.maximum(tau, 1.0 / np.log10(total))
    ess = total / tau
    ess[np.isnan(rho).any(axis=1)] = np.nan
    out[todo] = ess
    return out


def _quantile_type7(m: np.ndarray, probs: list[float]) -> np.ndarray:
    """R's type-7 quantiles of every row (numpy's default 'linear'): shape (len(probs), P)."""
    return np.quantile(m, probs, axis=1)


#: parameters processed together (bounds the temporaries to a few MB: faster than all at once)
CHUNK_ROWS = 16


def rank_diagnostics(x: np.ndarray) -> dict[str, np.ndarray]:
    """Rank R-hat, bulk-ESS and tail-ESS of every row of ``x`` (P, chain, draw), vectorised.

    Equal to ArviZ 0.23's ``_rhat_rank``, ``_ess_bulk`` and ``_ess_tail`` per row; rows
    with a NaN give NaN; R-hat needs >= 2 chains and >= 4 draws (else NaN).
    """
    x = np.asarray(x, dtype=float)
    if x.shape[0] > CHUNK_ROWS:
        parts = [_rank_diagnostics(x[i:i + CHUNK_ROWS]) for i in range(0, x.shape[0], CHUNK_ROWS)]
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return _rank_diagnostics(x)


def _rank_diagnostics(x: np.ndarray) -> dict[str, np.ndarray]:
    p_rows, c, s = x.shape
    rhat = np.full(p_rows, np.nan)
    ess_bulk = np.full(p_rows, np.nan)
    ess_tail = np.full(p_rows, np.nan)
    if s < 4:
        return {"rhat": rhat, "ess_bulk": ess_bulk, "ess_tail": ess_tail}
    ok = ~np.isnan(x).reshape(p_rows, -1).any(axis=1)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return {"rhat": rhat, "ess_bulk": ess_bulk, "ess_tail": ess_tail}
    xv = x[idx]
    sp = _split(xv)
    n_rows, m_chains, half = sp.shape
    flat = sp.reshape(n_rows, -1)
    z_bulk, srt = _z_scale_rows(flat)
    z_bulk = z_bulk.reshape(sp.shape)
    n_flat = flat.shape[1]
    median = 0.5 * (srt[:, (n_flat - 1) // 2] + srt[:, n_flat // 2])
    z_fold = _z_scale_rows(np.abs(flat - median[:, None]))[0].reshape(sp.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        if c >= 2:
            r_bulk, r_fold = _rhat_rows(z_bulk), _rhat_rows(z_fold)
            # NaN in either (a constant parameter) gives NaN, which fails the check
            # (ArviZ's builtin max() would keep a number that comes first)
            rhat[idx] = np.where(np.isnan(r_bulk) | np.isnan(r_fold), np.nan,
                                 np.maximum(r_bulk, r_fold))
    ess_bulk[idx] = _ess_rows(z_bulk)
    if 2 * half == s:  # the split chains hold every draw: quantiles from the sorted rows
        q = [_sorted_quantile(srt, 0.05), _sorted_quantile(srt, 0.95)]
    else:
        q = list(_quantile_type7(xv.reshape(idx.size, -1), [0.05, 0.95]))
    ind = np.concatenate([sp <= q[0][:, None, None], sp <= q[1][:, None, None]]).astype(float)
    ess_q = _ess_rows(ind)
    ess_tail[idx] = np.minimum(ess_q[:idx.size], ess_q[idx.size:])
    return {"rhat": rhat, "ess_bulk": ess_bulk, "ess_tail": ess_tail}


def ebfmi(energy: np.ndarray) -> np.ndarray:
    """E-BFMI per chain: mean(diff(E)^2) / var(E, ddof=1) (ArviZ ``_bfmi``)."""
    e = np.atleast_2d(np.asarray(energy, dtype=float))
    num = np.square(np.diff(e, axis=1)).mean(axis=1)
    den = e.var(axis=1, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return num / den


def _arviz_diagnostics(draws: Draws, names: list[str]) -> dict[str, np.ndarray]:
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=FutureWarning)
        warnings.filterwarnings("ignore", category=RuntimeWarning)
        import arviz as az

        idata = to_inference_data(draws)
        out = {}
        for key, fn in (("rhat", lambda: az.rhat(idata, method="rank")),
                        ("ess_bulk", lambda: az.ess(idata, method="bulk")),
                        ("ess_tail", lambda: az.ess(idata, method="tail"))):
            ds = fn()
            out[key] = np.concatenate([np.asarray(ds[v].values, dtype=float).reshape(-1)
                                       for v in draws.params])
    assert all(v.size == len(names) for v in out.values())
    return out


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
    (:func:`converged_under`).
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


def converged_under(table: "pandas.DataFrame", settings: ConvergenceSettings  # noqa: F821
                    ) -> np.ndarray:
    """(K,) bool: would each trajectory of a Stan-stage table pass under ``settings``?

    ``table`` is the per-trajectory table of rule gather_nuts (columns ``failed_checks``,
    comma-separated, and the worst diagnostics).  A trajectory passes when it failed no
    check outside :data:`THRESHOLD_CHECKS` (non-finite draws, KDE, sampling errors stay
    failures) and :func:`threshold_failures` finds none under the new thresholds.  No new
    sampling: the records keep every diagnostic the thresholds act on.
    """
    out = np.zeros(len(table), dtype=bool)
    for i, row in enumerate(table.to_dict("records")):
        other = [c for c in str(row.get("failed_checks") or "").split(",")
                 if c and c not in THRESHOLD_CHECKS]
        if other or row.get("status", "ok") != "ok":
            continue
        out[i] = not threshold_failures(row, settings)
    return out


#: the variants of the sensitivity table: (column, R-hat threshold, tree depth counted)
SENSITIVITY_VARIANTS = (("rhat1.01_treedepth_warns", 1.01, False),
                        ("rhat1.01_treedepth_fails", 1.01, True),
                        ("rhat1.05_treedepth_warns", 1.05, False),
                        ("rhat1.05_treedepth_fails", 1.05, True))


def sensitivity_table(tables: Mapping[str, "pandas.DataFrame"],  # noqa: F821
                      base: ConvergenceSettings) -> "pandas.DataFrame":  # noqa: F821
    """|K^Stan| of every scenario under R-hat 1.01 / 1.05 and tree depth warned / counted.

    ``tables`` maps scenario names to their gather_nuts tables; the other thresholds are
    those of ``base`` (the run's config).  Column ``K_stan_run`` is |K^Stan| as the run
    decided it, so a reader sees which variant the run used.
    """
    import pandas as pd

    rows = []
    for name, table in tables.items():
        row: dict[str, Any] = {"scenario": name, "K": int(len(table)),
                               "K_stan_run": int(np.asarray(table["converged"], bool).sum())}
        for col, rhat_max, td in SENSITIVITY_VARIANTS:
            settings = ConvergenceSettings(**{**base.to_dict(), "rhat_max": rhat_max,
                                              "treedepth_fails": td})
            row[col] = int(converged_under(table, settings).sum())
        rows.append(row)
    return pd.DataFrame(rows, columns=["scenario", "K", "K_stan_run",
                                       *[v[0] for v in SENSITIVITY_VARIANTS]])


# --------------------------------------------------------------------------- main entry
def check_convergence(draws: Draws, settings: ConvergenceSettings | None = None,
                      max_treedepth: int = 10) -> dict[str, Any]:
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
        messages.append(f"nonfinite: {n_nonfinite} non-finite draws in {bad[:5]}"
                        f"{' ...' if len(bad) > 5 else ''}")
        x = np.where(finite, x, np.nan)  # NaN rows get NaN diagnostics below

    stats = draws.sample_stats
    div = np.asarray(stats.get("divergent__", np.zeros((n_chains, n_draws))), dtype=float)
    n_div = int(np.nansum(div))
    if n_div > settings.max_divergences:
        failed.append("divergences")
        messages.append(f"divergences: {n_div} divergent transitions after warmup "
                        f"({100.0 * n_div / div.size:.2f} %), allowed {settings.max_divergences}")

    if settings.implementation == "arviz" and not n_nonfinite:
        diag = _arviz_diagnostics(draws, names)
    else:
        diag = rank_diagnostics(x)
    max_rhat, max_rhat_param = _worst(diag["rhat"], names, largest=True)
    min_bulk, min_bulk_param = _worst(diag["ess_bulk"], names, largest=False)
    min_tail, min_tail_param = _worst(diag["ess_tail"], names, largest=False)
    if not max_rhat < settings.rhat_max:
        failed.append("rhat")
        messages.append(f"rhat: max rank R-hat {max_rhat:.4g} ({max_rhat_param}) "
                        f">= {settings.rhat_max}")
    if not min_bulk >= settings.ess_bulk_min:
        failed.append("ess_bulk")
        messages.append(f"ess_bulk: min bulk-ESS {min_bulk:.4g} ({min_bulk_param}) "
                        f"< {settings.ess_bulk_min}")
    if not min_tail >= settings.ess_tail_min:
        failed.append("ess_tail")
        messages.append(f"ess_tail: min tail-ESS {min_tail:.4g} ({min_tail_param}) "
                        f"< {settings.ess_tail_min}")

    if "energy__" in stats:
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
        text = (f"treedepth: {hits} of {depth.size} draws ({100.0 * hits / depth.size:.2f} %) "
                f"hit max_treedepth {max_treedepth}")
        if settings.treedepth_fails:
            failed.append("treedepth")
            messages.append(text)
        else:
            warns.append(text)

    failed = [c for c in CHECKS if c in failed]
    # one rule for the thresholds: the same function re-evaluates stored records
    worst = {"n_divergent": n_div, "max_rhat": max_rhat, "min_ess_bulk": min_bulk,
             "min_ess_tail": min_tail, "min_ebfmi": min_bfmi, "n_treedepth_hits": hits}
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
    }
