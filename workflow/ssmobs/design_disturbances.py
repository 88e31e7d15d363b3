"""LCD design disturbances: point-symmetric Dirac mixture approximations of N(0, I_q).

The design disturbances of the paper (Sec. III.A) are K equally weighted points in R^q that
approximate the standard normal distribution N(0, I_q).  For ``method="design"`` they are the
point-symmetric set {s_1..s_N, -s_1..-s_N} (plus the origin for odd K) that minimises the modified
Cramér–von Mises distance between localized cumulative distributions (LCDs), followed by a
covariance correction.  Formulas and section numbers refer to
``docs/lcd-design-disturbances.md`` ("the doc"):

* distance (the doc's :math:`\\hat D`, normalised by :math:`\\pi^{-q/2}`): Sections 1-2, in the
  regularised form of Section 2.4 (each term minus :math:`B^2/2`);
* gradient: Section 4;
* width bound :math:`b_{\\max}`: Section 3 (toolbox rule);
* covariance correction after the optimisation: Section 5;
* optimiser settings and stopping-rule pitfalls: Section 6.

Vectorisation.  All pairwise quantities are computed block-wise on the upper triangle of the
(N x N) block grid (Gram trick, doc Section 6.3), so :math:`E_1` is evaluated once per unordered
pair and the working memory is a few (block x block) arrays.  In the small-argument regime that
occurs in practice (:math:`c = T/4B^2 \\le 1`, doc Section 7 item 1) :math:`E_1` is evaluated by
its convergent power series (``-gamma - ln c + sum (-1)^{k+1} c^k / (k k!)``), which is about
5x faster than ``scipy.special.exp1`` and agrees with it to ~1e-15 relative; larger arguments fall
back to ``scipy.special.exp1``.  :func:`design_disturbances` runs with a single OpenBLAS thread by
default (see its ``blas_threads`` argument): the work is dominated by single-threaded element-wise
NumPy loops, and multi-threaded BLAS on small GEMMs is 10-25x slower when the cores are shared.
"""

from __future__ import annotations

import ctypes
import math
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from scipy import optimize, special

from .seeds import check_seed

__all__ = [
    "METHODS",
    "DesignResult",
    "b_max_rule",
    "lcd_distance",
    "symmetric_distance_and_gradient",
    "design_disturbances",
]

METHODS: tuple[str, ...] = ("design", "random", "antithetic")

#: Gauss–Legendre nodes for J' and M on [0, asinh(sqrt(2) B)] (doc Section 2.4: 64-96).
N_NODES: int = 80
#: Rows per block of the pairwise (block-upper-triangular) evaluation.
BLOCK_SIZE: int = 256
#: Default relative objective test (toolbox rule, doc Section 6.1).
REL_TOL: float = 1e-6
#: Default gradient test on K * ||grad||_inf (doc Section 6.2: scale the gradient test by K).
GRAD_TOL: float = 1e-7
#: Default iteration cap (toolbox value).
MAX_ITER: int = 10_000

_EULER_GAMMA = 0.57721566490153286061
_SERIES_MAX = 1.0  # use the E1 power series for c <= 1
_SERIES_COEF = np.array(
    [(-1.0) ** (k + 1) / (k * math.factorial(k)) for k in range(1, 31)], dtype=np.float64
)
# smallest number of terms m so that the first omitted term c^{m+1}/((m+1)(m+1)!) <= 1e-17
_SERIES_CMAX = np.array(
    [(1e-17 * (m + 1) * math.factorial(m + 1)) ** (1.0 / (m + 1)) for m in range(1, 31)]
)


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
# b_max rule and quadrature
# --------------------------------------------------------------------------------------------


def b_max_rule(q: int) -> float:
    """Kernel width bound of the Nonlinear Estimation Toolbox (doc Section 3).

    Parameters
    ----------
    q : int
        Dimension (>= 1).

    Returns
    -------
    float
        5 for q = 1; 10 for q <= 10; 50 for q <= 100; 100 for q <= 1000; 200 otherwise.
    """
    q = _check_positive_int("q", q)
    if q == 1:
        return 5.0
    if q <= 10:
        return 10.0
    if q <= 100:
        return 50.0
    if q <= 1000:
        return 100.0
    return 200.0


