"""The fast paths of the exact stage's Kalman filter give the reference formulas' numbers to
the bit (issue 48): a change of the last bit would change the committed outputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
import ssmobs.exact.kalman_filter as kf
from ssmobs.exact.kalman_filter import kalman_marginal
from ssmobs.models import get_model

pytestmark = pytest.mark.unit


def _reference_p2(F, Q, H, R, z, smooth):
    """The p = 2 filter as it was before the entrywise path: 2x2 matrix products throughout
    (the closed-form 2x2 inverse, ``kf._inv``, is unchanged and shared)."""
    inv = kf._inv
    p = 2
    T, d = z.shape[-2:]
    Qi = 1 / Q
    HtRi = np.swapaxes(H, -1, -2) / R[..., None, :]
    hrh = HtRi @ H
    a0 = np.swapaxes(F, -1, -2) @ (Qi[..., :, None] * F)
    diagQi = Qi[..., :, None] * np.eye(p)
    a_mid, a_end = hrh + diagQi + a0, hrh + diagQi
    bm = -Qi[..., :, None] * F
    bmt = np.swapaxes(bm, -1, -2)
    c = ((z * z).sum(-2) / R).sum(-1)
    Si, det = inv(a0)
    y = np.zeros(np.broadcast_shapes(z.shape[:-2], F.shape[:-2]) + (p,))
    logdet, quad = np.log(det), 0.0
    Sis, ys = [Si], [y]
    for t in range(1, T + 1):
        g = bm @ Si
        S = (a_mid if t < T else a_end) - g @ bmt
        y = (HtRi @ z[..., t - 1, :, None])[..., 0] - (g @ y[..., None])[..., 0]
        Si, det = inv(S)
        quad = quad + np.einsum("...i,...ij,...j->...", y, Si, y)
        logdet = logdet + np.log(det)
        Sis.append(Si)
        ys.append(y)
    neg2 = (
        c
        - quad
        + logdet
        + T * (np.log(R).sum(-1) + np.log(Q).sum(-1))
        + ((d + p) * T - p * (T + 1)) * kf.LOG_2PI
    )
    if not smooth:
        return neg2, None, None
    shape = np.broadcast_shapes(np.shape(neg2), Sis[-1].shape[:-2])
    mean, var = np.empty(shape + (T + 1, p)), np.empty(shape + (T + 1, p))
    m, P = (Sis[T] @ ys[T][..., None])[..., 0], Sis[T]
    mean[..., T, :], var[..., T, :] = m, np.diagonal(P, axis1=-2, axis2=-1)
    for t in range(T - 1, -1, -1):
        gi = Sis[t] @ bmt
        m = (Sis[t] @ ys[t][..., None])[..., 0] - (gi @ m[..., None])[..., 0]
        P = Sis[t] + gi @ P @ np.swapaxes(gi, -1, -2)
        mean[..., t, :], var[..., t, :] = m, np.diagonal(P, axis1=-2, axis2=-1)
    return neg2, mean, var


def _same_bits(a, b):
    """Equal to the bit, NaN matching any NaN: which NaN an operation with two NaN operands
    returns (its sign bit) differs between NumPy's SIMD loops and their scalar remainders, so
    it depends on an element's place in the batch already in the reference (the callers map
    every non-finite value to -inf or to weight 0)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or not np.array_equal(np.isnan(a), np.isnan(b)):
        return False
    keep = ~np.isnan(a)
    return np.array_equal(a[keep].view(np.uint64), b[keep].view(np.uint64))


def _omega_sep_d1_p2(rng, shape, outside=True):
    """(a, b, c, d) inside the support, and if ``outside`` some where -2 log p is not finite
    (exact zeros in H and F, a^2 + b^2 > 1: a negative observation noise variance)."""
    om = np.stack(
        [rng.uniform(-0.7, 0.7, shape), rng.uniform(-0.7, 0.7, shape)]
        + [rng.uniform(-0.99, 0.99, shape) for _ in range(2)],
        axis=-1,
    )
    flat = om.reshape(-1, 4)
    if outside:
        flat[:5, 0] = 0.0  # x^(1) never observed: the flat prior's integral diverges
        flat[5:10, :2] = 0.9  # a^2 + b^2 > 1: negative R
        flat[10:14, 3] = -0.0  # F singular
    return om


