"""The grid over Omega of the exact marginal stage (:mod:`ssmobs.exact.marginal`, steps 1-3).

log p(Omega | z) comes from the Kalman filter (:func:`log_posterior_omega`); the grid works in
coordinates u (:class:`OmegaAxes`: Omega itself on bounded supports, log|Omega| on half
lines).  :func:`coarse_search` finds the interior local maxima on a coarse tensor grid,
:func:`interior_modes` refines them by Newton's method with finite differences,
:func:`fine_grid` evaluates the density on a box around the mode and :func:`marginal_omega`
reads every component's marginal MAP and quantiles from it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy.interpolate import CubicSpline

from ..models import PriorBounds, StateSpaceModel
from .kalman_filter import kalman_marginal
from .settings import QUANTILES, ExactSettings


# ---------------------------------------------------------------------- Omega axes
@dataclass(frozen=True)
class OmegaAxes:
    """Coordinates u of the Omega grid: u = Omega on bounded supports, u = log|Omega| on
    half lines; ``lo``/``hi`` are the limits of u used for grids (support minus a margin)."""

    lo: np.ndarray
    hi: np.ndarray
    log_scale: np.ndarray
    sign: np.ndarray

    def omega(self, u: np.ndarray) -> np.ndarray:
        return np.where(self.log_scale, self.sign * np.exp(u), u)

    def log_jacobian(self, u: np.ndarray) -> np.ndarray:
        """log |dOmega/du| summed over components."""
        return np.where(self.log_scale, u, 0.0).sum(-1)


def omega_axes(bounds: PriorBounds, margin: float, log_range: tuple[float, float]) -> OmegaAxes:
    """The grid coordinates of ``bounds``' support, ``margin`` (a fraction of a bounded
    interval) inside it; half lines at 0 span ``log_range`` in log|Omega|."""
    lo, hi = np.asarray(bounds.lower, float), np.asarray(bounds.upper, float)
    log_scale = ~(np.isfinite(lo) & np.isfinite(hi))
    sign = np.where(np.isfinite(lo) & ~np.isfinite(hi), 1.0, -1.0)
    with np.errstate(invalid="ignore"):  # inf - inf on the half lines, not used there
        ulo = np.where(log_scale, log_range[0], lo + margin * (hi - lo))
        uhi = np.where(log_scale, log_range[1], hi - margin * (hi - lo))
    for i in np.flatnonzero(log_scale):
        if not ((lo[i] == 0 and hi[i] == np.inf) or (lo[i] == -np.inf and hi[i] == 0)):
            raise ValueError(
                f"unsupported prior support ({lo[i]}, {hi[i]}) for the exact "
                f"marginal: need a bounded interval or a half line at 0"
            )
    return OmegaAxes(lo=ulo, hi=uhi, log_scale=log_scale, sign=sign)


# ---------------------------------------------------------------------- log posterior
def log_posterior_omega(
    model: StateSpaceModel, omega: np.ndarray, z: np.ndarray, bounds: PriorBounds
) -> np.ndarray:
    """log p(Omega | z) + const (flat priors on Omega and x_0); -inf outside the support.

    ``omega`` (..., m) and ``z`` (..., T, d) broadcast over their batch shapes.
    """
    from ..models.log_posterior import in_support

    omega = np.asarray(omega, dtype=float)
    flat = omega.reshape(-1, model.n_params)
    ok = in_support(model, flat, bounds).reshape(omega.shape[:-1])
    safe = np.where(ok[..., None], omega, _interior(bounds))
    val = -0.5 * kalman_marginal(model, safe, z).neg2_loglik
    val = np.where(np.isfinite(val), val, -np.inf)
    return np.where(ok, val, -np.inf)


def _interior(bounds: PriorBounds) -> np.ndarray:
    lo, hi = bounds.lower, bounds.upper
    return np.where(
        np.isfinite(lo) & np.isfinite(hi),
        (lo + hi) / 2,
        np.where(np.isfinite(lo), lo + 1.0, hi - 1.0),
    )


def log_density_u(
    model: StateSpaceModel, axes: OmegaAxes, u: np.ndarray, z: np.ndarray, bounds: PriorBounds
) -> tuple[np.ndarray, np.ndarray]:
    """log density in grid coordinates u (Jacobian included) and log p(Omega|z) itself."""
    lp = log_posterior_omega(model, axes.omega(u), z, bounds)
    return lp + axes.log_jacobian(u), lp


def trajectory_chunks(K: int, per_traj: int, limit: int) -> Iterator[slice]:
    """Slices of the K trajectories holding at most ``limit`` elements of ``per_traj``
    each (at least one trajectory per slice)."""
    step = max(1, limit // max(per_traj, 1))
    for s in range(0, K, step):
        yield slice(s, min(K, s + step))


# ---------------------------------------------------------------------- step 1: coarse grid
def tensor_grid(axes_1d: list[np.ndarray]) -> np.ndarray:
    """(..., n_1, ..., n_m, m) tensor grid from per-axis node arrays (..., n_j)."""
    m = len(axes_1d)
    lead = axes_1d[0].shape[:-1]
    sizes = [a.shape[-1] for a in axes_1d]
    out = np.empty(lead + tuple(sizes) + (m,))
    for j, a in enumerate(axes_1d):
        shape = lead + tuple(sizes[i] if i == j else 1 for i in range(m))
        out[..., j] = a.reshape(shape)
    return out


def _interior_local_maxima(lp: np.ndarray, m: int) -> np.ndarray:
    """Mask of interior nodes strictly above their 2m axis neighbours (last m axes)."""
    K = lp.shape[0]
    inner = tuple(slice(1, -1) for _ in range(m))
    centre = lp[(slice(None),) + inner]
    mask = np.isfinite(centre)
    for j in range(m):
        for shift in (0, 2):
            sl = [slice(None)] + [slice(1, -1)] * m
            sl[1 + j] = slice(shift, lp.shape[1 + j] - 2 + shift)
            mask &= centre > lp[tuple(sl)]
    out = np.zeros(lp.shape, dtype=bool)
    out[(slice(None),) + inner] = mask
    return out.reshape(K, *lp.shape[1:])


def coarse_search(
    model: StateSpaceModel,
    axes: OmegaAxes,
    z: np.ndarray,
    bounds: PriorBounds,
    settings: ExactSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``n_starts`` highest interior local maxima of the coarse grid per trajectory
    (K, n_starts, m) (NaN where fewer), and the grid spacing (m,)."""
    m = model.n_params
    n = settings.coarse(m)
    nodes = [np.linspace(axes.lo[j], axes.hi[j], n) for j in range(m)]
    grid = tensor_grid(nodes).reshape(-1, m)  # (G, m)
    K = z.shape[0]
    ns = settings.n_starts
    starts = np.full((K, ns, m), np.nan)
    for sl in trajectory_chunks(K, grid.shape[0] * z.shape[1], settings.chunk_elements * 8):
        _, lp = log_density_u(model, axes, grid[None, :, :], z[sl, None], bounds)  # (Kc, G)
        # cast: numpy's stubs give reshape() of a tuple[int, ...] a 0-d shape type
        lp = cast(np.ndarray, lp.reshape((lp.shape[0],) + (n,) * m))
        loc = _interior_local_maxima(lp, m).reshape(lp.shape[0], -1)
        masked = np.where(loc, lp.reshape(lp.shape[0], -1), -np.inf)
        top = np.argsort(-masked, axis=1)[:, :ns]
        found = np.take_along_axis(loc, top, 1)
        starts[sl] = np.where(found[..., None], grid[top], np.nan)
    spacing = (axes.hi - axes.lo) / (n - 1)
    return starts, spacing


