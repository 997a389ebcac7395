"""Sparse symmetric positive definite factorisation with a selected inverse.

Reliability needs only the blocks of N⁻¹ that couple the unknowns of one observation
(THEORY.md §11). After a reverse Cuthill-McKee ordering most normal matrices of networks and
strip blocks are banded with a half-bandwidth b ≪ u. Cut into blocks of size ≥ b, the permuted
matrix is block tridiagonal, its Cholesky factor is block lower bidiagonal

    N = L Lᵀ,  L = [L₀; B₀ L₁; B₁ L₂; ...],

and the entries of Σ = N⁻¹ on the same block pattern follow from the block form of Takahashi's
recursion (Takahashi, Fagan & Chen 1973), run from the last block up:

    X_K = B_K L_K⁻¹
    Σ_{K+1,K} = −Σ_{K+1,K+1} X_K
    Σ_{K,K}   = L_K⁻ᵀ L_K⁻¹ + X_Kᵀ Σ_{K+1,K+1} X_K

Every pair of unknowns that appears together in an observation is a non-zero of N and so lies
inside that pattern. Cost O(u b²) for the factorisation and the selected inverse alike; memory
O(u b). When the band is wide the matrix is one dense block and this is a dense Cholesky.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

from .errors import SingularError

MIN_BLOCK = 48


class SPDFactor:
    """Cholesky factor of a sparse SPD matrix in RCM-ordered block-tridiagonal form.

    Parameters
    ----------
    N : sparse (m × m) symmetric positive definite matrix.
    labels : optional names of the m unknowns, used in the error of a singular matrix.
    pivot_tol : a pivot d_i² < pivot_tol · N_ii marks the matrix numerically singular.
    """

    def __init__(self, N, labels=None, pivot_tol: float = 1e-11):
        N = sp.csr_matrix(N)
        m = N.shape[0]
        self.m = m
        self.labels = labels
        if m == 0:
            self.perm = np.zeros(0, dtype=np.int64)
            self.iperm = self.perm
            self.bs, self.nb = 1, 0
            return
        perm = np.asarray(reverse_cuthill_mckee(N, symmetric_mode=True), dtype=np.int64)
        iperm = np.empty_like(perm)
        iperm[perm] = np.arange(m)
        C = N.tocoo()
        pi, pj = iperm[C.row], iperm[C.col]
        band = int(np.abs(pi - pj).max()) if C.nnz else 0
        bs = max(band, MIN_BLOCK)
        if bs * 2 >= m:
            bs = m
        nb = -(-m // bs)
        self.perm, self.iperm, self.bs, self.nb, self.bandwidth = perm, iperm, bs, nb, band
        D = np.zeros((nb, bs, bs))
        O = np.zeros((max(nb - 1, 0), bs, bs))
        low = pi >= pj
        pi, pj, val = pi[low], pj[low], C.data[low]
        K, J = pi // bs, pj // bs
        same = K == J
        D[K[same], pi[same] % bs, pj[same] % bs] = val[same]
        D[K[same], pj[same] % bs, pi[same] % bs] = val[same]
        O[J[~same], pi[~same] % bs, pj[~same] % bs] = val[~same]
        pad = nb * bs - m
        if pad:
            D[-1, bs - pad:, bs - pad:] = np.eye(pad)
        diagN = np.ones(nb * bs)
        diagN[:m] = N.diagonal()[perm]
        self._factor(D, O, diagN, pivot_tol)
        self._selinv = None

    # -- factorisation -------------------------------------------------------------------------
    def _factor(self, D, O, diagN, pivot_tol):
        nb, bs = self.nb, self.bs
        L = np.empty_like(D)
        B = np.empty_like(O)
        for k in range(nb):
            A = D[k] if k == 0 else D[k] - B[k - 1] @ B[k - 1].T
            c, info = la.lapack.dpotrf(A, lower=1, clean=1)
            piv = np.diag(c) ** 2 if info == 0 else None
            if info != 0 or (piv < pivot_tol * diagN[k * bs:(k + 1) * bs]).any():
                if info > 0:
                    bad = k * bs + info - 1
                else:
                    bad = k * bs + int(np.argmin(piv / diagN[k * bs:(k + 1) * bs]))
                raise self._singular(min(bad, self.m - 1))
            L[k] = c
            if k + 1 < nb:
                B[k] = la.solve_triangular(c, O[k].T, lower=True, check_finite=False).T
        self.L, self.B = L, B

    def _singular(self, p):
        orig = int(self.perm[p])
        name = self.labels[orig] if self.labels is not None else f"unknown {orig}"
        err = SingularError(f"normal matrix is singular: {name} is not determined by the observations")
        err.index = orig
        return err

    # -- solves ---------------------------------------------------------------------------------
    def solve(self, b: np.ndarray) -> np.ndarray:
        """N⁻¹ b for a vector or a matrix of right-hand sides."""
        b = np.asarray(b, dtype=float)
        vec = b.ndim == 1
        B2 = b.reshape(self.m, -1)
        if self.m == 0:
            return b.copy()
        nb, bs = self.nb, self.bs
        y = np.zeros((nb * bs, B2.shape[1]))
        y[: self.m] = B2[self.perm]
        y = y.reshape(nb, bs, -1)
        for k in range(nb):
            rhs = y[k] if k == 0 else y[k] - self.B[k - 1] @ y[k - 1]
            y[k] = la.solve_triangular(self.L[k], rhs, lower=True, check_finite=False)
        for k in range(nb - 1, -1, -1):
            rhs = y[k] if k == nb - 1 else y[k] - self.B[k].T @ y[k + 1]
            y[k] = la.solve_triangular(self.L[k], rhs, lower=True, trans="T", check_finite=False)
        out = y.reshape(nb * bs, -1)[: self.m][self.iperm]
        return out.ravel() if vec else out

    def logdet(self) -> float:
        d = np.concatenate([np.diag(Lk) for Lk in self.L])[: self.m] if self.m else np.zeros(0)
        return 2.0 * float(np.log(d).sum())

    # -- selected inverse ---------------------------------------------------------------------
    def _selected_inverse(self):
        if self._selinv is None:
            nb, bs = self.nb, self.bs
            SD = np.empty((nb, bs, bs))
            SO = np.empty((max(nb - 1, 0), bs, bs))
            I = np.eye(bs)
            for k in range(nb - 1, -1, -1):
                Li = la.solve_triangular(self.L[k], I, lower=True, check_finite=False)
                S = Li.T @ Li
                if k < nb - 1:
                    X = self.B[k] @ Li
                    SX = SD[k + 1] @ X
                    SO[k] = -SX
                    S += X.T @ SX
                SD[k] = S
            self._selinv = (SD, SO)
        return self._selinv

    def entries(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Entries Σ_ij of N⁻¹ for index arrays i, j (same shape).

        Pairs inside the block pattern come from the selected inverse; any others (rare: pairs of
        unknowns that share no observation) are computed by solves for their columns.
        """
        i = np.asarray(i, dtype=np.int64)
        j = np.asarray(j, dtype=np.int64)
        shape = i.shape
        i, j = i.ravel(), j.ravel()
        out = np.empty(i.size)
        if i.size == 0:
            return out.reshape(shape)
        SD, SO = self._selected_inverse()
        bs = self.bs
        pi, pj = self.iperm[i], self.iperm[j]
        hi, lo = np.maximum(pi, pj), np.minimum(pi, pj)
        K, J = hi // bs, lo // bs
        same = K == J
        adj = K == J + 1
        out[same] = SD[K[same], hi[same] % bs, lo[same] % bs]
        out[adj] = SO[J[adj], hi[adj] % bs, lo[adj] % bs]
        rest = ~(same | adj)
        if rest.any():
            cols, inv = np.unique(j[rest], return_inverse=True)
            E = np.zeros((self.m, cols.size))
            E[cols, np.arange(cols.size)] = 1.0
            X = self.solve(E)
            out[rest] = X[i[rest], inv]
        return out.reshape(shape)

    def dense_inverse(self) -> np.ndarray:
        """N⁻¹ as a dense matrix (tests and small problems only)."""
        return self.solve(np.eye(self.m))
