"""Unit tests of ssmobs.design.disturbances (LCD design disturbances, paper Sec. III.A).

Reference values are from docs/lcd-design-disturbances.md ("the doc"), Sections 2.2 and 8.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, special
from ssmobs.design import disturbances as ddm
from ssmobs.design import lcd_distance as lcd
from ssmobs.design.disturbances import METHODS, DesignResult, design_disturbances
from ssmobs.design.lcd_distance import b_max_rule, lcd_distance, symmetric_distance_and_gradient

pytestmark = pytest.mark.unit

TIGHT = dict(rel_tol=1e-13, grad_tol=1e-12)


def _best_of_seeds(q: int, K: int, seeds=(0, 1, 2), **kw) -> DesignResult:
    results = [design_disturbances(q, K, seed=s, **kw) for s in seeds]
    return min(results, key=lambda r: r.distance_raw)


def _half(res: DesignResult) -> np.ndarray:
    return res.points[: res.K // 2]


def _sorted_radii(x: np.ndarray) -> np.ndarray:
    return np.sort(np.linalg.norm(x, axis=1))


def _random_orthogonal(q: int, rng: np.random.Generator) -> np.ndarray:
    a = rng.standard_normal((q, q))
    qmat, r = np.linalg.qr(a)
    return qmat * np.sign(np.diag(r))


# ------------------------------------------------------------------------------------------
# b_max rule, quadrature, E1
# ------------------------------------------------------------------------------------------


@pytest.mark.unit
@pytest.mark.parametrize(
    "q, b",
    [
        (1, 5.0),
        (2, 10.0),
        (10, 10.0),
        (11, 50.0),
        (100, 50.0),
        (101, 100.0),
        (1000, 100.0),
        (1001, 200.0),
    ],
)
def test_b_max_rule(q, b):
    assert b_max_rule(q) == b


@pytest.mark.unit
@pytest.mark.parametrize("B", [5.0, 10.0, 100.0])
def test_q2_closed_forms_against_quadrature(B):
    """Doc 2.2 test oracles for q = 2: D1 and J(n) (tolerance: round-off of J - B^2/2)."""
    quad = lcd._quadrature(2, B)
    d1p_exact = -0.5 * math.log1p(B * B)  # D1 - B^2/2 = (B^2 - ln(1 + B^2))/2 - B^2/2
    assert quad.d1p == pytest.approx(d1p_exact, abs=1e-13)
    tau = 1.0 + 2.0 * B * B
    n = np.array([0.0, 1e-3, 0.3, 2.0, 10.0, 50.0, 200.0])
    a = n[1:] / 2.0
    j_exact = np.concatenate(
        [
            [0.25 * (tau - 1.0 - math.log(tau))],
            0.25
            * (
                tau * np.exp(-a / tau)
                - np.exp(-a)
                - (a + 1.0) * (special.exp1(a / tau) - special.exp1(a))
            ),
        ]
    )
    jp, m = quad.j_prime_and_m(n)
    # the closed form subtracts B^2/2 after the fact: its own round-off is ~1e-16 * B^2
    np.testing.assert_allclose(jp, j_exact - B * B / 2.0, rtol=0, atol=1e-15 * B * B + 1e-13)
    assert quad.j0p == pytest.approx(j_exact[0] - B * B / 2.0, abs=1e-15 * B * B + 1e-13)

    # M(n) = -2 dJ/dn: closed-form derivative of the q = 2 oracle, by Richardson differences
    def j_closed(nn):
        aa = nn / 2.0
        return 0.25 * (
            tau * np.exp(-aa / tau)
            - np.exp(-aa)
            - (aa + 1.0) * (special.exp1(aa / tau) - special.exp1(aa))
        )

    for k, nk in enumerate(n[2:], start=2):
        h = 1e-3 * max(nk, 1.0)
        d1 = (j_closed(nk + h) - j_closed(nk - h)) / (2 * h)
        d2 = (j_closed(nk + h / 2) - j_closed(nk - h / 2)) / h
        deriv = (4 * d2 - d1) / 3
        assert m[k] == pytest.approx(-2.0 * deriv, rel=1e-7, abs=1e-11 * B * B)


@pytest.mark.unit
@pytest.mark.parametrize("q, B", [(1, 5.0), (3, 10.0), (7, 10.0), (50, 50.0), (200, 100.0)])
def test_d1_against_adaptive_quadrature(q, B):
    """D1' (composite Gauss–Legendre in v) against scipy.integrate.quad of the definition."""

    def integrand(b):
        return ((b * b / (1.0 + b * b)) ** (q / 2.0) - 1.0) * b  # D1 - B^2/2 as one integral

    ref, _ = integrate.quad(integrand, 0.0, B, limit=500, epsabs=1e-13, epsrel=1e-13)
    assert lcd._quadrature(q, B).d1p == pytest.approx(ref, rel=1e-10)


