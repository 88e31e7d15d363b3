"""Batched arrow / block-tridiagonal linear algebra (ssmobs.banded_linalg) against dense NumPy."""

from __future__ import annotations

import numpy as np
import pytest
from ssmobs.banded_linalg import (
    ArrowFactor,
    BlockTridiagonalCholesky,
    arrow_extreme_eigenpairs,
    arrow_to_dense,
    inverse_cholesky,
    lanczos,
    tridiagonal_max_eigenvalue,
    tridiagonal_top_eigenvector,
)

pytestmark = pytest.mark.unit


def random_arrow(K, N, p, m, seed, indefinite=False):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(K, m, m))
    A = A @ np.swapaxes(A, 1, 2) + m * np.eye(m)
    C = 0.3 * rng.normal(size=(K, N, p, m))
    Dd = rng.normal(size=(K, N, p, p))
    Dd = Dd @ np.swapaxes(Dd, 2, 3) + 3 * np.eye(p)
    Dl = 0.5 * rng.normal(size=(K, N - 1, p, p))
    if indefinite:
        Dd[0, N // 2] -= 20 * np.eye(p)
    return A, C, Dd, Dl


def random_spd_arrow(K, N, p, m, seed):
    """Random SPD arrow matrices H = L L^T, not diagonally dominant.

    In the order (states, head), L = [[Lx, 0], [G, Lw]] with Lx lower block-bidiagonal,
    G dense and Lw lower triangular, so L L^T = [[Lx Lx^T, Lx G^T], [G Lx^T, G G^T + Lw Lw^T]]
    has a block-tridiagonal state part: an arrow matrix.  Returns its blocks and the dense H
    in the order (head, states).
    """
    rng = np.random.default_rng(seed)
    nx = N * p
    H = np.empty((K, m + nx, m + nx))
    for k in range(K):
        Lx = np.zeros((nx, nx))
        for t in range(N):
            s = t * p
            Lx[s : s + p, s : s + p] = np.tril(rng.normal(size=(p, p)), -1) + np.diag(
                1.0 + np.abs(rng.normal(size=p))
            )
            if t:
                Lx[s : s + p, s - p : s] = 0.7 * rng.normal(size=(p, p))
        G = rng.normal(size=(m, nx))
        Lw = np.tril(rng.normal(size=(m, m)), -1) + np.diag(0.5 + np.abs(rng.normal(size=m)))
        L = np.block([[Lx, np.zeros((nx, m))], [G, Lw]])
        M = L @ L.T
        order = np.r_[nx : nx + m, 0:nx]
        H[k] = M[np.ix_(order, order)]
    A = H[:, :m, :m].copy()
    C = H[:, m:, :m].reshape(K, N, p, m).copy()
    Dd = np.stack(
        [H[:, m + t * p : m + (t + 1) * p, m + t * p : m + (t + 1) * p] for t in range(N)], axis=1
    )
    Dl = np.zeros((K, N - 1, p, p))
    for t in range(1, N):
        Dl[:, t - 1] = H[:, m + t * p : m + (t + 1) * p, m + (t - 1) * p : m + t * p]
    return (A, C, Dd, Dl), H


# --------------------------------------------------------------------------- against dense NumPy
@pytest.mark.parametrize(
    "N, p, m", [(1, 1, 1), (2, 1, 2), (12, 1, 2), (9, 2, 3), (6, 3, 4), (10, 2, 1)]
)
def test_arrow_solver_matches_dense_solve_on_random_spd_arrows(N, p, m):
    blocks, H = random_spd_arrow(K=6, N=N, p=p, m=m, seed=10 * N + p + m)
    n = H.shape[1]
    assert np.allclose(arrow_to_dense(*blocks), H, rtol=0, atol=0)  # exact arrow pattern
    rng = np.random.default_rng(1)
    b = rng.normal(size=(6, n))
    expect = np.linalg.solve(H, b[..., None])[..., 0]
    scale = np.abs(expect).max()
    fac = ArrowFactor(*blocks)
    assert fac.ok.all()
    assert np.allclose(fac.solve(b), expect, rtol=0, atol=1e-9 * scale)
    assert np.allclose(ArrowFactor(*blocks, rhs=b).solve_rhs(), expect, rtol=0, atol=1e-9 * scale)
    assert np.allclose(fac.matvec(b), np.einsum("kij,kj->ki", H, b), rtol=1e-13, atol=1e-12)
    inv = np.linalg.inv(H)
    assert np.allclose(fac.diag_inverse(), np.diagonal(inv, axis1=1, axis2=2), rtol=1e-9)
    # a diagonal shift tau I (the modified Newton step) solves the shifted system
    tau = np.linspace(0.0, 2.0, 6)
    shifted = H + tau[:, None, None] * np.eye(n)
    got = ArrowFactor(*blocks, tau=tau, rhs=b).solve_rhs()
    assert np.allclose(
        got, np.linalg.solve(shifted, b[..., None])[..., 0], rtol=0, atol=1e-9 * scale
    )


@pytest.mark.parametrize("p", [1, 2, 3])
def test_block_tridiagonal_cholesky_matches_dense_solve(p):
    (_, _, Dd, Dl), H = random_spd_arrow(K=4, N=8, p=p, m=1, seed=p)
    D = H[:, 1:, 1:]
    rhs = np.random.default_rng(p).normal(size=(4, 8, p, 3))
    fac = BlockTridiagonalCholesky(Dd, Dl)
    assert fac.ok.all()
    expect = np.linalg.solve(D, rhs.reshape(4, 8 * p, 3)).reshape(4, 8, p, 3)
    assert np.allclose(fac.solve(rhs), expect, rtol=0, atol=1e-9 * np.abs(expect).max())


@pytest.mark.parametrize("q", [1, 2, 3, 4])
def test_inverse_cholesky_matches_numpy_and_flags_indefinite(q):
    rng = np.random.default_rng(q)
    B = rng.normal(size=(5, q, q))
    S = B @ np.swapaxes(B, 1, 2) + 0.1 * np.eye(q)
    S[3] -= 50 * np.eye(q)  # indefinite
    S[4, 0, 0] = np.nan
    Linv, ok = inverse_cholesky(S)
    assert ok.tolist() == [True, True, True, False, False]
    assert np.allclose(Linv[:3], np.linalg.inv(np.linalg.cholesky(S[:3])), rtol=1e-10)
    assert np.all(np.isfinite(Linv[3]))


def test_tridiagonal_eigenpair_matches_eigh():
    rng = np.random.default_rng(4)
    a, b = rng.normal(size=(5, 9)), rng.normal(size=(5, 8))
    T = np.zeros((5, 9, 9))
    i = np.arange(9)
    T[:, i, i] = a
    T[:, i[1:], i[:-1]] = T[:, i[:-1], i[1:]] = b
    lam, vec = np.linalg.eigh(T)
    top = tridiagonal_max_eigenvalue(a, b)
    assert np.allclose(top, lam[:, -1], rtol=1e-12, atol=1e-12)
    y = tridiagonal_top_eigenvector(a, b, top)
    assert np.allclose(np.abs(np.einsum("ks,ks->k", y, vec[:, :, -1])), 1.0, atol=1e-8)


# --------------------------------------------------------------------------- factor, spectrum
@pytest.mark.parametrize("p", [1, 2])
def test_arrow_factor_solve_diag_inverse_matvec(p):
    A, C, Dd, Dl = random_arrow(K=5, N=9, p=p, m=3, seed=p)
    H = arrow_to_dense(A, C, Dd, Dl)
    fac = ArrowFactor(A, C, Dd, Dl)
    assert fac.ok.all()
    x = np.random.default_rng(0).normal(size=H.shape[:2])
    Hx = np.einsum("kij,kj->ki", H, x)
    assert np.allclose(fac.matvec(x), Hx, atol=1e-12)
    assert np.allclose(fac.solve(Hx), x, atol=1e-10)
    assert np.allclose(
        fac.diag_inverse(), np.diagonal(np.linalg.inv(H), axis1=1, axis2=2), rtol=1e-10
    )


@pytest.mark.parametrize("p", [1, 2])
def test_arrow_factor_detects_indefinite(p):
    A, C, Dd, Dl = random_arrow(K=3, N=7, p=p, m=2, seed=5, indefinite=True)
    H = arrow_to_dense(A, C, Dd, Dl)
    fac = ArrowFactor(A, C, Dd, Dl)
    assert fac.ok.tolist() == (np.linalg.eigvalsh(H)[:, 0] > 0).tolist() == [False, True, True]


@pytest.mark.parametrize("p", [1, 2])
def test_lanczos_extreme_eigenpairs(p):
    A, C, Dd, Dl = random_arrow(K=4, N=15, p=p, m=2, seed=11)
    Dd[:, 3] += 1e3 * np.eye(p)  # spread the spectrum
    H = arrow_to_dense(A, C, Dd, Dl)
    lam, vec = np.linalg.eigh(H)
    fac = ArrowFactor(A, C, Dd, Dl)
    lmin, lmax, v = arrow_extreme_eigenpairs(fac)
    assert np.allclose(lmin, lam[:, 0], rtol=1e-9)
    assert np.allclose(lmax, lam[:, -1], rtol=1e-9)
    assert np.allclose(np.abs(np.einsum("kn,kn->k", v, vec[:, :, 0])), 1.0, atol=1e-8)
    dense = arrow_extreme_eigenpairs(fac, "dense")
    assert np.allclose(dense[0], lam[:, 0]) and np.allclose(dense[1], lam[:, -1])
    with pytest.raises(ValueError, match="lanczos"):
        arrow_extreme_eigenpairs(fac, "power")


def test_lanczos_exact_when_steps_exceed_dimension():
    """T = 1 gives |Theta| = 3 < lanczos_steps: the tridiagonal matrix has the full spectrum."""
    A, C, Dd, Dl = random_arrow(K=3, N=2, p=1, m=1, seed=2)
    H = arrow_to_dense(A, C, Dd, Dl)
    fac = ArrowFactor(A, C, Dd, Dl)
    a, b, _ = lanczos(fac.matvec, np.ones((3, 3)), steps=40)
    assert a.shape == (3, 3)
    assert np.allclose(tridiagonal_max_eigenvalue(a, b), np.linalg.eigvalsh(H)[:, -1], rtol=1e-12)
