"""Array-level MCMC diagnostics: rank-normalised split R-hat, bulk-/tail-ESS and E-BFMI.

The statistics of Vehtari et al. (2021), the paper's [35], that Sec. III.C's convergence
checks (:mod:`ssmobs.nuts.convergence`) apply to every trajectory's NUTS run, on plain arrays
``(parameter, chain, draw)``:

* :func:`rank_diagnostics` -- R-hat (max of bulk and folded rank-normalised split R-hat),
  bulk-ESS and tail-ESS (min of the 5 % and 95 % quantile ESS) of every row;
* :func:`ebfmi` -- E-BFMI of every chain.

They are the formulas of ArviZ's array layer (``arviz_stats.base.array_stats``:
``rhat(method="rank")``, ``ess(method="bulk")``, ``ess(method="tail", prob=(0.05, 0.95))``,
``bfmi``; unchanged from ArviZ 0.23), evaluated for all parameters at once with NumPy: one
sort per parameter and transform instead of SciPy's ``rankdata``, and one batched FFT
instead of a Python loop over parameters.  Tested equal to arviz-stats to 1e-10 relative.

Why we keep our own (issue 13 asked to use ArviZ's array layer if it is within 1.5x of
ours): measured by ``benchmarks/bench_diagnostics.py`` on NUTS draws of model ``same``
(native backend, 102 parameters = a, x0, x[1..100]; ``BENCHMARKS.md``, section
"Diagnostics: ours vs arviz-stats (issue 13)", 2026-11-29, 2-core AMD EPYC under load),
one trajectory's four statistics for all parameters take, as CPU time (median of 3):

* 4 x 6 000 draws: 0.37 s ours vs 1.23 s arviz-stats 0.8.0 (3.3x; wall-time ratio 3.4x),
  and 3.3x (wall 2.7x) with a stuck chain and a constant column written in;
* 4 x 1 000 draws: 0.049 s vs 0.275 s (5.8x; wall 5.0x), 6.2x (wall 6.8x) with the defects;

largest relative difference 2.6e-14 (tail-ESS), same NaNs.  arviz-stats is 2.7-6.8x
slower, not within 1.5x, and the workflow computes these for every trajectory (thousands
per scenario), so we keep the vectorised code; :class:`~ssmobs.nuts.convergence.ConvergenceSettings`
``implementation="arviz"`` calls arviz-stats instead (same numbers).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special


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
    return np.concatenate([a[:, :, :half], a[:, :, a.shape[2] - half :]], axis=1)


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
    # autocovariance (biased, / n) by FFT, as arviz-stats' ``autocov``
    from scipy.fft import next_fast_len

    nfft = next_fast_len(2 * n)
    chain_mean = x.mean(axis=2)
    f = np.fft.rfft(x - chain_mean[:, :, None], n=nfft, axis=2)
    # |F|^2 averaged over chains before the one inverse FFT
    power = (
        np.einsum("rck,rck->rk", f.real, f.real) + np.einsum("rck,rck->rk", f.imag, f.imag)
    ) / m_chains
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
    ps = rho[:, 0 : 2 * n_pairs : 2] + rho[:, 1 : 2 * n_pairs : 2]  # pair sums, j = 0..jmax
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

    Equal to arviz-stats' ``_rhat_rank``, ``_ess_bulk`` and ``_ess_tail`` per row; rows
    with a NaN give NaN; R-hat needs >= 2 chains and >= 4 draws (else NaN).
    """
    x = np.asarray(x, dtype=float)
    if x.shape[0] > CHUNK_ROWS:
        parts = [_rank_diagnostics(x[i : i + CHUNK_ROWS]) for i in range(0, x.shape[0], CHUNK_ROWS)]
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
    n_rows, _, half = sp.shape
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
            rhat[idx] = np.where(
                np.isnan(r_bulk) | np.isnan(r_fold), np.nan, np.maximum(r_bulk, r_fold)
            )
    ess_bulk[idx] = _ess_rows(z_bulk)
    if 2 * half == s:  # the split chains hold every draw: quantiles from the sorted rows
        q = [_sorted_quantile(srt, 0.05), _sorted_quantile(srt, 0.95)]
    else:
        q = list(_quantile_type7(xv.reshape(idx.size, -1), [0.05, 0.95]))
    ind = np.concatenate([sp <= q[0][:, None, None], sp <= q[1][:, None, None]]).astype(float)
    ess_q = _ess_rows(ind)
    ess_tail[idx] = np.minimum(ess_q[: idx.size], ess_q[idx.size :])
    return {"rhat": rhat, "ess_bulk": ess_bulk, "ess_tail": ess_tail}


def ebfmi(energy: np.ndarray) -> np.ndarray:
    """E-BFMI per chain: mean(diff(E)^2) / var(E, ddof=1) (ArviZ ``_bfmi``)."""
    e = np.atleast_2d(np.asarray(energy, dtype=float))
    num = np.square(np.diff(e, axis=1)).mean(axis=1)
    den = e.var(axis=1, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return num / den
