"""The step of one iteration: N + λ diag(N) factored by one fused compiled pass over the points
(:class:`StepFactor`: no selected inverse, no reliability blocks; :class:`SchurFactor` is its
reference and takes the step where it does not apply).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..compiled import NUMBA, compiled, njit
from . import factor
from .factor import PIVOT_TOL, POINT_PIVOT_TOL
from .kernels import find_block, uniform6
from .ordering import factor_reduced, point_places, singular_error, unknown_diagonal
from .structure import Structure, canonical, weights

def _load_cluster(data, src_a, src_b, c, ac, bc):
    """a_c and b_c of cluster position c from the design matrix's data (0 where padded)."""
    for r in range(src_a.shape[1]):
        for i in range(src_a.shape[2]):
            k = src_a[c, r, i]
            ac[r, i] = data[k] if k >= 0 else 0.0
        for i in range(3):
            k = src_b[c, r, i]
            bc[r, i] = data[k] if k >= 0 else 0.0


def _cluster_E(data, src_a, src_b, Pd, c, a, b, Ec):
    """E_c = a_cᵀP_c b_c (K × 3) of cluster position c, diagonal P_c, summed in the order of
    :func:`_step_factor_kernel` (the same numbers: the solves make E_c again rather than keep
    K · 3 values per image point)."""
    _load_cluster(data, src_a, src_b, c, a, b)
    Ec[:, :] = 0.0
    for r in range(a.shape[0]):
        p = Pd[c, r]
        if p == 0.0:
            continue
        for i in range(a.shape[1]):
            pa = p * a[r, i]
            if pa == 0.0:
                continue
            for q in range(3):
                Ec[i, q] += pa * b[r, q]


