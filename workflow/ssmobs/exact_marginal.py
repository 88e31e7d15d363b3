"""Exact marginal posteriors for the models that are linear-Gaussian in the states (issue 11).

For fixed Omega the models Same, Sep, (Sep, d=2, p=1), (Sep, d=1, p=2) and ranWalk are
linear-Gaussian state space models (``model.linear_in_states``), so with the flat prior
p_0(x_0) of Sec. IV the states integrate out in closed form:

    p(Omega | z) ∝ p(Omega) ∫ p(z | Omega, x_0, ..., x_T) p(x_1..x_T | x_0, Omega) dx_0..dx_T.

:func:`ssmobs.kalman_filter.kalman_marginal` evaluates -2 log of that integral exactly
and the smoothed Gaussians of the states given (Omega, z).

:func:`exact_marginal` integrates over Omega per trajectory:

1. a coarse tensor grid over the prior support (log scale for half-line priors) finds the
   interior local maxima of p(Omega | z) (Definition 3: unique / several / none);
2. Newton's method with finite differences refines the highest one and its Hessian gives
   Laplace standard deviations sigma;
3. a fine tensor grid on the box mode ± ``box_sd`` sigma (clipped to the support, widened
   while a face of the box carries density above exp(-``face_drop``) of the peak) gives the
   marginal density of every Omega component: its mode (the exact marginal MAP) and its
   5 % / 95 % quantiles, from a cubic spline of the log marginal density;
4. the marginal of every state x_t is the mixture over a grid of the smoothed Gaussians,
   weighted by p(Omega | z), on the part of the fine box that holds all but
   ``state_tail_mass`` of its mass; its mode and quantiles come from Newton's method on the
   mixture.

Improper posteriors.  With the flat prior on x_0 the integral over x_0 contributes
1 / |det F(Omega)|, so for Same (F = a) p(a | z) grows like 1 / a as a -> 0+ and is not
integrable there (likewise c -> 0 for (Sep, d=2, p=1), c, d -> 0 for (Sep, d=1, p=2) and
a -> 0 for Sep and ranWalk).  :func:`boundary_slopes` measures d log p / d log(distance to
the boundary) along each axis; a slope <= -1 at a finite boundary (>= -1 at infinity)
means the posterior is improper there.  The marginal MAP reported is then the interior
local maximum and the quantiles are those of the posterior restricted to the basin of that
maximum (the box of step 3 stops at the valley between it and the improper boundary).
``spike_ratio`` estimates the mass of what was cut off, down to ``spike_distance`` from
the boundary, relative to the basin's (along the axis through the mode), so a user sees
where the interior basin does not dominate.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.special import ndtr, ndtri

from .kalman_filter import kalman_marginal
from .models import PriorBounds, StateSpaceModel

if TYPE_CHECKING:
    import pandas

logger = logging.getLogger("ssmobs.exact")

QUANTILES = (0.05, 0.95)
#: a mixture quantile has converged when a step moves it by at most this many mixture sd
QUANTILE_TOL = 1e-10
MAXIMA_KINDS = ("unique", "several", "none")


# ====================================================================== Omega axes
@dataclass(frozen=True)
class _Axes:
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


def _axes(bounds: PriorBounds, margin: float, log_range: tuple[float, float]) -> _Axes:
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
    return _Axes(lo=ulo, hi=uhi, log_scale=log_scale, sign=sign)


# ====================================================================== settings and result
@dataclass(frozen=True)
class ExactSettings:
    """Grid sizes and tolerances of :func:`exact_marginal`: the config block
    ``exact_marginal`` (workflow/schemas/config.schema.yaml describes every field; a test
    keeps the two equal).

    ``coarse_nodes``, ``state_nodes`` and ``state_thin`` hold one value per number m = 1..4
    of parameters; ``state_nodes`` nodes per axis carry the state mixtures (on their own
    box, :func:`_state_box`) and the fine Omega grid has ``(state_nodes - 1) * state_thin
    + 1`` nodes per axis: refining the state grid refines the Omega grid too.
    """

    coarse_nodes: tuple = (400, 48, 16, 9)
    state_nodes: tuple = (41, 21, 11, 7)
    state_thin: tuple = (10, 3, 2, 2)
    box_sd: float = 7.0
    state_tail_mass: float = 1e-6
    face_drop: float = 20.0
    max_widen: int = 4
    margin: float = 1e-6
    half_line_range: tuple = (1e-4, 1e4)
    spline_refine: int = 16
    mixture_mass: float = 0.9999999999
    newton_iter: int = 30
    spike_distance: float = 1e-6
    spike_tol: float = 1e-3
    n_starts: int = 4
    mixture_iter: int = 200
    mode_iter: int = 12
    valley_nodes: int = 200
    chunk_elements: int = 4_000_000

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> ExactSettings:
        """From the validated config block (its lists become tuples)."""
        fields: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in values.items()
        }
        return cls(**fields)

    @property
    def max_params(self) -> int:
        """The largest m the per-m settings cover."""
        return min(len(self.coarse_nodes), len(self.state_nodes), len(self.state_thin))

    def coarse(self, m: int) -> int:
        """Coarse grid nodes per axis for m parameters."""
        return int(self.coarse_nodes[m - 1])

    def state(self, m: int) -> int:
        """Nodes per axis of the grid carrying the state mixtures for m parameters."""
        return int(self.state_nodes[m - 1])

    def thin(self, m: int) -> int:
        """The fine grid's nodes per axis are (state_nodes - 1) x this + 1, for m parameters."""
        return int(self.state_thin[m - 1])

    def fine_nodes(self, m: int) -> int:
        """Fine grid nodes per axis for m parameters."""
        return (self.state(m) - 1) * self.thin(m) + 1


