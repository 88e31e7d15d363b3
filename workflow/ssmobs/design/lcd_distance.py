"""The LCD distance of a point set to N(0, I_q), and its gradient for point-symmetric sets.

The distance is the modified Cramér–von Mises distance between localized cumulative
distributions (LCDs) that :mod:`ssmobs.design.disturbances` minimises.  Formulas and
section numbers refer to ``docs/lcd-design-disturbances.md`` ("the doc"):

* distance (the doc's :math:`\\hat D`, normalised by :math:`\\pi^{-q/2}`): Sections 1-2, in the
  regularised form of Section 2.4 (each term minus :math:`B^2/2`);
* gradient: Section 4;
* width bound :math:`b_{\\max}`: Section 3 (toolbox rule).

Vectorisation.  All pairwise quantities are computed block-wise on the upper triangle of the
(N x N) block grid (Gram trick, doc Section 6.3), so :math:`E_1` is evaluated once per unordered
pair and the working memory is a few (block x block) arrays.  In the small-argument regime that
occurs in practice (:math:`c = T/4B^2 \\le 1`, doc Section 7 item 1) :math:`E_1` is evaluated by
its convergent power series (``-gamma - ln c + sum (-1)^{k+1} c^k / (k k!)``), which is about
5x faster than ``scipy.special.exp1`` and agrees with it to ~1e-15 relative; larger arguments fall
back to ``scipy.special.exp1``.

Kernels.  :func:`symmetric_distance` (what the optimiser calls) runs this NumPy code as the
reference and, up to q = :data:`COMPILED_MAX_Q`, the fused compiled kernel of
:mod:`ssmobs.design.lcd_native` (doc Section 6.6); the quadrature rule of both is computed in
decimal
arithmetic, the same bits everywhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import Decimal, localcontext
from functools import lru_cache

import numpy as np
from scipy import special

__all__ = [
    "b_max_rule",
    "lcd_distance",
    "symmetric_distance",
    "symmetric_distance_and_gradient",
]

#: Gauss–Legendre nodes for J' and M on [0, asinh(sqrt(2) B)] (doc Section 2.4: 64-96).
N_NODES: int = 80
#: Rows per block of the pairwise (block-upper-triangular) evaluation.
BLOCK_SIZE: int = 256

_EULER_GAMMA = 0.57721566490153286061
_SERIES_MAX = 1.0  # use the E1 power series for c <= 1
_SERIES_COEF = np.array(
    [(-1.0) ** (k + 1) / (k * math.factorial(k)) for k in range(1, 31)], dtype=np.float64
)
# smallest number of terms m so that the first omitted term c^{m+1}/((m+1)(m+1)!) <= 1e-17
_SERIES_CMAX = np.array(
    [(1e-17 * (m + 1) * math.factorial(m + 1)) ** (1.0 / (m + 1)) for m in range(1, 31)]
)


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
    q = check_positive_int("q", q)
    if q == 1:
        return 5.0
    if q <= 10:
        return 10.0
    if q <= 100:
        return 50.0
    if q <= 1000:
        return 100.0
    return 200.0


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


#: decimal digits of the quadrature rule's computation (then rounded to doubles)
_DIGITS = 45


def _dec_expm1(z: Decimal) -> Decimal:
    """exp(z) - 1, also for tiny |z| (series)."""
    if abs(z) < Decimal("1e-6"):
        return z * (1 + z / 2 * (1 + z / 3 * (1 + z / 4 * (1 + z / 5))))
    return z.exp() - 1


def _dec_log_tanh(v: Decimal) -> Decimal:
    e = (-2 * v).exp()
    return ((1 - e) / (1 + e)).ln()


@lru_cache(maxsize=8)
def _dec_gauss_legendre(n: int) -> tuple[tuple[Decimal, Decimal], ...]:
    """Gauss–Legendre nodes and weights on [-1, 1] by Newton's method on P_n in decimal
    arithmetic (start: the usual cosine estimate; only its last bits depend on the C
    library, the converged root does not)."""
    out = []
    eps = Decimal(10) ** (-(_DIGITS - 5))
    for i in range(1, n + 1):
        x = Decimal(repr(math.cos(math.pi * (i - 0.25) / (n + 0.5))))
        for _ in range(100):
            p0, p1 = Decimal(1), x
            for k in range(2, n + 1):
                p0, p1 = p1, ((2 * k - 1) * x * p1 - (k - 1) * p0) / k
            dp = n * (x * p1 - p0) / (x * x - 1)
            dx = p1 / dp
            x -= dx
            if abs(dx) < eps:
                break
        p0, p1 = Decimal(1), x
        for k in range(2, n + 1):
            p0, p1 = p1, ((2 * k - 1) * x * p1 - (k - 1) * p0) / k
        dp = n * (x * p1 - p0) / (x * x - 1)
        out.append((x, 2 / ((1 - x * x) * dp * dp)))
    return tuple(sorted(out))


@lru_cache(maxsize=64)
def _quadrature(q: int, b_max: float, n_nodes: int = N_NODES) -> _Quadrature:
    """The rule of doc Section 2.4 for (q, B), computed in decimal arithmetic with
    :data:`_DIGITS` digits and rounded to doubles: the same bits on any machine, whatever
    NumPy's or the C library's kernels (the compiled kernel's inputs)."""
    with localcontext() as ctx:
        ctx.prec = _DIGITS
        d = Decimal
        # J' and M: one L-node rule on [0, V], V = asinh(sqrt(2) B) (sqrt(2) b = sinh v)
        y = d(2).sqrt() * d(repr(float(b_max)))
        big_v = (y + (y * y + 1).sqrt()).ln()
        half = big_v / 2
        lam, sig, alpha, beta = [], [], [], []
        for x, w in _dec_gauss_legendre(n_nodes):
            v = half * (x + 1)
            wv = half * w
            e2 = (2 * v).exp()
            th = (e2 - 1) / (e2 + 1)
            lam.append(q * _dec_log_tanh(v))
            sig.append(1 - th * th)
            alpha.append(wv * (e2 - 1 / e2) / 8)  # w sinh(2v) / 4
            beta.append(wv * th / 2)
        # D1' = 1/2 int_0^{asinh B} (tanh^q u - 1) sinh(2u) du, composite rule (panels <= 0.25)
        yb = d(repr(float(b_max)))
        u_max = (yb + (yb * yb + 1).sqrt()).ln()
        n_panels = max(4, math.ceil(float(u_max) / 0.25))
        rule32 = _dec_gauss_legendre(32)
        d1p = d(0)
        for p in range(n_panels):
            lo, hi = u_max * p / n_panels, u_max * (p + 1) / n_panels
            part = d(0)
            for x, w in rule32:
                u = lo + (hi - lo) / 2 * (x + 1)
                e2 = (2 * u).exp()
                part += w * _dec_expm1(q * _dec_log_tanh(u)) * (e2 - 1 / e2) / 4
            d1p += (hi - lo) / 2 * part
        j0p = sum((_dec_expm1(lm) * al for lm, al in zip(lam, alpha)), d(0))
        arrays = [np.array([float(t) for t in col]) for col in (lam, sig, alpha, beta)]
    for arr in arrays:
        arr.setflags(write=False)
    lam_a, sig_a, alpha_a, beta_a = arrays
    return _Quadrature(q, float(b_max), lam_a, sig_a, alpha_a, beta_a, float(d1p), float(j0p))


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


def check_b_max(b_max: float) -> float:
    """``b_max`` as a float; ValueError unless it is finite and positive."""
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
    b = check_b_max(b_max)
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


#: the kernels of :func:`symmetric_distance`
KERNELS: tuple[str, ...] = ("auto", "compiled", "numpy")
#: ``kernel="auto"`` runs the compiled kernel up to this dimension and NumPy above it: its
#: baseline build loses to OpenBLAS's AVX2 products above it (K = 1000: 0.94x at q = 64,
#: 0.82x at q = 100); its AVX2 build wins per evaluation up to q = 100, but the default
#: profile's q = 100 sets (K <= 500) are no faster on it (0.96x at K = 500) and would change
#: their bits (BENCHMARKS.md)
COMPILED_MAX_Q: int = 48


def symmetric_distance(
    half: np.ndarray,
    K: int,
    b_max: float,
    *,
    gradient: bool,
    n_nodes: int = N_NODES,
    kernel: str = "auto",
) -> tuple[float, np.ndarray | None]:
    """Distance of the point-symmetric set of ``half`` (and its gradient w.r.t. ``half``
    with ``gradient=True``, else None), without checking the arguments
    (:func:`symmetric_distance_and_gradient` checks them).

    ``kernel="compiled"``: the fused C++ kernel of :mod:`ssmobs.design.lcd_native`, the same bits
    on any x86-64 CPU whatever NumPy's and OpenBLAS's kernels and threads (it raises
    :class:`ssmobs.design.lcd_native.LcdKernelUnavailable` where it cannot be built);
    ``"numpy"``: the NumPy reference below (block-wise, OpenBLAS products), which agrees
    with it to ~1e-12 relative, not in the last bits, and whose bits follow the kernels
    NumPy and OpenBLAS run (fixed by the workflow, :mod:`ssmobs.kernels`); ``"auto"``
    (default): ``"compiled"`` for q <= :data:`COMPILED_MAX_Q`, else ``"numpy"`` (a choice
    by q alone, never by the machine)."""
    if kernel == "auto":
        kernel = "compiled" if half.shape[1] <= COMPILED_MAX_Q else "numpy"
    if kernel == "compiled":
        from . import lcd_native

        quad = _quadrature(half.shape[1], b_max, n_nodes)
        rule = (quad.lam, quad.sig, quad.alpha, quad.beta, quad.d1p, quad.j0p)
        return lcd_native.symmetric_distance(half, K, b_max, rule, gradient)
    if kernel != "numpy":
        raise ValueError(f"kernel must be one of {KERNELS}; got {kernel!r}")
    return _symmetric_distance_numpy(half, K, b_max, gradient=gradient, n_nodes=n_nodes)


def _symmetric_distance_numpy(
    half: np.ndarray, K: int, b_max: float, *, gradient: bool, n_nodes: int = N_NODES
) -> tuple[float, np.ndarray | None]:
    """The NumPy reference of :func:`symmetric_distance` (block-wise pairs, see the module
    docstring)."""
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
    K = check_positive_int("K", K)
    if s.shape[0] != K // 2:
        raise ValueError(
            f"half must have K // 2 = {K // 2} rows for K = {K}; got {s.shape[0]} rows"
        )
    if s.shape[1] < 1:
        raise ValueError(f"half must have at least one column (q >= 1); got shape {s.shape}")
    value, grad = symmetric_distance(s, K, check_b_max(b_max), gradient=True, n_nodes=n_nodes)
    assert grad is not None
    return value, grad


def check_positive_int(name: str, value: object) -> int:
    """``value`` as an int; ValueError naming ``name`` unless it is an integer >= 1."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be a positive integer (>= 1); got {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be a positive integer (>= 1); got {value!r}")
    return int(value)