def _step_factor_kernel(ent_ptr, ent_cols, cl_sn, bptr, bcol, bstart, sn_diag, data, src_a, src_b, Pd, lam,
                        pivot_tol, S, Et, keep, Z, Ci, dC, dU, bad):
    """One pass over the entities for N + λ diag(N) (the package docstring's formulas in normal-
    equation form, every cluster seeing one supernode of K unknowns, diagonal P_c):
    U = Σ a_cᵀP_c a_c into the diagonal blocks of S (its diagonal into dU), E_c = a_cᵀP_c b_c
    (into Et transposed, 3 × K: at cluster position c when ``keep``, else at rows 0, 1, ... for
    the clusters of the entity at hand, Et holding one entity's), C_j = Σ b_cᵀP_c b_c (+ λ diag), its inverse Ci_j (3 × 3, equilibrated
    Cholesky; a missing coordinate gets 1), Z_c = E_c C_j⁻¹, and S −= Z_c E_c'ᵀ for every pair
    of clusters of point j. S is symmetric: only its upper half is summed (the diagonal blocks'
    upper triangles, the blocks (g, h) with g < h), then mirrored (:func:`_mirror_blocks`).
    bad[e] = coordinate whose pivot fails, else −1. a_c and b_c are read from the design
    matrix's data through ``src_a``, ``src_b`` (no padded copy of them is made)."""
    M = src_a.shape[1]
    K = src_a.shape[2]
    a = np.zeros((M, K))
    b = np.zeros((M, 3))
    C = np.zeros((3, 3))
    L = np.zeros((3, 3))
    Li = np.zeros((3, 3))
    dd = np.empty(3)
    for e in range(ent_ptr.size - 1):
        c0, c1 = ent_ptr[e], ent_ptr[e + 1]
        o = 0 if keep else c0                  # Et[c − o] is cluster position c's E_cᵀ
        C[:, :] = 0.0
        Et[c0 - o: c1 - o] = 0.0
        for c in range(c0, c1):
            g = cl_sn[c, 0]
            d0 = bstart[sn_diag[g]]
            _load_cluster(data, src_a, src_b, c, a, b)
            for r in range(M):
                p = Pd[c, r]
                if p == 0.0:
                    continue
                for i in range(K):
                    pa = p * a[r, i]
                    if pa == 0.0:
                        continue
                    dU[g, i] += pa * a[r, i]
                    for j in range(i, K):
                        S[d0 + i * K + j] += pa * a[r, j]
                    for q in range(3):
                        Et[c - o, q, i] += pa * b[r, q]
                for i in range(3):
                    pb = p * b[r, i]
                    for j in range(3):
                        C[i, j] += pb * b[r, j]
        if ent_cols[e, 0] < 0 and ent_cols[e, 1] < 0 and ent_cols[e, 2] < 0:
            continue
        for k in range(3):
            dC[e, k] = C[k, k]
            if ent_cols[e, k] < 0:
                C[k, :] = 0.0
                C[:, k] = 0.0
                C[k, k] = 1.0
            else:
                C[k, k] *= 1.0 + lam
        # equilibrated Cholesky C = D L Lᵀ D, D = diag(√C_kk)
        for k in range(3):
            dd[k] = np.sqrt(C[k, k]) if C[k, k] > 0.0 else 0.0
        ok = True
        for k in range(3):
            if dd[k] == 0.0:
                bad[e] = k
                ok = False
                break
        if not ok:
            continue
        L[:, :] = 0.0
        for j in range(3):
            s = C[j, j] / (dd[j] * dd[j])
            for k in range(j):
                s -= L[j, k] * L[j, k]
            if s <= pivot_tol:
                bad[e] = j
                ok = False
                break
            L[j, j] = np.sqrt(s)
            for i in range(j + 1, 3):
                t = C[i, j] / (dd[i] * dd[j])
                for k in range(j):
                    t -= L[i, k] * L[j, k]
                L[i, j] = t / L[j, j]
        if not ok:
            continue
        # C⁻¹ = D⁻¹ L⁻ᵀ L⁻¹ D⁻¹
        Li[:, :] = 0.0
        for i in range(3):
            Li[i, i] = 1.0 / L[i, i]
            for j in range(i):
                t = 0.0
                for k in range(j, i):
                    t -= L[i, k] * Li[k, j]
                Li[i, j] = t / L[i, i]
        for i in range(3):
            for j in range(3):
                t = 0.0
                for k in range(max(i, j), 3):
                    t += Li[k, i] * Li[k, j]
                Ci[e, i, j] = t / (dd[i] * dd[j])
        for c in range(c0, c1):
            for i in range(K):
                for q in range(3):
                    Z[c - c0, i, q] = Et[c - o, 0, i] * Ci[e, 0, q] + Et[c - o, 1, i] * Ci[e, 1, q] \
                        + Et[c - o, 2, i] * Ci[e, 2, q]
        for c in range(c0, c1):
            g = cl_sn[c, 0]
            u, ut = c - c0, c - o            # (Z's row, Et's row)
            for c2 in range(c, c1):
                h = cl_sn[c2, 0]
                w, wt = c2 - c0, c2 - o
                if g == h:
                    # a diagonal block: its upper triangle (two clusters of one point in one
                    # image, duplicate keypoints, add the pair's product and its transpose)
                    b1 = bstart[sn_diag[g]]
                    for i in range(K):
                        z0, z1, z2 = Z[u, i, 0], Z[u, i, 1], Z[u, i, 2]
                        for j in range(i, K):
                            y = z0 * Et[wt, 0, j] + z1 * Et[wt, 1, j] + z2 * Et[wt, 2, j]
                            if c2 != c:
                                y += Z[w, j, 0] * Et[ut, 0, i] + Z[w, j, 1] * Et[ut, 1, i] + Z[w, j, 2] * Et[ut, 2, i]
                            S[b1 + i * K + j] -= y
                    continue
                lo, hi = (u, wt) if g < h else (w, ut)
                b1 = bstart[find_block(bptr, bcol, min(g, h), max(g, h))]
                e0, e1, e2 = Et[hi, 0], Et[hi, 1], Et[hi, 2]
                for i in range(K):
                    z0, z1, z2 = Z[lo, i, 0], Z[lo, i, 1], Z[lo, i, 2]
                    row = S[b1 + i * K: b1 + i * K + K]      # (a view: the inner loop vectorises)
                    for j in range(K):
                        row[j] -= z0 * e0[j] + z1 * e1[j] + z2 * e2[j]
    _mirror_blocks(bptr, bcol, bstart, K, S)


def _mirror_blocks(bptr, bcol, bstart, K, S):
    """S's lower half from its upper half: block (h, g) = block (g, h)ᵀ for g < h, and the lower
    triangle of each diagonal block from its upper triangle."""
    for g in range(bptr.size - 1):
        for p in range(bptr[g], bptr[g + 1]):
            h = bcol[p]
            if h < g:
                continue
            b1 = bstart[p]
            if h == g:
                for i in range(K):
                    for j in range(i + 1, K):
                        S[b1 + j * K + i] = S[b1 + i * K + j]
                continue
            b2 = bstart[find_block(bptr, bcol, h, g)]
            for i in range(K):
                for j in range(K):
                    S[b2 + j * K + i] = S[b1 + i * K + j]


def _stored_E(Et, c, E):
    """E (K × 3) = Et[c]ᵀ, the E_c the factor kept (the same numbers :func:`_cluster_E` makes)."""
    for i in range(E.shape[0]):
        for q in range(3):
            E[i, q] = Et[c, q, i]


