"""The numeric factor of N = AᵀPA through the reduced camera system (:class:`SchurFactor`, the
package docstring), its solves and its selected inverse for reliability.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import OptionError
from ...model.problem import by_size
from ..compiled import NUMBA
from ..linalg import SPDFactor
from .kernels import SCATTER_CHUNKS, compiled_kernels, find_block, gather_np, scatter_np, uniform6
from .ordering import Permuted, factor_reduced, point_places, singular_error, unknown_diagonal
from .points import bmm, mT, point_roots, segment_sum, upper3_inverse
from .structure import Structure, canonical, weights

#: Camera unknowns up to which S may be factored as one dense block (8·n_c² bytes per copy, the
#: factor keeps about three: 1.5 GB at 8000); a larger S whose band after ordering exceeds half
#: its size raises MemoryError instead of silently going dense.
DENSE_LIMIT = 8000
PIVOT_TOL = 1e-11
#: the 3 × 3 point blocks are inverted in closed form, stable to a condition of ~1e14: a point
#: seen along nearly parallel rays (far away, short base) is weak but still determined
POINT_PIVOT_TOL = 1e-14
#: The step's factor keeps every E_c (K × 3 per image point) for its solves up to this many bytes
#: (Trafalgar 8 MB, Dubrovnik 18 MB); above, the solves make E_c again from the design matrix's
#: data (the same numbers), so a large block holds no K · 3 values per image point.
KEEP_E_BYTES = 64 << 20
#: Bytes of the per-cluster temporaries of one group of right-hand sides in SchurFactor.solve.
SOLVE_BYTES = 64 << 20
BACKENDS = ("numba", "numpy")


def default_backend() -> str:
    """``"numba"`` where numba is installed, else ``"numpy"``."""
    return "numba" if NUMBA else "numpy"


class SchurFactor:
    """N = AᵀPA factored through the reduced camera system (package docstring).

    Has the interface of :class:`baarda.solve.linalg.SPDFactor` (``m``, ``solve``, ``entries``,
    ``logdet``, ``dense_inverse``) plus the blocks reliability needs (:meth:`hat_blocks`).
    Raises SingularError naming an unknown the observations do not determine.
    """

    def __init__(self, st: Structure, Ar, P, backend: str | None = None, pivot_tol: float = PIVOT_TOL,
                 damping: float = 0.0):
        Ar = canonical(Ar)
        if not st.matches(Ar):
            raise ValueError("design matrix pattern differs from the analysed structure")
        self.backend = backend or default_backend()
        if self.backend not in BACKENDS or (self.backend == "numba" and not NUMBA):
            raise OptionError("backend", self.backend, BACKENDS, f"backend {self.backend!r} not available")
        self.st, self.m, self.labels = st, st.u, st.labels
        K = st.K
        # the common case (numba, one supernode per cluster) reads a_c, b_c from Ar's data in its
        # kernels and makes b̃_c and E_c per point (:mod:`.kernels`): no stack of a, b, b̃
        # or E over all clusters is held (216 + 192 bytes per image point of a bundle block);
        # E is made for the solves only when one is asked for (:attr:`E`). The other paths
        # keep the padded stacks a, b̃ and E.
        self.fused = self.backend == "numba" and uniform6(st)
        self._data = Ar.data if self.fused else None
        self._E = None
        if self.fused:
            self.a = self.b = None
            b = st.gather(Ar.data, st.src_b)           # (for the point roots only)
        else:
            self.a, b = st.cluster_blocks(Ar)
        self.P, Pc, diagonal = weights(st, P)
        self.Pc, self._diagonal_P = Pc, diagonal
        R, bad, dC = point_roots(b, Pc, st.ent_ptr, st.ent_size, damping,
                                  min(pivot_tol, POINT_PIVOT_TOL), self.backend, diagonal)
        if (bad >= 0).any():
            e = int(np.flatnonzero(bad >= 0)[0])
            raise singular_error(st, int(st.ent_cols[e, bad[e]]))
        # point unknowns p̃ = R_j p: the point blocks become I, b_c becomes b_c R_j⁻¹
        self.R, self.Ri = R, upper3_inverse(R)
        if self.fused:
            del b
        else:
            self.b = bmm(b, self.Ri[st.cl_ent])
            del b
            Pb = np.diagonal(Pc, axis1=1, axis2=2)[:, :, None] * self.b if diagonal else bmm(Pc, self.b)
            self._E = bmm(mT(self.a), Pb)          # E_c = a_cᵀ P_c b̃_c (= Q_c: C̃ = I)
            del Pb
        nnz = int(st.bstart[-1])
        sn_size = np.diff(st.sn_ptr)
        if self.fused:
            S_parts = np.zeros((SCATTER_CHUNKS, nnz))
            n_sn = st.sn_ptr.size - 1
            U_parts = np.zeros((SCATTER_CHUNKS, n_sn, K * K))
            compiled_kernels()["scatter6"](st.ent_ptr, st.ent_size, st.cl_sn, st.bptr, st.bcol, st.bstart,
                                   Ar.data, st.src_a, st.src_b, self.Ri, Pc, diagonal, self._maxent(),
                                   S_parts, U_parts)
            # U = Σ_c a_cᵀ P_c a_c: diagonal blocks only, one per supernode
            used = np.unique(st.cl_sn[:, 0])
            diag_pos = np.array([st.bstart[find_block(st.bptr, st.bcol, int(x), int(x))] for x in used],
                                dtype=np.int64)
            U = np.zeros(nnz)
            U[(diag_pos[:, None] + np.arange(K * K)[None, :]).ravel()] = U_parts.sum(axis=0)[used].ravel()
            S = S_parts.sum(axis=0) + U
        elif self.backend == "numba":
            S, U = np.zeros(nnz), np.zeros(nnz)
            compiled_kernels()["scatter"](st.ent_ptr, st.ent_size, st.cl_sn, st.cl_off, sn_size, st.bptr,
                                  st.bcol, st.bstart, self.a, Pc, self._E, self._E, S, U)
        else:
            Ua = np.matmul(mT(self.a), np.matmul(Pc, self.a))
            S, U = scatter_np(st, Ua, self._E, self._E, nnz)
        if damping:
            dsel0 = st.flat_r == st.flat_c
            S = S.copy()
            S[dsel0] += damping * U[dsel0]
        self.Svals, self.Uvals = S, U
        self.S = factor_reduced(st, S, pivot_tol, DENSE_LIMIT)
        self.bandwidth = getattr(self.S, "bandwidth", 0)
        dsel = st.flat_r == st.flat_c
        diag_c = np.empty(st.cam.size)
        diag_c[st.flat_r[dsel]] = U[dsel]
        self.diagonal = unknown_diagonal(st, diag_c, dC)
        self._pflat, self._pcols = point_places(st)
        self._blocks = None
        self._nuisance = None

    def _maxent(self) -> int:
        """The most cluster positions of one entity (the kernels' scratch size)."""
        return max(int(np.diff(self.st.ent_ptr).max(initial=0)), 1)

    @property
    def E(self) -> np.ndarray:
        """E_c = a_cᵀ P_c b̃_c of every cluster position (nc, K, 3), for the solves. The common
        case's kernels make it per point; here it is made from Ar's data once a solve needs it,
        and kept for the next solve when it takes at most :data:`KEEP_E_BYTES` (a large block
        makes it again for each solve: K · 24 bytes per image point not held)."""
        if self._E is not None:
            return self._E
        st = self.st
        E = np.empty((st.cl_id.size, st.K, 3))
        compiled_kernels()["E6"](st.ent_ptr, self._data, st.src_a, st.src_b, self.Ri, self.Pc,
                         self._diagonal_P, self._maxent(), E)
        if E.nbytes <= KEEP_E_BYTES:
            self._E = E
        return E

    # -- solves -------------------------------------------------------------------------------
    def solve(self, b: np.ndarray) -> np.ndarray:
        """N⁻¹ b for a vector or a matrix of right-hand sides (reduced unknowns). Several
        right-hand sides go in groups whose per-cluster temporaries (~ 8 · K · 6 bytes per image
        point and column) stay within :data:`SOLVE_BYTES`: each column's numbers are the same."""
        st = self.st
        b = np.asarray(b, dtype=float)
        vec = b.ndim == 1
        B = b.reshape(self.m, -1)
        q = B.shape[1]
        per_col = 48 * st.K * max(st.cl_sn.shape[0], 1)
        if q > 1 and q * per_col > SOLVE_BYTES:
            step = max(1, SOLVE_BYTES // per_col)
            return np.hstack([self.solve(B[:, k:k + step]).reshape(self.m, -1) for k in range(0, q, step)])
        ne = st.ent_size.size
        bp = np.zeros((ne * 3, q))
        bp[self._pflat] = B[self._pcols]
        yp = bmm(mT(self.Ri), bp.reshape(ne, 3, q))             # Ṽ⁻¹ b̃_p = R⁻ᵀ b_p  (ne, 3, q)
        E = self.E
        Wy = bmm(E, yp[st.cl_ent]).reshape(-1, q)                 # E_c y_e(c)  (nc·K, q)
        cols = st.col_S.ravel()
        ok = cols >= 0
        rhs = B[st.cam].copy()
        for j in range(q):
            rhs[:, j] -= np.bincount(cols[ok], weights=Wy[ok, j], minlength=st.cam.size)
        xc = self.S.solve(rhs).reshape(-1, q)
        xk = np.where(ok[:, None], xc[np.maximum(cols, 0)], 0.0).reshape(-1, st.K, q)
        t = segment_sum(bmm(mT(E), xk), st.ent_ptr)            # W_jᵀ x_c  (ne, 3, q)
        del E
        xp = bmm(self.Ri, yp - t).reshape(ne * 3, q)            # p = R⁻¹ p̃
        out = np.empty((self.m, q))
        out[st.cam] = xc
        out[self._pcols] = xp[self._pflat]
        return out.ravel() if vec else out

    def logdet(self) -> float:
        d = 2.0 * np.log(np.diagonal(self.R, axis1=1, axis2=2)).sum()
        return float(self.S.logdet() + d)

    def dense_inverse(self) -> np.ndarray:
        """N⁻¹ as a dense matrix (tests and small problems only)."""
        return self.solve(np.eye(self.m))

    # -- selected inverse and reliability blocks ----------------------------------------------
    def nuisance_factor(self):
        """Factor of BᵀPB over the nuisance unknowns (ascending reduced index), or None."""
        self._selected()
        return self._nuisance

    def _selected(self):
        """Σ and Σ_t on the block pattern of S, and the per-cluster blocks (package docstring)."""
        if self._blocks is not None:
            return self._blocks
        st = self.st
        Sig = self.S.entries(st.flat_r, st.flat_c)
        sn_of = np.repeat(np.arange(st.sn_t.size), np.diff(st.sn_ptr))
        tflat = st.sn_t[sn_of[st.flat_r]] & st.sn_t[sn_of[st.flat_c]]
        Sigt = np.zeros_like(Sig)
        tS = np.flatnonzero(st.sn_t[sn_of])                # S indices of nuisance unknowns
        if tS.size:
            tpos = np.full(st.cam.size, -1, dtype=np.int64)
            tpos[tS] = np.arange(tS.size)
            Ntt = sp.csr_matrix((self.Uvals[tflat], (tpos[st.flat_r[tflat]], tpos[st.flat_c[tflat]])),
                                shape=(tS.size, tS.size))
            T = SPDFactor(Ntt)
            Sigt[tflat] = T.entries(tpos[st.flat_r[tflat]], tpos[st.flat_c[tflat]])
            # in ascending reduced order
            red = st.cam[tS]
            self._nuisance = Permuted(T, np.argsort(red))
        nc, M, K = st.cl_id.size, st.M, st.K
        sn_size = np.diff(st.sn_ptr)
        if self.fused:
            # H, Ht by cluster id (the order of :meth:`hat_blocks` when all clusters have M rows:
            # the result takes them without a copy)
            H, Ht = np.empty((nc, M, M)), np.empty((nc, M, M))
            Spp = np.empty((st.ent_size.size, 3, 3))
            compiled_kernels()["hat6"](st.ent_ptr, st.ent_size, st.cl_sn, st.sn_t, st.bptr, st.bcol, st.bstart,
                               self._data, st.src_a, st.src_b, self.Ri, self.Pc, self._diagonal_P, st.cl_id,
                               Sig, Sigt, H, Ht, Spp)
            self._blocks = (H, Ht, bmm(bmm(self.Ri, Spp), mT(self.Ri)), True)   # Σ_pp = R⁻¹ Σ̃ R⁻ᵀ
            return self._blocks
        Q = self._E
        if self.backend == "numba":
            Gc, SA, SAt = np.zeros((nc, K, 3)), np.zeros((nc, K, M)), np.zeros((nc, K, M))
            compiled_kernels()["gather"](st.ent_ptr, st.ent_size, st.cl_sn, st.cl_off, sn_size, st.sn_t, st.bptr,
                                 st.bcol, st.bstart, Q, self.a, Sig, Sigt, Gc, SA, SAt)
        else:
            Gc, SA, SAt = gather_np(st, Q, self.a, Sig, Sigt)
        a, b = self.a, self.b
        F = bmm(a, Gc)                                        # a_c Σ_{k_c p}  (nc, M, 3)
        I3 = np.broadcast_to(np.eye(3), (st.ent_size.size, 3, 3))
        Spp = I3 - segment_sum(bmm(mT(Q), Gc), st.ent_ptr)      # Σ of p̃ (C̃ = I)
        FbT = bmm(F, mT(b))
        H = bmm(a, SA) + FbT + mT(FbT) + bmm(bmm(b, Spp[st.cl_ent]), mT(b))
        Ht = bmm(a, SAt)
        self._blocks = (H, Ht, bmm(bmm(self.Ri, Spp), mT(self.Ri)), False)   # (by cluster position)
        self.a = self.b = None             # only these blocks needed them (solve uses E and R)
        return self._blocks

    def hat_blocks(self, cov):
        """a_i Σ a_jᵀ and a_i Σ_t a_jᵀ (nuisance part) for all pairs within each covariance
        cluster, laid out as :func:`baarda.solve.pairs.cluster_pairs` lays them out. When the factor's
        blocks are in that layout already (one cluster size, clusters in id order: a bundle block)
        they are returned themselves, not copied (the result repairs them in place: the factor
        holds no second copy of them)."""
        H, Ht, _, by_id = self._selected()
        groups = list(by_size(cov))
        if by_id and len(groups) == 1 and groups[0][0] == H.shape[1] \
                and np.array_equal(groups[0][1], np.arange(H.shape[0])):
            return H.reshape(-1), Ht.reshape(-1)       # the layout asked for: no copy
        out_h, out_t = [], []
        for m, clusters, _ in groups:
            p = clusters if by_id else self.st.cl_pos[clusters]
            out_h.append(H[p, :m, :m].reshape(-1))
            out_t.append(Ht[p, :m, :m].reshape(-1))
        if len(out_h) == 1:            # (one cluster size: its stacks are new arrays already)
            return out_h[0], out_t[0]
        return np.concatenate(out_h), np.concatenate(out_t)

    def entries(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Entries Σ_ij of N⁻¹ (reduced unknowns): camera pairs from the selected inverse of S,
        pairs within one point from Σ_pp, any other pair by solves for its columns."""
        st = self.st
        i = np.asarray(i, dtype=np.int64)
        j = np.asarray(j, dtype=np.int64)
        shape = i.shape
        i, j = i.ravel(), j.ravel()
        out = np.empty(i.size)
        ci, cj = st.cam_pos[i], st.cam_pos[j]
        cc = (ci >= 0) & (cj >= 0)
        if cc.any():
            out[cc] = self.S.entries(ci[cc], cj[cc])
        ent = np.full(st.u, -1, dtype=np.int64)
        crd = np.full(st.u, -1, dtype=np.int64)
        ok = st.ent_cols >= 0
        ent[st.ent_cols[ok]] = np.nonzero(ok)[0]
        crd[st.ent_cols[ok]] = np.nonzero(ok)[1]
        pp = (ent[i] >= 0) & (ent[i] == ent[j])
        if pp.any():
            Spp = self._selected()[2]
            out[pp] = Spp[ent[i[pp]], crd[i[pp]], crd[j[pp]]]
        rest = ~(cc | pp)
        if rest.any():
            cols, inv = np.unique(j[rest], return_inverse=True)
            Em = np.zeros((self.m, cols.size))
            Em[cols, np.arange(cols.size)] = 1.0
            X = self.solve(Em)
            out[rest] = X[i[rest], inv]
        return out.reshape(shape)