@pytest.mark.unit
def test_e1_series_matches_scipy():
    c = np.concatenate([np.logspace(-14, 0, 2001), np.linspace(0.5, 1.0, 101)])
    np.testing.assert_allclose(lcd._e1(c.copy()), special.exp1(c), rtol=1e-14)
    big = np.array([0.0, 0.5, 3.0, 40.0])  # > 1 falls back to scipy; E1(0) := 0
    np.testing.assert_allclose(lcd._e1(big.copy()), [0.0, *special.exp1(big[1:])], rtol=1e-15)


# ------------------------------------------------------------------------------------------
# Distance: general vs symmetric formula, invariances, B behaviour
# ------------------------------------------------------------------------------------------


@pytest.mark.unit
@pytest.mark.parametrize("q, K", [(1, 3), (2, 6), (3, 7), (7, 20), (12, 33), (40, 81)])
def test_general_equals_symmetric_and_rotation_invariance(q, K):
    rng = np.random.default_rng(q * 100 + K)
    B = b_max_rule(q)
    half = rng.standard_normal((K // 2, q))
    x = ddm._symmetric_points(half, K)
    d_sym, _ = symmetric_distance_and_gradient(half, K, B)
    d_gen = lcd_distance(x, B)
    assert d_sym > 0
    assert d_gen == pytest.approx(d_sym, rel=1e-12, abs=1e-14)
    rot = _random_orthogonal(q, rng)
    assert lcd_distance(x @ rot.T, B) == pytest.approx(d_gen, rel=1e-12, abs=1e-14)
    d_rot, _ = symmetric_distance_and_gradient(half @ rot.T, K, B)
    assert d_rot == pytest.approx(d_sym, rel=1e-12, abs=1e-14)
    # permutations of the points and sign flips of the s_i
    perm = rng.permutation(K)
    assert lcd_distance(x[perm], B) == pytest.approx(d_gen, rel=1e-12, abs=1e-14)
    signs = rng.choice([-1.0, 1.0], size=(K // 2, 1))
    d_flip, _ = symmetric_distance_and_gradient(half * signs, K, B)
    assert d_flip == pytest.approx(d_sym, rel=1e-12, abs=1e-14)


@pytest.mark.unit
@pytest.mark.parametrize("q, B", [(1, 0.7), (2, 1.5), (2, 10.0), (3, 5.0)])
def test_distance_against_direct_integration(q, B):
    """lcd_distance against adaptive quadrature over b of the doc 2.1 inner closed forms.

    Independent of the regularised form, of g_B / E1 and of the Gauss–Legendre rule; small B
    makes c = T / 4B^2 > 1 (scipy.special.exp1 branch).
    """
    rng = np.random.default_rng(int(10 * B) + q)
    x = 1.5 * rng.standard_normal((5, q))
    w = 1.0 / len(x)
    n = np.sum(x * x, axis=1)
    t = np.sum((x[:, None, :] - x[None, :, :]) ** 2, axis=-1)
    opts = dict(limit=400, epsabs=1e-14, epsrel=1e-13)

    # integrands: pi^{-q/2} b^{1-q} P_i(b) of doc 2.1
    def p1(b):
        return (b * b / (1.0 + b * b)) ** (q / 2.0) * b

    def p2(b):
        return (
            (2 * b * b / (1 + 2 * b * b)) ** (q / 2.0)
            * b
            * w
            * np.sum(np.exp(-n / (2 * (1 + 2 * b * b))))
        )

    def p3(b):
        return b * w * w * np.sum(np.exp(-t / (4 * b * b)))

    d = sum(f * integrate.quad(p, 0.0, B, **opts)[0] for f, p in ((1, p1), (-2, p2), (1, p3)))
    ref_scale = B * B / 2  # the three terms are ~B^2/2 each before cancelling
    assert lcd_distance(x, B) == pytest.approx(d, rel=1e-9, abs=1e-12 * ref_scale)
    xs = ddm._symmetric_points(x[:2], 5)
    t = np.sum((xs[:, None, :] - xs[None, :, :]) ** 2, axis=-1)
    n = np.sum(xs * xs, axis=1)
    d = sum(f * integrate.quad(p, 0.0, B, **opts)[0] for f, p in ((1, p1), (-2, p2), (1, p3)))
    d_sym, _ = symmetric_distance_and_gradient(x[:2], 5, B)
    assert d_sym == pytest.approx(d, rel=1e-9, abs=1e-12 * ref_scale)


@pytest.mark.unit
def test_distance_behaviour_in_b_max():
    """Doc 2.5 / 9.4: symmetric sets converge as B grows; a shifted set grows like |mu|^2/2 ln B."""
    half = np.array([[1.434603, 0.0], [0.0, 1.434603]])
    x = ddm._symmetric_points(half, 5)
    d = [lcd_distance(x, B) for B in (1e3, 1e4, 1e5)]
    assert d[0] == pytest.approx(0.01991861, abs=2e-8)  # doc 9.4: 0.01991861 at B = 1e3
    assert abs(d[2] - d[1]) < 1e-7
    mu = np.array([0.3, 0.0])
    ds = [lcd_distance(x + mu, B) for B in (1e4, 1e5)]
    assert ds[1] - ds[0] == pytest.approx(0.5 * 0.09 * math.log(10.0), rel=1e-3)


@pytest.mark.unit
def test_random_set_distance_nonnegative_and_single_point():
    rng = np.random.default_rng(5)
    for q, K in [(1, 1), (2, 1), (3, 10), (20, 15)]:
        assert lcd_distance(rng.standard_normal((K, q)), b_max_rule(q)) > 0
    # K = 1: only the origin (N = 0); symmetric and general formula agree
    d_sym, g = symmetric_distance_and_gradient(np.zeros((0, 3)), 1, 10.0)
    assert g.shape == (0, 3)
    assert d_sym == pytest.approx(lcd_distance(np.zeros((1, 3)), 10.0), rel=1e-13)


# ------------------------------------------------------------------------------------------
# Gradient
# ------------------------------------------------------------------------------------------


@pytest.mark.unit
@pytest.mark.parametrize(
    "q, K, rtol",
    [
        (1, 2, 1e-8),
        (1, 3, 1e-8),
        (2, 6, 1e-8),
        (3, 9, 1e-8),
        (4, 12, 1e-8),
        (5, 7, 1e-8),
        (40, 81, 1e-5),
    ],
)
def test_gradient_matches_finite_differences(q, K, rtol):
    """Central differences with one Richardson step (doc 9.2); odd and even K.

    For q = 40 the round-off floor of the regularised objective (~1e-13 absolute, doc Section 7
    item 3) limits the check to ~1e-5 relative.
    """
    rng = np.random.default_rng(q + 7 * K)
    B = b_max_rule(q)
    half = rng.standard_normal((K // 2, q))
    _, grad = symmetric_distance_and_gradient(half, K, B)

    def f(s):
        return symmetric_distance_and_gradient(s, K, B)[0]

    def richardson(direction, h=1e-3):
        def cd(hh):
            return (f(half + hh * direction) - f(half - hh * direction)) / (2 * hh)

        return (4 * cd(h / 2) - cd(h)) / 3

    gscale = np.max(np.abs(grad))
    for _ in range(3):  # random directions
        d = rng.standard_normal(half.shape)
        d /= np.linalg.norm(d)
        assert richardson(d) == pytest.approx(np.vdot(grad, d), rel=rtol, abs=rtol * gscale)
    for idx in list(np.ndindex(half.shape))[:4]:  # single coordinates
        e = np.zeros_like(half)
        e[idx] = 1.0
        assert richardson(e) == pytest.approx(grad[idx], rel=rtol, abs=rtol * gscale)


# ------------------------------------------------------------------------------------------
# Known optima (doc Section 8)
# ------------------------------------------------------------------------------------------

# (q, K, D*, sorted radii before whitening, D after whitening or None, sorted radii after)
KNOWN_OPTIMA = [
    (1, 2, 3.0076188e-2, [0.789836] * 2, 4.8375806e-2, [1.0] * 2),
    (1, 3, 1.1373319e-2, [0.0] + [1.074509] * 2, 1.6434290e-2, [0.0] + [math.sqrt(1.5)] * 2),
    (1, 4, 5.7309527e-3, [0.316542] * 2 + [1.253559] * 2, None, [0.346242] * 2 + [1.371174] * 2),
    (
        1,
        5,
        3.3773491e-3,
        [0.0] + [0.522618] * 2 + [1.381884] * 2,
        None,
        [0.0] + [0.559312] * 2 + [1.478908] * 2,
    ),
    (2, 5, 1.9842376e-2, [0.0] + [1.434603] * 4, 2.5148086e-2, [0.0] + [math.sqrt(2.5)] * 4),
    (3, 6, 3.2203643e-2, [1.554598] * 6, None, [math.sqrt(3.0)] * 6),
]


@pytest.mark.unit
@pytest.mark.parametrize("q, K, d_star, radii, d_white, radii_white", KNOWN_OPTIMA)
def test_known_optima(q, K, d_star, radii, d_white, radii_white):
    """Doc Section 8 table (best of 3 seeds, tight tolerance); invariants, not coordinates."""
    raw = _best_of_seeds(q, K, correct_covariance=False, **TIGHT)
    assert raw.covariance_correction == "none"
    assert raw.distance == raw.distance_raw
    assert raw.distance_raw == pytest.approx(d_star, rel=2e-7)  # table has 8 digits
    np.testing.assert_allclose(_sorted_radii(raw.points), radii, atol=2e-6)

    white = design_disturbances(q, K, seed=raw.seed, **TIGHT)
    assert white.covariance_correction == "whitened"
    assert white.distance_raw == raw.distance_raw  # same optimisation path
    np.testing.assert_allclose(_sorted_radii(white.points), radii_white, atol=2e-6)
    if d_white is not None:
        assert white.distance == pytest.approx(d_white, rel=2e-7)
    if q >= 2:  # cross / octahedron: the half-set vectors are mutually orthogonal
        h = _half(raw)
        gram = h @ h.T
        off = gram - np.diag(np.diag(gram))
        assert np.max(np.abs(off)) < 1e-5


@pytest.mark.unit
@pytest.mark.parametrize(
    "K, r_star, d_star, r_white",
    [(10, 2.076536, 3.6207195e-2, math.sqrt(5.0)), (11, 2.218586, 3.2284538e-2, math.sqrt(5.5))],
)
def test_cross_polytope_law_q5(K, r_star, d_star, r_white):
    """Doc Section 8: for K = 2q and 2q + 1 the optimum is the scaled cross-polytope."""
    q = 5
    raw = _best_of_seeds(q, K, correct_covariance=False, **TIGHT)
    assert raw.distance_raw == pytest.approx(d_star, rel=2e-7)
    h = _half(raw)
    np.testing.assert_allclose(np.linalg.norm(h, axis=1), r_star, atol=2e-6)
    gram = h @ h.T
    assert np.max(np.abs(gram - np.diag(np.diag(gram)))) < 1e-4
    white = design_disturbances(q, K, seed=raw.seed, **TIGHT)
    np.testing.assert_allclose(np.linalg.norm(_half(white), axis=1), r_white, atol=1e-6)


@pytest.mark.unit
def test_distance_falls_with_K():
    """Doc Section 8 'Decrease with K' (q = 2): before-whitening values within 15 %."""
    q = 2
    doc = {5: 1.98e-2, 11: 4.83e-3, 21: 1.44e-3, 51: 2.81e-4}
    res = {K: design_disturbances(q, K, seed=0) for K in doc}
    raw = [res[K].distance_raw for K in doc]
    final = [res[K].distance for K in doc]
    assert all(a > b for a, b in zip(raw, raw[1:]))
    assert all(a > b for a, b in zip(final, final[1:]))
    for K, ref in doc.items():
        assert res[K].distance_raw == pytest.approx(ref, rel=0.15)


@pytest.mark.unit
@pytest.mark.parametrize("q, K, factor", [(2, 51, 0.3), (10, 101, 0.9)])
def test_design_beats_whitened_antithetic(q, K, factor):
    """The optimised design has a clearly smaller distance than a whitened antithetic set."""
    des = design_disturbances(q, K, "design", seed=0)
    anti = [design_disturbances(q, K, "antithetic", seed=s).distance for s in range(3)]
    assert des.distance < factor * min(anti)


# ------------------------------------------------------------------------------------------
# Structure, moments, covariance correction
# ------------------------------------------------------------------------------------------


@pytest.mark.unit
@pytest.mark.parametrize(
    "q, K, method",
    [
        (3, 7, "design"),
        (4, 8, "design"),
        (6, 13, "antithetic"),
        (5, 10, "antithetic"),
        (12, 40, "design"),
    ],
)
def test_symmetry_mean_and_whitening(q, K, method):
    res = design_disturbances(q, K, method, seed=3)
    x = res.matrix
    n = K // 2
    assert x.shape == (q, K)
    assert res.covariance_correction == "whitened"
    # point symmetry, column order s_1..s_N, -s_1..-s_N, 0
    assert np.array_equal(x[:, n : 2 * n], -x[:, :n])
    if K % 2:
        assert np.array_equal(x[:, -1], np.zeros(q))
    # the mean is exactly zero: sum of the s_i plus sum of the -s_i cancels bit for bit
    assert np.array_equal(x[:, :n].sum(axis=1) + x[:, n : 2 * n].sum(axis=1), np.zeros(q))
    assert np.max(np.abs(x.mean(axis=1))) < 1e-14
    # sample covariance with divisor K is I to 1e-12 (round-off of the eigen-whitening)
    cov = x @ x.T / K
    assert np.max(np.abs(cov - np.eye(q))) < 1e-12
    assert res.distance > 0 and res.distance_raw > 0
    # the reported distance is the distance of the returned set
    assert res.distance == pytest.approx(lcd_distance(res.points, res.b_max), rel=1e-11)


@pytest.mark.unit
@pytest.mark.parametrize(
    "q, K, method",
    [(5, 7, "design"), (5, 9, "design"), (10, 9, "antithetic"), (30, 40, "antithetic")],
)
def test_trace_scaling_when_K_below_2q(q, K, method):
    """K < 2q: covariance cannot be I (rank <= K // 2); trace(C) = q to 1e-12 relative."""
    res = design_disturbances(q, K, method, seed=1)
    x = res.matrix
    assert res.covariance_correction == "trace-scaled"
    cov = x @ x.T / K
    assert np.trace(cov) == pytest.approx(q, rel=1e-12)
    assert np.linalg.matrix_rank(cov) <= K // 2
    assert np.array_equal(x[:, K // 2 : 2 * (K // 2)], -x[:, : K // 2])


@pytest.mark.unit
def test_random_method_moments_and_layout():
    """i.i.d. N(0,1): each entry of C - I has sd <= sqrt(2/K); bound 6 sd (seeded)."""
    q, K, seed = 3, 5000, 11
    res = design_disturbances(q, K, "random", seed=seed)
    assert res.b_max is None and res.iterations == 0 and res.covariance_correction == "none"
    assert res.distance == res.distance_raw > 0
    expected = np.random.default_rng(seed).standard_normal((K, q)).T
    assert np.array_equal(res.matrix, expected)
    cov = res.matrix @ res.matrix.T / K
    assert np.max(np.abs(cov - np.eye(q))) < 6.0 * math.sqrt(2.0 / K)
    assert np.max(np.abs(res.matrix.mean(axis=1))) < 6.0 / math.sqrt(K)


@pytest.mark.unit
def test_antithetic_layout_and_raw_distance():
    q, K = 4, 9
    res = design_disturbances(q, K, "antithetic", seed=2)
    half = np.random.default_rng(2).standard_normal((K // 2, q))
    d_raw, _ = symmetric_distance_and_gradient(half, K, b_max_rule(q))
    assert res.iterations == 0 and res.b_max == b_max_rule(q)
    assert res.distance_raw == pytest.approx(d_raw, rel=1e-14)
    # whitening is a linear map applied to the half-set: directions are preserved up to W
    w = np.linalg.lstsq(half, _half(res), rcond=None)[0]
    np.testing.assert_allclose(half @ w, _half(res), atol=1e-12)
    np.testing.assert_allclose(w, w.T, atol=1e-12)  # symmetric whitening matrix C^{-1/2}


@pytest.mark.unit
def test_single_point_and_small_K():
    res = design_disturbances(3, 1, "design")
    assert res.matrix.shape == (3, 1) and np.all(res.matrix == 0)
    assert res.iterations == 0 and res.covariance_correction == "none"
    assert res.distance == res.distance_raw > 0
    res2 = design_disturbances(1, 2, "design")
    np.testing.assert_allclose(np.sort(res2.matrix.ravel()), [-1.0, 1.0], atol=1e-14)


# ------------------------------------------------------------------------------------------
# Determinism, progress, argument checking
# ------------------------------------------------------------------------------------------


@pytest.mark.unit
@pytest.mark.parametrize("method", METHODS)
def test_determinism(method):
    a = design_disturbances(6, 15, method, seed=4)
    b = design_disturbances(6, 15, method, seed=4)
    c = design_disturbances(6, 15, method, seed=5)
    assert np.array_equal(a.matrix, b.matrix)
    assert a.distance == b.distance and a.iterations == b.iterations
    assert not np.array_equal(a.matrix, c.matrix)
    assert (a.method, a.q, a.K, a.seed) == (method, 6, 15, 4)


@pytest.mark.unit
def test_progress_callback():
    messages: list[str] = []
    res = design_disturbances(10, 101, seed=0, progress=messages.append)
    assert res.iterations >= 50
    assert len(messages) == res.iterations // 50 + 1
    assert all(isinstance(m, str) and "\n" not in m for m in messages)
    assert "iteration 50" in messages[0] and "distance" in messages[0] and " s" in messages[0]


@pytest.mark.unit
def test_explicit_b_max():
    res = design_disturbances(2, 5, seed=0, b_max=20.0)
    assert res.b_max == 20.0
    assert res.distance == pytest.approx(lcd_distance(res.points, 20.0), rel=1e-12)


@pytest.mark.unit
@pytest.mark.parametrize(
    "kwargs, pattern",
    [
        (dict(q=0, K=5), r"q must be a positive integer.*got 0"),
        (dict(q=-2, K=5), r"q must be a positive integer.*got -2"),
        (dict(q=2.5, K=5), r"q must be a positive integer.*got 2\.5"),
        (dict(q=2, K=0), r"K must be a positive integer.*got 0"),
        (dict(q=2, K=True), r"K must be a positive integer.*got True"),
        (
            dict(q=2, K=5, method="sobol"),
            r"method must be one of \('design', 'random', 'antithetic'\); got 'sobol'",
        ),
        (dict(q=2, K=5, seed=-1), r"seed must be an integer in \[0, 4294967295\]; got -1"),
        (dict(q=2, K=5, seed=2**70), r"seed must be an integer in \[0, 4294967295\]; got 1180"),
        (dict(q=2, K=5, b_max=0.0), r"b_max must be a positive finite number; got 0\.0"),
    ],
)
def test_invalid_arguments(kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        design_disturbances(**kwargs)


@pytest.mark.unit
def test_invalid_arguments_low_level():
    with pytest.raises(ValueError, match=r"half must have K // 2 = 3 rows for K = 7; got 2 rows"):
        symmetric_distance_and_gradient(np.ones((2, 2)), 7, 10.0)
    with pytest.raises(ValueError, match="points must be a 2-D array"):
        lcd_distance(np.ones(3), 10.0)
    with pytest.raises(ValueError, match="q must be a positive integer"):
        b_max_rule(0)


@pytest.mark.unit
@pytest.mark.parametrize("q, K", [(1, 5), (10, 51), (200, 401)])
def test_quadrature_nodes_converged(q, K):
    """The default fixed Gauss–Legendre rule agrees with a 400-node rule (doc 2.4)."""
    B = b_max_rule(q)
    half = np.random.default_rng(q).standard_normal((K // 2, q))
    v1, g1 = symmetric_distance_and_gradient(half, K, B)
    v2, g2 = symmetric_distance_and_gradient(half, K, B, n_nodes=400)
    assert abs(v1 - v2) < 1e-11
    assert np.max(np.abs(g1 - g2)) < 1e-10 * np.max(np.abs(g2))


def test_every_mth_design_point_is_a_point_symmetric_subset_when_m_divides_half_of_K():
    """Section IV rows on subsets (scenario key stan_every, docs/decisions.md): the columns
    are s_1..s_N, -s_1..-s_N, so every m-th with m | N keeps both points of each pair."""
    K, m = 40, 4
    points = design_disturbances(3, K, "design", seed=0).matrix.T  # (K, q)
    subset = points[::m]
    assert len(subset) == K // m
    np.testing.assert_allclose(subset[: K // (2 * m)], -subset[K // (2 * m) :])
