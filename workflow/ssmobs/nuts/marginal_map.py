"""Marginal MAP estimates and 90 % intervals from MCMC draws (Sec. III.C, Eq. (11), (12)).

For every component Theta_j of Theta = (Omega, x_0, x_1..x_T) the marginal MAP estimate is
the argmax of a kernel density estimate of its pooled draws (Eq. (11)), and the interval is
(empirical 5 % quantile, empirical 95 % quantile) of the same draws (Eq. (12)).

The KDE
-------
The paper's kde is that of Silverman (1986) [31]: a Gaussian kernel with the rule-of-thumb
bandwidth ``h = 0.9 min(sd, IQR / 1.34) n^(-1/5)`` (Silverman's Eq. (3.31); R's
``bw.nrd0``), computed the way Silverman's own algorithm does it (Silverman 1982, Appl.
Stat. AS 176; also R's ``density()``): linear binning of the draws onto a regular grid,
then convolution with the kernel by FFT.  We do that for all |Theta| components at once
(one ``bincount`` and one batched FFT), so 102 components x 24 000 draws take a few
hundredths of a second.  The grid spacing is at most h / 8 (the grid covers the draws plus
4 h on each side, and has 2^k points, 256 <= 2^k <= 65 536), and the argmax is refined by
a parabola through the three grid values around it; the binned density differs from the
exact Gaussian KDE by O(spacing^2 / h^2) (tested against ``scipy.stats.gaussian_kde``).

Why not ArviZ's KDE (``arviz_stats``' ``kde``, formerly ``az.kde``): it is binned too but
convolves directly on a 512-point grid over [min, max], so its grid error grows with the
range of the draws (heavy tails), it loops in Python per component, and its default
bandwidth ("experimental": mean of Silverman's rule and ISJ) is not the paper's.  Both
agree on the mode well within Monte Carlo error (``tests/unit/nuts/test_marginal_map.py``).

Empirical quantiles are R's type 7 (NumPy's default ``linear``), as ``quantile()`` in R.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..stan_backends.base import Draws

if TYPE_CHECKING:
    from ..models.base import StateSpaceModel

#: grid spacing is at most bandwidth / GRID_PER_BW
GRID_PER_BW = 8
GRID_MIN = 256
GRID_MAX = 65536
#: the grid extends this many bandwidths beyond the smallest and largest draw
GRID_MARGIN_BW = 4.0


class KDEError(ValueError):
    """A KDE mode cannot be computed (non-finite draws, zero spread, too few draws)."""


def silverman_bandwidth(
    x: np.ndarray, sd: np.ndarray | None = None, iqr: np.ndarray | None = None
) -> np.ndarray:
    """Silverman's rule of thumb 0.9 min(sd, IQR/1.34) n^(-1/5) per row of ``x`` (rows, n).

    When the IQR is 0 (more than half the draws tied) the sd is used, as R's ``bw.nrd0``.
    """
    x = np.atleast_2d(x)
    n = x.shape[1]
    if sd is None:
        sd = x.std(axis=1, ddof=1)
    if iqr is None:
        q25, q75 = np.quantile(x, [0.25, 0.75], axis=1)
        iqr = q75 - q25
    spread = np.where(iqr > 0, np.minimum(sd, iqr / 1.34), sd)
    return 0.9 * spread * n ** (-0.2)


def _validate(x: np.ndarray, names: list[str] | None) -> None:
    label = (lambda i: names[i]) if names else (lambda i: f"row {i}")
    if x.shape[1] < 2:
        raise KDEError(f"a KDE needs at least 2 draws, got {x.shape[1]}")
    finite = np.isfinite(x).all(axis=1)
    if not finite.all():
        bad = [label(i) for i in np.flatnonzero(~finite)]
        raise KDEError(f"non-finite draws in {bad[:5]}{' ...' if len(bad) > 5 else ''}")
    spread = x.max(axis=1) - x.min(axis=1)
    zero = ~(spread > 0)
    if zero.any():
        bad = [label(i) for i in np.flatnonzero(zero)]
        raise KDEError(
            f"zero spread (all draws equal) in {bad[:5]}{' ...' if len(bad) > 5 else ''}"
        )


def binned_kde(
    x: np.ndarray, bw: np.ndarray | None = None, names: list[str] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gaussian KDE of every row of ``x`` (rows, n) on a regular grid, by binning + FFT.

    Returns ``lo`` (rows,), ``delta`` (rows,) and ``density`` (rows, G): the density at
    ``lo + j * delta``, j = 0..G-1 (integrates to about 1).  Raises :class:`KDEError`
    for non-finite draws or zero spread.
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    _validate(x, names)
    rows, n = x.shape
    xmin, xmax = x.min(axis=1), x.max(axis=1)
    if bw is None:
        bw = silverman_bandwidth(x)
    bw = np.asarray(bw, dtype=float)
    if not np.all(bw > 0):
        raise KDEError("bandwidth must be positive")
    width = (xmax - xmin) + 2 * GRID_MARGIN_BW * bw
    need = int(np.max(np.ceil(width / (bw / GRID_PER_BW)))) + 1
    g = int(min(GRID_MAX, max(GRID_MIN, 1 << (need - 1).bit_length())))
    lo = xmin - GRID_MARGIN_BW * bw
    delta = width / (g - 1)
    # linear binning: each draw splits its weight between the two neighbouring grid points
    pos = (x - lo[:, None]) / delta[:, None]
    left = np.floor(pos)
    frac = pos - left
    left = np.clip(left.astype(np.int64), 0, g - 2)
    base = (np.arange(rows, dtype=np.int64) * g)[:, None]
    idx = (base + left).ravel()
    counts = np.bincount(idx, weights=(1.0 - frac).ravel(), minlength=rows * g)
    counts += np.bincount(idx + 1, weights=frac.ravel(), minlength=rows * g)
    counts = counts.reshape(rows, g)
    # circular convolution with the Gaussian kernel; the draws sit >= 4 h from both grid
    # ends, so wrap-around mixes values >= 8 h apart (weight exp(-32)): negligible
    offs = np.arange(g, dtype=float)
    offs = np.where(offs < g / 2, offs, offs - g)
    kern = np.exp(-0.5 * (offs[None, :] * (delta / bw)[:, None]) ** 2)
    dens = np.fft.irfft(np.fft.rfft(counts, axis=1) * np.fft.rfft(kern, axis=1), n=g, axis=1)
    dens /= (n * bw * math.sqrt(2 * math.pi))[:, None]
    return lo, delta, dens


def _modes_from_grid(lo: np.ndarray, delta: np.ndarray, dens: np.ndarray) -> np.ndarray:
    g = dens.shape[1]
    j = np.argmax(dens, axis=1)
    jc = np.clip(j, 1, g - 2)
    rows = np.arange(dens.shape[0])
    ym, y0, yp = dens[rows, jc - 1], dens[rows, jc], dens[rows, jc + 1]
    denom = ym - 2 * y0 + yp
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(denom < 0, 0.5 * (ym - yp) / denom, 0.0)
    off = np.clip(off, -0.5, 0.5)
    pos = np.where(j == jc, jc + off, j)
    return lo + pos * delta


def kde_modes(x: np.ndarray, names: list[str] | None = None) -> np.ndarray:
    """Argmax of the binned Gaussian KDE of every row of ``x`` (rows, n) (Eq. (11))."""
    lo, delta, dens = binned_kde(x, names=names)
    return _modes_from_grid(lo, delta, dens)


def kde_mode(draws_1d: np.ndarray) -> float:
    """Marginal MAP of one component: argmax of the KDE of its (pooled) draws (Eq. (11)).

    Raises :class:`KDEError` for non-finite draws, zero spread or fewer than 2 draws.
    """
    x = np.asarray(draws_1d, dtype=float).reshape(1, -1)
    return float(kde_modes(x)[0])


# --------------------------------------------------------------------------- Theta draws
def _param_block(draws: Draws, name: str, shape_tail: tuple[int, ...]) -> np.ndarray:
    """Parameter ``name`` as (chain, draw, prod(shape_tail)), C order of ``shape_tail``.

    Size-1 axes are ignored when matching (a scalar may come as (chain, draw, 1)); a
    (T, p) block stored as (p, T) is transposed.
    """
    if name not in draws.params:
        raise KeyError(f"the draws have no parameter '{name}' (have {sorted(draws.params)})")
    arr = np.asarray(draws.params[name], dtype=float)
    if arr.ndim < 2:
        raise ValueError(f"parameter '{name}' has shape {arr.shape}; expected (chain, draw, ...)")
    c, s = arr.shape[:2]
    tail = arr.shape[2:]

    def squeeze(shp: tuple[int, ...]) -> tuple[int, ...]:
        return tuple(d for d in shp if d != 1)

    if squeeze(tail) == squeeze(shape_tail):
        return arr.reshape(c, s, -1)
    if len(shape_tail) == 2 and tail == shape_tail[::-1]:
        return np.swapaxes(arr, 2, 3).reshape(c, s, -1)
    raise ValueError(f"parameter '{name}' has shape {tail} per draw, expected {shape_tail}")


def theta_draws(draws: Draws, model: StateSpaceModel, T: int) -> np.ndarray:
    """Draws of Theta = (Omega, x_0, x_1..x_T) as (|Theta|, chain * draw), pooled over chains.

    Row order is ``model.theta_names(T)``.  The Stan programs name Omega's components as
    the model's ``param_names`` (scalars), the initial state ``x0`` (scalar, or vector of
    length p) and the states ``x`` ((T,) or (T, p)); a program that keeps x_0 inside ``x``
    ((T+1,) or (T+1, p), no ``x0``) is accepted too.
    """
    p = int(model.state_dim)
    blocks = [_param_block(draws, name, ()) for name in model.param_names]

    def state_shape(rows: int) -> tuple[int, ...]:
        return (rows,) if p == 1 else (rows, p)

    if "x0" in draws.params:
        blocks.append(_param_block(draws, "x0", () if p == 1 else (p,)))
        blocks.append(_param_block(draws, "x", state_shape(T)))
    else:
        blocks.append(_param_block(draws, "x", state_shape(T + 1)))
    full = np.concatenate(blocks, axis=2)  # (chain, draw, |Theta|)
    c, s, n = full.shape
    expected = len(model.theta_names(T))
    if n != expected:
        raise ValueError(f"Theta has {n} components in the draws, expected {expected}")
    return np.ascontiguousarray(full.reshape(c * s, n).T)


def marginal_summary(draws: Draws, model: StateSpaceModel, T: int) -> dict[str, Any]:
    """Marginal MAP (Eq. (11)) and 5 % / 95 % empirical quantiles (Eq. (12)) of every
    component of Theta, in ``model.theta_names(T)`` order.

    Returns ``{"names": list[str], "map": (|Theta|,), "q5": (|Theta|,), "q95": (|Theta|,)}``.
    Raises :class:`KDEError` (naming the components) for non-finite draws or zero spread.
    """
    names = model.theta_names(T)
    x = theta_draws(draws, model, T)
    _validate(x, names)
    q5, q25, q75, q95 = np.quantile(x, [0.05, 0.25, 0.75, 0.95], axis=1)
    bw = silverman_bandwidth(x, iqr=q75 - q25)
    lo, delta, dens = binned_kde(x, bw=bw, names=names)
    return {"names": names, "map": _modes_from_grid(lo, delta, dens), "q5": q5, "q95": q95}
