"""The Kalman filter of the models that are linear-Gaussian in the states (issue 11).

For fixed Omega, :func:`kalman_marginal` evaluates -2 log p(z | Omega) with the flat prior
p_0(x_0) of Sec. IV integrated out (the log marginal likelihood with a diffuse initial state,
exactly, including its Omega-dependent normalising terms) by the information form of the
Kalman filter: forward elimination of the block-tridiagonal precision of (x_0, ..., x_T)
given z, starting from zero information on x_0.  The same recursion run backwards
(Rauch-Tung-Striebel) gives the smoothed Gaussian N(mu_t, P_t) of every state x_t given
(Omega, z).  Everything is vectorised over Omega values and trajectories (a scalar
recursion for p = 1, p x p blocks otherwise).  It knows of a model only its matrices
``state_space_matrices(omega) -> (F, Q, H, R)``; the grid over Omega that turns it into
marginal posteriors is :mod:`ssmobs.exact.marginal`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models import StateSpaceModel

LOG_2PI = math.log(2 * math.pi)

#: the smallest batch for which the p = 2 filter works on the blocks' entries (it makes about
#: twice as many NumPy calls per step as the 2x2 matrix products, which cost more per element:
#: entrywise is 2.0x faster at 660 elements, 2.8x at 30000, and slower below about 50)
ENTRYWISE_MIN_BATCH = 64


@dataclass(frozen=True)
class KalmanMarginal:
    """Result of :func:`kalman_marginal` (batch shape ``B`` = broadcast of Omega and z)."""

    #: -2 log ∫ p(z, x_1..x_T | Omega, x_0) dx_0..dx_T (flat prior on x_0), shape B
    neg2_loglik: np.ndarray
    #: smoothed means E[x_t | Omega, z], t = 0..T, shape B + (T+1, p) (None unless smooth)
    mean: np.ndarray | None = None
    #: smoothed marginal variances Var[x_{t,i} | Omega, z], shape B + (T+1, p)
    var: np.ndarray | None = None


def kalman_marginal(
    model: StateSpaceModel, omega: np.ndarray, z: np.ndarray, smooth: bool = False
) -> KalmanMarginal:
    """Log marginal likelihood with a diffuse x_0 and, optionally, the smoothed states.

    Parameters
    ----------
    model : a model with ``linear_in_states``.
    omega : (..., m) parameter values.
    z : (..., T, d) observations; the batch shapes of ``omega`` and ``z`` broadcast.
    smooth : also return smoothed means and marginal variances of x_0..x_T.

    Returns
    -------
    :class:`KalmanMarginal`; -2 log p is +inf (or NaN) where Omega makes F singular or a
    noise variance non-positive (the value is then meaningless: callers mask the support).
    """
    if not model.linear_in_states:
        raise ValueError(f"model '{model.slug}' is not linear-Gaussian in the states")
    omega = np.asarray(omega, dtype=float)
    z = np.asarray(z, dtype=float)
    F, Q, H, R = model.state_space_matrices(omega)
    shape = np.broadcast_shapes(omega.shape[:-1], z.shape[:-2])
    parts = []
    with np.errstate(all="ignore"):
        for block in _blocks(shape):
            # each element's numbers depend on its own inputs only: blocks that fit in the
            # cache give the same numbers as the whole batch
            Fb, Qb, Hb, Rb, zb = (
                _take(a, block, shape, n_core)
                for a, n_core in ((F, 2), (Q, 1), (H, 2), (R, 1), (z, 2))
            )
            if model.state_dim == 1:
                parts.append(_kalman_p1(Fb[..., 0, 0], Qb[..., 0], Hb[..., :, 0], Rb, zb, smooth))
            else:
                parts.append(_kalman_general(Fb, Qb, Hb, Rb, zb, smooth))
    if len(parts) == 1:
        return parts[0]
    axis = len(shape) - 1
    neg2 = np.concatenate([k.neg2_loglik for k in parts], axis)
    if not smooth:
        return KalmanMarginal(neg2)
    mean = np.concatenate([k.mean for k in parts if k.mean is not None], axis)
    var = np.concatenate([k.var for k in parts if k.var is not None], axis)
    return KalmanMarginal(neg2, mean, var)


#: the filter runs on blocks of about this many batch elements (along the batch's last
#: axis), whose arrays stay in the CPU cache: 1.5x (p = 1) and 1.3x (p = 2) faster than
#: whole fine grids of 13 x 29791 and 5 x 28561 elements, and 2048 or 32768 gain less
FILTER_BLOCK = 8192


def _blocks(shape: tuple[int, ...]) -> list[slice]:
    """Slices of the batch's last axis holding about FILTER_BLOCK elements each."""
    n = math.prod(shape)
    if not shape or n <= FILTER_BLOCK:
        return [slice(None)]
    step = max(1, FILTER_BLOCK * shape[-1] // n)
    return [slice(s, s + step) for s in range(0, shape[-1], step)]


def _take(a: np.ndarray, block: slice, shape: tuple[int, ...], n_core: int) -> np.ndarray:
    """``a``'s part in ``block`` of the batch's last axis (all of it where ``a`` is
    broadcast along that axis); ``n_core`` trailing axes are not batch axes."""
    n_batch = a.ndim - n_core
    if block == slice(None) or n_batch < 1 or a.shape[n_batch - 1] == 1:
        return a
    assert a.shape[n_batch - 1] == shape[-1]
    return a[(Ellipsis, block) + (slice(None),) * n_core]


def _kalman_p1(
    f: np.ndarray, q: np.ndarray, h: np.ndarray, r: np.ndarray, z: np.ndarray, smooth: bool
) -> KalmanMarginal:
    T, d = z.shape[-2:]
    hr = h / r  # (..., d)
    hrh = sum(h[..., i] * hr[..., i] for i in range(d))
    a0 = f * f / q
    a_mid = hrh + 1 / q + a0
    a_end = hrh + 1 / q
    bm = -f / q  # block (t, t-1) of the precision
    zz = (z * z).sum(-2)
    c = sum(zz[..., i] / r[..., i] for i in range(d))
    S = a0
    y = np.zeros(np.broadcast_shapes(z.shape[:-2], np.shape(f)))
    logdet = np.log(S)
    quad: np.ndarray | float = 0.0
    Ss, ys = [S], [y]
    # the sums over d in place, in the order of sum(): ((0 + z_t1 hr_1) + z_t2 hr_2) + ...
    hr_i = [hr[..., i].copy() for i in range(d)]
    z_i = [z[..., i].copy() for i in range(d)]
    y_shape = np.broadcast_shapes(y.shape, np.shape(hr)[:-1], np.shape(bm))
    for t in range(1, T + 1):
        g = bm / S
        S = (a_mid if t < T else a_end) - g * bm
        y_new = np.multiply(z_i[0][..., t - 1], hr_i[0], out=np.empty(y_shape))  # H' R^-1 z_t
        y_new += 0.0
        for i in range(1, d):
            y_new += z_i[i][..., t - 1] * hr_i[i]
        y_new -= g * y
        y = y_new
        term = y * y
        term /= S
        quad = _add_term(quad, term)
        logdet = logdet + np.log(S)
        if smooth:
            Ss.append(S)
            ys.append(y)
    neg2 = (
        c
        - quad
        + logdet
        + T * (sum(np.log(r[..., i]) for i in range(d)) + np.log(q))
        + ((d + 1) * T - (T + 1)) * LOG_2PI
    )
    if not smooth:
        return KalmanMarginal(neg2)
    shape = np.broadcast_shapes(np.shape(neg2), np.shape(Ss[-1]))
    mean = np.empty(shape + (T + 1, 1))
    var = np.empty(shape + (T + 1, 1))
    m = ys[T] / Ss[T]
    v = 1 / Ss[T]
    mean[..., T, 0], var[..., T, 0] = m, v
    for t in range(T - 1, -1, -1):
        gi = bm / Ss[t]
        m = ys[t] / Ss[t] - gi * m
        v = 1 / Ss[t] + gi * gi * v
        mean[..., t, 0], var[..., t, 0] = m, v
    return KalmanMarginal(neg2, mean, var)


def _add_term(total: np.ndarray | float, term: np.ndarray) -> np.ndarray:
    """``total + term``, in place once ``total`` is an array (the first step's 0.0 + term
    makes it one): the numbers of ``total = total + term``, without a new array per step."""
    if isinstance(total, np.ndarray):
        total += term
        return total
    return total + term


def _inv(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of (..., 2, 2) matrices in closed form."""
    det = A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] * A[..., 1, 0]
    out = np.empty(np.shape(A))
    out[..., 0, 0] = A[..., 1, 1] / det
    out[..., 1, 1] = A[..., 0, 0] / det
    out[..., 0, 1] = -A[..., 0, 1] / det
    out[..., 1, 0] = -A[..., 1, 0] / det
    return out, det


def _kalman_general(
    F: np.ndarray, Q: np.ndarray, H: np.ndarray, R: np.ndarray, z: np.ndarray, smooth: bool
) -> KalmanMarginal:
    p = F.shape[-1]
    if p != 2:
        raise NotImplementedError("the exact marginal is implemented for p = 1 and p = 2")
    T, d = z.shape[-2:]
    Ft = np.swapaxes(F, -1, -2)
    Qi = 1 / Q
    HtRi = np.swapaxes(H, -1, -2) / R[..., None, :]  # (..., p, d)
    hrh = HtRi @ H
    a0 = Ft @ (Qi[..., :, None] * F)
    diagQi = Qi[..., :, None] * np.eye(p)
    a_mid = hrh + diagQi + a0
    a_end = hrh + diagQi
    bm = -Qi[..., :, None] * F  # block (t, t-1)
    bmt = np.swapaxes(bm, -1, -2)
    c = ((z * z).sum(-2) / R).sum(-1)
    S = a0
    Si, det = _inv(S)
    shape = np.broadcast_shapes(z.shape[:-2], F.shape[:-2])
    entrywise = d == 1 and math.prod(shape) >= ENTRYWISE_MIN_BATCH and _off_diagonal_zero(bm)
    prec = _Precision(a_mid, a_end, bm, HtRi, Si, det, shape)
    if entrywise:
        # the smoother's means and variances keep the zero terms (they are used unmasked)
        quad, logdet, Sis, ys = _forward_diagonal(prec, z, smooth, zero_terms=smooth)
    else:
        quad, logdet, Sis, ys = _forward_blas(prec, z, smooth)
    neg2 = (
        c
        - quad
        + logdet
        + T * (np.log(R).sum(-1) + np.log(Q).sum(-1))
        + ((d + p) * T - p * (T + 1)) * LOG_2PI
    )
    if not smooth:
        return KalmanMarginal(neg2)
    shape = np.broadcast_shapes(np.shape(neg2), Sis[-1].shape[:-2])
    mean = np.empty(shape + (T + 1, p))
    var = np.empty(shape + (T + 1, p))
    m = (Sis[T] @ ys[T][..., None])[..., 0]
    P = Sis[T]
    mean[..., T, :], var[..., T, :] = m, np.diagonal(P, axis1=-2, axis2=-1)
    for t in range(T - 1, -1, -1):
        gi = Sis[t] @ bmt  # S_t^-1 B'
        m = (Sis[t] @ ys[t][..., None])[..., 0] - (gi @ m[..., None])[..., 0]
        P = Sis[t] + gi @ P @ np.swapaxes(gi, -1, -2)
        mean[..., t, :], var[..., t, :] = m, np.diagonal(P, axis1=-2, axis2=-1)
    return KalmanMarginal(neg2, mean, var)


#: what a forward pass returns: the quadratic form and log-determinant sums, and (smooth
#: only, else empty) S_t^-1 and the information vectors y_t for t = 0..T
Forward = tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]


@dataclass(frozen=True)
class _Precision:
    """The blocks of the precision of (x_0..x_T) given Omega and z that a forward pass of
    the p = 2 filter eliminates: diagonal blocks A (t < T and t = T), the off-diagonal
    block B = -Q^-1 F, H' R^-1, and S_0^-1 with det S_0; ``shape`` is the batch's."""

    a_mid: np.ndarray
    a_end: np.ndarray
    bm: np.ndarray
    HtRi: np.ndarray
    Si0: np.ndarray
    det0: np.ndarray
    shape: tuple[int, ...]


def _forward_blas(prec: _Precision, z: np.ndarray, smooth: bool) -> Forward:
    """Forward elimination of the block-tridiagonal precision with 2x2 blocks (any F, d)."""
    a_mid, a_end, bm, HtRi = prec.a_mid, prec.a_end, prec.bm, prec.HtRi
    Si, det, shape = prec.Si0, prec.det0, prec.shape
    T = z.shape[-2]
    bmt = np.swapaxes(bm, -1, -2)
    y = np.zeros(shape + (2,))
    logdet = np.log(det)
    quad: np.ndarray | float = 0.0
    Sis, ys = [Si], [y]
    for t in range(1, T + 1):
        g = bm @ Si
        S = (a_mid if t < T else a_end) - g @ bmt
        b_t = (HtRi @ z[..., t - 1, :, None])[..., 0]
        y = b_t - (g @ y[..., None])[..., 0]
        Si, det = _inv(S)
        quad = quad + np.einsum("...i,...ij,...j->...", y, Si, y)
        logdet = logdet + np.log(det)
        if smooth:
            Sis.append(Si)
            ys.append(y)
    return np.asarray(quad), logdet, (Sis if smooth else []), (ys if smooth else [])


def _off_diagonal_zero(bm: np.ndarray) -> bool:
    """Whether every block B = -Q^-1 F is diagonal (F diagonal and Q^-1 finite)."""
    return not (np.any(bm[..., 0, 1]) or np.any(bm[..., 1, 0]))


def _forward_diagonal(
    prec: _Precision, z: np.ndarray, smooth: bool, zero_terms: bool = False
) -> Forward:
    """:func:`_forward_blas` for a diagonal B and d = 1, on the blocks' entries.

    Every product of 2x2 blocks that involves B has one exactly zero term per entry (B's
    off-diagonal), so the sum of the two products is the same whether the matrix library
    fuses the multiply-add or not.  With ``zero_terms`` each entry is written out term by
    term, zero term included: the library's numbers to the bit, non-finite ones included.
    Without them a zero term is left out, which changes nothing (but the sign of a zero)
    while every S_t^-1, t < T, is finite, where the zero term is +-0; and if one is not,
    S_t+1 or a later S is not finite either, so log det and -2 log p are not finite on
    both paths (their callers map that to log p = -inf).  g y has two non-zero terms and
    stays the library's product (same operand shapes, so the same loop of the library);
    the quadratic form is einsum's order, (((y0 S00 y0 + y0 S01 y1) + y1 S10 y0) + y1 S11 y1).
    """
    a_mid, a_end, bm, HtRi = prec.a_mid, prec.a_end, prec.bm, prec.HtRi
    Si, det, shape = prec.Si0, prec.det0, prec.shape
    T = z.shape[-2]
    b00, b01, b10, b11 = (bm[..., i, j].copy() for i in (0, 1) for j in (0, 1))
    h0, h1 = HtRi[..., 0, 0].copy(), HtRi[..., 1, 0].copy()
    mid = [a_mid[..., i, j].copy() for i in (0, 1) for j in (0, 1)]
    end = [a_end[..., i, j].copy() for i in (0, 1) for j in (0, 1)]
    s00, s01, s10, s11 = (Si[..., i, j] for i in (0, 1) for j in (0, 1))
    # g = B S^-1 (for the library's matrix-vector product); like S it does not depend on z
    g = np.empty(np.broadcast_shapes(bm.shape[:-2], Si.shape[:-2]) + (2, 2))
    g00, g01, g10, g11 = g[..., 0, 0], g[..., 0, 1], g[..., 1, 0], g[..., 1, 1]
    y = np.zeros(shape + (2,))
    logdet = np.log(det)
    quad: np.ndarray | float = 0.0
    Sis, ys = [Si], [y]
    for t in range(1, T + 1):
        a00, a01, a10, a11 = mid if t < T else end
        if zero_terms:
            np.add(b00 * s00, b01 * s10, out=g00)
            np.add(b00 * s01, b01 * s11, out=g01)
            np.add(b10 * s00, b11 * s10, out=g10)
            np.add(b10 * s01, b11 * s11, out=g11)
            # S = A - g B'
            S00 = a00 - (g00 * b00 + g01 * b01)
            S01 = a01 - (g00 * b10 + g01 * b11)
            S10 = a10 - (g10 * b00 + g11 * b01)
            S11 = a11 - (g10 * b10 + g11 * b11)
        else:
            np.multiply(b00, s00, out=g00)
            np.multiply(b00, s01, out=g01)
            np.multiply(b11, s10, out=g10)
            np.multiply(b11, s11, out=g11)
            S00 = a00 - g00 * b00
            S01 = a01 - g01 * b11
            S10 = a10 - g10 * b00
            S11 = a11 - g11 * b11
        gy = g @ y[..., None]
        z_t = z[..., t - 1, 0]
        y0 = np.multiply(h0, z_t, out=np.empty(shape))
        y0 += 0.0  # the library's 0 + h z
        y0 -= gy[..., 0, 0]
        y1 = np.multiply(h1, z_t, out=np.empty(shape))
        y1 += 0.0
        y1 -= gy[..., 1, 0]
        y = np.stack([y0, y1], -1)
        # S^-1 as _inv
        det = S00 * S11 - S01 * S10
        s00, s11, s01, s10 = S11 / det, S00 / det, -S01 / det, -S10 / det
        q = y0 * s00
        q *= y0
        for u, s_uv, v in ((y0, s01, y1), (y1, s10, y0), (y1, s11, y1)):
            term = u * s_uv
            term *= v
            q += term
        quad = _add_term(quad, q)
        logdet = logdet + np.log(det)
        if smooth:
            Si = np.empty(np.shape(det) + (2, 2))
            Si[..., 0, 0], Si[..., 0, 1], Si[..., 1, 0], Si[..., 1, 1] = s00, s01, s10, s11
            Sis.append(Si)
            ys.append(y)
    return np.asarray(quad), logdet, (Sis if smooth else []), (ys if smooth else [])
