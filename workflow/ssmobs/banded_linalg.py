"""Batched linear algebra for arrow matrices with a block-tridiagonal part.

An arrow matrix (here: the Hessian of -2 pi in Theta = (Omega, x_0..x_T), Sec. III.B) is

    H = [[A, C^T],
         [C, D  ]],

with a dense m x m block A, m dense columns C (N blocks of p x m) and a block-tridiagonal
D (diagonal blocks p x p, sub-diagonal blocks p x p).  Everything here works on K such
matrices at once (leading axis k), vectorised over k with loops over the N blocks only:

* :func:`inverse_cholesky`: L^{-1} of small SPD matrices (..., q, q);
* :class:`BlockTridiagonalCholesky`: block Cholesky of D and solves with it;
* :class:`ArrowFactor`: H = LL^T through D's factor and the m x m Schur complement
  (solve, product, diagonal of H^{-1}, positive definiteness);
* :func:`lanczos`, :func:`tridiagonal_max_eigenvalue`, :func:`tridiagonal_top_eigenvector`
  and :func:`arrow_extreme_eigenpairs`: extreme eigenvalues of H (and the eigenvector of the
  smallest) in O(n) per Lanczos step.

Nothing here knows about models; the layout is the only contract.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def inverse_cholesky(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse Cholesky factor L^{-1} (S = L L^T) of a batch of small SPD matrices.

    S : (..., q, q).  Returns (Linv, ok) with Linv lower triangular, Linv S Linv^T = I where
    ok; where S is not positive definite (or not finite) ok is False and Linv is finite junk.
    """
    q = S.shape[-1]
    if q == 1:
        d = S[..., 0, 0]
        ok = np.isfinite(d) & (d > 0)
        with np.errstate(all="ignore"):
            inv = 1.0 / np.sqrt(np.where(ok, d, 1.0))
        return inv[..., None, None], ok
    ok = np.all(np.isfinite(S), axis=(-2, -1))
    if q == 2:
        a, b, c = S[..., 0, 0], S[..., 1, 0], S[..., 1, 1]
        with np.errstate(all="ignore"):
            good = ok & (a > 0)
            l11 = np.sqrt(np.where(good, a, 1.0))
            l21 = b / l11
            r = c - l21**2
            good &= r > 0
            l22 = np.sqrt(np.where(good, r, 1.0))
            Linv = np.zeros_like(S)
            Linv[..., 0, 0] = 1.0 / l11
            Linv[..., 1, 1] = 1.0 / l22
            Linv[..., 1, 0] = -l21 / (l11 * l22)
        return Linv, good
    L = np.zeros_like(S)
    for j in range(q):
        s = S[..., j, j] - np.sum(L[..., j, :j] ** 2, axis=-1)
        good = s > 0
        ok &= good
        L[..., j, j] = np.sqrt(np.where(good, s, 1.0))
        for i in range(j + 1, q):
            off = S[..., i, j] - np.sum(L[..., i, :j] * L[..., j, :j], axis=-1)
            L[..., i, j] = off / L[..., j, j]
    Linv = np.zeros_like(S)
    for i in range(q):
        Linv[..., i, i] = 1.0 / L[..., i, i]
        for j in range(i):
            Linv[..., i, j] = -np.sum(L[..., i, j:i] * Linv[..., j:i, j], axis=-1) / L[..., i, i]
    return Linv, ok