@dataclass
class ExactResult:
    """Per-trajectory exact marginal summaries (K rows), see :meth:`to_frame`."""

    theta_names: list[str]
    theta_map: np.ndarray  # (K, |Theta|)
    theta_q5: np.ndarray
    theta_q95: np.ndarray
    maxima: np.ndarray  # (K,) str: unique / several / none
    n_local_max: np.ndarray  # (K,) interior local maxima on the coarse grid
    joint_mode: np.ndarray  # (K, m) mode of p(Omega | z)
    laplace_sd: np.ndarray  # (K, m)
    box_truncated: np.ndarray  # (K,) a box face still carries non-negligible density
    spike_ratio: np.ndarray  # (K,) improper part cut off / basin mass (_valley_limits)
    spike_tol: float
    slopes_lower: np.ndarray  # (K, m) d log p / d log(distance to lower boundary)
    slopes_upper: np.ndarray  # (K, m)
    info: dict

    def to_frame(self, model: StateSpaceModel) -> pandas.DataFrame:
        """One row per trajectory, columns like the Stan stage's gather table:
        ``k``, ``status``, ``converged`` (= unique interior maximum and the grid box not
        truncated: Definition 3's set, the rows the statistics use), ``maxima``,
        ``spike_ratio`` and ``spike_not_negligible`` (>= ``spike_tol``: the non-integrable
        part near an improper boundary, down to ``spike_distance`` from it, is not
        negligible against the interior mode's basin; reported, not used as a filter),
        ``n_local_max``, ``box_truncated``, ``improper_lower_<p>``/``improper_upper_<p>``,
        ``slope_lower_<p>``/``slope_upper_<p>``, ``mode_<p>``, ``laplace_sd_<p>`` and
        ``<name>_map``/``_q5``/``_q95`` for every component of Theta."""
        import pandas as pd

        K = self.theta_map.shape[0]
        cols: dict[str, Any] = {
            "k": np.arange(K, dtype=np.int64),
            "status": np.where(self.maxima == "none", "no_interior_maximum", "ok"),
            "converged": (self.maxima == "unique") & ~self.box_truncated,
            "spike_not_negligible": self.spike_ratio >= self.spike_tol,
            "maxima": self.maxima.astype(str),
            "n_local_max": self.n_local_max.astype(np.int64),
            "box_truncated": self.box_truncated.astype(bool),
            "spike_ratio": self.spike_ratio,
        }
        for i, pname in enumerate(model.param_names):
            cols[f"slope_lower_{pname}"] = self.slopes_lower[:, i]
            cols[f"slope_upper_{pname}"] = self.slopes_upper[:, i]
            cols[f"improper_lower_{pname}"] = improper(self.slopes_lower[:, i], finite=True)
            cols[f"improper_upper_{pname}"] = improper(
                self.slopes_upper[:, i], finite=not np.isinf(self.info["upper"][i])
            )
            cols[f"mode_{pname}"] = self.joint_mode[:, i]
            cols[f"laplace_sd_{pname}"] = self.laplace_sd[:, i]
        for j, name in enumerate(self.theta_names):
            cols[f"{name}_map"] = self.theta_map[:, j]
            cols[f"{name}_q5"] = self.theta_q5[:, j]
            cols[f"{name}_q95"] = self.theta_q95[:, j]
        return pd.DataFrame(cols)


