"""Sparse symmetric positive definite factorisation with a selected inverse.

Reliability needs only the blocks of N⁻¹ that couple the unknowns of one observation
(F80 §5: r_i needs a_i Σ a_iᵀ only). After a reverse Cuthill-McKee ordering most normal matrices of networks and
strip blocks are banded with a half-bandwidth b ≪ u. Cut into consecutive blocks such that every
non-zero couples a block only with itself and its neighbours (the cut is greedy: block K + 1 ends
where the farthest neighbour of block K lies, and at least :data:`MIN_BLOCK` on), the permuted
matrix is block tridiagonal with blocks as wide as the *local* bandwidth, its Cholesky factor is
block lower bidiagonal

    N = L Lᵀ,  L = [L₀; B₀ L₁; B₁ L₂; ...],

and the entries of Σ = N⁻¹ on the same block pattern follow from the block form of Takahashi's
recursion (TFC73), run from the last block up:

    X_K = B_K L_K⁻¹
    Σ_{K+1,K} = −Σ_{K+1,K+1} X_K
    Σ_{K,K}   = L_K⁻ᵀ L_K⁻¹ + X_Kᵀ Σ_{K+1,K+1} X_K

(L_K⁻ᵀ L_K⁻¹ by LAPACK ``dpotri``). Every pair of unknowns that appears together in an
observation is a non-zero of N and so lies inside that pattern. Cost O(u b²) for the
factorisation and the selected inverse alike; memory O(u b). When the band is wide the matrix is
one dense block and this is a dense Cholesky.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

from ..errors import SingularError

MIN_BLOCK = 48


def block_partition(pi: np.ndarray, pj: np.ndarray, m: int, min_block: int = MIN_BLOCK) -> np.ndarray:
    """Starts of consecutive blocks (nb + 1) making a matrix with non-zeros (pi, pj) block
    tridiagonal: block K + 1 reaches at least as far as any neighbour of blocks ≤ K."""
    reach = np.arange(m)
    if pi.size:
        np.maximum.at(reach, pi, pj)
        np.maximum.at(reach, pj, pi)
    far = np.maximum.accumulate(reach)
    starts = [0]
    end = min(m, min_block)
    while end < m:
        starts.append(end)
        end = min(m, max(end + min_block, int(far[end - 1]) + 1))
    if len(starts) > 1 and m - starts[-1] < min_block // 2:
        starts.pop()                   # a small last block joins its neighbour
    starts.append(m)
    return np.asarray(starts, dtype=np.int64)


class SPDFactor:
    """Cholesky factor of a sparse SPD matrix in RCM-ordered block-tridiagonal form.

    Parameters
    ----------
    N : sparse (m × m) symmetric positive definite matrix.
    labels : optional names of the m unknowns, used in the error of a singular matrix.
    pivot_tol : a pivot d_i² < pivot_tol · N_ii marks the matrix numerically singular.
    perm : optional fill-reducing order (default reverse Cuthill-McKee).
    """

    def __init__(self, N, labels=None, pivot_tol: float = 1e-11, perm=None):
        N = sp.csr_matrix(N)
        m = N.shape[0]
        self.m = m
        self.labels = labels
        self._selinv = None
        if m == 0:
            self.perm = np.zeros(0, dtype=np.int64)
            self.iperm = self.perm
            self.starts = np.zeros(1, dtype=np.int64)
            self.nb, self.bandwidth, self.L, self.B = 0, 0, [], []
            return
        if perm is None:
            perm = reverse_cuthill_mckee(N, symmetric_mode=True)
        perm = np.asarray(perm, dtype=np.int64)
        iperm = np.empty_like(perm)
        iperm[perm] = np.arange(m)
        C = N.tocoo()
        pi, pj = iperm[C.row], iperm[C.col]
        band = int(np.abs(pi - pj).max()) if C.nnz else 0
        starts = block_partition(pi, pj, m)
        if 2 * band >= m:
            starts = np.array([0, m], dtype=np.int64)
        nb = starts.size - 1
        self.perm, self.iperm, self.starts, self.nb, self.bandwidth = perm, iperm, starts, nb, band
        size = np.diff(starts)
        blk = np.repeat(np.arange(nb), size)
        off = np.arange(m) - starts[blk]
        self._blk, self._off, self._size = blk, off, size
        D = [np.zeros((s, s)) for s in size]
        O = [np.zeros((size[k + 1], size[k])) for k in range(nb - 1)]
        low = pi >= pj
        pi, pj, val = pi[low], pj[low], C.data[low]
        K, J = blk[pi], blk[pj]
        if (K - J > 1).any():
            raise AssertionError("block partition is not tridiagonal")
        order = np.argsort(K, kind="stable")
        pi, pj, val, K, J = pi[order], pj[order], val[order], K[order], J[order]
        bounds = np.searchsorted(K, np.arange(nb + 1))
        for k in range(nb):
            sl = slice(bounds[k], bounds[k + 1])
            same = J[sl] == k
            a, b, v = off[pi[sl]], off[pj[sl]], val[sl]
            D[k][a[same], b[same]] = v[same]
            D[k][b[same], a[same]] = v[same]
            if k:
                O[k - 1][a[~same], b[~same]] = v[~same]
        diagN = N.diagonal()[perm]
        del C, pi, pj, val, K, J, order, low
        self._factor(D, O, diagN, pivot_tol)

    # -- factorisation -------------------------------------------------------------------------
    def _factor(self, D, O, diagN, pivot_tol):
        nb, starts = self.nb, self.starts
        L, B = [], []
        for k in range(nb):
            A = D[k] if k == 0 else D[k] - B[k - 1] @ B[k - 1].T
            D[k] = None                 # the input blocks are let go as they are factored
            c, info = la.lapack.dpotrf(A, lower=1, clean=1)
            del A
            dN = diagN[starts[k]:starts[k + 1]]
            piv = np.diag(c) ** 2 if info == 0 else None
            if info != 0 or (piv < pivot_tol * dN).any():
                if info > 0:
                    bad = starts[k] + info - 1
                else:
                    bad = starts[k] + int(np.argmin(piv / dN))
                raise self._singular(min(bad, self.m - 1))
            L.append(c)
            if k + 1 < nb:
                B.append(la.solve_triangular(c, O[k].T, lower=True, check_finite=False).T)
                O[k] = None
        self.L, self.B = L, B

    def _singular(self, p):
        orig = int(self.perm[p])
        name = self.labels[orig] if self.labels is not None else f"unknown {orig}"
        return SingularError(unknown=name, index=orig)

    # -- solves ---------------------------------------------------------------------------------
    def solve(self, b: np.ndarray) -> np.ndarray:
        """N⁻¹ b for a vector or a matrix of right-hand sides."""
        b = np.asarray(b, dtype=float)
        if self.m == 0:
            return b.copy()
        vec = b.ndim == 1
        B2 = b.reshape(self.m, -1)
        st = self.starts
        y = B2[self.perm].copy()
        for k in range(self.nb):
            sl = slice(st[k], st[k + 1])
            rhs = y[sl] if k == 0 else y[sl] - self.B[k - 1] @ y[st[k - 1]:st[k]]
            y[sl] = la.solve_triangular(self.L[k], rhs, lower=True, check_finite=False)
        for k in range(self.nb - 1, -1, -1):
            sl = slice(st[k], st[k + 1])
            rhs = y[sl] if k == self.nb - 1 else y[sl] - self.B[k].T @ y[st[k + 1]:st[k + 2]]
            y[sl] = la.solve_triangular(self.L[k], rhs, lower=True, trans="T", check_finite=False)
        out = y[self.iperm]
        return out.ravel() if vec else out

    def logdet(self) -> float:
        d = np.concatenate([np.diag(Lk) for Lk in self.L]) if self.m else np.zeros(0)
        return 2.0 * float(np.log(d).sum())

    # -- selected inverse ---------------------------------------------------------------------
    def _selected_inverse(self):
        """Σ on the block pattern, flat: diagonal blocks row-major, then the sub-diagonal ones."""
        if self._selinv is None:
            nb, size = self.nb, self._size
            d_start = np.concatenate([[0], np.cumsum(size.astype(np.int64) ** 2)])
            o_start = np.concatenate([[0], np.cumsum(size[1:].astype(np.int64) * size[:-1])])
            # the blocks are written straight into the flat arrays (no second copy of Σ)
            flatD = np.empty(int(d_start[-1]))
            flatO = np.empty(int(o_start[-1]))
            SD = [flatD[d_start[k]:d_start[k + 1]].reshape(size[k], size[k]) for k in range(nb)]
            SO = [flatO[o_start[k]:o_start[k + 1]].reshape(size[k + 1], size[k]) for k in range(nb - 1)]
            for k in range(nb - 1, -1, -1):
                c, info = la.lapack.dpotri(self.L[k], lower=1)
                S = np.tril(c) + np.tril(c, -1).T
                del c
                if k < nb - 1:
                    # X = B_k L_k⁻¹: solve L_kᵀ Xᵀ = B_kᵀ
                    X = la.solve_triangular(self.L[k], self.B[k].T, lower=True, trans="T",
                                            check_finite=False).T
                    SX = SD[k + 1] @ X
                    np.negative(SX, out=SO[k])
                    S += X.T @ SX
                    del X, SX
                SD[k][...] = S
            self._selinv = (flatD, d_start, flatO, o_start)
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
        flatD, d_start, flatO, o_start = self._selected_inverse()
        pi, pj = self.iperm[i], self.iperm[j]
        hi, lo = np.maximum(pi, pj), np.minimum(pi, pj)
        K, J = self._blk[hi], self._blk[lo]
        oh, ol = self._off[hi], self._off[lo]
        same = K == J
        adj = K == J + 1
        out[same] = flatD[d_start[K[same]] + oh[same] * self._size[K[same]] + ol[same]]
        out[adj] = flatO[o_start[J[adj]] + oh[adj] * self._size[J[adj]] + ol[adj]]
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


class LowRankUpdate:
    """Factor of N' = N + Vᵀ M V from a factor of N (Sherman-Morrison-Woodbury).

    With Y = N⁻¹ Vᵀ (k solves with the old factor) and T = (I + M V Y)⁻¹ M (k × k),

        N'⁻¹ = N⁻¹ − Y T Yᵀ,

    which needs no inverse of M, so M may be singular or indefinite: leaving out whole
    covariance clusters is M = −P_c, leaving out part of one is M = −P_c + P_c' (the weight of
    the remaining members). Same interface as :class:`SPDFactor` (``m``, ``solve``, ``entries``,
    ``logdet``, ``dense_inverse``). Raises SingularError when N' is singular (the update removed
    the last observation of an unknown), judged by the condition of I + M V Y.

    Reference: Hager, W. W. (1989), Updating the inverse of a matrix, SIAM Review 31(2).
    """

    def __init__(self, base, V, M: np.ndarray, cond_max: float = 1e10):
        V = sp.csr_matrix(V)
        self.base, self.m, self.labels = base, base.m, getattr(base, "labels", None)
        k = V.shape[0]
        self.Y = np.asarray(base.solve(V.T.toarray())).reshape(base.m, k)
        K = np.eye(k) + M @ (V @ self.Y)
        if k and np.linalg.cond(K) > cond_max:
            raise SingularError("normal matrix is singular after the update: the removed "
                                "observations were needed to determine some unknowns")
        T = la.solve(K, M) if k else np.zeros((0, 0))
        self.T = 0.5 * (T + T.T)
        self._logdet_K = float(np.linalg.slogdet(K)[1]) if k else 0.0

    def solve(self, b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=float)
        vec = b.ndim == 1
        B2 = b.reshape(self.m, -1)
        out = self.base.solve(B2).reshape(self.m, -1) - self.Y @ (self.T @ (self.Y.T @ B2))
        return out.ravel() if vec else out

    def entries(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        i = np.asarray(i, dtype=np.int64)
        j = np.asarray(j, dtype=np.int64)
        corr = np.einsum("...a,...a->...", self.Y[i] @ self.T, self.Y[j])
        return self.base.entries(i, j) - corr

    def logdet(self) -> float:
        return self.base.logdet() + self._logdet_K

    def dense_inverse(self) -> np.ndarray:
        return self.solve(np.eye(self.m))


def keep_columns(A: sp.csr_matrix, keep: np.ndarray, consume: bool = False) -> sp.csr_matrix:
    """A[:, keep] for sorted ``keep`` by one pass over the entries (scipy's column indexing
    costs a gather per entry and a re-sort; here the order is kept and so is canonical form).
    consume: A's values are not needed afterwards; the kept ones are moved to the front of A's
    own data array (A is left invalid) instead of being copied (no second array of values)."""
    A = sp.csr_matrix(A)
    if keep.size == A.shape[1]:
        return A
    colmap = np.full(A.shape[1], -1, dtype=A.indices.dtype)
    colmap[keep] = np.arange(keep.size)
    new = colmap[A.indices]
    m = new >= 0
    dropped = np.flatnonzero(~m)                           # (the held columns' few entries)
    indptr = A.indptr - np.searchsorted(dropped, A.indptr).astype(A.indptr.dtype)
    del dropped
    data = compact(A.data, m) if consume else A.data[m]
    out = sp.csr_matrix((data, compact(new, m), indptr), shape=(A.shape[0], keep.size), copy=False)
    out.has_sorted_indices = A.has_sorted_indices
    return out


def compact(a: np.ndarray, m: np.ndarray, chunk: int = 1 << 22) -> np.ndarray:
    """a[m] moved to the front of ``a`` itself, chunk by chunk (the order kept; no second array
    of a's size): returns the view of those first values."""
    pos = 0
    for s in range(0, a.size, chunk):
        part = a[s:s + chunk][m[s:s + chunk]]
        a[pos:pos + part.size] = part
        pos += part.size
    return a[:pos]
