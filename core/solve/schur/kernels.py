"""The pair loops of :class:`baarda.solve.schur.factor.SchurFactor` — scattering −Q_c E_c'ᵀ into
S and gathering Σ_{k_c k_c'} Q_c' over the pairs of clusters of one point (package docstring) —
each compiled kernel beside its numpy twin (the same formulas, chunked: ``backend="numpy"``),
and the kernels of the common case (one supernode per cluster, the square-root elimination
fused per point), whose reference is the general kernel and its twin.
"""

from __future__ import annotations

import numpy as np

from ..compiled import compiled, njit, prange
from .structure import Structure

#: Entries of the temporary arrays in one chunk of the numpy fallback.
CHUNK = 1 << 21


def find_block(bptr, bcol, g, h):
    """The place of block (g, h) in the block pattern of S (CSR over supernodes: bptr, bcol)."""
    lo, hi = bptr[g], bptr[g + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if bcol[mid] < h:
            lo = mid + 1
        else:
            hi = mid
    return lo


def _scatter_kernel(ent_ptr, ent_size, cl_sn, cl_off, sn_size, bptr, bcol, bstart, a, Pc, Q, E, S, U):
    """S += Σ_c a_cᵀP_c a_c − Σ_{c,c' ∈ j} Q_c E_c'ᵀ and U += Σ_c a_cᵀP_c a_c, blockwise."""
    G = cl_sn.shape[1]
    M = a.shape[1]
    for e in range(ent_ptr.size - 1):
        c0, c1 = ent_ptr[e], ent_ptr[e + 1]
        schur = ent_size[e] > 0
        for c in range(c0, c1):
            for s in range(G):
                g = cl_sn[c, s]
                if g < 0:
                    break
                ag, ng = cl_off[c, s], sn_size[g]
                for c2 in range(c0, c1):
                    if not schur and c2 != c:
                        continue
                    for t in range(G):
                        h = cl_sn[c2, t]
                        if h < 0:
                            break
                        bh, nh = cl_off[c2, t], sn_size[h]
                        base = bstart[find_block(bptr, bcol, g, h)]
                        if schur:
                            for i in range(ng):
                                for j in range(nh):
                                    y = (Q[c, ag + i, 0] * E[c2, bh + j, 0] + Q[c, ag + i, 1] * E[c2, bh + j, 1]
                                         + Q[c, ag + i, 2] * E[c2, bh + j, 2])
                                    S[base + i * nh + j] -= y
                        if c2 == c:
                            for i in range(ng):
                                for j in range(nh):
                                    v = 0.0
                                    for r in range(M):
                                        pa = 0.0
                                        for r2 in range(M):
                                            pa += Pc[c, r, r2] * a[c, r2, bh + j]
                                        v += a[c, r, ag + i] * pa
                                    S[base + i * nh + j] += v
                                    U[base + i * nh + j] += v


def _pairs(ent_ptr):
    """All ordered pairs (c, c') of cluster positions of one entity, c-major."""
    k = np.diff(ent_ptr)
    reps = np.repeat(k, k)                            # partners of each position
    c = np.repeat(np.arange(ent_ptr[-1], dtype=np.int64), reps)
    first = np.repeat(np.concatenate([[0], np.cumsum(reps)[:-1]]), reps)
    c2 = np.repeat(np.repeat(ent_ptr[:-1], k), reps) + (np.arange(c.size) - first)
    return c, c2


def _local_columns(st: Structure):
    """Per position and local camera column: supernode and offset in it (−1 padded)."""
    sn_size = np.diff(st.sn_ptr)
    nc = st.cl_sn.shape[0]
    col_sn = np.full((nc, st.K), -1, dtype=np.int64)
    col_off = np.zeros((nc, st.K), dtype=np.int64)
    for s in range(st.G):
        g = st.cl_sn[:, s]
        ok = g >= 0
        for i in range(int(sn_size.max(initial=0))):
            m = ok & (i < sn_size[np.maximum(g, 0)])
            p = np.flatnonzero(m)
            col_sn[p, st.cl_off[p, s] + i] = g[p]
            col_off[p, st.cl_off[p, s] + i] = i
    return col_sn, col_off


def _pair_positions(st, col_sn, col_off, c, c2):
    sn_size = np.diff(st.sn_ptr)
    nsn = sn_size.size
    gs, hs = col_sn[c][:, :, None], col_sn[c2][:, None, :]
    valid = (gs >= 0) & (hs >= 0)
    brow = np.repeat(np.arange(nsn, dtype=np.int64), np.diff(st.bptr))
    bkey = brow * nsn + st.bcol
    key = np.where(valid, gs * nsn + hs, 0)
    blk = np.minimum(np.searchsorted(bkey, key), bkey.size - 1)
    pos = st.bstart[blk] + col_off[c][:, :, None] * sn_size[np.maximum(hs, 0)] + col_off[c2][:, None, :]
    return np.where(valid, pos, 0), valid


def scatter_np(st, Ua, Q, E, nnz):
    col_sn, col_off = _local_columns(st)
    S = np.zeros(nnz)
    U = np.zeros(nnz)
    c, c2 = _pairs(st.ent_ptr)
    step = max(1, CHUNK // (st.K * st.K))
    for s in range(0, c.size, step):
        ci, cj = c[s:s + step], c2[s:s + step]
        pos, valid = _pair_positions(st, col_sn, col_off, ci, cj)
        Y = -np.einsum("pkq,plq->pkl", Q[ci], E[cj])
        Y[st.ent_size[st.cl_ent[ci]] == 0] = 0.0
        same = ci == cj
        Uv = np.where(same[:, None, None], Ua[ci], 0.0)
        S += np.bincount(pos[valid], weights=(Y + Uv)[valid], minlength=nnz)
        U += np.bincount(pos[valid], weights=Uv[valid], minlength=nnz)
    return S, U


def _gather_kernel(ent_ptr, ent_size, cl_sn, cl_off, sn_size, sn_t, bptr, bcol, bstart, Q, a,
               Sig, Sigt, Gc, SA, SAt):
    """G_c = −Σ_{c'} Σ_{k_c k_c'} Q_c', SA_c = Σ_{k_c k_c} a_cᵀ, SAt_c = Σt_{k_c k_c} a_cᵀ."""
    G = cl_sn.shape[1]
    M = a.shape[1]
    for e in range(ent_ptr.size - 1):
        c0, c1 = ent_ptr[e], ent_ptr[e + 1]
        schur = ent_size[e] > 0
        for c in range(c0, c1):
            for s in range(G):
                g = cl_sn[c, s]
                if g < 0:
                    break
                ag, ng = cl_off[c, s], sn_size[g]
                for c2 in range(c0, c1):
                    if not schur and c2 != c:
                        continue
                    for t in range(G):
                        h = cl_sn[c2, t]
                        if h < 0:
                            break
                        bh, nh = cl_off[c2, t], sn_size[h]
                        base = bstart[find_block(bptr, bcol, g, h)]
                        if schur:
                            for i in range(ng):
                                for j in range(nh):
                                    sg = Sig[base + i * nh + j]
                                    for q in range(3):
                                        Gc[c, ag + i, q] -= sg * Q[c2, bh + j, q]
                        if c2 == c:
                            tt = sn_t[g] and sn_t[h]
                            for i in range(ng):
                                for j in range(nh):
                                    sg = Sig[base + i * nh + j]
                                    st = Sigt[base + i * nh + j]
                                    for r in range(M):
                                        SA[c, ag + i, r] += sg * a[c, r, bh + j]
                                        if tt:
                                            SAt[c, ag + i, r] += st * a[c, r, bh + j]


def gather_np(st, Q, a, Sig, Sigt):
    col_sn, col_off = _local_columns(st)
    nc, M, K = a.shape
    sn_t = st.sn_t
    Gc = np.zeros((nc, K, 3))
    SA = np.zeros((nc, K, M))
    SAt = np.zeros((nc, K, M))
    c, c2 = _pairs(st.ent_ptr)
    step = max(1, CHUNK // (K * K))
    for s in range(0, c.size, step):
        ci, cj = c[s:s + step], c2[s:s + step]
        pos, valid = _pair_positions(st, col_sn, col_off, ci, cj)
        Sg = np.where(valid, Sig[pos], 0.0)
        contrib = -np.einsum("pkl,plq->pkq", Sg, Q[cj])
        contrib[st.ent_size[st.cl_ent[ci]] == 0] = 0.0
        np.add.at(Gc, ci, contrib)
        same = np.flatnonzero(ci == cj)
        if same.size:
            p = ci[same]
            SA[p] += np.einsum("pkl,pml->pkm", Sg[same], a[p])
            tt = valid[same] & sn_t[np.maximum(col_sn[p], 0)][:, :, None] & sn_t[np.maximum(col_sn[p], 0)][:, None, :]
            St = np.where(tt, Sigt[pos[same]], 0.0)
            SAt[p] += np.einsum("pkl,pml->pkm", St, a[p])
    return Gc, SA, SAt


# -- the common case, specialised: every cluster sees one supernode of n unknowns (the
# orientation of its image, with its camera constants when they are the image's own),
# and E = Q (the square-root elimination). Entities are split in chunks that run in parallel (prange), each scattering into
# its own copy of S (no races; the copies are summed in a fixed order, so the result does not
# depend on the thread count). Half the pairs suffice: Q_c' Q_cᵀ = (Q_c Q_c'ᵀ)ᵀ.
SCATTER_CHUNKS = 2


def _entity_blocks(data, src_a, src_b, Ri, Pc, diagonal, e, c0, c1, A_, B_, Q_, bc, pb):
    """For the clusters c0:c1 of entity e, from the design matrix's data (``src_a``, ``src_b``;
    0 where padded): A_[c − c0] = a_c, B_[c − c0] = b̃_c = b_c R_e⁻¹ and Q_[c − c0] = E_c =
    a_cᵀ P_c b̃_c — the products summed in the order of :func:`bmm`, so the numbers are those of
    the stacked arrays :class:`SchurFactor` makes on the other paths. bc, pb: (M, 3) scratch."""
    M = src_a.shape[1]
    K = src_a.shape[2]
    for c in range(c0, c1):
        m = c - c0
        for r in range(M):
            for i in range(K):
                k = src_a[c, r, i]
                A_[m, r, i] = data[k] if k >= 0 else 0.0
            for i in range(3):
                k = src_b[c, r, i]
                bc[r, i] = data[k] if k >= 0 else 0.0
        for r in range(M):
            for q in range(3):
                acc = 0.0
                for j in range(3):
                    acc += bc[r, j] * Ri[e, j, q]
                B_[m, r, q] = acc
        for r in range(M):
            for q in range(3):
                if diagonal:
                    pb[r, q] = Pc[c, r, r] * B_[m, r, q]
                else:
                    acc = 0.0
                    for j in range(M):
                        acc += Pc[c, r, j] * B_[m, j, q]
                    pb[r, q] = acc
        for i in range(K):
            for q in range(3):
                acc = 0.0
                for r in range(M):
                    acc += A_[m, r, i] * pb[r, q]
                Q_[m, i, q] = acc


def _scatter6_kernel(ent_ptr, ent_size, cl_sn, bptr, bcol, bstart, data, src_a, src_b, Ri, Pc, diagonal,
                     maxent, S_parts, U_parts):
    """S_parts[k] −= Σ_{c ≤ c' ∈ j} Q_c Q_c'ᵀ (and its transpose) and U_parts[k, g] +=
    a_cᵀ P_c a_c (the diagonal blocks of U = A_cᵀPA_c, per supernode g) for the entities of
    chunk k. a_c and Q_c = E_c are made per entity (:func:`_entity_blocks`): no stack of them
    over all clusters is held."""
    nchunk = S_parts.shape[0]
    ne = ent_ptr.size - 1
    M = src_a.shape[1]
    n = src_a.shape[2]
    for k in prange(nchunk):
        S = S_parts[k]
        A_ = np.empty((maxent, M, n))
        B_ = np.empty((maxent, M, 3))
        Q = np.empty((maxent, n, 3))
        bc = np.empty((M, 3))
        pb = np.empty((M, 3))
        for e in range(k * ne // nchunk, (k + 1) * ne // nchunk):
            c0, c1 = ent_ptr[e], ent_ptr[e + 1]
            _entity_blocks(data, src_a, src_b, Ri, Pc, diagonal, e, c0, c1, A_, B_, Q, bc, pb)
            for c in range(c0, c1):
                g = cl_sn[c, 0]
                for r in range(M):
                    for r2 in range(M):
                        p = Pc[c, r, r2]
                        if p == 0.0:
                            continue
                        for i in range(n):
                            pa = p * A_[c - c0, r, i]
                            for j in range(n):
                                U_parts[k, g, i * n + j] += pa * A_[c - c0, r2, j]
            if ent_size[e] == 0:
                continue
            for c in range(c0, c1):
                g = cl_sn[c, 0]
                for c2 in range(c, c1):
                    h = cl_sn[c2, 0]
                    b1 = bstart[find_block(bptr, bcol, g, h)]
                    b2 = bstart[find_block(bptr, bcol, h, g)]
                    for i in range(n):
                        q0, q1, q2 = Q[c - c0, i, 0], Q[c - c0, i, 1], Q[c - c0, i, 2]
                        for j in range(n):
                            y = q0 * Q[c2 - c0, j, 0] + q1 * Q[c2 - c0, j, 1] + q2 * Q[c2 - c0, j, 2]
                            S[b1 + i * n + j] -= y
                            if c2 != c:
                                S[b2 + j * n + i] -= y


def _hat6_kernel(ent_ptr, ent_size, cl_sn, sn_t, bptr, bcol, bstart, data, src_a, src_b, Ri, Pc, diagonal,
                 out, Sig, Sigt, H, Ht, Spp):
    """_gather_kernel for one supernode of n unknowns per cluster, fused with what follows it,
    per entity (in parallel): G_c = −Σ_c' Σ_{k_c k_c'} Q_c', Σ̃_pp = I − Σ_c Q_cᵀ G_c and the
    cluster blocks H_c = a Σ_kk aᵀ + a G b̃ᵀ + b̃ Gᵀ aᵀ + b̃ Σ̃_pp b̃ᵀ, Ht_c = a Σt_kk aᵀ (the formulas
    of :meth:`SchurFactor._selected`), written to H[out[c]], Ht[out[c]] (by cluster id). a_c, b̃_c,
    Q_c and G of an entity live in scratch memory of its own (:func:`_entity_blocks`)."""
    M = src_a.shape[1]
    n = src_a.shape[2]
    for e in prange(ent_ptr.size - 1):
        c0, c1 = ent_ptr[e], ent_ptr[e + 1]
        schur = ent_size[e] > 0
        a = np.empty((c1 - c0, M, n))
        b = np.empty((c1 - c0, M, 3))
        Q = np.empty((c1 - c0, n, 3))
        bc = np.empty((M, 3))
        pb = np.empty((M, 3))
        _entity_blocks(data, src_a, src_b, Ri, Pc, diagonal, e, c0, c1, a, b, Q, bc, pb)
        Gc = np.zeros((c1 - c0, n, 3))
        if schur:
            for c in range(c0, c1):
                g = cl_sn[c, 0]
                for c2 in range(c0, c1):
                    h = cl_sn[c2, 0]
                    base = bstart[find_block(bptr, bcol, g, h)]
                    for i in range(n):
                        s0 = 0.0
                        s1 = 0.0
                        s2 = 0.0
                        for j in range(n):
                            sg = Sig[base + i * n + j]
                            s0 += sg * Q[c2 - c0, j, 0]
                            s1 += sg * Q[c2 - c0, j, 1]
                            s2 += sg * Q[c2 - c0, j, 2]
                        Gc[c - c0, i, 0] -= s0
                        Gc[c - c0, i, 1] -= s1
                        Gc[c - c0, i, 2] -= s2
        for q in range(3):
            for q2 in range(3):
                acc = 1.0 if q == q2 else 0.0
                if schur:
                    for c in range(c0, c1):
                        for i in range(n):
                            acc -= Q[c - c0, i, q] * Gc[c - c0, i, q2]
                Spp[e, q, q2] = acc
        for c in range(c0, c1):
            m = c - c0
            g = cl_sn[c, 0]
            base = bstart[find_block(bptr, bcol, g, g)]
            tt = sn_t[g]
            o = out[c]
            for r in range(M):
                for r2 in range(M):
                    # a Σ_kk aᵀ and a Σt_kk aᵀ
                    hv = 0.0
                    ht = 0.0
                    for i in range(n):
                        sa = 0.0
                        st = 0.0
                        for j in range(n):
                            sa += Sig[base + i * n + j] * a[m, r2, j]
                            st += Sigt[base + i * n + j] * a[m, r2, j]
                        hv += a[m, r, i] * sa
                        if tt:
                            ht += a[m, r, i] * st
                    if schur:
                        for q in range(3):
                            f1 = 0.0
                            f2 = 0.0
                            for i in range(n):
                                f1 += a[m, r, i] * Gc[m, i, q]
                                f2 += a[m, r2, i] * Gc[m, i, q]
                            hv += f1 * b[m, r2, q] + f2 * b[m, r, q]
                            sb = 0.0
                            for q2 in range(3):
                                sb += Spp[e, q, q2] * b[m, r2, q2]
                            hv += b[m, r, q] * sb
                    H[o, r, r2] = hv
                    Ht[o, r, r2] = ht


def _E6_kernel(ent_ptr, data, src_a, src_b, Ri, Pc, diagonal, maxent, E):
    """E_c = a_cᵀ P_c b̃_c of every cluster position (:func:`_entity_blocks`), for the solves."""
    M = src_a.shape[1]
    n = src_a.shape[2]
    A_ = np.empty((maxent, M, n))
    B_ = np.empty((maxent, M, 3))
    bc = np.empty((M, 3))
    pb = np.empty((M, 3))
    for e in range(ent_ptr.size - 1):
        c0, c1 = ent_ptr[e], ent_ptr[e + 1]
        _entity_blocks(data, src_a, src_b, Ri, Pc, diagonal, e, c0, c1, A_, B_, E[c0:c1], bc, pb)


_KERNELS = {}


def compiled_kernels() -> dict:
    """The numba-compiled pair loops (compiled on first use, cached on disk): ``scatter``,
    ``gather`` (twins :func:`scatter_np`, :func:`gather_np`), ``scatter6``, ``hat6``, ``E6``."""
    if "scatter" not in _KERNELS:
        _KERNELS["scatter"] = njit(cache=True)(_scatter_kernel)
        _KERNELS["gather"] = njit(cache=True)(_gather_kernel)
        _KERNELS["scatter6"] = njit(cache=True, parallel=True)(_scatter6_kernel)
        _KERNELS["hat6"] = njit(cache=True, parallel=True)(_hat6_kernel)
        _KERNELS["E6"] = njit(cache=True)(_E6_kernel)
    return _KERNELS


def uniform6(st) -> bool:
    """Every cluster sees exactly one supernode, of K unknowns, at local column 0."""
    if st.G != 1 or st.cl_sn.size == 0:
        return False
    sn_size = np.diff(st.sn_ptr)
    used = st.cl_sn[:, 0]
    return bool((used >= 0).all() and (sn_size[used] == st.K).all() and (st.cl_off[:, 0] == 0).all())


# the kernels call these compiled helpers (numba resolves globals)
find_block = compiled(find_block, cache=True)
_entity_blocks = compiled(_entity_blocks, cache=True)