def _log_tanh(v: np.ndarray) -> np.ndarray:
    e = np.exp(-2.0 * v)
    return np.log1p(-e) - np.log1p(e)


@dataclass(frozen=True, eq=False)
class _Quadrature:
    """Precomputed fixed Gauss–Legendre rule of doc Section 2.4 for one (q, B)."""

    q: int
    b_max: float
    lam: np.ndarray  # q * log tanh(v_l)
    sig: np.ndarray  # sech^2(v_l)
    alpha: np.ndarray  # w_l sinh(2 v_l) / 4   (J')
    beta: np.ndarray  # w_l tanh(v_l) / 2     (M)
    d1p: float  # D1' = D1 - B^2/2
    j0p: float  # J'(0)

    def j_prime(self, n: np.ndarray) -> np.ndarray:
        """J'(n) = J(n) - B^2/2 for squared norms ``n`` (doc 2.4)."""
        a = self.lam[None, :] - 0.5 * np.asarray(n, dtype=np.float64)[:, None] * self.sig[None, :]
        return np.expm1(a) @ self.alpha

    def j_prime_and_m(self, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """J'(n) and M(n) = -2 dJ/dn (doc Sections 2.4 and 4) with shared nodes."""
        a = self.lam[None, :] - 0.5 * n[:, None] * self.sig[None, :]
        jp = np.expm1(a) @ self.alpha
        np.exp(a, out=a)
        return jp, a @ self.beta


def _gauss_legendre(lo: float, hi: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(n)
    half = 0.5 * (hi - lo)
    return lo + half * (x + 1.0), half * w


@lru_cache(maxsize=64)
def _quadrature(q: int, b_max: float, n_nodes: int = N_NODES) -> _Quadrature:
    # J' and M: one L-node rule on [0, V], V = asinh(sqrt(2) B) (substitution sqrt(2) b = sinh v)
    v, w = _gauss_legendre(0.0, math.asinh(math.sqrt(2.0) * b_max), n_nodes)
    lam = q * _log_tanh(v)
    sig = 1.0 / np.cosh(v) ** 2
    alpha = 0.25 * w * np.sinh(2.0 * v)
    beta = 0.5 * w * np.tanh(v)
    # D1' = 1/2 int_0^{asinh B} (tanh^q u - 1) sinh(2u) du, composite rule (panels <= 0.25 wide)
    u_max = math.asinh(b_max)
    n_panels = max(4, math.ceil(u_max / 0.25))
    edges = np.linspace(0.0, u_max, n_panels + 1)
    xs, ws = np.polynomial.legendre.leggauss(32)
    d1p = 0.0
    for lo, hi in zip(edges[:-1], edges[1:]):
        u = lo + 0.5 * (hi - lo) * (xs + 1.0)
        d1p += (
            0.5
            * (hi - lo)
            * float(np.sum(ws * 0.5 * np.expm1(q * _log_tanh(u)) * np.sinh(2.0 * u)))
        )
    j0p = float(np.expm1(lam) @ alpha)
    for arr in (lam, sig, alpha, beta):
        arr.setflags(write=False)
    return _Quadrature(q, b_max, lam, sig, alpha, beta, d1p, j0p)


# --------------------------------------------------------------------------------------------
# Pairwise terms: E1 and psi (doc Sections 2.4 and 4)
# --------------------------------------------------------------------------------------------


def _e1(c: np.ndarray, zero_diag: bool = False) -> np.ndarray:
    """E1(c) for an array c >= 0, with the convention E1(0) := 0 (doc Section 4).

    ``zero_diag`` marks a square block whose diagonal is exactly zero (T^-_{ii}).
    """
    if c.size == 0:
        return np.zeros_like(c)
    cmax = float(c.max())
    if zero_diag:
        # placeholder inside the range of c (keeps cmax and the series length), reset below
        np.fill_diagonal(c, cmax if cmax > 0.0 else 1.0)
    cmin = float(c.min())
    with np.errstate(divide="ignore"):
        if cmax > _SERIES_MAX:
            e = special.exp1(c)
        else:
            # number of terms: first m with cmax <= _SERIES_CMAX[m - 1]
            m = (
                min(int(np.searchsorted(_SERIES_CMAX, cmax, side="left")), len(_SERIES_COEF) - 1)
                + 1
            )
            e = np.multiply(c, _SERIES_COEF[m - 1])
            for k in range(m - 2, -1, -1):
                e += _SERIES_COEF[k]
                e *= c
            e -= np.log(c)
            e -= _EULER_GAMMA
    if cmin <= 0.0:
        e[c <= 0.0] = 0.0
    if zero_diag:
        np.fill_diagonal(c, 0.0)
        np.fill_diagonal(e, 0.0)
    return e


def _psi_sum(c: np.ndarray, e: np.ndarray) -> float:
    """sum of psi(T) / (4 B^2) = sum [c E1(c) + 1 - exp(-c)] over a block (doc 2.4)."""
    return float(np.einsum("i,i->", c.reshape(-1), e.reshape(-1))) - float(np.sum(np.expm1(-c)))


def _blocks(n: int, size: int) -> list[tuple[int, int]]:
    return [(a, min(a + size, n)) for a in range(0, n, size)]


def _check_points(points: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(
            f"{name} must be a 2-D array of shape (n_points, q); got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _check_b_max(b_max: float) -> float:
    try:
        b = float(b_max)
    except (TypeError, ValueError):
        raise ValueError(f"b_max must be a positive finite number; got {b_max!r}") from None
    if not (math.isfinite(b) and b > 0.0):
        raise ValueError(f"b_max must be a positive finite number; got {b_max!r}")
    return b


# --------------------------------------------------------------------------------------------
# Distances
# --------------------------------------------------------------------------------------------


def lcd_distance(points: np.ndarray, b_max: float, *, n_nodes: int = N_NODES) -> float:
    """Modified CvM (LCD) distance between N(0, I_q) and equally weighted points (doc 2.2, 2.4).

    General (asymmetric) formula with weights 1/K and the :math:`\\pi^{-q/2}` normalisation
    (the doc's :math:`\\hat D`): ``D1' - 2 (1/K) sum_k J'(|x_k|^2)
    - (1/(8K^2)) sum_{k,l} psi(|x_k - x_l|^2)``.  Meant for tests and reporting; O(K^2 q) time,
    O(K q + block^2) memory.

    Parameters
    ----------
    points : numpy.ndarray
        Shape ``(K, q)``; row k is point k.
    b_max : float
        Kernel width bound B.
    n_nodes : int, optional
        Gauss–Legendre nodes for J'.

    Returns
    -------
    float
        :math:`\\hat D \\ge 0`.
    """
    x = _check_points(points, "points")
    k, q = x.shape
    if k < 1 or q < 1:
        raise ValueError(f"points must have at least one row and one column; got shape {x.shape}")
    b = _check_b_max(b_max)
    quad = _quadrature(q, b, n_nodes)
    inv4b2 = 1.0 / (4.0 * b * b)
    w = 1.0 / k
    n = np.einsum("ij,ij->i", x, x)
    d2p = w * float(np.sum(quad.j_prime(n)))
    cn = n * inv4b2
    psi = 0.0
    blocks = _blocks(k, BLOCK_SIZE)
    for bi, (a0, a1) in enumerate(blocks):
        for b0, b1 in blocks[bi:]:
            diag = a0 == b0
            c = x[a0:a1] @ x[b0:b1].T
            c *= -2.0 * inv4b2
            c += cn[a0:a1, None]
            c += cn[None, b0:b1]
            np.maximum(c, 0.0, out=c)
            e = _e1(c, zero_diag=diag)
            psi += (1.0 if diag else 2.0) * _psi_sum(c, e)
    d3p = -(w * w / 8.0) * 4.0 * b * b * psi
    return quad.d1p - 2.0 * d2p + d3p


def _symmetric_eval(
    half: np.ndarray, K: int, b_max: float, *, gradient: bool, n_nodes: int = N_NODES
) -> tuple[float, np.ndarray | None]:
    s = half
    n_half, q = s.shape
    quad = _quadrature(q, b_max, n_nodes)
    w = 1.0 / K
    eps = K - 2 * n_half
    inv4b2 = 1.0 / (4.0 * b_max * b_max)
    n = np.einsum("ij,ij->i", s, s)
    jp, m = quad.j_prime_and_m(n)
    d2p = 2.0 * w * float(np.sum(jp)) + eps * w * quad.j0p

    cn = n * inv4b2
    psi = 0.0  # sum over ordered pairs (i, j) of [psi(T-) + psi(T+)] / (4 B^2)
    if gradient:
        gpair = np.zeros_like(s)  # ((E- - E+) S)_i
        rsum = np.zeros(n_half)  # ((E- + E+) 1)_i
    blocks = _blocks(n_half, BLOCK_SIZE)
    for bi, (a0, a1) in enumerate(blocks):
        si = s[a0:a1]
        for b0, b1 in blocks[bi:]:
            diag = a0 == b0
            sj = s[b0:b1]
            g2 = si @ sj.T
            g2 *= 2.0 * inv4b2
            cm = np.add.outer(cn[a0:a1], cn[b0:b1])
            cp = cm + g2
            cm -= g2
            np.maximum(cm, 0.0, out=cm)
            np.maximum(cp, 0.0, out=cp)
            em = _e1(cm, zero_diag=diag)
            ep = _e1(cp)
            f = 1.0 if diag else 2.0
            psi += f * (_psi_sum(cm, em) + _psi_sum(cp, ep))
            if gradient:
                r = em + ep
                em -= ep  # em now holds E- - E+
                gpair[a0:a1] += em @ sj
                rsum[a0:a1] += r.sum(axis=1)
                if not diag:
                    gpair[b0:b1] += em.T @ si
                    rsum[b0:b1] += r.sum(axis=0)
    psi0 = 0.0
    e0 = None
    if eps and n_half:
        c0 = cn.copy()
        e0 = _e1(c0)
        psi0 = _psi_sum(c0, e0)
    d3p = -(w * w / 8.0) * 4.0 * b_max * b_max * (2.0 * psi + 4.0 * eps * psi0)
    value = quad.d1p - 2.0 * d2p + d3p
    if not gradient:
        return value, None
    grad = (4.0 * w) * m[:, None] * s
    grad += (w * w) * (gpair - rsum[:, None] * s)
    if e0 is not None:
        grad -= (w * w) * e0[:, None] * s
    return value, grad


def symmetric_distance_and_gradient(
    half: np.ndarray, K: int, b_max: float, *, n_nodes: int = N_NODES
) -> tuple[float, np.ndarray]:
    """Distance of a point-symmetric set and its gradient w.r.t. the half-set (doc 2.4, 4).

    The set is ``{s_i} U {-s_i}`` (plus the origin if K is odd), weights 1/K.

    Parameters
    ----------
    half : numpy.ndarray
        Half-set S, shape ``(N, q)`` with ``N = K // 2`` (N may be 0 only for K = 1).
    K : int
        Total number of points (``2N`` or ``2N + 1``).
    b_max : float
        Kernel width bound B.
    n_nodes : int, optional
        Gauss–Legendre nodes for J' and M (doc 2.4 recommends 64-96).

    Returns
    -------
    value : float
        :math:`\\hat D = \\hat D_1' - 2\\hat D_2' + \\hat D_3'` (regularised form, doc 2.4).
    grad : numpy.ndarray
        :math:`\\partial \\hat D / \\partial S`, shape ``(N, q)`` (doc Section 4, boxed formula;
        the j = i term of E+ is kept).  It is the exact gradient of the discretised objective.
    """
    s = _check_points(half, "half")
    K = _check_positive_int("K", K)
    if s.shape[0] != K // 2:
        raise ValueError(
            f"half must have K // 2 = {K // 2} rows for K = {K}; got {s.shape[0]} rows"
        )
    if s.shape[1] < 1:
        raise ValueError(f"half must have at least one column (q >= 1); got shape {s.shape}")
    value, grad = _symmetric_eval(s, K, _check_b_max(b_max), gradient=True, n_nodes=n_nodes)
    assert grad is not None
    return value, grad


# --------------------------------------------------------------------------------------------
# Design generation
# --------------------------------------------------------------------------------------------


_BLAS_THREAD_SYMBOLS = (
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("openblas_get_num_threads", "openblas_set_num_threads"),
)


@lru_cache(maxsize=1)
def _openblas_thread_controls() -> tuple[tuple[Callable[[], int], Callable[[int], None]], ...]:
    """(get, set) thread-count functions of the OpenBLAS libraries loaded in this process.

    Found via /proc/self/maps (Linux); empty elsewhere or if nothing is found.
    """
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted(
                {
                    line.split()[-1]
                    for line in fh
                    if "openblas" in line.lower() and line.split()[-1].startswith("/")
                }
            )
    except OSError:
        return ()
    controls = []
    mode = getattr(os, "RTLD_NOLOAD", 0) | getattr(os, "RTLD_NOW", 2)
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=mode)
        except OSError:
            continue
        for get_name, set_name in _BLAS_THREAD_SYMBOLS:
            get_fn = getattr(lib, get_name, None)
            set_fn = getattr(lib, set_name, None)
            if get_fn is not None and set_fn is not None:
                get_fn.restype = ctypes.c_int
                get_fn.argtypes = []
                set_fn.restype = None
                set_fn.argtypes = [ctypes.c_int]
                controls.append((get_fn, set_fn))
                break
    return tuple(controls)


@contextmanager
def _blas_threads(n: int | None) -> Iterator[None]:
    """Temporarily set the OpenBLAS thread count (no-op for None or if OpenBLAS is not found).

    The pairwise work is dominated by single-threaded NumPy element-wise loops; multi-threaded
    BLAS gains little on an idle machine and slows the small GEMMs down by 10-25x when the cores
    are shared with other processes (OpenBLAS threads spin), so the optimisation runs with 1.
    """
    saved = []
    if n is not None:
        for get_fn, set_fn in _openblas_thread_controls():
            try:
                old = int(get_fn())
                set_fn(int(n))
                saved.append((set_fn, old))
            except Exception:  # pragma: no cover - defensive, foreign library
                continue
    try:
        yield
    finally:
        for set_fn, old in reversed(saved):
            set_fn(old)


def _check_positive_int(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be a positive integer (>= 1); got {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be a positive integer (>= 1); got {value!r}")
    return int(value)


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
        f, g = _symmetric_eval(x.reshape(shape), K, b_max, gradient=True)
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

    f_start, _ = _symmetric_eval(s0, K, b_max, gradient=False)
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
    q = _check_positive_int("q", q)
    K = _check_positive_int("K", K)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}; got {method!r}")
    seed = check_seed(seed)
    bm = b_max_rule(q) if b_max is None else _check_b_max(b_max)
    if not (float(rel_tol) >= 0.0 and float(grad_tol) >= 0.0):
        raise ValueError(f"rel_tol and grad_tol must be >= 0; got {rel_tol!r}, {grad_tol!r}")
    max_iter = _check_positive_int("max_iter", max_iter)
    if blas_threads is not None:
        blas_threads = _check_positive_int("blas_threads", blas_threads)
    with _blas_threads(blas_threads):
        return _generate(
            q, K, method, seed, bm, progress, correct_covariance, rel_tol, grad_tol, max_iter
        )


def _generate(
    q: int,
    K: int,
    method: str,
    seed: int,
    bm: float,
    progress: Callable[[str], None] | None,
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
        d_raw, _ = _symmetric_eval(half, K, bm, gradient=False)

    if correct_covariance:
        half_c, label = _covariance_correct(half, K)
    else:
        half_c, label = half, "none"
    if label == "none" and half_c is half:
        d_final = d_raw
    else:
        d_final, _ = _symmetric_eval(half_c, K, bm, gradient=False)
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
