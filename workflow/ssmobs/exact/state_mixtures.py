"""The states' marginals of the exact marginal stage (:mod:`ssmobs.exact.marginal`, step 4).

The marginal of every state x_t is a mixture, over a grid of Omega, of the smoothed
Gaussians given (Omega, z), weighted by p(Omega | z) (:func:`state_mixtures` on the box of
:func:`state_box`); :func:`mixture_mode_quantiles` finds its mode and quantiles.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from scipy.special import ndtr, ndtri

from ..models import PriorBounds, StateSpaceModel
from .kalman_filter import kalman_marginal
from .omega_grid import OmegaAxes, log_density_u, tensor_grid, trajectory_chunks, trapezoid_weights
from .settings import QUANTILES, ExactSettings

logger = logging.getLogger("ssmobs.exact")

#: a mixture quantile has converged when a step moves it by at most this many mixture sd
QUANTILE_TOL = 1e-10


def state_box(
    w: np.ndarray, lo_box: np.ndarray, hi_box: np.ndarray, settings: ExactSettings
) -> tuple[np.ndarray, np.ndarray]:
    """The box of the state mixtures' grid: per axis, the fine grid's nodes outside which
    p(Omega | z) holds at most ``state_tail_mass`` / (2 m) on each side, so the box holds
    all but ``state_tail_mass`` of the fine grid's mass.

    Not the fine box itself: that box widens along a long flat tail (``face_drop``) for the
    Omega marginals, and a state grid spread over it put its nodes about 3 Laplace sd apart
    in (Sep, d=2, p=1) at T = 50 (boxes 31-33 sd wide in a and b), which moved x0's 5 %
    quantile by 0.065 in the median over 198 trajectories."""
    m = w.ndim - 1
    n = w.shape[1]
    tail = settings.state_tail_mass / (2 * m)
    lo, hi = lo_box.copy(), hi_box.copy()
    for j in range(m):
        marg = w.sum(axis=tuple(1 + i for i in range(m) if i != j))  # (K, n)
        marg = marg / marg.sum(1, keepdims=True)
        # nodes 0..a-1 hold at most `tail` together, as do nodes b+1..n-1
        a = (np.cumsum(marg, 1) <= tail).sum(1)
        b = n - 1 - (np.cumsum(marg[:, ::-1], 1) <= tail).sum(1)
        a = np.clip(np.minimum(a, b - 2), 0, n - 1)
        b = np.clip(np.maximum(b, a + 2), 0, n - 1)
        step = (hi_box[:, j] - lo_box[:, j]) / (n - 1)
        lo[:, j] = lo_box[:, j] + a * step
        hi[:, j] = lo_box[:, j] + b * step
    return lo, hi


def state_mixtures(
    model: StateSpaceModel,
    axes: OmegaAxes,
    z: np.ndarray,
    bounds: PriorBounds,
    lo: np.ndarray,
    hi: np.ndarray,
    settings: ExactSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """Marginal MAP and quantiles of x_0..x_T: mixtures over a tensor grid of
    ``state_nodes`` nodes per axis on the box [lo, hi] (:func:`state_box`).

    Node g carries weight w_g ∝ p(Omega_g | z) x (trapezoid weight) and the smoothed
    Gaussian N(mu_t(Omega_g), P_t(Omega_g)), widened by the variance of mu_t across the
    node's cell, sum_j (d mu_t / d index_j)^2 / 12 (midpoint rule for the cell, so that a
    coarse Omega grid does not make the mixture bumpy).  Nodes are pruned to the heaviest
    ones holding ``mixture_mass`` of the weight.
    """
    K, m = lo.shape
    ns = settings.state(m)
    nodes = [np.linspace(lo[:, j], hi[:, j], ns, axis=-1) for j in range(m)]
    grid = tensor_grid(nodes).reshape(K, -1, m)
    lps = np.empty((K, ns**m))
    for sl in trajectory_chunks(K, ns**m, settings.chunk_elements):
        lps[sl] = log_density_u(model, axes, grid[sl], z[sl, None], bounds)[0]
    lps = lps.reshape((K,) + (ns,) * m)
    tw = trapezoid_weights(ns)
    logw = lps.copy()
    for j in range(m):
        logw = logw + np.log(tw).reshape((1,) + tuple(ns if i == j else 1 for i in range(m)))
    logw = logw.reshape(K, -1)
    w = np.exp(logw - logw.max(1, keepdims=True))
    w /= w.sum(1, keepdims=True)
    order = np.argsort(-w, axis=1)
    w_sorted = np.take_along_axis(w, order, 1)
    keep = int(min(w.shape[1], (np.cumsum(w_sorted, 1) < settings.mixture_mass).sum(1).max() + 1))
    order = order[:, :keep]
    w = np.take_along_axis(w, order, 1)
    w /= w.sum(1, keepdims=True)
    T = z.shape[1]
    p = model.state_dim
    n_states = (T + 1) * p
    est = np.empty((K, n_states))
    q = np.empty((K, n_states, len(QUANTILES)))
    for sl in trajectory_chunks(K, grid.shape[1] * n_states * 6, settings.chunk_elements):
        km = kalman_marginal(model, axes.omega(grid[sl]), z[sl, None], smooth=True)
        assert km.mean is not None and km.var is not None  # smooth=True
        kc = km.mean.shape[0]
        mean = km.mean.reshape((kc,) + (ns,) * m + (n_states,))
        var = km.var.reshape(mean.shape)
        # for the mode: each node stands for a cell of the grid, across which the smoothed
        # mean moves (nearly linearly): spread the component by the cell's variance
        # (gh)^2 / 12 so that the mixture density is not bumpy on a coarse grid.  The
        # quantiles use the plain components (trapezoid rule: spectrally accurate).
        spread = np.sum([np.gradient(mean, axis=1 + j) ** 2 for j in range(m)], axis=0) / 12
        idx = order[sl][:, :, None]
        mean, var, spread = (
            np.take_along_axis(a.reshape(kc, -1, n_states), idx, 1) for a in (mean, var, spread)
        )  # (Kc, G_kept, S)
        wc = np.broadcast_to(w[sl][:, :, None], mean.shape)
        # a component whose smoother lost precision (far from the mode) gets weight 0
        bad = ~(np.isfinite(mean) & np.isfinite(var) & (var > 0))
        wc = np.where(bad, 0.0, wc)
        wc = wc / wc.sum(1, keepdims=True)
        mean = np.where(bad, mean[:, :1], mean)
        var = np.where(bad, var[:, :1], var)
        spread = np.where(np.isfinite(spread), spread, 0.0)
        est[sl], q[sl] = mixture_mode_quantiles(
            wc, mean, np.sqrt(var), settings, np.sqrt(var + spread)
        )
    return est, q


def mixture_mode_quantiles(
    w: np.ndarray,
    mean: np.ndarray,
    sd: np.ndarray,
    settings: ExactSettings,
    sd_mode: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Mode and quantiles of sum_g w_g N(mean_g, sd_g^2) along axis 1.

    Weights are sorted (heaviest first); ``sd_mode`` (default ``sd``) are the component
    standard deviations used for the mode.  Quantiles: Newton's method on the mixture CDF,
    safeguarded by bisection on a bracket that holds every component's ±12 sd, until a step
    moves no quantile by more than ``QUANTILE_TOL`` mixture sd (at most ``mixture_iter``
    steps: a light, very wide component makes the bracket ~1e7 sd wide); mode:
    Newton's method on the log density from the heaviest component's mean, steps limited
    to half the mixture's standard deviation and kept inside the components' means.
    """
    # scale and bracket from the components that matter (weight >= 1e-6 of the heaviest)
    big = w >= 1e-6 * w.max(1, keepdims=True)
    wb = np.where(big, w, 0.0)
    wb = wb / wb.sum(1, keepdims=True)
    M = (wb * mean).sum(1)
    V = (wb * (sd**2 + mean**2)).sum(1) - M**2
    S = np.sqrt(np.maximum(V, 1e-300))
    lo_m = np.where(big, mean, np.inf).min(1)
    hi_m = np.where(big, mean, -np.inf).max(1)
    sdm = sd if sd_mode is None else sd_mode
    mode = _mixture_mode(w, mean, sdm, S, lo_m, hi_m, settings.mode_iter)

    # the quantiles element by element (trajectory, state): components last, and each step
    # only on the elements that have not converged yet
    def flat(a: np.ndarray) -> np.ndarray:
        return np.moveaxis(a, 1, -1).reshape(-1, a.shape[1])

    wf, mf, sf = flat(w), flat(mean), flat(sd)
    lo0 = flat(np.where(big, mean - 12 * sd, np.inf)).min(1)
    hi0 = flat(np.where(big, mean + 12 * sd, -np.inf)).max(1)
    # a tolerance no finer than the floating-point resolution of the quantile itself
    scale = np.maximum(np.abs(lo0), np.abs(hi0))
    tol = np.maximum(QUANTILE_TOL * S.reshape(-1), 4 * np.finfo(float).eps * scale)
    qs = []
    for level in QUANTILES:
        lo, hi = lo0.copy(), hi0.copy()
        x = np.clip((M + ndtri(level) * S).reshape(-1), lo, hi)
        todo = np.arange(x.size)
        for _ in range(settings.mixture_iter):
            xa, wa, ma, sa = x[todo], wf[todo], mf[todo], sf[todo]
            u = (xa[:, None] - ma) / sa
            F = (wa * ndtr(u)).sum(1) - level
            f = (wa * np.exp(-0.5 * u * u) / sa).sum(1) / math.sqrt(2 * math.pi)
            lo[todo] = np.where(F < 0, xa, lo[todo])
            hi[todo] = np.where(F >= 0, xa, hi[todo])
            with np.errstate(all="ignore"):
                newton = xa - F / f
            inside = np.isfinite(newton) & (newton > lo[todo]) & (newton < hi[todo])
            x[todo] = np.where(inside, newton, 0.5 * (lo[todo] + hi[todo]))
            todo = todo[np.abs(x[todo] - xa) > tol[todo]]
            if todo.size == 0:
                break
        if todo.size:
            logger.warning(
                "%d of %d mixture %g-quantiles not converged after %d steps (mixture_iter)",
                todo.size,
                x.size,
                level,
                settings.mixture_iter,
            )
        qs.append(x.reshape(M.shape))
    return mode, np.stack(qs, -1)


