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
    with np.errstate(all="ignore"):
        if model.state_dim == 1:
            return _kalman_p1(F[..., 0, 0], Q[..., 0], H[..., :, 0], R, z, smooth)
        return _kalman_general(F, Q, H, R, z, smooth)


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
    quad = 0.0
    Ss, ys = [S], [y]
    for t in range(1, T + 1):
        g = bm / S
        S = (a_mid if t < T else a_end) - g * bm
        b_t = sum(z[..., t - 1, i] * hr[..., i] for i in range(d))  # H' R^-1 z_t
        y = b_t - g * y
        quad = quad + y * y / S
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
    y = np.zeros(np.broadcast_shapes(z.shape[:-2], F.shape[:-2]) + (p,))
    logdet = np.log(det)
    quad = 0.0
    Ss, Sis, ys = [S], [Si], [y]
    for t in range(1, T + 1):
        g = bm @ Si
        S = (a_mid if t < T else a_end) - g @ bmt
        b_t = (HtRi @ z[..., t - 1, :, None])[..., 0]
        y = b_t - (g @ y[..., None])[..., 0]
        Si, det = _inv(S)
        quad = quad + np.einsum("...i,...ij,...j->...", y, Si, y)
        logdet = logdet + np.log(det)
        if smooth:
            Ss.append(S)
            Sis.append(Si)
            ys.append(y)
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
