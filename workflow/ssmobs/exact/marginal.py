"""Exact marginal posteriors for the models that are linear-Gaussian in the states (issue 11).

For fixed Omega the models Same, Sep, (Sep, d=2, p=1), (Sep, d=1, p=2) and ranWalk are
linear-Gaussian state space models (``model.linear_in_states``), so with the flat prior
p_0(x_0) of Sec. IV the states integrate out in closed form:

    p(Omega | z) ∝ p(Omega) ∫ p(z | Omega, x_0, ..., x_T) p(x_1..x_T | x_0, Omega) dx_0..dx_T.

:func:`ssmobs.exact.kalman_filter.kalman_marginal` evaluates -2 log of that integral exactly
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

Interior singularities.  Where a prior support contains a point at which x_0 drops out of
the likelihood (a coefficient that carries x_0 is 0 there, as a in Sep with an unrestricted
prior, or two components become indistinguishable, as c = d in (Sep, d=1, p=2)), p(Omega |
z) diverges at that point inside the support.
:func:`ssmobs.exact.interior_singularities.interior_dropouts` finds it on each bounded
axis through the mode (the rank of the observability matrix of x_0), the slope toward it
is measured as at the ends, and where it is improper the box stops at the valley between
it and the mode: the marginal MAP and quantiles are those of the interior maximum's basin,
never of the spike, and ``spike_ratio`` counts the spike's mass on the mode's side.

The steps live in their own modules: the grid over Omega (steps 1-3) in
:mod:`ssmobs.exact.omega_grid`, the state mixtures (step 4) in
:mod:`ssmobs.exact.state_mixtures`, the boundary slopes and the valley limits in
:mod:`ssmobs.exact.boundaries`, the interior singularities in
:mod:`ssmobs.exact.interior_singularities`, the settings in :mod:`ssmobs.exact.settings`;
this module holds the driver and its result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..models import PriorBounds, StateSpaceModel
from .boundaries import boundary_slopes, improper, valley_limits
from .interior_singularities import interior_dropouts, interior_slopes, interior_valleys
from .omega_grid import (
    coarse_search,
    fine_grid,
    grid_mass,
    interior_modes,
    marginal_omega,
    omega_axes,
)
from .settings import ExactSettings
from .state_mixtures import state_box, state_mixtures

if TYPE_CHECKING:
    import pandas

MAXIMA_KINDS = ("unique", "several", "none")


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
    spike_ratio: np.ndarray  # (K,) improper part cut off / basin mass (valley_limits)
    spike_tol: float
    slopes_lower: np.ndarray  # (K, m) d log p / d log(distance to lower boundary)
    slopes_upper: np.ndarray  # (K, m)
    info: dict
    #: (K, m) where x0 drops out inside the support along each axis (NaN: nowhere), and the
    #: slope toward it; None for a scenario without any such point
    interior_points: np.ndarray | None = None
    slopes_interior: np.ndarray | None = None

    def to_frame(self, model: StateSpaceModel) -> pandas.DataFrame:
        """One row per trajectory, columns like the Stan stage's gather table:
        ``k``, ``status``, ``converged`` (= unique interior maximum and the grid box not
        truncated: Definition 3's set, the rows the statistics use), ``maxima``,
        ``spike_ratio`` and ``spike_not_negligible`` (>= ``spike_tol``: the non-integrable
        part near an improper boundary, down to ``spike_distance`` from it, is not
        negligible against the interior mode's basin; reported, not used as a filter),
        ``n_local_max``, ``box_truncated``, ``improper_lower_<p>``/``improper_upper_<p>``,
        ``slope_lower_<p>``/``slope_upper_<p>``, ``mode_<p>``, ``laplace_sd_<p>`` and
        ``<name>_map``/``_q5``/``_q95`` for every component of Theta.  Where x0 drops out
        of the likelihood inside the support
        (:func:`ssmobs.exact.interior_singularities.interior_dropouts`) for some
        trajectory, also ``interior_<p>`` (the point, NaN: none on that axis),
        ``slope_interior_<p>`` and ``improper_interior_<p>`` (the marginal is not integrable
        there: the estimates are those of the interior maximum's basin)."""
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
        if self.interior_points is not None and self.slopes_interior is not None:
            for i, pname in enumerate(model.param_names):
                slope = self.slopes_interior[:, i]
                cols[f"interior_{pname}"] = self.interior_points[:, i]
                cols[f"slope_interior_{pname}"] = slope
                cols[f"improper_interior_{pname}"] = improper(slope, finite=True)
        for j, name in enumerate(self.theta_names):
            cols[f"{name}_map"] = self.theta_map[:, j]
            cols[f"{name}_q5"] = self.theta_q5[:, j]
            cols[f"{name}_q95"] = self.theta_q95[:, j]
        return pd.DataFrame(cols)


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
    axes = omega_axes(bounds, settings.margin, log_range)

    starts, spacing = coarse_search(model, axes, z, bounds, settings)
    u, H, n_max, _ = interior_modes(model, axes, z, bounds, starts, spacing, settings)
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
    lim_lo, lim_hi, spike_ratio = valley_limits(
        model,
        axes,
        z,
        bounds,
        u,
        H,
        (slopes_lower, slopes_upper),
        (cut_lower, cut_upper),
        settings=settings,
    )
    # x0 dropping out inside the support: a spike the basin must stop short of, as at the ends
    inner = interior_dropouts(model, bounds, mode, settings.margin)
    found_inner = bool(np.isfinite(inner).any())
    slopes_inner = interior_slopes(model, z, bounds, mode, inner) if found_inner else None
    if slopes_inner is not None:
        lim_lo, lim_hi, inner_ratio = interior_valleys(
            model,
            axes,
            z,
            bounds,
            u,
            H,
            inner,
            slopes_inner,
            limits=(lim_lo, lim_hi),
            settings=settings,
        )
        spike_ratio = np.maximum(spike_ratio, inner_ratio)
    lpu, lo_box, hi_box, truncated = fine_grid(
        model, axes, z, bounds, u, sd, lim_lo, lim_hi, settings=settings
    )
    mass = grid_mass(lpu)
    om_map, om_q = marginal_omega(axes, mass, lo_box, hi_box, settings)
    x_map, x_q = state_mixtures(
        model, axes, z, bounds, *state_box(mass, lo_box, hi_box, settings), settings
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
        interior_points=inner if found_inner else None,
        slopes_interior=slopes_inner,
    )