def improper(slope: np.ndarray, finite: bool) -> np.ndarray:
    """Non-integrable where density ~ distance^slope with slope <= -1 at a finite boundary
    (tolerance 0.05), or ~ Omega^slope with slope >= -1 at infinity."""
    slope = np.asarray(slope, dtype=float)
    with np.errstate(invalid="ignore"):
        return (slope <= -0.95) if finite else (slope >= -1.05)


# ====================================================================== log posterior
def log_posterior_omega(
    model: StateSpaceModel, omega: np.ndarray, z: np.ndarray, bounds: PriorBounds
) -> np.ndarray:
    """log p(Omega | z) + const (flat priors on Omega and x_0); -inf outside the support.

    ``omega`` (..., m) and ``z`` (..., T, d) broadcast over their batch shapes.
    """
    from .models.log_posterior import in_support

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


def _logp_u(
    model: StateSpaceModel, axes: _Axes, u: np.ndarray, z: np.ndarray, bounds: PriorBounds
) -> tuple[np.ndarray, np.ndarray]:
    """log density in grid coordinates u (Jacobian included) and log p(Omega|z) itself."""
    lp = log_posterior_omega(model, axes.omega(u), z, bounds)
    return lp + axes.log_jacobian(u), lp


def _chunks(K: int, per_traj: int, limit: int) -> Iterator[slice]:
    step = max(1, limit // max(per_traj, 1))
    for s in range(0, K, step):
        yield slice(s, min(K, s + step))


# ====================================================================== step 1: coarse grid
def _tensor(axes_1d: list[np.ndarray]) -> np.ndarray:
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


def _coarse_search(
    model: StateSpaceModel, axes: _Axes, z: np.ndarray, bounds: PriorBounds, settings: ExactSettings
) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``n_starts`` highest interior local maxima of the coarse grid per trajectory
    (K, n_starts, m) (NaN where fewer), and the grid spacing (m,)."""
    m = model.n_params
    n = settings.coarse(m)
    nodes = [np.linspace(axes.lo[j], axes.hi[j], n) for j in range(m)]
    grid = _tensor(nodes).reshape(-1, m)  # (G, m)
    K = z.shape[0]
    ns = settings.n_starts
    starts = np.full((K, ns, m), np.nan)
    for sl in _chunks(K, grid.shape[0] * z.shape[1], settings.chunk_elements * 8):
        _, lp = _logp_u(model, axes, grid[None, :, :], z[sl, None], bounds)  # (Kc, G)
        # cast: numpy's stubs give reshape() of a tuple[int, ...] a 0-d shape type
        lp = cast(np.ndarray, lp.reshape((lp.shape[0],) + (n,) * m))
        loc = _interior_local_maxima(lp, m).reshape(lp.shape[0], -1)
        masked = np.where(loc, lp.reshape(lp.shape[0], -1), -np.inf)
        top = np.argsort(-masked, axis=1)[:, :ns]
        found = np.take_along_axis(loc, top, 1)
        starts[sl] = np.where(found[..., None], grid[top], np.nan)
    spacing = (axes.hi - axes.lo) / (n - 1)
    return starts, spacing


def _modes(
    model: StateSpaceModel,
    axes: _Axes,
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


def _valley_limits(
    model: StateSpaceModel,
    axes: _Axes,
    z: np.ndarray,
    bounds: PriorBounds,
    u: np.ndarray,
    H: np.ndarray,
    slopes: tuple[np.ndarray, np.ndarray],
    cut: tuple[np.ndarray, np.ndarray],
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
            lpu, lp = _logp_u(model, axes, pts, z[:, None], bounds)
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
            with np.errstate(all="ignore"):
                y0 = delta / dist
                integral = np.where(
                    np.abs(slope + 1) < 1e-2, np.log(1 / y0), (1 - y0 ** (slope + 1)) / (slope + 1)
                )
                om_mode = axes.omega(u)[:, j]
                sd_om = sd_u * np.where(axes.log_scale[j], np.abs(om_mode), 1.0)
                log_r = (
                    lp[rows, i]
                    + np.log(dist * np.maximum(integral, 0))
                    - lp[:, -1]
                    - np.log(math.sqrt(2 * math.pi) * sd_om)
                )
                r = np.where(valley, np.exp(np.minimum(log_r, 700)), np.inf)
            ratio = np.where(cut_j, np.maximum(ratio, np.nan_to_num(r, nan=np.inf)), ratio)
    return lo_lim, hi_lim, ratio


# ====================================================================== step 2: Newton
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
    axes: _Axes,
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
        _, lp = _logp_u(model, axes, points, z[:, None], bounds)
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


# ====================================================================== step 3: fine grid
def _trapezoid_weights(n: int) -> np.ndarray:
    w = np.ones(n)
    w[0] = w[-1] = 0.5
    return w


def _fine_grid(
    model: StateSpaceModel,
    axes: _Axes,
    z: np.ndarray,
    bounds: PriorBounds,
    centre: np.ndarray,
    sd: np.ndarray,
    lim_lo: np.ndarray,
    lim_hi: np.ndarray,
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
            grid = _tensor(nodes).reshape(part.size, -1, m)
            lpu, _ = _logp_u(model, axes, grid, z[part, None], bounds)
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


def _grid_mass(lpu: np.ndarray) -> np.ndarray:
    """The fine grid's nodes' masses (up to a factor per trajectory): density relative to the
    peak times the tensor trapezoid weights."""
    K, m, n = lpu.shape[0], lpu.ndim - 1, lpu.shape[1]
    w = np.exp(lpu - lpu.reshape(K, -1).max(1).reshape((K,) + (1,) * m))
    tw = _trapezoid_weights(n)
    for j in range(m):
        w = w * tw.reshape((1,) + tuple(n if i == j else 1 for i in range(m)))
    return w


def _marginal_omega(
    axes: _Axes, w: np.ndarray, lo_box: np.ndarray, hi_box: np.ndarray, settings: ExactSettings
) -> tuple[np.ndarray, np.ndarray]:
    """Marginal MAP (Omega scale) and 5 %/95 % quantiles of every Omega component, from the
    fine grid's masses ``w`` (:func:`_grid_mass`)."""
    K = w.shape[0]
    m = w.ndim - 1
    n = w.shape[1]
    tw = _trapezoid_weights(n)
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


# ====================================================================== step 4: states
def _state_box(
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


def _state_mixtures(
    model: StateSpaceModel,
    axes: _Axes,
    z: np.ndarray,
    bounds: PriorBounds,
    lo: np.ndarray,
    hi: np.ndarray,
    settings: ExactSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """Marginal MAP and quantiles of x_0..x_T: mixtures over a tensor grid of
    ``state_nodes`` nodes per axis on the box [lo, hi] (:func:`_state_box`).

    Node g carries weight w_g ∝ p(Omega_g | z) x (trapezoid weight) and the smoothed
    Gaussian N(mu_t(Omega_g), P_t(Omega_g)), widened by the variance of mu_t across the
    node's cell, sum_j (d mu_t / d index_j)^2 / 12 (midpoint rule for the cell, so that a
    coarse Omega grid does not make the mixture bumpy).  Nodes are pruned to the heaviest
    ones holding ``mixture_mass`` of the weight.
    """
    K, m = lo.shape
    ns = settings.state(m)
    nodes = [np.linspace(lo[:, j], hi[:, j], ns, axis=-1) for j in range(m)]
    grid = _tensor(nodes).reshape(K, -1, m)
    lps = np.empty((K, ns**m))
    for sl in _chunks(K, ns**m, settings.chunk_elements):
        lps[sl] = _logp_u(model, axes, grid[sl], z[sl, None], bounds)[0]
    lps = lps.reshape((K,) + (ns,) * m)
    tw = _trapezoid_weights(ns)
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
    for sl in _chunks(K, grid.shape[1] * n_states * 6, settings.chunk_elements):
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
        est[sl], q[sl] = _mixture_mode_quantiles(
            wc, mean, np.sqrt(var), settings, np.sqrt(var + spread)
        )
    return est, q


def _mixture_mode_quantiles(
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
    x = mean[:, 0].copy()  # the heaviest component (weights are sorted)
    for _ in range(settings.mode_iter):
        u = (x[:, None] - mean) / sdm
        phi = w * np.exp(-0.5 * u * u) / sdm
        f = phi.sum(1)
        f1 = -(phi * u / sdm).sum(1)
        f2 = (phi * (u * u - 1) / sdm**2).sum(1)
        with np.errstate(all="ignore"):
            g = f1 / f
            gp = f2 / f - g * g
            step = np.where(gp < 0, -g / gp, np.sign(g) * S / 4)
        step = np.where(np.isfinite(step), step, 0.0)
        x = np.clip(x + np.clip(step, -S / 2, S / 2), lo_m, hi_m)
    mode = x

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


# ====================================================================== boundaries
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


# ====================================================================== driver
def exact_marginal(
    model: StateSpaceModel,
    z: np.ndarray,
    bounds: PriorBounds,
    settings: ExactSettings | None = None,
) -> ExactResult:
    """Exact marginal posteriors of every trajectory ``z`` (K, T, d) (module docstring).

    Returns per trajectory the marginal MAP and 5 %/95 % quantiles of every component of
    Theta = (Omega, x_0, x_1..x_T), and Definition 3's classification of the marginal
    posterior p(Omega | z): ``unique`` (one interior local maximum), ``several`` or
    ``none`` (no interior maximum: the maximum is on the boundary or a ridge).
    """
    settings = settings or ExactSettings()
    if not model.linear_in_states:
        raise ValueError(
            f"model '{model.slug}' is not linear-Gaussian in the states; the "
            f"exact marginal does not apply"
        )
    m = model.n_params
    if not 1 <= m <= settings.max_params:
        raise ValueError(
            f"exact marginal grids are set for 1..{settings.max_params} parameters, "
            f"model '{model.slug}' has {m}"
        )
    z = np.asarray(z, dtype=float)
    if z.ndim != 3 or z.shape[2] != model.obs_dim:
        raise ValueError(f"z must have shape (K, T, {model.obs_dim}), got {z.shape}")
    K, T, _ = z.shape
    log_range = (math.log(settings.half_line_range[0]), math.log(settings.half_line_range[1]))
    axes = _axes(bounds, settings.margin, log_range)

    starts, spacing = _coarse_search(model, axes, z, bounds, settings)
    u, H, n_max, _ = _modes(model, axes, z, bounds, starts, spacing, settings)
    has_mode = np.all(np.isfinite(u), axis=1)
    maxima = np.where(n_max == 0, "none", np.where(n_max == 1, "unique", "several"))
    # trajectories without an interior maximum: grids around the best coarse node anyway
    # (their estimates are reported as NaN)
    fallback = np.where(np.isfinite(starts[:, 0]), starts[:, 0], (axes.lo + axes.hi) / 2)
    u = np.where(has_mode[:, None], u, fallback)
    with np.errstate(all="ignore"):
        cov = np.linalg.inv(np.where(has_mode[:, None, None], -H, np.eye(m)))
        sd = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    sd = np.where(has_mode[:, None] & np.isfinite(sd) & (sd > 0), sd, 2 * spacing)
    mode = axes.omega(u)
    slopes_lower, slopes_upper = boundary_slopes(model, z, bounds, mode)
    cut_lower = improper(slopes_lower, finite=True) | (
        axes.log_scale & np.isinf(bounds.lower) & improper(slopes_lower, finite=False)
    )
    cut_upper = improper(slopes_upper, finite=True) & np.isfinite(bounds.upper) | (
        np.isinf(bounds.upper) & improper(slopes_upper, finite=False)
    )
    lim_lo, lim_hi, spike_ratio = _valley_limits(
        model, axes, z, bounds, u, H, (slopes_lower, slopes_upper), (cut_lower, cut_upper), settings
    )
    lpu, lo_box, hi_box, truncated = _fine_grid(
        model, axes, z, bounds, u, sd, lim_lo, lim_hi, settings
    )
    mass = _grid_mass(lpu)
    om_map, om_q = _marginal_omega(axes, mass, lo_box, hi_box, settings)
    x_map, x_q = _state_mixtures(
        model, axes, z, bounds, *_state_box(mass, lo_box, hi_box, settings), settings
    )
    nan_rows = maxima == "none"
    theta_map = np.concatenate([om_map, x_map], 1)
    theta_q5 = np.concatenate([om_q[..., 0], x_q[..., 0]], 1)
    theta_q95 = np.concatenate([om_q[..., 1], x_q[..., 1]], 1)
    for arr in (theta_map, theta_q5, theta_q95):
        arr[nan_rows] = np.nan
    info = {
        "coarse_nodes": settings.coarse(m),
        "fine_nodes": settings.fine_nodes(m),
        "state_nodes": settings.state(m),
        "box_sd": settings.box_sd,
        "face_drop": settings.face_drop,
        "lower": bounds.lower.tolist(),
        "upper": bounds.upper.tolist(),
    }
    return ExactResult(
        theta_names=model.theta_names(T),
        theta_map=theta_map,
        theta_q5=theta_q5,
        theta_q95=theta_q95,
        maxima=maxima,
        n_local_max=n_max,
        joint_mode=mode,
        laplace_sd=sd,
        box_truncated=truncated,
        spike_ratio=spike_ratio,
        spike_tol=settings.spike_tol,
        slopes_lower=slopes_lower,
        slopes_upper=slopes_upper,
        info=info,
    )
