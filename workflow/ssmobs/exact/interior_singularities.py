"""Interior singularities of p(Omega | z) for the exact stage (:mod:`ssmobs.exact.marginal`).

With the flat prior on x_0 (Sec. IV) the marginal posterior diverges where x_0 drops out of
the likelihood; at an end of the support that is :mod:`ssmobs.exact.boundaries`' case, here
the point lies inside it (e.g. like 1/|a1 a2| for two AR(1) components seen through their
sum).  :func:`interior_dropouts` finds such points on each bounded axis through the mode,
:func:`interior_slopes` measures the slope toward them as at the ends, and
:func:`interior_valleys` stops the grid's box at the valley between the point and the mode.
"""

from __future__ import annotations

import math

import numpy as np

from ..models import PriorBounds, StateSpaceModel
from .boundaries import improper, spike_ratio
from .omega_grid import OmegaAxes, log_density_u, log_posterior_omega
from .settings import ExactSettings

#: nodes of the scan along each axis for points where x0 drops out
DROPOUT_SCAN_NODES = 2001
#: log s_min of O this far below its largest value on the scan line marks a candidate node
DROPOUT_CANDIDATE_DROP = 5.0
#: ... and after refinement this far below: x0 drops out there (s_min = 0 up to rounding)
DROPOUT_CONFIRM_DROP = 25.0


def _log_observability(model: StateSpaceModel, omega: np.ndarray) -> np.ndarray:
    """log s_min, the smallest singular value of the observability matrix
    O = [H F; H F^2; ...; H F^p] of x_0 at ``omega`` (..., m): -inf (down to rounding)
    where a direction of x_0 never reaches the mean of z."""
    F, _, H, _ = model.state_space_matrices(omega)
    p = F.shape[-1]
    blocks = []
    power = F
    for _ in range(p):
        blocks.append(H @ power)
        power = power @ F
    obs = np.concatenate(blocks, axis=-2)
    with np.errstate(all="ignore"):
        sv = np.linalg.svd(obs, compute_uv=False)
        return np.log(sv[..., -1])


def interior_dropouts(
    model: StateSpaceModel, bounds: PriorBounds, at: np.ndarray, margin: float = 1e-6
) -> np.ndarray:
    """Per trajectory and component j of a bounded support, the point c strictly inside it
    where the flat-prior x_0 drops out of the likelihood along axis j through ``at`` (K, m)
    (the other components held there), nearest to ``at``; NaN where there is none.

    x_0 drops out where the observability matrix O of (F, H) loses rank (a direction of x_0
    reaches no observation), e.g. a1 = 0, a2 = 0 and a1 = a2 for two AR(1) components seen
    through their sum.  Found on a scan of :data:`DROPOUT_SCAN_NODES` nodes (interior local
    minima of log s_min of O), refined by golden-section search and kept where that
    falls :data:`DROPOUT_CONFIRM_DROP` below the scan's largest value.  Half lines are not
    scanned."""
    K, m = at.shape
    out = np.full((K, m), np.nan)
    n = DROPOUT_SCAN_NODES
    for j in range(m):
        lo, hi = float(bounds.lower[j]), float(bounds.upper[j])
        if not (np.isfinite(lo) and np.isfinite(hi)):
            continue
        width = hi - lo
        nodes = np.linspace(lo + margin * width, hi - margin * width, n)
        pts = np.repeat(at[:, None, :], n, axis=1)
        pts[:, :, j] = nodes
        g = _log_observability(model, pts)  # (K, n)
        top = np.max(np.where(np.isfinite(g), g, -np.inf), axis=1, keepdims=True)
        inner = g[:, 1:-1]
        local_min = (inner <= g[:, :-2]) & (inner <= g[:, 2:])
        local_min &= inner < top - DROPOUT_CANDIDATE_DROP
        if not local_min.any():
            continue
        dist = np.where(local_min, np.abs(nodes[1:-1][None, :] - at[:, j : j + 1]), np.inf)
        i = dist.argmin(1) + 1  # node index of the nearest candidate
        has = np.isfinite(dist.min(1))
        a, b = nodes[np.maximum(i - 1, 0)], nodes[np.minimum(i + 1, n - 1)]
        c, gc = _golden_minimum(model, at, j, a, b)
        ok = has & (gc < top[:, 0] - DROPOUT_CONFIRM_DROP) & (c > lo) & (c < hi)
        out[:, j] = np.where(ok, c, np.nan)
    return out