def _step_solve_kernel(ent_ptr, cl_sn, sn_ptr, data, src_a, src_b, Pd, Et, Ci, bp, rhs_c):
    """rhs_c −= Σ_c E_c C_j⁻¹ b_p,j (the reduced right-hand side); returns t = C⁻¹ b_p. (Every
    cluster sees the K unknowns of one supernode: S indices sn_ptr[cl_sn[c, 0]] + 0 .. K − 1.)
    E_c is read from ``Et`` where the factor kept it (Et not empty), else made again."""
    M, K = src_a.shape[1], src_a.shape[2]
    a, b, E = np.zeros((M, K)), np.zeros((M, 3)), np.zeros((K, 3))
    t = np.zeros((ent_ptr.size - 1, 3))
    for e in range(ent_ptr.size - 1):
        for q in range(3):
            t[e, q] = Ci[e, q, 0] * bp[e, 0] + Ci[e, q, 1] * bp[e, 1] + Ci[e, q, 2] * bp[e, 2]
        for c in range(ent_ptr[e], ent_ptr[e + 1]):
            if Et.shape[0]:
                _stored_E(Et, c, E)
            else:
                _cluster_E(data, src_a, src_b, Pd, c, a, b, E)
            k0 = sn_ptr[cl_sn[c, 0]]
            for i in range(K):
                rhs_c[k0 + i] -= E[i, 0] * t[e, 0] + E[i, 1] * t[e, 1] + E[i, 2] * t[e, 2]
    return t


def _step_back_kernel(ent_ptr, cl_sn, sn_ptr, data, src_a, src_b, Pd, Et, Ci, bp, xc):
    """x_p,j = C_j⁻¹ (b_p,j − Σ_c E_cᵀ x_c)."""
    M, K = src_a.shape[1], src_a.shape[2]
    a, b, E = np.zeros((M, K)), np.zeros((M, 3)), np.zeros((K, 3))
    ne = ent_ptr.size - 1
    xp = np.zeros((ne, 3))
    s = np.zeros(3)
    for e in range(ne):
        s[0], s[1], s[2] = bp[e, 0], bp[e, 1], bp[e, 2]
        for c in range(ent_ptr[e], ent_ptr[e + 1]):
            if Et.shape[0]:
                _stored_E(Et, c, E)
            else:
                _cluster_E(data, src_a, src_b, Pd, c, a, b, E)
            k0 = sn_ptr[cl_sn[c, 0]]
            for i in range(K):
                for q in range(3):
                    s[q] -= E[i, q] * xc[k0 + i]
        for q in range(3):
            xp[e, q] = Ci[e, q, 0] * s[0] + Ci[e, q, 1] * s[1] + Ci[e, q, 2] * s[2]
    return xp


# the kernels call these compiled helpers (numba resolves globals)
_load_cluster = compiled(_load_cluster, cache=True)
_mirror_blocks = compiled(_mirror_blocks, cache=True)
_cluster_E = compiled(_cluster_E, cache=True)
_stored_E = compiled(_stored_E, cache=True)
_KERNELS = {}


def _step_kernels():
    """The compiled kernels of the step (compiled on first use, cached on disk)."""
    if "step" not in _KERNELS:
        _KERNELS["step"] = njit(cache=True)(_step_factor_kernel)
        _KERNELS["step_solve"] = njit(cache=True)(_step_solve_kernel)
        _KERNELS["step_back"] = njit(cache=True)(_step_back_kernel)
    return _KERNELS