@pytest.mark.parametrize("smooth", [False, True])
@pytest.mark.parametrize(
    ("omega_shape", "z_shape"),
    [((300,), (300,)), ((1, 200), (7, 1)), ((3, 100), (3, 1)), ((40,), (40,))],
)
@pytest.mark.parametrize("outside", [False, True])
def test_p2_filter_equals_the_matrix_product_formula_to_the_bit(
    omega_shape, z_shape, smooth, outside, monkeypatch
):
    """Batches above and below ENTRYWISE_MIN_BATCH, shared and per-trajectory Omega grids,
    Omega inside the support and some where -2 log p is not finite: there it is not finite
    either (the callers mask it) and the smoother (zero terms kept) matches to the bit."""
    calls: list[bool] = []
    fn = kf._forward_diagonal

    def spy(*args, zero_terms=False):
        calls.append(zero_terms)
        return fn(*args, zero_terms=zero_terms)

    monkeypatch.setattr(kf, "_forward_diagonal", spy)
    rng = np.random.default_rng(math.prod(omega_shape) + len(z_shape))
    model = get_model("sep_d1_p2")
    omega = _omega_sep_d1_p2(rng, omega_shape, outside)
    z = 3 * rng.standard_normal(z_shape + (25, 1))
    got = kalman_marginal(model, omega, z, smooth=smooth)
    with np.errstate(all="ignore"):
        ref = _reference_p2(*model.state_space_matrices(omega), z, smooth)
    finite = np.isfinite(ref[0])
    assert np.array_equal(np.isfinite(got.neg2_loglik), finite)
    assert _same_bits(got.neg2_loglik[finite], ref[0][finite])
    if smooth:
        assert _same_bits(got.neg2_loglik, ref[0])
        assert _same_bits(got.mean, ref[1]) and _same_bits(got.var, ref[2])
    # the fixtures reach what they are meant to: finite values, and non-finite ones outside
    assert finite.any() and finite.all() != outside
    big = math.prod(np.broadcast_shapes(omega_shape, z_shape)) >= kf.ENTRYWISE_MIN_BATCH
    assert calls == ([smooth] if big else [])


def test_p2_entrywise_path_is_taken_only_for_diagonal_blocks(monkeypatch):
    """A non-diagonal F (or an infinite Q^-1, whose zero off-diagonals become NaN) keeps the
    matrix products; the entrywise path runs for sep_d1_p2's grids."""
    calls: list[str] = []
    for name in ("_forward_blas", "_forward_diagonal"):
        fn = getattr(kf, name)
        monkeypatch.setattr(
            kf, name, lambda *a, _fn=fn, _n=name, **kw: calls.append(_n) or _fn(*a, **kw)
        )
    rng = np.random.default_rng(3)
    model = get_model("sep_d1_p2")
    omega = rng.uniform(0.1, 0.6, (100, 4))
    F, Q, H, R = model.state_space_matrices(omega)
    z = rng.standard_normal((100, 10, 1))
    kalman_marginal(model, omega, z)
    assert calls == ["_forward_diagonal"]
    F = F.copy()
    F[..., 0, 1] = 0.3
    got = kf._kalman_general(F, Q, H, R, z, True)
    ref = _reference_p2(F, Q, H, R, z, True)
    assert calls[-1] == "_forward_blas"
    assert _same_bits(got.neg2_loglik, ref[0]) and _same_bits(got.mean, ref[1])
    Q = Q.copy()
    Q[0, 0] = 0.0
    with np.errstate(all="ignore"):
        kf._kalman_general(F * np.eye(2), Q, H, R, z, False)
    assert calls[-1] == "_forward_blas"


def _reference_p1(f, q, h, r, z):
    """-2 log p of the p = 1 filter as it was before the sums over d went in place."""
    T, d = z.shape[-2:]
    hr = h / r
    hrh = sum(h[..., i] * hr[..., i] for i in range(d))
    a0 = f * f / q
    a_mid, a_end, bm = hrh + 1 / q + a0, hrh + 1 / q, -f / q
    zz = (z * z).sum(-2)
    c = sum(zz[..., i] / r[..., i] for i in range(d))
    S, y = a0, np.zeros(np.broadcast_shapes(z.shape[:-2], np.shape(f)))
    logdet, quad = np.log(S), 0.0
    for t in range(1, T + 1):
        g = bm / S
        S = (a_mid if t < T else a_end) - g * bm
        y = sum(z[..., t - 1, i] * hr[..., i] for i in range(d)) - g * y
        quad = quad + y * y / S
        logdet = logdet + np.log(S)
    log_r = sum(np.log(r[..., i]) for i in range(d))
    return c - quad + logdet + T * (log_r + np.log(q)) + ((d + 1) * T - (T + 1)) * kf.LOG_2PI


