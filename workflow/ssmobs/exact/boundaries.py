"""Improper boundaries of p(Omega | z) for the exact marginal stage (:mod:`ssmobs.exact.marginal`).

:func:`boundary_slopes` measures d log p / d log(distance to the boundary) along each axis,
:func:`improper` reads a slope as non-integrable, and :func:`valley_limits` cuts the grid's
box at the valley between the interior mode and an improper boundary, estimating the mass
cut off (``spike_ratio``).  The same inside the support:
:mod:`ssmobs.exact.interior_singularities`.
"""

from __future__ import annotations

import math

import numpy as np

from ..models import PriorBounds, StateSpaceModel
from .omega_grid import OmegaAxes, log_density_u, log_posterior_omega
from .settings import ExactSettings


def improper(slope: np.ndarray, finite: bool) -> np.ndarray:
    """Non-integrable where density ~ distance^slope with slope <= -1 at a finite boundary
    (tolerance 0.05), or ~ Omega^slope with slope >= -1 at infinity."""
    slope = np.asarray(slope, dtype=float)
    with np.errstate(invalid="ignore"):
        return (slope <= -0.95) if finite else (slope >= -1.05)


def boundary_slopes(
    model: StateSpaceModel,
    z: np.ndarray,
    bounds: PriorBounds,
    at: np.ndarray,
    distances: tuple[float, float] = (1e-4, 1e-6),
) -> tuple[np.ndarray, np.ndarray]:
    """Slopes d log p(Omega|z) / d log(distance) toward each boundary of each component.

    Along axis j from ``at`` (K, m) (the other components held there): at a finite bound
    the slope is that of log p against log|Omega_j - bound| between the two ``distances``;
    at an infinite bound it is that of log p against log|Omega_j| between 1/d.  NaN where
    the points leave the support (e.g. the constraint a^2 + b^2 < 1).
    """
    K, m = at.shape
    lower = np.full((K, m), np.nan)
    upper = np.full((K, m), np.nan)
    d1, d2 = distances
    for j in range(m):
        for side, out in ((0, lower), (1, upper)):
            bound = bounds.lower[j] if side == 0 else bounds.upper[j]
            pts = np.repeat(at[:, None, :], 2, axis=1)
            if np.isfinite(bound):
                sgn = 1.0 if side == 0 else -1.0
                pts[:, 0, j] = bound + sgn * d1
                pts[:, 1, j] = bound + sgn * d2
                x = np.log([d1, d2])
            else:
                sgn = 1.0 if bound > 0 else -1.0
                pts[:, 0, j] = sgn / d1
                pts[:, 1, j] = sgn / d2
                x = np.log([1 / d1, 1 / d2])
            lp = log_posterior_omega(model, pts, z[:, None], bounds)
            with np.errstate(invalid="ignore"):
                s = (lp[:, 1] - lp[:, 0]) / (x[1] - x[0])
            out[:, j] = np.where(np.all(np.isfinite(lp), axis=1), s, np.nan)
    return lower, upper


def spike_ratio(
    lp_valley: np.ndarray,
    lp_mode: np.ndarray,
    dist: np.ndarray,
    slope: np.ndarray,
    delta: float,
    sd: np.ndarray,
    valley: np.ndarray,
) -> np.ndarray:
    """Mass of a spike beyond a valley relative to the mode's basin, per trajectory: the
    density at the valley (log ``lp_valley``, at ``dist`` from the singular point) continued
    as a power law of exponent ``slope`` down to ``delta`` from the point, against a Gaussian
    basin of standard deviation ``sd`` at the mode (log ``lp_mode``); inf where no valley."""
    with np.errstate(all="ignore"):
        y0 = delta / dist
        integral = np.where(
            np.abs(slope + 1) < 1e-2, np.log(1 / y0), (1 - y0 ** (slope + 1)) / (slope + 1)
        )
        log_r = (
            lp_valley
            + np.log(dist * np.maximum(integral, 0))
            - lp_mode
            - np.log(math.sqrt(2 * math.pi) * sd)
        )
        return np.where(valley, np.exp(np.minimum(log_r, 700)), np.inf)


def valley_limits(
    model: StateSpaceModel,
    axes: OmegaAxes,
    z: np.ndarray,
    bounds: PriorBounds,
    u: np.ndarray,
    H: np.ndarray,
    slopes: tuple[np.ndarray, np.ndarray],
    cut: tuple[np.ndarray, np.ndarray],
    *,
    settings: ExactSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Box limits that keep the interior mode's basin, and the size of what they cut off.

    Toward each boundary flagged in ``cut`` = (cut_lower, cut_upper) (K, m) - where the
    posterior is improper - the limit is the lowest point (the valley) of the density in
    grid coordinates along the axis through the mode ``u``.  Beyond the valley the density
    behaves like distance^slope (``slopes`` = (lower, upper) from :func:`boundary_slopes`);
    its mass down to ``spike_distance`` from the boundary, relative to the mass of the
    mode's basin (Gaussian with the conditional sd 1/sqrt(-H_jj)), both along that axis,
    is the returned ``spike_ratio`` (K,) (the largest over the cut sides; +inf where the
    density rises all the way to the boundary, 0 where nothing is cut).
    """
    K, m = u.shape
    n = settings.valley_nodes
    lo_lim = np.tile(axes.lo, (K, 1))
    hi_lim = np.tile(axes.hi, (K, 1))
    ratio = np.zeros(K)
    s = np.linspace(0, 1, n)
    rows = np.arange(K)
    delta = settings.spike_distance
    for j in range(m):
        with np.errstate(all="ignore"):
            sd_u = 1 / np.sqrt(-H[:, j, j])
        for side in (0, 1):
            cut_j = cut[side][:, j]
            if not cut_j.any():
                continue
            end = axes.lo[j] if side == 0 else axes.hi[j]
            pts = np.repeat(u[:, None, :], n, axis=1)
            pts[:, :, j] = end + (u[:, j : j + 1] - end) * s  # end -> mode
            lpu, lp = log_density_u(model, axes, pts, z[:, None], bounds)
            lpu = np.where(np.isfinite(lpu), lpu, np.inf)
            i = lpu.argmin(1)
            valley = cut_j & (i > 0) & (lpu[:, 0] > lpu[rows, i])
            where = pts[rows, i, j]
            if side == 0:
                lo_lim[:, j] = np.where(valley, where, lo_lim[:, j])
            else:
                hi_lim[:, j] = np.where(valley, where, hi_lim[:, j])
            # spike mass (Omega scale) beyond the valley, relative to the basin's
            om_v = axes.omega(pts[rows, i])[:, j]
            bound = bounds.lower[j] if side == 0 else bounds.upper[j]
            dist = np.abs(om_v - (0.0 if np.isinf(bound) else bound))
            slope = slopes[side][:, j]
            om_mode = axes.omega(u)[:, j]
            sd_om = sd_u * np.where(axes.log_scale[j], np.abs(om_mode), 1.0)
            r = spike_ratio(lp[rows, i], lp[:, -1], dist, slope, delta, sd_om, valley)
            ratio = np.where(cut_j, np.maximum(ratio, np.nan_to_num(r, nan=np.inf)), ratio)
    return lo_lim, hi_lim, ratio