class BlockTridiagonalCholesky:
    """Block Cholesky D = L L^T of a batch of block-tridiagonal SPD matrices.

    ``diag`` (K, N, p, p) and ``lower`` (K, N-1, p, p) (block (t, t-1)).  Stores L_t^{-1}
    and M_t = D_{t,t-1} L_{t-1}^{-T}, time-major for fast per-step access; ``ok`` (K,) is
    False where D is not positive definite (or not finite).  O(N p^3) per matrix.
    """

    def __init__(self, diag: np.ndarray, lower: np.ndarray) -> None:
        K, N, p, _ = diag.shape
        self.p, self.N = p, N
        dg = np.moveaxis(diag, 1, 0)
        lo = np.moveaxis(lower, 1, 0)
        self.ok = np.ones(K, dtype=bool)
        if p == 1:
            # scalar recursion: l_t = 1/sqrt(pivot_t), m_t = D_{t,t-1} l_{t-1}
            dg = dg[..., 0, 0]
            lo = lo[..., 0, 0]
            linv = np.empty((N, K))
            mm = np.empty((max(N - 1, 0), K))
            piv = dg[0]
            with np.errstate(all="ignore"):
                for t in range(N):
                    if t > 0:
                        mm[t - 1] = lo[t - 1] * linv[t - 1]
                        piv = dg[t] - mm[t - 1] ** 2
                    good = piv > 0
                    self.ok &= good
                    linv[t] = 1.0 / np.sqrt(np.where(good, piv, 1.0))
            self.ok &= np.all(np.isfinite(linv), axis=0) & np.all(np.isfinite(mm), axis=0)
            self.linv, self.m = linv, mm
            return
        linv = np.empty((N, K, p, p))
        mm = np.empty((max(N - 1, 0), K, p, p))
        with np.errstate(all="ignore"):
            for t in range(N):
                S = dg[t]
                if t > 0:
                    mm[t - 1] = lo[t - 1] @ np.swapaxes(linv[t - 1], -1, -2)
                    S = S - mm[t - 1] @ np.swapaxes(mm[t - 1], -1, -2)
                linv[t], good = inverse_cholesky(S)
                self.ok &= good
        self.linv, self.m = linv, mm

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """D^{-1} rhs for rhs (K, N, p, r); returns (K, N, p, r)."""
        N = self.N
        R = np.moveaxis(rhs, 1, 0)
        u = np.empty_like(R)
        with np.errstate(all="ignore"):
            if self.p == 1:
                linv, mm = self.linv[:, :, None], self.m[:, :, None]
                R = R[:, :, 0, :]
                u = np.empty_like(R)
                u[0] = linv[0] * R[0]
                for t in range(1, N):
                    u[t] = linv[t] * (R[t] - mm[t - 1] * u[t - 1])
                v = np.empty_like(u)
                v[N - 1] = linv[N - 1] * u[N - 1]
                for t in range(N - 2, -1, -1):
                    v[t] = linv[t] * (u[t] - mm[t] * v[t + 1])
                return np.moveaxis(v, 0, 1)[:, :, None, :]
            Li, mm = self.linv, self.m
            u[0] = Li[0] @ R[0]
            for t in range(1, N):
                u[t] = Li[t] @ (R[t] - mm[t - 1] @ u[t - 1])
            v = np.empty_like(u)
            v[N - 1] = np.swapaxes(Li[N - 1], -1, -2) @ u[N - 1]
            for t in range(N - 2, -1, -1):
                v[t] = np.swapaxes(Li[t], -1, -2) @ (u[t] - np.swapaxes(mm[t], -1, -2) @ v[t + 1])
        return np.moveaxis(v, 0, 1)


def arrow_to_dense(A: np.ndarray, C: np.ndarray, Dd: np.ndarray, Dl: np.ndarray) -> np.ndarray:
    """(K, n, n) dense arrow matrices, n = m + N p, from the blocks of :class:`ArrowFactor`."""
    K, N, p, m = C.shape
    n = m + N * p
    H = np.zeros((K, n, n))
    H[:, :m, :m] = A
    cross = C.reshape(K, N * p, m)
    H[:, m:, :m] = cross
    H[:, :m, m:] = np.swapaxes(cross, 1, 2)
    for t in range(N):
        s = m + t * p
        H[:, s : s + p, s : s + p] = Dd[:, t]
        if t >= 1:
            H[:, s : s + p, s - p : s] = Dl[:, t - 1]
            H[:, s - p : s, s : s + p] = np.swapaxes(Dl[:, t - 1], 1, 2)
    return H