@pytest.mark.parametrize("slug", ["sep_d2_p1", "same"])
@pytest.mark.parametrize(
    ("omega_shape", "z_shape"), [((), ()), ((50,), (50,)), ((1, 80), (6, 1)), ((5,), ())]
)
def test_p1_filter_equals_the_reference_formula_to_the_bit(slug, omega_shape, z_shape):
    rng = np.random.default_rng(len(omega_shape) + 3 * len(z_shape))
    model = get_model(slug)
    omega = rng.uniform(-0.99, 0.99, omega_shape + (model.n_params,))
    omega.reshape(-1, model.n_params)[:1, 0] = 0.0  # an exact zero in H
    z = 3 * rng.standard_normal(z_shape + (20, model.obs_dim))
    with np.errstate(all="ignore"):
        got = kalman_marginal(model, omega, z).neg2_loglik
        F, Q, H, R = model.state_space_matrices(omega)
        ref = _reference_p1(F[..., 0, 0], Q[..., 0], H[..., :, 0], R, z)
    assert _same_bits(got, ref)


@pytest.mark.parametrize("smooth", [False, True])
@pytest.mark.parametrize("slug", ["sep_d1_p2", "sep_d2_p1", "same"])
@pytest.mark.parametrize(
    ("omega_shape", "z_shape"), [((1, 300), (4, 1)), ((4, 300), (4, 1)), ((900,), (900,))]
)
def test_blocks_of_the_batch_give_the_whole_batch_numbers(
    slug, omega_shape, z_shape, smooth, monkeypatch
):
    """The filter on cache-sized blocks of the batch's last axis (FILTER_BLOCK) gives the
    numbers of one pass over the whole batch, shared and per-trajectory Omega alike."""
    rng = np.random.default_rng(len(slug) + len(omega_shape))
    model = get_model(slug)
    omega = rng.uniform(0.2, 0.9, omega_shape + (model.n_params,))
    if slug == "sep_d1_p2":
        omega[..., :2] *= 0.7  # a^2 + b^2 < 1
    z = 3 * rng.standard_normal(z_shape + (15, model.obs_dim))
    whole = kalman_marginal(model, omega, z, smooth=smooth)
    monkeypatch.setattr(kf, "FILTER_BLOCK", 70)
    assert len(kf._blocks(np.broadcast_shapes(omega_shape, z_shape))) > 3
    blocked = kalman_marginal(model, omega, z, smooth=smooth)
    assert _same_bits(blocked.neg2_loglik, whole.neg2_loglik)
    if smooth:
        assert _same_bits(blocked.mean, whole.mean) and _same_bits(blocked.var, whole.var)


def test_matrices_with_smaller_batches_broadcast_as_in_the_reference():
    """One trajectory, H and R shared by every Omega (batch shape 1) against F and Q per
    Omega, for both filters: the in-place sums allocate the full batch."""
    rng = np.random.default_rng(11)
    n, T = 120, 12
    z = rng.standard_normal((T, 2))
    f, q = rng.uniform(0.3, 0.9, n), rng.uniform(0.2, 1.0, n)
    h, r = np.array([[0.8, 0.5]]), np.array([[0.4, 0.7]])
    got = kf._kalman_p1(f, q, h, r, z, False).neg2_loglik
    assert got.shape == (n,) and _same_bits(got, _reference_p1(f, q, h, r, z))
    zero = np.zeros(n)
    F = np.stack([np.stack([f, zero], -1), np.stack([zero, f[::-1]], -1)], -2)
    Q = np.stack([q, q[::-1]], -1)
    H, R = np.array([[[0.6, 0.5]]]), np.array([[0.3]])
    z1 = z[..., :1]
    for smooth in (False, True):
        got2 = kf._kalman_general(F, Q, H, R, z1, smooth)
        ref2 = _reference_p2(F, Q, H, R, z1, smooth)
        assert _same_bits(got2.neg2_loglik, ref2[0])
        if smooth:
            assert _same_bits(got2.mean, ref2[1]) and _same_bits(got2.var, ref2[2])
