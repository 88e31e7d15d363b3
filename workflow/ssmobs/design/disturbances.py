"""LCD design disturbances: point-symmetric Dirac mixture approximations of N(0, I_q).

The design disturbances of the paper (Sec. III.A) are K equally weighted points in R^q that
approximate the standard normal distribution N(0, I_q).  For ``method="design"`` they are the
point-symmetric set {s_1..s_N, -s_1..-s_N} (plus the origin for odd K) that minimises the modified
Cramér–von Mises distance between localized cumulative distributions (LCDs)
(:mod:`ssmobs.design.lcd_distance`), followed by a covariance correction.  Formulas and section
numbers refer to ``docs/lcd-design-disturbances.md`` ("the doc"):

* covariance correction after the optimisation: Section 5;
* optimiser settings and stopping-rule pitfalls: Section 6.

:func:`design_disturbances` runs with a single OpenBLAS thread by default (see its
``blas_threads`` argument, :mod:`ssmobs.openblas_threads`): the work is dominated by
single-threaded element-wise NumPy loops, and multi-threaded BLAS on small GEMMs is 10-25x
slower when the cores are shared.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize

from .. import kernels
from ..openblas_threads import openblas_threads
from ..seeds import check_seed
from .lcd_distance import (
    b_max_rule,
    check_b_max,
    check_positive_int,
    lcd_distance,
    symmetric_distance,
)

__all__ = [
    "METHODS",
    "DesignResult",
    "design_disturbances",
]

METHODS: tuple[str, ...] = ("design", "random", "antithetic")

#: Default relative objective test (toolbox rule, doc Section 6.1).
REL_TOL: float = 1e-6
#: Default gradient test on K * ||grad||_inf (doc Section 6.2: scale the gradient test by K).
GRAD_TOL: float = 1e-7
#: Default iteration cap (toolbox value).
MAX_ITER: int = 10_000


@dataclass(frozen=True, eq=False)
class DesignResult:
    """A set of K design disturbance vectors in R^q (paper Sec. III.A).

    Attributes
    ----------
    matrix : numpy.ndarray
        Shape ``(q, K)``; column ``k`` is disturbance vector ``k`` (paper layout).  For the
        symmetric methods the columns are ``s_1..s_N, -s_1..-s_N`` and, for odd K, ``0``.
    method : str
        One of :data:`METHODS`.
    q, K, seed : int
        Dimension, number of points and seed of ``numpy.random.default_rng``.
    b_max : float or None
        Kernel width bound used by the optimisation (``None`` for ``"random"``; its distances are
        evaluated at ``b_max_rule(q)`` or at the ``b_max`` passed in).
    distance_raw : float
        Modified CvM distance (doc's :math:`\\hat D`, :math:`\\pi^{-q/2}` normalisation) of the set
        before the covariance correction.
    distance : float
        Distance of the returned set (after the correction).
    iterations : int
        L-BFGS iterations (0 for ``"random"`` and ``"antithetic"``).
    covariance_correction : str
        ``"whitened"`` (K >= 2q: sample covariance exactly I), ``"trace-scaled"`` (K < 2q: trace of
        the sample covariance equals q) or ``"none"``.
    """

    matrix: np.ndarray
    method: str
    q: int
    K: int
    seed: int
    b_max: float | None
    distance_raw: float
    distance: float
    iterations: int
    covariance_correction: str

    @property
    def points(self) -> np.ndarray:
        """The points as rows, shape ``(K, q)`` (a transposed view of :attr:`matrix`)."""
        return self.matrix.T


# --------------------------------------------------------------------------------------------
# Design generation
# --------------------------------------------------------------------------------------------


def _symmetric_points(half: np.ndarray, K: int) -> np.ndarray:
    """Rows s_1..s_N, -s_1..-s_N, then 0 if K is odd; shape (K, q)."""
    parts = [half, -half]
    if K % 2:
        parts.append(np.zeros((1, half.shape[1])))
    return np.concatenate(parts, axis=0)


def _inv_sqrt(lam: np.ndarray, vec: np.ndarray) -> np.ndarray:
    w = (vec / np.sqrt(lam)) @ vec.T
    return 0.5 * (w + w.T)


def _covariance_correct(half: np.ndarray, K: int) -> tuple[np.ndarray, str]:
    """Covariance correction of a symmetric set (doc Section 5), applied to the half-set.

    C = X^T X / K = 2 S^T S / K (divisor K, origin included).  If N >= q (K >= 2q) the set is
    whitened with the symmetric W = C^{-1/2} (plus one refinement pass with the residual
    C' ~ I, so that the sample covariance is I to ~1e-15 even for ill-conditioned C);
    otherwise (C rank-deficient) it is scaled so that trace(C) = q.  A numerically singular
    C with K >= 2q also falls back to trace scaling.
    """
    n_half, q = half.shape
    if n_half == 0:
        return half.copy(), "none"
    c = (2.0 / K) * (half.T @ half)
    c = 0.5 * (c + c.T)
    if n_half >= q:
        lam, vec = np.linalg.eigh(c)
        if lam[0] > 1e-12 * lam[-1] and lam[0] > 0.0:
            out = half @ _inv_sqrt(lam, vec)
            # one refinement step: removes the O(eps * cond(C)) round-off of the first pass
            c2 = (2.0 / K) * (out.T @ out)
            lam2, vec2 = np.linalg.eigh(0.5 * (c2 + c2.T))
            return out @ _inv_sqrt(lam2, vec2), "whitened"
    tr = float(np.trace(c))
    if tr <= 0.0:
        return half.copy(), "none"
    return half * math.sqrt(q / tr), "trace-scaled"


def _optimise_half(
    s0: np.ndarray,
    K: int,
    b_max: float,
    *,
    rel_tol: float,
    grad_tol: float,
    max_iter: int,
    progress: Callable[[str], None] | None,
) -> tuple[np.ndarray, float, int]:
    """L-BFGS (SciPy L-BFGS-B, maxcor=10) on the half-set; returns (S*, D(S*), iterations).

    Stopping (doc Section 6.2): K * ||grad||_inf <= grad_tol (SciPy's gtol = grad_tol / K),
    or the toolbox relative test |f_{k-1} - f_k| <= rel_tol |f_k| (callback), or max_iter.
    SciPy's own absolute ftol test is disabled (ftol = 1e-15, the round-off level of D).
    """
    shape = s0.shape
    t0 = time.perf_counter()
    state: dict[str, Any] = {
        "it": 0,
        "f_prev": math.inf,
        "best_f": math.inf,
        "best_x": s0.ravel().copy(),
    }

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        f, g = symmetric_distance(x.reshape(shape), K, b_max, gradient=True)
        assert g is not None  # gradient=True
        return f, g.ravel()

    def callback(intermediate_result: optimize.OptimizeResult) -> None:
        state["it"] += 1
        f = float(intermediate_result.fun)
        if f < state["best_f"]:
            state["best_f"] = f
            state["best_x"] = np.array(intermediate_result.x, copy=True)
        if progress is not None and state["it"] % 50 == 0:
            progress(
                f"LCD design K={K} q={shape[1]}: iteration {state['it']}, "
                f"distance {f:.7e}, {time.perf_counter() - t0:.1f} s"
            )
        f_prev = state["f_prev"]
        state["f_prev"] = f
        if abs(f_prev - f) <= rel_tol * abs(f):
            state["stop"] = f"relative objective change <= {rel_tol:g}"
            raise StopIteration

    f_start, _ = symmetric_distance(s0, K, b_max, gradient=False)
    state["best_f"] = f_start
    res = optimize.minimize(
        fun,
        s0.ravel(),
        jac=True,
        method="L-BFGS-B",
        callback=callback,
        options={
            "maxcor": 10,
            "gtol": grad_tol / K,
            "ftol": 1e-15,
            "maxiter": max_iter,
            "maxfun": 10 * max_iter + 100,
            "maxls": 40,
        },
    )
    x, f = state["best_x"], state["best_f"]
    if float(res.fun) < f:
        x, f = np.asarray(res.x), float(res.fun)
    if progress is not None:
        reason = state.get("stop") or str(res.message)
        progress(
            f"LCD design K={K} q={shape[1]}: done after {state['it']} iterations "
            f"({res.nfev} evaluations), distance {f:.7e}, {time.perf_counter() - t0:.1f} s, "
            f"stopped: {reason}"
        )
    return x.reshape(shape).copy(), f, int(state["it"])


def design_disturbances(
    q: int,
    K: int,
    method: str = "design",
    seed: int = 0,
    *,
    b_max: float | None = None,
    progress: Callable[[str], None] | None = None,
    correct_covariance: bool = True,
    rel_tol: float = REL_TOL,
    grad_tol: float = GRAD_TOL,
    max_iter: int = MAX_ITER,
    blas_threads: int | None = 1,
) -> DesignResult:
    """Generate K design disturbance vectors approximating N(0, I_q) (paper Sec. III.A).

    Parameters
    ----------
    q : int
        Dimension (>= 1), e.g. ``(d + p) T`` in the paper.
    K : int
        Number of vectors (>= 1).
    method : {"design", "random", "antithetic"}
        ``"design"``: optimal point-symmetric LCD Dirac mixture (doc Sections 0-6): even K gives
        ``{s_1..s_N, -s_1..-s_N}``, odd K adds 0; the half-set starts from seeded i.i.d. N(0, 1)
        entries and is optimised by L-BFGS with the analytic gradient, then covariance-corrected.
        ``"random"``: i.i.d. N(0, 1) entries (drawn as a ``(K, q)`` array), no correction (the
        paper's baseline).  ``"antithetic"``: i.i.d. N(0, 1) half-set, ± pairs (odd K adds 0), same
        covariance correction as ``"design"`` (ablation).
    seed : int
        Seed of ``numpy.random.default_rng`` (non-negative).
    b_max : float, optional
        Kernel width bound; default :func:`b_max_rule` (doc Section 3).
    progress : callable, optional
        Called with a one-line status string every 50 optimiser iterations and at the end.
    correct_covariance : bool, optional
        Apply the covariance correction (default True).  With False the raw optimum is returned
        and ``covariance_correction == "none"``.
    rel_tol, grad_tol, max_iter : optional
        Stopping rule of the optimisation (doc Section 6.2): stop when the relative objective
        change of one iteration is <= ``rel_tol`` (toolbox rule, default 1e-6), when
        ``K * ||grad||_inf <= grad_tol`` (default 1e-7, i.e. the toolbox's absolute 1e-8 at
        K = 10, but not loosening as K grows), or after ``max_iter`` iterations.
    blas_threads : int or None, optional
        OpenBLAS thread count used while generating (default 1, restored afterwards; None leaves
        it alone).  Multi-threaded BLAS gains little here and is 10-25x slower when the cores are
        shared with other processes.

    Returns
    -------
    DesignResult
        ``matrix`` has shape ``(q, K)``; column k is point k, ordered ``s_1..s_N, -s_1..-s_N, 0``.

    Notes
    -----
    Covariance correction (doc Section 5), applied after the optimisation, to ``"design"`` and
    ``"antithetic"``: with C = X^T X / K (divisor K, origin included)

    * K >= 2q: symmetric whitening x_k <- C^{-1/2} x_k, so the sample covariance (divisor K) is
      I up to round-off, the mean is exactly 0 and the set stays point-symmetric ("whitened");
    * K < 2q: C has rank <= K // 2 < q and cannot equal I; the set is scaled by
      sqrt(q / trace C) so that trace(C) = q, i.e. the mean squared norm is q ("trace-scaled").

    ``distance_raw`` / ``distance`` are the doc's :math:`\\hat D` before / after the correction.
    For ``"random"`` both are the distance of the sample, evaluated at ``b_max`` (or
    ``b_max_rule(q)``), and ``b_max`` is reported as None.  Results depend on the random start and
    on floating-point details (doc Section 6.5); store designs rather than regenerating them on
    other machines.

    Raises
    ------
    ValueError
        If q < 1, K < 1, the method is unknown, the seed is not an integer in
        [0, 2**32 - 1] or b_max is not positive.
    """
    kernels.warn_once_if_not_fixed("ssmobs.design.disturbances.design_disturbances")
    q = check_positive_int("q", q)
    K = check_positive_int("K", K)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}; got {method!r}")
    seed = check_seed(seed)
    bm = b_max_rule(q) if b_max is None else check_b_max(b_max)
    if not (float(rel_tol) >= 0.0 and float(grad_tol) >= 0.0):
        raise ValueError(f"rel_tol and grad_tol must be >= 0; got {rel_tol!r}, {grad_tol!r}")
    max_iter = check_positive_int("max_iter", max_iter)
    if blas_threads is not None:
        blas_threads = check_positive_int("blas_threads", blas_threads)
    with openblas_threads(blas_threads):
        return _generate(
            q,
            K,
            method,
            seed,
            bm,
            progress,
            correct_covariance=correct_covariance,
            rel_tol=rel_tol,
            grad_tol=grad_tol,
            max_iter=max_iter,
        )


def _generate(
    q: int,
    K: int,
    method: str,
    seed: int,
    bm: float,
    progress: Callable[[str], None] | None,
    *,
    correct_covariance: bool,
    rel_tol: float,
    grad_tol: float,
    max_iter: int,
) -> DesignResult:
    rng = np.random.default_rng(seed)
    n_half = K // 2

    if method == "random":
        x = rng.standard_normal((K, q))
        d = lcd_distance(x, bm)
        return DesignResult(
            matrix=np.ascontiguousarray(x.T),
            method=method,
            q=q,
            K=K,
            seed=seed,
            b_max=None,
            distance_raw=d,
            distance=d,
            iterations=0,
            covariance_correction="none",
        )

    half = rng.standard_normal((n_half, q))
    iterations = 0
    if method == "design" and n_half > 0:
        half, d_raw, iterations = _optimise_half(
            half, K, bm, rel_tol=rel_tol, grad_tol=grad_tol, max_iter=max_iter, progress=progress
        )
    else:
        d_raw, _ = symmetric_distance(half, K, bm, gradient=False)

    if correct_covariance:
        half_c, label = _covariance_correct(half, K)
    else:
        half_c, label = half, "none"
    if label == "none" and half_c is half:
        d_final = d_raw
    else:
        d_final, _ = symmetric_distance(half_c, K, bm, gradient=False)
    x = _symmetric_points(half_c, K)
    return DesignResult(
        matrix=np.ascontiguousarray(x.T),
        method=method,
        q=q,
        K=K,
        seed=seed,
        b_max=bm,
        distance_raw=float(d_raw),
        distance=float(d_final),
        iterations=iterations,
        covariance_correction=label,
    )