class ArrowFactor:
    """Factorisation of a batch of arrow matrices H = [[A, C^T], [C, D]] (+ tau I).

    A (K, m, m) is the dense head block, C (K, N, p, m) couples block t of D with the head
    and D is block-tridiagonal with diagonal blocks Dd (K, N, p, p) and sub-diagonal blocks
    Dl (K, N-1, p, p); n = m + N p.  D is eliminated by its block Cholesky, leaving the
    m x m Schur complement S = A - C^T D^{-1} C; H is positive definite iff D and S are
    (``ok`` (K,)).  O(N (p^3 + p^2 m + p m^2) + m^3) per matrix.  ``tau`` (K,) shifts the
    diagonal; ``rhs`` (K, n), if given, is solved for together with D^{-1} C (one pass
    over t, see :meth:`solve_rhs`).  :meth:`matvec` uses the unshifted H.
    """

    def __init__(
        self,
        A: np.ndarray,
        C: np.ndarray,
        Dd: np.ndarray,
        Dl: np.ndarray,
        tau: np.ndarray | None = None,
        rhs: np.ndarray | None = None,
    ) -> None:
        K, N, p, m = C.shape
        self.K, self.N, self.p, self.m = K, N, p, m
        self.A, self.C, self.Dd, self.Dl = A, C, Dd, Dl
        if tau is not None:
            A = A + tau[:, None, None] * np.eye(m)
            Dd = Dd + tau[:, None, None, None] * np.eye(p)
        self.fac = BlockTridiagonalCholesky(Dd, Dl)
        cols = [C] if rhs is None else [C, rhs[:, m:].reshape(K, N, p, 1)]
        Y = self.fac.solve(np.concatenate(cols, axis=-1))
        self.Y = Y[..., :m]
        self._rhs, self._y_rhs = rhs, (None if rhs is None else Y[..., m])
        with np.errstate(all="ignore"):
            S = A - np.einsum("ktpi,ktpj->kij", C, self.Y)
            self.LSi, okS = inverse_cholesky(S)
        self.ok = (
            self.fac.ok
            & okS
            & np.all(np.isfinite(self.Y), axis=(1, 2, 3))
            & np.all(np.isfinite(self.LSi), axis=(1, 2))
        )

    def _finish(self, bw: np.ndarray, y: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            r = bw - np.einsum("ktpi,ktp->ki", self.C, y)
            xw = np.einsum("kji,kj->ki", self.LSi, np.einsum("kij,kj->ki", self.LSi, r))
            xx = y - np.einsum("ktpi,ki->ktp", self.Y, xw)
        return np.concatenate([xw, xx.reshape(self.K, -1)], axis=1)

    def solve_rhs(self) -> np.ndarray:
        """H^{-1} rhs for the ``rhs`` given at construction."""
        assert self._rhs is not None and self._y_rhs is not None, "no rhs given at construction"
        return self._finish(self._rhs[:, : self.m], self._y_rhs)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """H^{-1} b for b (K, n)."""
        y = self.fac.solve(b[:, self.m :].reshape(self.K, self.N, self.p, 1))[..., 0]
        return self._finish(b[:, : self.m], y)

    def matvec(self, v: np.ndarray) -> np.ndarray:
        """H v for v (K, n) (unshifted H)."""
        m = self.m
        vw, vx = v[:, :m], v[:, m:].reshape(self.K, self.N, self.p)
        out_w = np.einsum("kij,kj->ki", self.A, vw) + np.einsum("ktpi,ktp->ki", self.C, vx)
        out_x = np.einsum("ktpi,ki->ktp", self.C, vw) + np.einsum("ktpq,ktq->ktp", self.Dd, vx)
        out_x[:, 1:] += np.einsum("ktpq,ktq->ktp", self.Dl, vx[:, :-1])
        out_x[:, :-1] += np.einsum("ktqp,ktq->ktp", self.Dl, vx[:, 1:])
        return np.concatenate([out_w, out_x.reshape(self.K, -1)], axis=1)

    def diag_inverse(self) -> np.ndarray:
        """(K, n) diagonal of H^{-1} (selected inversion, O(n) per matrix).

        (H^{-1})_{Omega} = S^{-1};  (H^{-1})_{x} = D^{-1} + Y S^{-1} Y^T with Y = D^{-1} C,
        and the diagonal blocks Z_t of D^{-1} follow from the block Cholesky factor by
        Z_{N-1} = L_{N-1}^{-T} L_{N-1}^{-1},
        Z_t = L_t^{-T} (I + M_{t+1}^T Z_{t+1} M_{t+1}) L_t^{-1}.
        """
        K, N, p = self.K, self.N, self.p
        with np.errstate(all="ignore"):
            Sinv = np.einsum("kji,kjl->kil", self.LSi, self.LSi)
            zd = np.empty((N, K, p))
            if p == 1:
                linv, mm = self.fac.linv, self.fac.m
                z = linv[N - 1] ** 2
                zd[N - 1, :, 0] = z
                for t in range(N - 2, -1, -1):
                    z = linv[t] ** 2 * (1.0 + mm[t] ** 2 * z)
                    zd[t, :, 0] = z
            else:
                Li, mm = self.fac.linv, self.fac.m
                tr = lambda a: np.swapaxes(a, -1, -2)  # noqa: E731
                Z = tr(Li[N - 1]) @ Li[N - 1]
                zd[N - 1] = np.diagonal(Z, axis1=-2, axis2=-1)
                for t in range(N - 2, -1, -1):
                    inner = np.eye(p) + tr(mm[t]) @ Z @ mm[t]
                    Z = tr(Li[t]) @ inner @ Li[t]
                    zd[t] = np.diagonal(Z, axis1=-2, axis2=-1)
            dx = np.moveaxis(zd, 0, 1) + np.einsum("ktpa,kab,ktpb->ktp", self.Y, Sinv, self.Y)
        return np.concatenate([np.diagonal(Sinv, axis1=1, axis2=2), dx.reshape(K, -1)], axis=1)


def lanczos(
    apply: Callable[[np.ndarray], np.ndarray], v0: np.ndarray, steps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched Lanczos with full reorthogonalisation.

    ``apply`` maps (K, n) -> (K, n) (a symmetric operator per k).  Returns the diagonal
    alpha (K, s) and off-diagonal beta (K, s-1) of the Lanczos tridiagonal matrix and the
    basis Q (K, s, n), s = min(steps, n); with s = n its eigenvalues are the exact spectrum.
    An invariant subspace found early is continued with a fresh orthogonal direction
    (beta = 0), which keeps the tridiagonal matrix's eigenvalues those of the operator.
    """
    K, n = v0.shape
    s = min(steps, n)
    Q = np.zeros((K, s, n))
    alpha = np.zeros((K, s))
    beta = np.zeros((K, max(s - 1, 0)))
    fresh = np.random.default_rng(n)
    q = v0 / np.linalg.norm(v0, axis=1, keepdims=True)

    def orth(w: np.ndarray, Qj: np.ndarray) -> np.ndarray:
        for _ in range(2):  # "twice is enough"
            w = w - (((w[:, None, :] @ np.swapaxes(Qj, 1, 2)) @ Qj)[:, 0])
        return w

    with np.errstate(all="ignore"):
        for j in range(s):
            Q[:, j] = q
            w = apply(q)
            alpha[:, j] = np.einsum("kn,kn->k", w, q)
            if j == s - 1:
                break
            w = orth(w, Q[:, : j + 1])
            b = np.linalg.norm(w, axis=1)
            scale = np.abs(alpha[:, : j + 1]).max(axis=1) + 1e-300
            dead = ~(b > 1e-10 * scale)
            if dead.any():
                r = np.broadcast_to(fresh.standard_normal(n), (int(dead.sum()), n)).copy()
                w[dead] = orth(r, Q[dead, : j + 1])
                b[dead] = 0.0
            beta[:, j] = b
            q = w / np.linalg.norm(w, axis=1, keepdims=True)
    return alpha, beta, Q


def tridiagonal_max_eigenvalue(a: np.ndarray, b: np.ndarray, iters: int = 60) -> np.ndarray:
    """Largest eigenvalue of symmetric tridiagonal matrices (diag a (K, s), off b (K, s-1)).

    Bisection on the Sturm sequence count inside the Gershgorin interval; vectorised over
    K, no LAPACK (whose threaded batched calls are slow on small matrices).
    """
    K, s = a.shape
    rad = np.zeros((K, s))
    rad[:, :-1] += np.abs(b)
    rad[:, 1:] += np.abs(b)
    lo, hi = (a - rad).min(axis=1), (a + rad).max(axis=1)
    b2 = b**2
    tiny = np.finfo(float).tiny
    with np.errstate(all="ignore"):
        for _ in range(iters):
            x = 0.5 * (lo + hi)
            q = a[:, 0] - x
            count = (q < 0).astype(int)
            for i in range(1, s):
                q = np.where(q == 0, tiny, q)
                q = a[:, i] - x - b2[:, i - 1] / q
                count += q < 0
            all_below = count == s  # every eigenvalue < x: lambda_max < x
            hi = np.where(all_below, x, hi)
            lo = np.where(all_below, lo, x)
    return hi


def tridiagonal_top_eigenvector(a: np.ndarray, b: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Unit eigenvector (K, s) for the largest eigenvalue ``lam`` (inverse iteration).

    The shift sits just above lam, so T - sigma I is negative definite and its LDL^T
    factorisation (no pivoting) is stable.
    """
    K, s = a.shape
    sigma = lam + 1e-9 * (np.abs(lam) + np.abs(a).max(axis=1) + 1e-300)
    d = a - sigma[:, None]
    piv = np.empty((K, s))
    ell = np.zeros((K, s))
    y = np.ones((K, s))
    with np.errstate(all="ignore"):
        piv[:, 0] = d[:, 0]
        for i in range(1, s):
            ell[:, i] = b[:, i - 1] / piv[:, i - 1]
            piv[:, i] = d[:, i] - ell[:, i] * b[:, i - 1]
        for _ in range(3):
            u = y.copy()
            for i in range(1, s):
                u[:, i] -= ell[:, i] * u[:, i - 1]
            x = u / piv
            for i in range(s - 2, -1, -1):
                x[:, i] -= ell[:, i + 1] * x[:, i + 1]
            y = x / np.linalg.norm(x, axis=1, keepdims=True)
    return y


def arrow_extreme_eigenpairs(
    fac: ArrowFactor, method: str = "lanczos", steps: int = 24
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smallest and largest eigenvalue of each arrow matrix H and the unit eigenvector of the
    smallest: (K,), (K,), (K, n); NaN where H is not finite.

    ``method="lanczos"``: ``steps`` Lanczos steps on H give lambda_max (and lambda_min where
    H is not PD); where H is PD, Lanczos on H^{-1} (applied through ``fac``) gives lambda_min
    and its eigenvector accurately even when lambda_min << lambda_max.  ``method="dense"``:
    LAPACK eigh of the assembled matrix (O(n^3) per matrix; for checks).
    """
    if method not in ("lanczos", "dense"):
        raise ValueError(f"eigenvalue method {method!r} must be 'lanczos' or 'dense'")
    K, n = fac.K, fac.m + fac.N * fac.p
    lam_min, lam_max = np.full(K, np.nan), np.full(K, np.nan)
    v_min = np.full((K, n), np.nan)
    if method == "dense":
        H = arrow_to_dense(fac.A, fac.C, fac.Dd, fac.Dl)
        fin = np.all(np.isfinite(H), axis=(1, 2))
        if fin.any():
            lam, vec = np.linalg.eigh(H[fin])
            lam_min[fin], lam_max[fin], v_min[fin] = lam[:, 0], lam[:, -1], vec[:, :, 0]
        return lam_min, lam_max, v_min
    v0 = np.broadcast_to(np.random.default_rng(n + 1).standard_normal(n), (K, n))
    fin = np.flatnonzero(
        np.all(np.isfinite(fac.A), axis=(1, 2))
        & np.all(np.isfinite(fac.Dd.reshape(K, -1)), axis=1)
        & np.all(np.isfinite(fac.C.reshape(K, -1)), axis=1)
        & np.all(np.isfinite(fac.Dl.reshape(K, -1)), axis=1)
    )
    if fin.size:
        sub = ArrowFactor(fac.A[fin], fac.C[fin], fac.Dd[fin], fac.Dl[fin])
        a, b, _ = lanczos(sub.matvec, v0[fin], steps)
        lam_max[fin] = tridiagonal_max_eigenvalue(a, b)
        nonpd = ~fac.ok[fin]
        if nonpd.any():  # H^{-1} is not available: the smallest Ritz value of H
            lam_min[fin[nonpd]] = -tridiagonal_max_eigenvalue(-a[nonpd], b[nonpd])
    pd_ = np.flatnonzero(fac.ok)
    if pd_.size:
        sub = ArrowFactor(fac.A[pd_], fac.C[pd_], fac.Dd[pd_], fac.Dl[pd_])
        a, b, Q = lanczos(sub.solve, v0[pd_], steps)
        top = tridiagonal_max_eigenvalue(a, b)
        with np.errstate(all="ignore"):
            lam_min[pd_] = 1.0 / top
        y = tridiagonal_top_eigenvector(a, b, top)
        v = np.einsum("ksn,ks->kn", Q, y)
        v_min[pd_] = v / np.linalg.norm(v, axis=1, keepdims=True)
    return lam_min, lam_max, v_min
