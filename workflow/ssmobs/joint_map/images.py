"""Images of found joint maxima under the model's symmetries (issues 47 and 60).

A map g of Theta = (Omega, x_0, x_1..x_T) that leaves -2 pi(Theta | z) unchanged for every z
maps every maximum onto a maximum of the same height (Sec. III.B's checks pass at both).
The multi-start (:mod:`ssmobs.joint_map.multi_start`) uses two sources of such maps:

- the maps the user declares in ``model.mirror_images`` (e.g. x -> -x);
- the discrete symmetries found from the model's terms,
  :func:`ssmobs.models.symmetries.model_symmetries` (sign changes, swaps of blocks,
  translations by a period in both directions, reflections), without any declaration.

An image is *admissible* for a row when -2 pi is finite there and its Omega lies inside the
prior support and the model constraints.  Two points are the *same* when no component
differs by more than ``distinct_tol`` local standard deviations of the maximum
(sqrt(LVar_j), Sec. II.B), the rule that clusters the starts' results.  A maximum with an
admissible image that is not the same point has a twin of the same height: its trajectory
has more than one maximum, whether or not a run from the image passed the checks.

:func:`image_runs` optimises again from every admissible image of every distinct maximum the
starts found (extra joint MAPs, not counted among the n starts); :func:`symmetric_twins`
says which trajectories have a maximum with a twin.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ..models.base import PriorBounds, StateSpaceModel
from ..models.log_posterior import in_support, neg2_log_posterior
from ..models.symmetries import model_symmetries
from .driver import JointMapResult, joint_map
from .problem import JointMapProblem
from .settings import JointMapSettings


def symmetry_images(model: StateSpaceModel, theta: np.ndarray) -> list[np.ndarray]:
    """Images of the rows ``theta`` (K, |Theta|): the user's ``mirror_images`` first, then
    every discrete symmetry found (translations in both directions)."""
    theta = np.asarray(theta, dtype=float)
    images = [np.asarray(image, dtype=float) for image in model.mirror_images(theta)]
    images += [
        np.asarray(image, dtype=float) for image in model_symmetries(model).images(model, theta)
    ]
    return images


def same_point(a: np.ndarray, b: np.ndarray, sd: np.ndarray, tol: float) -> np.ndarray:
    """(K,) no component of the rows of ``a`` and ``b`` differs by more than ``tol * sd``."""
    with np.errstate(invalid="ignore"):
        return np.all(np.abs(a - b) <= tol * sd, axis=1)


def admissible_images(
    model: StateSpaceModel,
    z: np.ndarray,
    bounds: PriorBounds,
    theta: np.ndarray,
    local_variance: np.ndarray,
    tol: float,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per image map (:func:`symmetry_images`): the image rows and the (K,) mask of the rows
    where the image is admissible and another point, the same as neither the maximum
    ``theta`` nor an earlier image of it (so each distinct image is run once)."""
    m = model.n_params
    sd = np.sqrt(local_variance)
    seen: list[np.ndarray] = [theta]
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for image in symmetry_images(model, theta):
        with np.errstate(all="ignore"):
            (value,) = neg2_log_posterior(model, image, z, bounds)
        usable = np.isfinite(value) & np.all(np.isfinite(image), axis=1)
        usable &= in_support(model, image[:, :m], bounds)
        for other in seen:
            usable &= ~same_point(image, other, sd, tol)
        seen.append(image)
        out.append((image, usable))
    return out


def has_distinct_image(
    model: StateSpaceModel,
    z: np.ndarray,
    bounds: PriorBounds,
    theta: np.ndarray,
    local_variance: np.ndarray,
    tol: float,
) -> np.ndarray:
    """(K,) the maximum in each row of ``theta`` has an admissible image that is another
    point: a twin of the same height (with a translation, infinitely many)."""
    found = np.zeros(theta.shape[0], dtype=bool)
    for _, usable in admissible_images(model, z, bounds, theta, local_variance, tol):
        found |= usable
    return found


def _expand(result: JointMapResult, rows: np.ndarray, K: int) -> JointMapResult:
    """A result of the trajectories ``rows`` spread to all K (status ``not-run`` elsewhere)."""
    out = JointMapResult.unfilled(K, result.theta_names, "not-run", "image start not run")
    for name in (
        "theta_hat",
        "neg2_log_post",
        "local_variance",
        "eig_ratio",
        "grad_max",
        "iterations",
        "status",
        "reason",
    ):
        getattr(out, name)[rows] = getattr(result, name)
    return out


def maxima_by_round(
    runs: list[JointMapResult], first_start: list[np.ndarray]
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Round r: the trajectories k with more than r distinct maxima, and Theta and the
    local variances of the r-th maximum of each (from the first run reaching it)."""
    for r in range(max((f.size for f in first_start), default=0)):
        rows = np.array([k for k, f in enumerate(first_start) if f.size > r], dtype=np.int64)
        found = np.stack([runs[int(first_start[k][r])].theta_hat[k] for k in rows])
        lvar = np.stack([runs[int(first_start[k][r])].local_variance[k] for k in rows])
        yield rows, found, lvar


def image_runs(
    problem: JointMapProblem, runs: list[JointMapResult], first_start: list[np.ndarray]
) -> list[JointMapResult]:
    """Runs from the admissible images (:func:`admissible_images`: ``model.mirror_images``
    and the model's found discrete symmetries) of every distinct
    maximum found: round r starts, for every k with more than r maxima, from the images of
    its r-th maximum (each distinct image once, and none that is a maximum already found)."""
    model, z, bounds, settings = problem.model, problem.z, problem.bounds, problem.settings
    K = z.shape[0]
    out: list[JointMapResult] = []
    rounds = list(maxima_by_round(runs, first_start))
    for rows, found, lvar in rounds:
        images = admissible_images(model, z[rows], bounds, found, lvar, settings.distinct_tol)
        sd = np.sqrt(lvar)
        for image, usable in images:
            for other_rows, other, _ in rounds:  # a maximum a start already reached
                at = np.flatnonzero(np.isin(rows, other_rows))
                known = np.searchsorted(other_rows, rows[at])
                usable[at] &= ~same_point(image[at], other[known], sd[at], settings.distinct_tol)
            if not usable.any():
                continue
            sub = rows[usable]
            res = joint_map(problem.replace(z=z[sub]), theta_start=image[usable])
            out.append(_expand(res, sub, K))
    return out


def symmetric_twins(
    model: StateSpaceModel,
    z: np.ndarray,
    bounds: PriorBounds,
    runs: list[JointMapResult],
    first_start: list[np.ndarray],
    settings: JointMapSettings,
) -> np.ndarray:
    """(K,) some distinct maximum of k has an admissible image under a symmetry that is
    another point (:func:`has_distinct_image`)."""
    K = z.shape[0]
    twin = np.zeros(K, dtype=bool)
    for rows, found, lvar in maxima_by_round(runs, first_start):
        twin[rows] |= has_distinct_image(model, z[rows], bounds, found, lvar, settings.distinct_tol)
    return twin