def _golden_minimum(
    model: StateSpaceModel, at: np.ndarray, j: int, a: np.ndarray, b: np.ndarray, steps: int = 80
) -> tuple[np.ndarray, np.ndarray]:
    """Golden-section search for the minimum of :func:`_log_observability` along axis j in
    [a, b] (K,)."""
    ratio = (np.sqrt(5.0) - 1) / 2

    def g(x: np.ndarray) -> np.ndarray:
        pts = at.copy()
        pts[:, j] = x
        return _log_observability(model, pts)

    a, b = a.copy(), b.copy()
    for _ in range(steps):
        x1, x2 = b - ratio * (b - a), a + ratio * (b - a)
        left = g(x1) <= g(x2)
        b = np.where(left, x2, b)
        a = np.where(left, a, x1)
    c = (a + b) / 2
    return c, g(c)


def interior_slopes(
    model: StateSpaceModel,
    z: np.ndarray,
    bounds: PriorBounds,
    at: np.ndarray,
    points: np.ndarray,
    distances: tuple[float, float] = (1e-4, 1e-6),
) -> np.ndarray:
    """Slopes d log p(Omega|z) / d log|Omega_j - c_j| toward the interior points ``points``
    (K, m) (:func:`interior_dropouts`; NaN: none) from the side of ``at``, as
    :func:`boundary_slopes` measures them at the ends: between the two ``distances``."""
    K, m = at.shape
    out = np.full((K, m), np.nan)
    d1, d2 = distances
    for j in range(m):
        c = points[:, j]
        if not np.isfinite(c).any():
            continue
        sgn = np.where(at[:, j] >= c, 1.0, -1.0)
        safe = np.where(np.isfinite(c), c, at[:, j])
        pts = np.repeat(at[:, None, :], 2, axis=1)
        pts[:, 0, j] = safe + sgn * d1
        pts[:, 1, j] = safe + sgn * d2
        lp = log_posterior_omega(model, pts, z[:, None], bounds)
        with np.errstate(invalid="ignore"):
            s = (lp[:, 1] - lp[:, 0]) / (math.log(d2) - math.log(d1))
        out[:, j] = np.where(np.isfinite(c) & np.all(np.isfinite(lp), axis=1), s, np.nan)
    return out


def interior_valleys(
    model: StateSpaceModel,
    axes: OmegaAxes,
    z: np.ndarray,
    bounds: PriorBounds,
    u: np.ndarray,
    H: np.ndarray,
    points: np.ndarray,
    slopes: np.ndarray,
    *,
    limits: tuple[np.ndarray, np.ndarray],
    settings: ExactSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`valley_limits` for the improper interior points ``points`` (K, m) (NaN: none):
    toward each, the box stops at the valley between it and the mode ``u`` (the lower limit
    where the point lies below the mode, else the upper; at the spike's foot,
    ``spike_distance`` from the point, where there is no valley), within ``limits`` = (lo, hi)
    (K, m) already set; the returned ratio (K,) is the mass of the spike on the mode's side
    of the point beyond the valley, down to ``spike_distance`` from it, relative to the
    basin's (0 where no point is cut; the spike's other side is not counted)."""
    K, m = u.shape
    n = settings.valley_nodes
    lo_lim, hi_lim = limits[0].copy(), limits[1].copy()
    ratio = np.zeros(K)
    s = np.linspace(0, 1, n)
    rows = np.arange(K)
    delta = settings.spike_distance
    cut = np.isfinite(points) & improper(slopes, finite=True)
    for j in range(m):
        if axes.log_scale[j] or not cut[:, j].any():
            continue
        c = np.where(cut[:, j], points[:, j], u[:, j])
        below = c < u[:, j]
        sgn = np.where(below, 1.0, -1.0)
        start = c + sgn * delta  # the spike's foot on the mode's side
        pts = np.repeat(u[:, None, :], n, axis=1)
        pts[:, :, j] = start[:, None] + (u[:, j : j + 1] - start[:, None]) * s
        lpu, lp = log_density_u(model, axes, pts, z[:, None], bounds)
        lpu = np.where(np.isfinite(lpu), lpu, np.inf)
        i = lpu.argmin(1)
        valley = cut[:, j] & (i > 0) & (lpu[:, 0] > lpu[rows, i])
        where = pts[rows, i, j]
        # without a valley the box still never crosses the point: it stops at the spike's foot
        stop = np.where(valley, where, start)
        lo_lim[:, j] = np.where(cut[:, j] & below, np.maximum(lo_lim[:, j], stop), lo_lim[:, j])
        hi_lim[:, j] = np.where(cut[:, j] & ~below, np.minimum(hi_lim[:, j], stop), hi_lim[:, j])
        with np.errstate(all="ignore"):
            sd = 1 / np.sqrt(-H[:, j, j])
        dist = np.abs(where - c)
        r = spike_ratio(lp[rows, i], lp[:, -1], dist, slopes[:, j], delta, sd, valley)
        ratio = np.where(cut[:, j], np.maximum(ratio, np.nan_to_num(r, nan=np.inf)), ratio)
    return lo_lim, hi_lim, ratio