class StepFactor:
    """N + λ diag(N) factored for the step of one iteration of :func:`baarda.adjust.adjust`:
    the same reduced camera system as :class:`SchurFactor`, by one fused compiled pass over the
    points in normal-equation form (3 × 3 point blocks by an equilibrated Cholesky factor), and
    nothing of what reliability needs (no square-root elimination, no selected inverse).

    For blocks whose every cluster sees one supernode (:func:`uniform6`: an image's pose with
    its camera's constants) and a diagonal weight per cluster, with numba (:meth:`applicable`);
    otherwise :class:`SchurFactor` takes the step (and it stays the reference: the same steps,
    tests/test_adjust.py). Interface: ``solve``, ``diagonal`` (undamped diag(N)), ``m``.
    """

    def __init__(self, st: Structure, Ar, P, damping: float = 0.0, pivot_tol: float = PIVOT_TOL):
        Ar = canonical(Ar)
        if not st.matches(Ar):
            raise ValueError("design matrix pattern differs from the analysed structure")
        self.st, self.m, self.labels = st, st.u, st.labels
        K = st.K
        Pd = self.cluster_diagonal(st, P)
        nsn = st.sn_ptr.size - 1
        sn_diag = st.cache.sn_diag
        if sn_diag is None:
            sn_diag = np.array([find_block(st.bptr, st.bcol, g, g) for g in range(nsn)], dtype=np.int64)
            st.cache.sn_diag = sn_diag
        ne = st.ent_size.size
        S = np.zeros(int(st.bstart[-1]))
        maxent = int(np.diff(st.ent_ptr).max(initial=1))
        nc = st.cl_sn.shape[0]
        keep = nc * K * 3 * 8 <= factor.KEEP_E_BYTES              # every E_c, or one entity's at a time
        Et, Z = np.zeros((nc if keep else maxent, 3, K)), np.zeros((maxent, K, 3))
        Ci = np.zeros((ne, 3, 3))
        dC = np.zeros((ne, 3))
        dU = np.zeros((nsn, K))
        bad = np.full(ne, -1, dtype=np.int64)
        _step_kernels()["step"](st.ent_ptr, st.ent_cols, st.cl_sn, st.bptr, st.bcol, st.bstart, sn_diag,
                                Ar.data, st.src_a, st.src_b, Pd, float(damping),
                                min(pivot_tol, POINT_PIVOT_TOL), S, Et, keep, Z, Ci, dC, dU, bad)
        if (bad >= 0).any():
            e = int(np.flatnonzero(bad >= 0)[0])
            raise singular_error(st, int(st.ent_cols[e, bad[e]]))
        diag_c = self._camera_diagonal(st, dU)              # diag(U) by S index
        if damping:
            dsel = st.flat_r == st.flat_c
            S[dsel] += damping * diag_c[st.flat_r[dsel]]
        self.Ci, self._data, self._Pd = Ci, Ar.data, Pd
        self._Et = Et if keep else np.zeros((0, 3, K))     # (else E_c is made again by the solves)
        del Et, Z
        self.S = factor_reduced(st, S, pivot_tol)
        self.diagonal = unknown_diagonal(st, diag_c, dC)
        self._pflat, self._pcols = point_places(st)

    @staticmethod
    def applicable(st: Structure, P) -> bool:
        """numba is there, every cluster sees one supernode, and P is diagonal (the answer kept
        with the structure for this P: asked at every step)."""
        cached = st.cache.step_applicable
        if cached is not None and cached[0] is P:
            return cached[1]
        ok = NUMBA and uniform6(st) and bool((np.diff(st.sn_ptr) == st.K).all())
        if ok:
            Pc = sp.csr_matrix(P)
            rows = np.repeat(np.arange(Pc.shape[0]), np.diff(Pc.indptr))
            ok = not np.any(Pc.data[rows != Pc.indices])
        st.cache.step_applicable = (P, ok)
        return ok

    @staticmethod
    def cluster_diagonal(st: Structure, P) -> np.ndarray:
        """The diagonal weights of every cluster position (nc, M): a view of the cluster weights
        kept with the structure (:func:`baarda.solve.schur.structure.weights`, which the reliability's factor uses too)."""
        return np.diagonal(weights(st, P)[1], axis1=1, axis2=2)

    @staticmethod
    def _camera_diagonal(st, dU):
        """diag(U) per S index (supernodes in order, K each)."""
        return dU.ravel()[: st.cam.size] if dU.shape[1] * dU.shape[0] == st.cam.size else \
            np.concatenate([dU[g, : st.sn_ptr[g + 1] - st.sn_ptr[g]] for g in range(dU.shape[0])])

    def solve(self, b: np.ndarray) -> np.ndarray:
        """(N + λ diag N)⁻¹ b for a vector b over the reduced unknowns."""
        st = self.st
        b = np.asarray(b, dtype=float)
        ne = st.ent_size.size
        bp = np.zeros(ne * 3)
        bp[self._pflat] = b[self._pcols]
        bp = bp.reshape(ne, 3)
        k = _step_kernels()
        rhs = b[st.cam].copy()
        k["step_solve"](st.ent_ptr, st.cl_sn, st.sn_ptr, self._data, st.src_a, st.src_b, self._Pd, self._Et,
                        self.Ci, bp, rhs)
        xc = self.S.solve(rhs)
        xp = k["step_back"](st.ent_ptr, st.cl_sn, st.sn_ptr, self._data, st.src_a, st.src_b, self._Pd, self._Et,
                            self.Ci, bp, xc)
        out = np.empty(self.m)
        out[st.cam] = xc
        out[self._pcols] = xp.ravel()[self._pflat]
        return out