def interior_modes(
    model: StateSpaceModel,
    axes: OmegaAxes,
    z: np.ndarray,
    bounds: PriorBounds,
    starts: np.ndarray,
    spacing: np.ndarray,
    settings: ExactSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Newton from every start; distinct proper local maxima per trajectory.

    Returns the highest mode u (K, m) (NaN if none), its Hessian, the number of distinct
    interior local maxima (K,) and the log density at the mode (K,).
    """
    K, ns, m = starts.shape
    valid = np.all(np.isfinite(starts), axis=2)
    flat = np.where(valid[..., None], starts, (axes.lo + axes.hi) / 2).reshape(K * ns, m)
    zz = np.repeat(z, ns, axis=0)
    u, H, ok, f = _newton(model, axes, zz, bounds, flat, spacing, settings)
    u, H, ok, f = (u.reshape(K, ns, m), H.reshape(K, ns, m, m), ok.reshape(K, ns), f.reshape(K, ns))
    ok &= valid
    # distinct maxima: farther apart than 1e-3 of the coarse spacing in some coordinate
    n_distinct = np.zeros(K, dtype=np.int64)
    distinct = np.zeros((K, ns), dtype=bool)
    for i in range(ns):
        new = ok[:, i].copy()
        for j in range(i):
            same = np.all(np.abs(u[:, i] - u[:, j]) < 1e-3 * spacing, axis=1)
            new &= ~(same & distinct[:, j])
        distinct[:, i] = new
        n_distinct += new
    fbest = np.where(ok, f, -np.inf)
    best = fbest.argmax(1)
    rows = np.arange(K)
    # cast: numpy's stubs type any(axis) as a scalar or an array
    u_best = np.where(cast(np.ndarray, ok.any(1))[:, None], u[rows, best], np.nan)
    return u_best, H[rows, best], n_distinct, fbest[rows, best]


# ---------------------------------------------------------------------- step 2: Newton
def _fd_derivatives(
    f: Callable[[np.ndarray], np.ndarray], u: np.ndarray, h: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Value, gradient and Hessian of f at u (K, m) by central differences with steps h (m,)."""
    K, m = u.shape
    pts = [u]
    for i in range(m):
        e = np.zeros(m)
        e[i] = h[i]
        pts += [u + e, u - e]
    for i in range(m):
        for j in range(i + 1, m):
            ei = np.zeros(m)
            ej = np.zeros(m)
            ei[i], ej[j] = h[i], h[j]
            pts += [u + ei + ej, u + ei - ej, u - ei + ej, u - ei - ej]
    vals = f(np.stack(pts, axis=1))  # (K, P)
    f0 = vals[:, 0]
    g = np.empty((K, m))
    H = np.empty((K, m, m))
    with np.errstate(invalid="ignore"):
        for i in range(m):
            fp, fm = vals[:, 1 + 2 * i], vals[:, 2 + 2 * i]
            g[:, i] = (fp - fm) / (2 * h[i])
            H[:, i, i] = (fp - 2 * f0 + fm) / h[i] ** 2
        c = 1 + 2 * m
        for i in range(m):
            for j in range(i + 1, m):
                pp, pm, mp, mm = (vals[:, c + r] for r in range(4))
                H[:, i, j] = H[:, j, i] = (pp - pm - mp + mm) / (4 * h[i] * h[j])
                c += 4
    return f0, g, H


def _newton(
    model: StateSpaceModel,
    axes: OmegaAxes,
    z: np.ndarray,
    bounds: PriorBounds,
    u0: np.ndarray,
    spacing: np.ndarray,
    settings: ExactSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Maximise log p(Omega|z) (no Jacobian) over u from u0 (K, m).

    Newton steps (gradient steps where the Hessian is not negative definite), at most one
    coarse spacing long, with backtracking.  Returns u, the Hessian there, ``ok`` (a proper
    interior local maximum: negative definite Hessian, Newton step below 1e-3 of the
    Laplace sd, not at the end of the grid range) and the log density there.
    """
    K, m = u0.shape
    h = spacing * 1e-3

    def f(points: np.ndarray) -> np.ndarray:
        _, lp = log_density_u(model, axes, points, z[:, None], bounds)
        return lp

    u = u0.copy()
    lo, hi = axes.lo + 2 * h, axes.hi - 2 * h
    for _ in range(settings.newton_iter):
        f0, g, H = _fd_derivatives(f, u, h)
        with np.errstate(all="ignore"):
            Hs = np.where(np.isfinite(H), H, 0.0)
            negdef = np.all(np.linalg.eigvalsh(Hs) < 0, axis=1)
            step = np.where(
                negdef[:, None],
                -np.linalg.solve(
                    np.where(negdef[:, None, None], Hs, -np.eye(m)),
                    np.where(np.isfinite(g), g, 0.0)[..., None],
                )[..., 0],
                np.sign(g) * spacing / 2,
            )
        step = np.where(np.isfinite(step), step, 0.0)
        step = np.clip(step, -spacing, spacing)
        t = np.ones(K)
        accepted = np.zeros(K, dtype=bool)
        for _ in range(12):
            cand = np.clip(u + t[:, None] * step, lo, hi)
            fc = f(cand[:, None, :])[:, 0]
            better = (fc >= f0) & ~accepted
            u = np.where(better[:, None], cand, u)
            accepted |= better
            t = np.where(accepted, t, t / 2)
            if accepted.all():
                break
        if np.all(np.abs(step * t[:, None]) < 1e-10 * np.maximum(spacing, 1)):
            break
    f0, g, H = _fd_derivatives(f, u, h)
    with np.errstate(all="ignore"):
        Hs = np.where(np.isfinite(H), H, 0.0)
        ok = np.all(np.linalg.eigvalsh(Hs) < 0, axis=1)
        cov = np.linalg.inv(np.where(ok[:, None, None], -Hs, np.eye(m)))
        step = (cov @ np.where(np.isfinite(g), g, np.inf)[..., None])[..., 0]
        sd = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
        ok &= np.all(np.abs(step) <= 1e-3 * sd, axis=1)  # converged: gradient ~ 0
    at_edge = np.any((u <= lo + 1e-12) | (u >= hi - 1e-12), axis=1)
    return u, H, ok & ~at_edge & np.isfinite(f0), f0


# ---------------------------------------------------------------------- step 3: fine grid
def trapezoid_weights(n: int) -> np.ndarray:
    """Trapezoid rule weights of ``n`` equally spaced nodes (unit spacing)."""
    w = np.ones(n)
    w[0] = w[-1] = 0.5
    return w


def fine_grid(
    model: StateSpaceModel,
    axes: OmegaAxes,
    z: np.ndarray,
    bounds: PriorBounds,
    centre: np.ndarray,
    sd: np.ndarray,
    lim_lo: np.ndarray,
    lim_hi: np.ndarray,
    *,
    settings: ExactSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """log density (Jacobian included) on the per-trajectory boxes centre ± box_sd sd,
    within [lim_lo, lim_hi] (K, m), widened while a face carries non-negligible density."""
    K, m = centre.shape
    n = settings.fine_nodes(m)
    left = np.minimum(settings.box_sd * sd, centre - lim_lo)
    right = np.minimum(settings.box_sd * sd, lim_hi - centre)
    todo = np.ones(K, dtype=bool)
    out_lp = np.empty((K,) + (n,) * m)
    lo_box = np.empty((K, m))
    hi_box = np.empty((K, m))
    truncated = np.zeros(K, dtype=bool)
    for rnd in range(settings.max_widen + 1):
        idx = np.flatnonzero(todo)
        if idx.size == 0:
            break
        for part in np.array_split(idx, max(1, idx.size * n**m // settings.chunk_elements + 1)):
            if part.size == 0:
                continue
            lo = centre[part] - left[part]
            hi = centre[part] + right[part]
            nodes = [np.linspace(lo[:, j], hi[:, j], n, axis=-1) for j in range(m)]
            grid = tensor_grid(nodes).reshape(part.size, -1, m)
            lpu, _ = log_density_u(model, axes, grid, z[part, None], bounds)
            out_lp[part] = lpu.reshape((part.size,) + (n,) * m)
            lo_box[part], hi_box[part] = lo, hi
        sub = out_lp[idx]
        peak = sub.reshape(idx.size, -1).max(1)
        widen_l = np.zeros((idx.size, m), dtype=bool)
        widen_r = np.zeros((idx.size, m), dtype=bool)
        for j in range(m):
            face_l = np.take(sub, 0, axis=1 + j).reshape(idx.size, -1).max(1)
            face_r = np.take(sub, n - 1, axis=1 + j).reshape(idx.size, -1).max(1)
            high_l = face_l > peak - settings.face_drop
            high_r = face_r > peak - settings.face_drop
            widen_l[:, j] = high_l & (lo_box[idx, j] > lim_lo[idx, j] + 1e-12)
            widen_r[:, j] = high_r & (hi_box[idx, j] < lim_hi[idx, j] - 1e-12)
        need = widen_l.any(1) | widen_r.any(1)
        if rnd == settings.max_widen:
            truncated[idx[need]] = True
            break
        left[idx] = np.where(
            widen_l, np.minimum(2 * left[idx], centre[idx] - lim_lo[idx]), left[idx]
        )
        right[idx] = np.where(
            widen_r, np.minimum(2 * right[idx], lim_hi[idx] - centre[idx]), right[idx]
        )
        todo[:] = False
        todo[idx[need]] = True
    return out_lp, lo_box, hi_box, truncated


def grid_mass(lpu: np.ndarray) -> np.ndarray:
    """The fine grid's nodes' masses (up to a factor per trajectory): density relative to the
    peak times the tensor trapezoid weights."""
    K, m, n = lpu.shape[0], lpu.ndim - 1, lpu.shape[1]
    w = np.exp(lpu - lpu.reshape(K, -1).max(1).reshape((K,) + (1,) * m))
    tw = trapezoid_weights(n)
    for j in range(m):
        w = w * tw.reshape((1,) + tuple(n if i == j else 1 for i in range(m)))
    return w


def marginal_omega(
    axes: OmegaAxes, w: np.ndarray, lo_box: np.ndarray, hi_box: np.ndarray, settings: ExactSettings
) -> tuple[np.ndarray, np.ndarray]:
    """Marginal MAP (Omega scale) and 5 %/95 % quantiles of every Omega component, from the
    fine grid's masses ``w`` (:func:`grid_mass`)."""
    K = w.shape[0]
    m = w.ndim - 1
    n = w.shape[1]
    tw = trapezoid_weights(n)
    r = settings.spline_refine
    s_fine = np.linspace(0, n - 1, (n - 1) * r + 1)
    est = np.full((K, m), np.nan)
    q = np.full((K, m, len(QUANTILES)), np.nan)
    for j in range(m):
        marg = w.sum(axis=tuple(1 + i for i in range(m) if i != j)) / tw[None, :]  # (K, n)
        with np.errstate(divide="ignore"):
            logm = np.log(marg)
        top = logm.max(1, keepdims=True)
        logm = np.maximum(logm, top - 60.0)
        spl = CubicSpline(np.arange(n), logm.T, axis=0)
        log_fine = spl(s_fine).T  # (K, nf)
        u_fine = lo_box[:, j : j + 1] + (hi_box - lo_box)[:, j : j + 1] * s_fine / (n - 1)
        dens_u = np.exp(log_fine - log_fine.max(1, keepdims=True))
        # density of Omega_j itself (Jacobian of u = log|Omega| removed)
        log_dens_om = log_fine - np.where(axes.log_scale[j], u_fine, 0.0)
        om_fine = np.where(axes.log_scale[j], axes.sign[j] * np.exp(u_fine), u_fine)
        # the highest interior local maximum of the marginal density (a density that is
        # improper at a boundary rises toward the box edge there; that is not the MAP)
        inner = log_dens_om[:, 1:-1]
        is_max = (inner > log_dens_om[:, :-2]) & (inner >= log_dens_om[:, 2:])
        has_max = is_max.any(1)
        i = np.where(is_max, inner, -np.inf).argmax(1) + 1
        rows = np.arange(K)
        x = np.stack([om_fine[rows, i - 1], om_fine[rows, i], om_fine[rows, i + 1]], 1)
        y = np.stack([log_dens_om[rows, i - 1], log_dens_om[rows, i], log_dens_om[rows, i + 1]], 1)
        est[:, j] = np.where(has_max, _parabola_vertex(x, y), np.nan)
        cdf = np.concatenate(
            [np.zeros((K, 1)), np.cumsum(0.5 * (dens_u[:, 1:] + dens_u[:, :-1]), axis=1)], axis=1
        )
        cdf /= cdf[:, -1:]
        for qi, level in enumerate(QUANTILES):
            k = np.clip((cdf < level).sum(1), 1, s_fine.size - 1)
            c0, c1 = cdf[rows, k - 1], cdf[rows, k]
            frac = np.where(c1 > c0, (level - c0) / (c1 - c0), 0.5)
            uq = u_fine[rows, k - 1] + frac * (u_fine[rows, k] - u_fine[rows, k - 1])
            q[:, j, qi] = np.where(axes.log_scale[j], axes.sign[j] * np.exp(uq), uq)
    return est, q


def _parabola_vertex(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Vertex of the parabola through three points (rows of x, y); middle x if degenerate."""
    x0, x1, x2 = x.T
    y0, y1, y2 = y.T
    d0 = (y1 - y0) / (x1 - x0)
    d1 = (y2 - y1) / (x2 - x1)
    curv = (d1 - d0) / (x2 - x0)
    with np.errstate(all="ignore"):
        v = (x0 + x1) / 2 - d0 / (2 * curv)
    ok = np.isfinite(v) & (curv < 0) & (v >= x0) & (v <= x2)
    return np.where(ok, v, x1)