#: halvings of a step where the log density is not concave before the step is dropped
ASCENT_HALVINGS = 60


def _density(x: np.ndarray, w: np.ndarray, mean: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """The mixture density sum_g w_g N(x; mean_g, sd_g^2) (components on axis 1), without
    the constant 1 / sqrt(2 pi)."""
    u = (x[:, None] - mean) / sd
    return (w * np.exp(-0.5 * (u * u)) / sd).sum(1)


def _ascending(
    x_new: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    where: np.ndarray,
    mixture: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> np.ndarray:
    """``x_new`` where it does not lower the density ``f`` at ``x``; elsewhere, among the
    elements ``where`` (steps where the log density is not concave, whose length is a
    fraction of the mixture's standard deviation), the step halved until it does not
    (:data:`ASCENT_HALVINGS` at most, then no step).

    Without this a light, far component (a grid node near a prior's end where the smoother's
    mean runs off: weight 0.003 at x about 2.5e6 in one trajectory of Sep at T = 75) widens
    the mixture's standard deviation to 1.4e5, and one such step left the mode at 5.9e5
    while the 90 % interval was [2.53, 3.54]."""
    # only the trajectories (first axis) with such a step: the density of a row is summed in
    # the same order whichever rows are taken, so the others keep x_new to the bit
    rows = np.flatnonzero(where.any(1))
    if rows.size == 0:
        return x_new
    w, mean, sd = (a[rows] for a in mixture)
    x0, f0, new = x[rows], f[rows], x_new[rows]
    todo = where[rows] & ~(_density(new, w, mean, sd) >= f0)
    for _ in range(ASCENT_HALVINGS):
        if not todo.any():
            break
        new = np.where(todo, x0 + 0.5 * (new - x0), new)
        todo = todo & ~(_density(new, w, mean, sd) >= f0)
    out = x_new.copy()
    out[rows] = np.where(todo, x0, new)
    return out


def _mixture_mode(
    w: np.ndarray,
    mean: np.ndarray,
    sd: np.ndarray,
    S: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    n_iter: int,
) -> np.ndarray:
    """``n_iter`` safeguarded Newton steps on the log of sum_g w_g N(mean_g, sd_g^2) (axis 1)
    from the heaviest component's mean (:func:`mixture_mode_quantiles`).

    A step is a function of x alone, so an x that a step leaves unchanged to the bit stays
    so: a trajectory (first axis) whose every x is such a fixed point drops out of the
    remaining steps.  Its rows keep their layout (components on axis 1, states last), so the
    sums over the components add in the same order as over all trajectories.  A step where
    the log density is not concave may not lower the density (:func:`_ascending`).
    """
    x = mean[:, 0].copy()  # the heaviest component (weights are sorted)
    rows = np.arange(x.shape[0])
    sd2 = sd**2
    half, quarter = S / 2, S / 4
    for _ in range(n_iter):
        xr = x[rows]
        u = (xr[:, None] - mean) / sd
        uu = u * u  # -0.5 * u * u = -0.5 * uu: halving is exact
        phi = w * np.exp(-0.5 * uu) / sd
        f = phi.sum(1)
        f1 = -(phi * u / sd).sum(1)
        f2 = (phi * (uu - 1) / sd2).sum(1)
        with np.errstate(all="ignore"):
            g = f1 / f
            gp = f2 / f - g * g
            step = np.where(gp < 0, -g / gp, np.sign(g) * quarter)
        step = np.where(np.isfinite(step), step, 0.0)
        x_new = np.clip(xr + np.clip(step, -half, half), lo, hi)
        x_new = _ascending(x_new, xr, f, ~(gp < 0), (w, mean, sd))
        x[rows] = x_new
        moved = (x_new.view(np.uint64) != xr.view(np.uint64)).any(1)
        if not moved.all():
            rows = rows[moved]
            if rows.size == 0:
                break
            w, mean, sd, sd2 = w[moved], mean[moved], sd[moved], sd2[moved]
            half, quarter, lo, hi = half[moved], quarter[moved], lo[moved], hi[moved]
    return x
