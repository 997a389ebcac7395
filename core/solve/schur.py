"""Point elimination: the reduced camera system of bundle blocks and its selected inverse.

A bundle block has many point unknowns k in 3 × 3 blocks (2 × 2 or 1 × 1 where the datum holds
some coordinates) that no observation couples with each other: every image point, every control
point sees one point and some nuisance parameters t (orientations, APs; F80 eq. 1). Order the
unknowns as "cameras" c (all unknowns that are not eliminated) and points p:

.. math::

    N = \\begin{pmatrix} U & W \\\\ W^T & V \\end{pmatrix},\\quad
    V = \\operatorname{diag}(C_j),\\quad S = U - W V^{-1} W^T

(S the reduced camera system, the Schur complement of V). With Z_j = C_j⁻¹ W_jᵀ the blocks of
Σ = N⁻¹ are (the block inverse of N; TFC73 for S)

.. math::

    Σ_{cc} = S^{-1},\\quad Σ_{c p_j} = -Σ_{cc} Z_j^T,\\quad
    Σ_{p_j p_j} = C_j^{-1} + Z_j Σ_{cc} Z_j^T .

Z_j has non-zero columns only for the cameras K_j that observe point j, and every pair of them is
a non-zero block of S; so the selected inverse of S on its own pattern (Takahashi,
:class:`baarda.solve.linalg.SPDFactor`) gives every block that a_i Σ a_iᵀ of an observation of point j
needs. Per covariance cluster c (one image point, one control point) of point j, with a_c its
camera columns, b_c its point columns, P_c its weight, E_c = a_cᵀ P_c b_c and E_c C_j⁻¹ = Q_c:

    W_j = Σ_c E_c,           G_c = Σ_{k_c, p_j} = −Σ_{c' ∈ j} Σ_{k_c k_c'} Q_c',
    Σ_{p_j p_j} = C_j⁻¹ − Σ_c Q_cᵀ G_c,
    a_c Σ a_cᵀ (the cluster's block of A Σ Aᵀ) = a Σ_{kk} aᵀ + a G bᵀ + b Gᵀ aᵀ + b Σ_pp bᵀ.

The two loops over pairs of clusters of one point — scattering −Q_c E_c'ᵀ into S, and gathering
Σ_{k_c k_c'} Q_c' — are kernels compiled by numba when it is installed; a chunked numpy version
of the same formulas gives the same numbers to round-off (``backend="numpy"``).

Cameras are grouped into *supernodes*, columns that the same observation rows touch (the six
orientation unknowns of one image, the APs of one camera), and S is stored as dense blocks
between supernodes on the pattern of point-sharing (a block-sparse matrix). S is then factored by
:class:`baarda.solve.linalg.SPDFactor` (reverse Cuthill-McKee, block tridiagonal; a small or densely
connected S becomes one dense LAPACK Cholesky). Nothing larger than the band of S is ever dense;
:data:`DENSE_LIMIT` bounds the size of a dense S.

Solving N x = b goes through the same elimination: y_p = V⁻¹ b_p,
S x_c = b_c − W y_p, x_p = y_p − V⁻¹ Wᵀ x_c, with W applied as A_cᵀ P A_p (sparse products).

The nuisance split u_t (F80 eq. 16) needs (BᵀPB)⁻¹ over the nuisance columns B; that matrix is
U restricted to the nuisance supernodes (block diagonal per image without APs, coupled through
shared APs otherwise) and is factored and selected-inverted the same way.

Datum: eliminated points are whatever coordinates remain after the datum plan
(:mod:`baarda.datum`) holds d coordinates of S-base points: a point with a held coordinate simply
has a 2 × 2 or 1 × 1 block. The regularised system is the one the generic path solves, so x̂, the
generalised inverse and every statistic agree with it.

Reference: Takahashi, K., Fagan, J., Chen, M.-S. (1973), Formation of a sparse bus impedance
matrix and its application to short circuit study, PICA; Triggs, B. et al. (2000), Bundle
adjustment — a modern synthesis, §6.1 (reduced camera system).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import laplacian, reverse_cuthill_mckee
from scipy.sparse.linalg import eigsh

from ..errors import OptionError, SingularError
from ..model.problem import LazySequence, by_size, take
from .linalg import SPDFactor, block_partition

try:                       # optional: compiled pair loops
    import numba
except ImportError:        # pragma: no cover - exercised where numba is absent
    numba = None

#: Largest covariance cluster (observations) the padded per-cluster arrays accept.
MAX_CLUSTER = 6
#: Automatic choice: eliminate points when at least this many point unknowns ...
MIN_ELIMINATED = 2000
#: ... make up at least this share of the unknowns.
MIN_SHARE = 0.3
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
#: Entries of the temporary arrays in one chunk of the numpy fallback.
CHUNK = 1 << 21
BACKENDS = ("numba", "numpy")
#: the solvers :func:`schur_structure` chooses between
SOLVERS = ("auto", "schur", "generic")


def default_backend() -> str:
    return "numba" if numba is not None else "numpy"


def _canonical(A) -> sp.csr_matrix:
    A = sp.csr_matrix(A)
    if not A.has_canonical_format:
        A = A.copy()
        A.sum_duplicates()
    return A


# ------------------------------------------------------------------------------------------
# structure (pattern only, computed once per design-matrix pattern)
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Structure:
    """The elimination layout of one design-matrix pattern (see the module docstring).

    Positions p number the covariance clusters grouped by entity (an eliminated point, or a
    cluster that sees none); S indices number the camera unknowns supernode by supernode.
    """

    n: int
    u: int
    M: int                     # rows per cluster (padded)
    K: int                     # camera columns per cluster (padded)
    G: int                     # supernodes per cluster (padded)
    indptr: np.ndarray         # canonical pattern of the design matrix
    indices: np.ndarray
    cam: np.ndarray            # reduced index of each S index (n_c,)
    cam_pos: np.ndarray        # S index of each reduced unknown, −1 for eliminated (u,)
    sn_ptr: np.ndarray         # supernode g = S indices sn_ptr[g]:sn_ptr[g+1]
    sn_t: np.ndarray           # supernode of nuisance unknowns
    n_points: int              # entities 0..n_points−1 are points
    ent_ptr: np.ndarray        # positions of entity e: ent_ptr[e]:ent_ptr[e+1]
    ent_cols: np.ndarray       # (ne, 3) reduced indices of the point's coordinates, −1 padded
    ent_size: np.ndarray       # (ne,)
    cl_id: np.ndarray          # cluster id at position p
    cl_pos: np.ndarray         # position of each cluster id
    cl_ent: np.ndarray         # entity of position p
    cl_sn: np.ndarray          # (nc, G) supernodes of position p, −1 padded
    cl_off: np.ndarray         # (nc, G) their first local column
    cluster: np.ndarray        # cluster of each observation (n,)
    rpos: np.ndarray           # position of each observation within its cluster (n,)
    src_a: np.ndarray          # (nc, M, K) place in the design matrix's data of each entry of a, −1 padded
    src_b: np.ndarray          # (nc, M, 3) the same for b
    bptr: np.ndarray           # block pattern of S (CSR over supernodes)
    bcol: np.ndarray
    bstart: np.ndarray         # offset of each block in the flat value array (nblocks+1)
    flat_r: np.ndarray         # S row and column of each stored entry
    flat_c: np.ndarray
    labels: np.ndarray | None

    @property
    def n_eliminated(self) -> int:
        return int(self.ent_size[: self.n_points].sum())

    @property
    def n_cameras(self) -> int:
        return int(self.cam.size)

    def matches(self, Ar) -> bool:
        """Whether ``Ar`` has the pattern this structure was analysed for."""
        Ar = _canonical(Ar)
        return (Ar.shape == (self.n, self.u) and np.array_equal(Ar.indptr, self.indptr)
                and np.array_equal(Ar.indices, self.indices))

    def cluster_blocks(self, Ar) -> tuple[np.ndarray, np.ndarray]:
        """The entries of ``Ar`` (of this pattern) per cluster: a (clusters × M × K) on the
        camera side, b (clusters × M × 3) on the point side, zero-padded. (The compiled kernels
        of the common case read Ar's data through :attr:`src_a`, :attr:`src_b` instead: these
        padded copies are made only for the general kernels and the numpy fallback.)"""
        return self.gather(Ar.data, self.src_a), self.gather(Ar.data, self.src_b)

    @staticmethod
    def gather(data: np.ndarray, src: np.ndarray) -> np.ndarray:
        """data[src] with 0 where src is −1 (padding)."""
        out = np.take(data, src, mode="wrap")
        out[src < 0] = 0.0
        return out

    @cached_property
    def col_S(self) -> np.ndarray:
        """(nc, K) S index of each local camera column, −1 padded (made when first asked for: the
        kernels of the iterations read it off cl_sn and sn_ptr)."""
        sn_size = np.diff(self.sn_ptr)
        col_S = np.full((self.cl_sn.shape[0], self.K), -1, dtype=_index_dtype(self.cam.size))
        for s_ in range(self.G):                 # a cluster sees every column of its supernodes
            g = self.cl_sn[:, s_]
            for i in range(int(sn_size.max(initial=0))):
                p_ = np.flatnonzero((g >= 0) & (i < sn_size[np.maximum(g, 0)]))
                col_S[p_, self.cl_off[p_, s_] + i] = self.sn_ptr[g[p_]] + i
        return col_S

    def worthwhile(self) -> bool:
        """Whether elimination pays (the automatic choice of :func:`baarda.adjust.adjust`)."""
        return self.n_eliminated >= MIN_ELIMINATED and self.n_eliminated >= MIN_SHARE * self.u


def analyse(Ar, cov, kind: np.ndarray, point: np.ndarray, labels=None) -> Structure | None:
    """The elimination layout for design matrix ``Ar`` (n × u, reduced unknowns).

    kind: "k"/"t" per reduced unknown; point: its point index (−1 for none). A point is
    eliminated when no covariance cluster sees it together with another point. Returns None
    when the problem does not fit the padded layout (a cluster of more than
    :data:`MAX_CLUSTER` observations) or nothing would be eliminated.
    """
    Ar = _canonical(Ar)
    n, u = Ar.shape
    kind = np.asarray(kind)
    point = np.asarray(point, dtype=np.int64)
    cluster = np.asarray(cov.cluster, dtype=np.int64)
    ncl = len(cov.members)
    csize = np.bincount(cluster, minlength=ncl)
    M = int(csize.max(initial=1))
    if M > MAX_CLUSTER or n == 0 or u == 0:
        return None
    order = np.argsort(cluster, kind="stable")
    cstart = np.concatenate([[0], np.cumsum(csize)[:-1]])
    rpos = np.empty(n, dtype=np.int64)
    rpos[order] = np.arange(n) - cstart[cluster[order]]
    del order, cstart
    # (the per-entry temporaries below are made chunk by chunk of whole rows: _entries)

    # eliminable points: candidates seen by no cluster together with another point
    is_pt = (kind == "k") & (point >= 0)
    npt = int(point.max(initial=-1)) + 1
    keys = []
    for _, row, col in _entries(Ar):
        m = is_pt[col]
        key = cluster[row[m]]                     # clusters of the point entries only
        key *= max(npt, 1)
        key += point[col[m]]
        keys.append(_unique_sorted(key))
    key = _unique_sorted(np.concatenate(keys)) if keys else np.zeros(0, dtype=np.int64)
    del keys
    kc, kp = key // max(npt, 1), key % max(npt, 1)
    del key
    per_cl = np.bincount(kc, minlength=ncl)
    bad = np.zeros(max(npt, 1), dtype=bool)
    bad[kp[per_cl[kc] > 1]] = True
    elig = is_pt & ~bad[np.maximum(point, 0)]
    if not elig.any():
        return None
    pts = np.unique(point[elig])
    ent_of_point = np.full(max(npt, 1), -1, dtype=np.int64)
    ent_of_point[pts] = np.arange(pts.size)
    ecols = np.flatnonzero(elig)
    e_of = ent_of_point[point[ecols]]
    srt = np.lexsort((ecols, e_of))              # by entity, then unknown (x, y, z order)
    ecols, e_of = ecols[srt], e_of[srt]
    first = np.searchsorted(e_of, np.arange(pts.size))
    coord = np.arange(ecols.size) - first[e_of]
    if coord.max(initial=0) > 2:
        return None
    n_points = pts.size
    # entity of each cluster: its point, or an entity of its own
    cl_point_ent = np.full(ncl, -1, dtype=np.int64)
    sel = ~bad[kp]
    cl_point_ent[kc[sel]] = ent_of_point[kp[sel]]
    del kc, kp, sel, per_cl, bad, ent_of_point, pts
    alone = np.flatnonzero(cl_point_ent < 0)
    ent_of_cl = cl_point_ent.copy()
    ent_of_cl[alone] = n_points + np.arange(alone.size)
    ne = n_points + alone.size
    cl_id = np.argsort(ent_of_cl, kind="stable")
    cl_pos = np.empty(ncl, dtype=np.int64)
    cl_pos[cl_id] = np.arange(ncl)
    cl_ent = ent_of_cl[cl_id]
    ent_ptr = np.concatenate([[0], np.cumsum(np.bincount(cl_ent, minlength=ne))]).astype(np.int64)
    ent_cols = np.full((ne, 3), -1, dtype=np.int64)
    ent_cols[e_of, coord] = ecols
    del e_of, first, cl_point_ent, ent_of_cl
    ent_size = (ent_cols >= 0).sum(axis=1).astype(np.int64)

    # the point side (its places in b), and supernodes: camera columns touched by the same rows
    # (two random row hashes, summed chunk by chunk of whole rows: columns touched by the same
    # rows get the same chunk sums and so the same totals)
    camcols = np.flatnonzero(~elig)
    nnz = Ar.indices.size
    stype = _index_dtype(nnz + 1)
    coord_col = np.full(u, -1, dtype=np.int64)
    coord_col[ecols] = coord
    src_b = np.full(ncl * M * 3, -1, dtype=stype)
    rng = np.random.default_rng(12345)
    w1, w2 = rng.random(n), rng.random(n)
    del rng
    h1, h2, cnt = np.zeros(u), np.zeros(u), np.zeros(u, dtype=np.int64)
    for e0, row, col in _entries(Ar):
        cm = ~elig[col]
        rowb = row[~cm]
        dest_b = cl_pos[cluster[rowb]]
        dest_b *= M
        dest_b += rpos[rowb]
        dest_b *= 3
        dest_b += coord_col[col[~cm]]
        src_b[dest_b] = _positions(~cm, e0, stype)
        del rowb, dest_b
        colc, rowc = col[cm], row[cm]
        h1 += np.bincount(colc, weights=w1[rowc], minlength=u)
        h2 += np.bincount(colc, weights=w2[rowc], minlength=u)
        cnt += np.bincount(colc, minlength=u)
    src_b = src_b.reshape(ncl, M, 3)
    del w1, w2, coord_col
    h1, h2, cnt = h1[camcols], h2[camcols], cnt[camcols]
    tk = (kind[camcols] == "t").astype(float)
    _, grp = np.unique(np.stack([h1, h2, cnt.astype(float), tk], 1), axis=0, return_inverse=True)
    grp = grp.ravel()
    ngrp = int(grp.max(initial=-1)) + 1
    firstcol = np.full(ngrp, np.iinfo(np.int64).max)
    np.minimum.at(firstcol, grp, camcols)
    rank = np.empty(ngrp, dtype=np.int64)
    rank[np.argsort(firstcol)] = np.arange(ngrp)
    sn = rank[grp]
    o = np.lexsort((camcols, sn))
    cam = camcols[o]
    sn_sorted = sn[o]
    nsn = ngrp
    sn_size = np.bincount(sn_sorted, minlength=nsn).astype(np.int64)
    sn_ptr = np.concatenate([[0], np.cumsum(sn_size)]).astype(np.int64)
    cam_pos = np.full(u, -1, dtype=np.int64)
    cam_pos[cam] = np.arange(cam.size)
    sn_of = np.full(u, -1, dtype=np.int64)
    sn_of[cam] = sn_sorted
    off_of = np.full(u, -1, dtype=np.int64)
    off_of[cam] = np.arange(cam.size) - sn_ptr[sn_sorted]
    sn_t = np.zeros(nsn, dtype=bool)
    sn_t[sn_sorted] = kind[cam] == "t"
    del h1, h2, cnt, tk, grp, firstcol, rank, sn, o, sn_sorted

    # supernode slots of each cluster position
    nc = ncl
    # runs of camera entries of one row and one supernode (a row's entries make one run or a
    # few): the keys cluster position · nsn + supernode are made per run, not per entry
    sn_of_e = sn_of.astype(_index_dtype(max(nsn, 1)))
    del sn_of
    rkey, rlen, nrun = [], [], []
    for _, row, col in _entries(Ar):
        cm = ~elig[col]
        colc, rowc = col[cm], row[cm]
        sn_e = sn_of_e[colc]
        brk = np.ones(colc.size, dtype=bool)
        if brk.size:
            np.not_equal(rowc[1:], rowc[:-1], out=brk[1:])
            brk[1:] |= sn_e[1:] != sn_e[:-1]
        run = np.flatnonzero(brk)
        rkey.append(cl_pos[cluster[rowc[run]]] * max(nsn, 1) + sn_e[run])
        rlen.append(np.diff(np.r_[run, colc.size]))
        nrun.append(run.size)
    rkey = np.concatenate(rkey) if rkey else np.zeros(0, dtype=np.int64)
    rlen = np.concatenate(rlen) if rlen else np.zeros(0, dtype=np.int64)
    skey = _unique_sorted(rkey)
    sp_, sg = skey // max(nsn, 1), skey % max(nsn, 1)
    sfirst = np.searchsorted(sp_, np.arange(nc))
    slot = np.arange(skey.size) - sfirst[sp_]
    G = int(slot.max(initial=-1)) + 1
    G = max(G, 1)
    cl_sn = np.full((nc, G), -1, dtype=np.int64)
    cl_sn[sp_, slot] = sg
    sizes = np.where(cl_sn >= 0, sn_size[np.maximum(cl_sn, 0)], 0)
    cl_off = np.cumsum(sizes, axis=1) - sizes
    K = max(int(sizes.sum(axis=1).max(initial=0)), 1)
    # (position·M + rpos)·K + local, in place, in the narrowest type that holds nc·M·K
    itype = _index_dtype(nc * M * K)
    loc = np.searchsorted(skey, rkey)
    run_off = cl_off[sp_[loc], slot[loc]].astype(itype)
    del loc, rkey, skey, sp_, sg, sfirst, slot, sizes, sn_of_e
    pos_row = cl_pos.astype(itype)[cluster]
    rpos_t, off_t = rpos.astype(itype), off_of.astype(itype)
    src_a = np.full(nc * M * K, -1, dtype=stype)
    r0 = 0
    for (e0, row, col), k in zip(_entries(Ar), nrun):
        cm = ~elig[col]
        colc, rowc = col[cm], row[cm]
        local = np.repeat(run_off[r0:r0 + k], rlen[r0:r0 + k])
        r0 += k
        local += off_t[colc]
        dest_a = pos_row[rowc]
        dest_a *= M
        dest_a += rpos_t[rowc]
        dest_a *= K
        dest_a += local
        src_a[dest_a] = _positions(cm, e0, stype)
    src_a = src_a.reshape(nc, M, K)
    del run_off, rlen, pos_row, rpos_t, off_t
    rpos = _narrow(rpos, M)

    # block pattern of S: supernodes sharing an entity (plus the diagonal)
    valid = cl_sn >= 0
    er = np.repeat(cl_ent[:, None], G, axis=1)[valid]
    Inc = sp.csr_matrix((np.ones(er.size), (er, cl_sn[valid])), shape=(ne, nsn))
    Inc.data[:] = 1.0
    Pat = (Inc.T @ Inc + sp.identity(nsn, format="csr")).tocsr()
    Pat.sort_indices()
    bptr = Pat.indptr.astype(np.int64)
    bcol = Pat.indices.astype(np.int64)
    brow = np.repeat(np.arange(nsn, dtype=np.int64), np.diff(bptr))
    bsz = sn_size[brow] * sn_size[bcol]
    bstart = np.concatenate([[0], np.cumsum(bsz)]).astype(np.int64)
    # one entry per stored S value (camera count squared, not image points): int32 where it fits
    it = _index_dtype(max(int(bstart[-1]), bcol.size + 1))
    blk = np.repeat(np.arange(bcol.size, dtype=it), bsz)
    local = np.arange(int(bstart[-1]), dtype=it)
    local -= bstart.astype(it)[blk]
    wh = sn_size.astype(it)[bcol.astype(it)[blk]]
    flat_r = np.divmod(local, wh)
    flat_c = flat_r[1]
    flat_c += sn_ptr.astype(it)[bcol.astype(it)[blk]]
    flat_r = flat_r[0]
    flat_r += sn_ptr.astype(it)[brow.astype(it)[blk]]
    del blk, local, wh
    # the pattern is kept by reference (read-only views, no copy of the n·k indices); matches()
    # compares it with the next design matrix's
    return Structure(n=n, u=u, M=M, K=K, G=G, indptr=_readonly(Ar.indptr), indices=_readonly(Ar.indices),
                     cam=cam, cam_pos=cam_pos, sn_ptr=sn_ptr, sn_t=sn_t, n_points=n_points,
                     ent_ptr=ent_ptr, ent_cols=ent_cols, ent_size=ent_size, cl_id=cl_id,
                     cl_pos=cl_pos, cl_ent=cl_ent, cl_sn=cl_sn, cl_off=cl_off.astype(np.int64),
                     cluster=cluster, rpos=rpos, src_a=src_a, src_b=src_b, bptr=bptr,
                     bcol=bcol, bstart=bstart, flat_r=flat_r, flat_c=flat_c,
                     labels=None if labels is None or isinstance(labels, LazySequence) else np.asarray(labels))


def _entries(A: sp.csr_matrix, chunk: int = 1 << 21):
    """(e0, row, col) of runs of whole rows of ``A`` with about ``chunk`` entries each: the row
    and column of the entries e0, e0 + 1, ... (the per-entry temporaries of :func:`analyse` are
    a chunk's, not the whole matrix's: 4 bytes per entry and array)."""
    indptr, n = A.indptr, A.shape[0]
    rtype = _index_dtype(n)
    r0 = 0
    while r0 < n:
        e0 = int(indptr[r0])
        r1 = min(max(int(np.searchsorted(indptr, e0 + chunk, side="right")) - 1, r0 + 1), n)
        e1 = int(indptr[r1])
        yield e0, np.repeat(np.arange(r0, r1, dtype=rtype), np.diff(indptr[r0:r1 + 1])), A.indices[e0:e1]
        r0 = r1


def _positions(mask: np.ndarray, e0: int, dtype) -> np.ndarray:
    """The places e0 + k in the design matrix's data of the True entries k of ``mask``."""
    idx = np.flatnonzero(mask).astype(dtype)
    idx += e0
    return idx


def _index_dtype(top: int):
    """int32 for indices below ``top`` when they fit (half the memory of int64), else int64."""
    return np.int32 if top < np.iinfo(np.int32).max else np.int64


def _narrow(a: np.ndarray, top: int) -> np.ndarray:
    """``a`` (values in [0, top)) as :func:`_index_dtype` (top)."""
    dt = _index_dtype(top)
    return a if a.dtype == dt else a.astype(dt)


def _readonly(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.setflags(write=False)
    return v


def _unique_sorted(key: np.ndarray) -> np.ndarray:
    """Sorted unique values (runs removed first: the keys of one row repeat)."""
    if key.size:
        key = key[np.r_[True, key[1:] != key[:-1]]]
    key = np.sort(key)
    return key[np.r_[True, key[1:] != key[:-1]]] if key.size else key


# ------------------------------------------------------------------------------------------
# pair kernels (pure Python source, compiled by numba when available)
# ------------------------------------------------------------------------------------------
def _find_block(bptr, bcol, g, h):
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
                        base = bstart[_find_block(bptr, bcol, g, h)]
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
                        base = bstart[_find_block(bptr, bcol, g, h)]
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
    for k in numba.prange(nchunk):
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
                    b1 = bstart[_find_block(bptr, bcol, g, h)]
                    b2 = bstart[_find_block(bptr, bcol, h, g)]
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
    for e in numba.prange(ent_ptr.size - 1):
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
                    base = bstart[_find_block(bptr, bcol, g, h)]
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
            base = bstart[_find_block(bptr, bcol, g, g)]
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


def _kernels():
    """The numba-compiled pair loops (compiled on first use, cached on disk)."""
    if "scatter" not in _KERNELS:
        _KERNELS["scatter"] = numba.njit(cache=True)(_scatter_kernel)
        _KERNELS["gather"] = numba.njit(cache=True)(_gather_kernel)
        _KERNELS["scatter6"] = numba.njit(cache=True, parallel=True)(_scatter6_kernel)
        _KERNELS["hat6"] = numba.njit(cache=True, parallel=True)(_hat6_kernel)
        _KERNELS["E6"] = numba.njit(cache=True)(_E6_kernel)
    return _KERNELS


def _uniform6(st) -> bool:
    """Every cluster sees exactly one supernode, of K unknowns, at local column 0."""
    if st.G != 1 or st.cl_sn.size == 0:
        return False
    sn_size = np.diff(st.sn_ptr)
    used = st.cl_sn[:, 0]
    return bool((used >= 0).all() and (sn_size[used] == st.K).all() and (st.cl_off[:, 0] == 0).all())


if numba is not None:       # the kernels call these compiled helpers (numba resolves globals)
    _find_block = numba.njit(cache=True)(_find_block)
    _entity_blocks = numba.njit(cache=True)(_entity_blocks)


# ------------------------------------------------------------------------------------------
# numpy fallback of the pair loops (same formulas, chunked)
# ------------------------------------------------------------------------------------------
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


def _scatter_np(st, Ua, Q, E, nnz):
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


def _gather_np(st, Q, a, Sig, Sigt):
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


# ------------------------------------------------------------------------------------------
# small dense helpers
# ------------------------------------------------------------------------------------------
def _givens_kernel(Bw, ent_ptr, extra, R):
    """R_e of the rows of entity e (whitened cluster rows, then the rows diag(extra_e)), one
    Givens rotation per non-zero: the upper triangular factor of a QR decomposition."""
    M = Bw.shape[1]
    for e in numba.prange(ent_ptr.size - 1):
        r00 = r01 = r02 = r11 = r12 = r22 = 0.0
        last = ent_ptr[e + 1] * M
        for k in range(ent_ptr[e] * M, last + 3):
            if k < last:
                v0, v1, v2 = Bw[k // M, k % M, 0], Bw[k // M, k % M, 1], Bw[k // M, k % M, 2]
            else:
                v0 = extra[e, 0] if k == last else 0.0
                v1 = extra[e, 1] if k == last + 1 else 0.0
                v2 = extra[e, 2] if k == last + 2 else 0.0
            if v0 != 0.0:
                rr = np.hypot(r00, v0)
                cs, sn = r00 / rr, v0 / rr
                r00 = rr
                t = cs * r01 + sn * v1
                v1 = cs * v1 - sn * r01
                r01 = t
                t = cs * r02 + sn * v2
                v2 = cs * v2 - sn * r02
                r02 = t
            if v1 != 0.0:
                rr = np.hypot(r11, v1)
                cs, sn = r11 / rr, v1 / rr
                r11 = rr
                t = cs * r12 + sn * v2
                v2 = cs * v2 - sn * r12
                r12 = t
            if v2 != 0.0:
                r22 = np.hypot(r22, v2)
        R[e, 0, 0], R[e, 0, 1], R[e, 0, 2] = r00, r01, r02
        R[e, 1, 1], R[e, 1, 2], R[e, 2, 2] = r11, r12, r22


def _point_roots(b: np.ndarray, Pc: np.ndarray, ent_ptr: np.ndarray, ent_size: np.ndarray,
                 damping: float, tol: float, backend: str = "numpy", diagonal: bool | None = None):
    """Square roots R_j (upper triangular, C_j = R_jᵀR_j) of the point blocks, from a QR
    decomposition of each point's whitened rows — never from C_j itself.

    A point near infinity has a 3 × 3 block of condition 1e12 (its depth along the rays is
    hardly determined): a Cholesky factor of C_j loses ε·cond(C_j) ≈ 1e-4 of its weakest
    direction, and every product E C_j⁻¹ Eᵀ of the elimination loses as much to cancellation
    (r_i < 0 came out). The QR of the whitened rows [L_cᵀ b_c; √(λ diag C_j)] loses only
    ε·cond(B_j) = ε·√cond(C_j), and with p̃ = R_j p as the point unknowns the point blocks are the
    identity, so no product in the elimination is formed through C_j⁻¹ (the "square-root"
    elimination: Demmel, N. et al. (2021), Square root bundle adjustment for large-scale
    reconstruction, CVPR). Givens rotations row by row (numba) or stacked Householder QR per
    track length (numpy) give the same R to round-off.

    A padded coordinate gets a unit row, ``damping`` λ adds the rows √(λ C_ii) of
    Levenberg-Marquardt. Returns (R, bad, dC): bad the first coordinate whose pivot
    R_ii² ≤ tol · C_ii (−1 where all pass), dC the diagonals of C_j (padded: 1).
    """
    nc, M, _ = b.shape
    ne = ent_size.size
    eyeM = np.eye(M)
    d = np.diagonal(Pc, axis1=1, axis2=2)
    if diagonal is None:
        diagonal = M == 1 or not np.any(Pc - d[:, :, None] * eyeM)
    if diagonal:                                                # uncorrelated rows: √p_r
        Bw = np.sqrt(np.maximum(d, 0.0))[:, :, None] * b
    else:
        L = np.linalg.cholesky(Pc + eyeM * (d <= 0)[:, None, :])       # padded rows: unit weight
        Bw = np.matmul(_T(L), b)                                      # whitened rows (nc, M, 3)
    pad = np.arange(3)[None, :] >= ent_size[:, None]
    dC = _segment_sum((Bw * Bw).sum(axis=1), ent_ptr)                 # diag C_j = Σ rows²
    dC[pad] = 1.0
    extra = np.where(pad, 1.0, np.sqrt(damping * np.maximum(dC, 0.0)))  # (ne, 3)
    R = np.zeros((ne, 3, 3))
    if backend == "numba" and numba is not None:
        if "givens" not in _KERNELS:
            _KERNELS["givens"] = numba.njit(cache=True, parallel=True)(_givens_kernel)
        _KERNELS["givens"](np.ascontiguousarray(Bw), ent_ptr, extra, R)
    else:
        count = np.diff(ent_ptr)
        for n in np.unique(count):
            ents = np.flatnonzero(count == n)
            pos = ent_ptr[ents][:, None] + np.arange(n)[None, :]
            X = np.concatenate([Bw[pos].reshape(ents.size, n * M, 3),
                                extra[ents][:, :, None] * np.eye(3)[None]], axis=1)
            R[ents] = np.linalg.qr(X, mode="r")[:, :3, :]
        sign = np.where(np.diagonal(R, axis1=1, axis2=2) < 0, -1.0, 1.0)
        R *= sign[:, :, None]                                         # positive diagonal
    piv = np.diagonal(R, axis1=1, axis2=2) ** 2
    fail = ~(piv > tol * np.where(pad, 1.0, np.maximum(dC, 1e-300)))
    bad = np.where(fail.any(axis=1), fail.argmax(axis=1), -1)
    return R, bad, dC


def _upper3_inverse(R: np.ndarray) -> np.ndarray:
    """Inverses of a stack of upper triangular 3 × 3 matrices by back-substitution."""
    Ri = np.zeros_like(R)
    d = np.diagonal(R, axis1=1, axis2=2)
    Ri[:, 0, 0], Ri[:, 1, 1], Ri[:, 2, 2] = 1.0 / d[:, 0], 1.0 / d[:, 1], 1.0 / d[:, 2]
    Ri[:, 0, 1] = -R[:, 0, 1] * Ri[:, 1, 1] / d[:, 0]
    Ri[:, 1, 2] = -R[:, 1, 2] * Ri[:, 2, 2] / d[:, 1]
    Ri[:, 0, 2] = -(R[:, 0, 1] * Ri[:, 1, 2] + R[:, 0, 2] * Ri[:, 2, 2]) / d[:, 0]
    return Ri


def _T(X: np.ndarray) -> np.ndarray:
    return np.swapaxes(X, 1, 2)


def _bmm_loops(X, Y, out):
    """out[p] = X[p] @ Y[p] (pure loops, compiled by numba)."""
    for p in range(X.shape[0]):
        for i in range(X.shape[1]):
            for k in range(Y.shape[2]):
                acc = 0.0
                for j in range(X.shape[2]):
                    acc += X[p, i, j] * Y[p, j, k]
                out[p, i, k] = acc


def bmm(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """X[p] @ Y[p] for stacks of small matrices: compiled loops when numba is installed (numpy's
    stacked matmul pays a call per tiny matrix), numpy's matmul otherwise."""
    if numba is None:
        return np.matmul(X, Y)
    if "bmm" not in _KERNELS:
        _KERNELS["bmm"] = numba.njit(cache=True)(_bmm_loops)
    out = np.empty((X.shape[0], X.shape[1], Y.shape[2]))
    _KERNELS["bmm"](X, Y, out)
    return out


def _segment_sum(X: np.ndarray, ptr: np.ndarray) -> np.ndarray:
    """Sums of X over consecutive segments ptr[e]:ptr[e+1] (empty segments give 0)."""
    ne = ptr.size - 1
    out = np.zeros((ne,) + X.shape[1:])
    nonempty = np.flatnonzero(np.diff(ptr) > 0)
    if nonempty.size:
        out[nonempty] = np.add.reduceat(X, ptr[:-1][nonempty], axis=0)
    return out


def _partition_cost(Smat, perm) -> float:
    """Flops (∝ Σ s_K³) of the block-tridiagonal factor of S in the order ``perm``."""
    ip = np.empty_like(perm)
    ip[perm] = np.arange(perm.size)
    C = Smat.tocoo()
    size = np.diff(block_partition(ip[C.row], ip[C.col], perm.size))
    return float((size.astype(float) ** 3).sum())


def _order(Smat, st) -> np.ndarray:
    """Order of S for the block-tridiagonal factor: reverse Cuthill-McKee, or the spectral order
    of the supernode graph (sorted Fiedler vector; Barnard, Pothen & Simon 1995) when its blocks
    are cheaper — strip blocks are ordered along the block rather than in RCM's diagonal fronts.
    It depends on the pattern only, so it is computed once per structure."""
    order = st.__dict__.get("_order")
    if order is None:
        order = _compute_order(Smat, st)
        st.__dict__["_order"] = order
    return order


def _compute_order(Smat, st) -> np.ndarray:
    rcm = np.asarray(reverse_cuthill_mckee(Smat, symmetric_mode=True), dtype=np.int64)
    nsn = st.sn_t.size
    if nsn < 50:
        return rcm
    Pat = sp.csr_matrix((np.ones(st.bcol.size), st.bcol, st.bptr), shape=(nsn, nsn))
    try:
        vals, vecs = eigsh(laplacian(Pat) + 1e-8 * sp.identity(nsn), k=2, sigma=-1e-3, which="LM")
    except Exception:          # no convergence: keep RCM
        return rcm
    fiedler = vecs[:, np.argsort(vals)[1]]
    sn_order = np.argsort(fiedler, kind="stable")
    size = np.diff(st.sn_ptr)
    spec = (np.repeat(st.sn_ptr[sn_order], size[sn_order])
            + np.arange(st.sn_ptr[-1]) - np.repeat(np.cumsum(size[sn_order]) - size[sn_order], size[sn_order]))
    return spec if _partition_cost(Smat, spec) < _partition_cost(Smat, rcm) else rcm


class _Permuted:
    """A factor kept in another order: unknown k of the caller is unknown perm[k] of the factor."""

    def __init__(self, factor: SPDFactor, perm: np.ndarray):
        self.factor, self.perm, self.m = factor, perm, perm.size

    def solve(self, b):
        b = np.asarray(b, dtype=float)
        y = np.empty_like(b)
        y[self.perm] = b
        return self.factor.solve(y)[self.perm]


# ------------------------------------------------------------------------------------------
# numeric factor
# ------------------------------------------------------------------------------------------
def _weights(st: Structure, P):
    """(P as CSR, the weights P_c of every cluster position (nc, M, M), whether every P_c is
    diagonal). They depend on P only: kept with the structure for the next factor of the same P
    (every iteration, the reliability at the solution)."""
    cached = st.__dict__.get("_weights")
    if cached is not None and cached[0] is P:
        return cached[1:]
    Pcsr = sp.csr_matrix(P)
    Pc = SchurFactor._cluster_weights(st, Pcsr)
    Pd = np.diagonal(Pc, axis1=1, axis2=2)
    diagonal = bool(st.M == 1 or not np.any(Pc - Pd[:, :, None] * np.eye(st.M)))
    st.__dict__["_weights"] = (P, Pcsr, Pc, diagonal)
    return Pcsr, Pc, diagonal


class SchurFactor:
    """N = AᵀPA factored through the reduced camera system (module docstring).

    Has the interface of :class:`baarda.solve.linalg.SPDFactor` (``m``, ``solve``, ``entries``,
    ``logdet``, ``dense_inverse``) plus the blocks reliability needs (:meth:`hat_blocks`).
    Raises SingularError naming an unknown the observations do not determine.
    """

    def __init__(self, st: Structure, Ar, P, backend: str | None = None, pivot_tol: float = PIVOT_TOL,
                 damping: float = 0.0):
        Ar = _canonical(Ar)
        if not st.matches(Ar):
            raise ValueError("design matrix pattern differs from the analysed structure")
        self.backend = backend or default_backend()
        if self.backend not in BACKENDS or (self.backend == "numba" and numba is None):
            raise OptionError("backend", self.backend, BACKENDS, f"backend {self.backend!r} not available")
        self.st, self.m, self.labels = st, st.u, st.labels
        K = st.K
        # the common case (numba, one supernode per cluster) reads a_c, b_c from Ar's data in its
        # kernels and makes b̃_c and E_c per point (:func:`_entity_blocks`): no stack of a, b, b̃
        # or E over all clusters is held (216 + 192 bytes per image point of a bundle block);
        # E is made for the solves only when one is asked for (:attr:`E`). The other paths
        # keep the padded stacks a, b̃ and E.
        self.fused = self.backend == "numba" and _uniform6(st)
        self._data = Ar.data if self.fused else None
        self._E = None
        if self.fused:
            self.a = self.b = None
            b = st.gather(Ar.data, st.src_b)           # (for the point roots only)
        else:
            self.a, b = st.cluster_blocks(Ar)
        self.P, Pc, diagonal = _weights(st, P)
        self.Pc, self._diagonal_P = Pc, diagonal
        R, bad, dC = _point_roots(b, Pc, st.ent_ptr, st.ent_size, damping,
                                  min(pivot_tol, POINT_PIVOT_TOL), self.backend, diagonal)
        if (bad >= 0).any():
            e = int(np.flatnonzero(bad >= 0)[0])
            raise self._singular(int(st.ent_cols[e, bad[e]]))
        # point unknowns p̃ = R_j p: the point blocks become I, b_c becomes b_c R_j⁻¹
        self.R, self.Ri = R, _upper3_inverse(R)
        if self.fused:
            del b
        else:
            self.b = bmm(b, self.Ri[st.cl_ent])
            del b
            Pb = np.diagonal(Pc, axis1=1, axis2=2)[:, :, None] * self.b if diagonal else bmm(Pc, self.b)
            self._E = bmm(_T(self.a), Pb)          # E_c = a_cᵀ P_c b̃_c (= Q_c: C̃ = I)
            del Pb
        nnz = int(st.bstart[-1])
        sn_size = np.diff(st.sn_ptr)
        if self.fused:
            S_parts = np.zeros((SCATTER_CHUNKS, nnz))
            n_sn = st.sn_ptr.size - 1
            U_parts = np.zeros((SCATTER_CHUNKS, n_sn, K * K))
            _kernels()["scatter6"](st.ent_ptr, st.ent_size, st.cl_sn, st.bptr, st.bcol, st.bstart,
                                   Ar.data, st.src_a, st.src_b, self.Ri, Pc, diagonal, self._maxent(),
                                   S_parts, U_parts)
            # U = Σ_c a_cᵀ P_c a_c: diagonal blocks only, one per supernode
            used = np.unique(st.cl_sn[:, 0])
            diag_pos = np.array([st.bstart[_find_block(st.bptr, st.bcol, int(x), int(x))] for x in used],
                                dtype=np.int64)
            U = np.zeros(nnz)
            U[(diag_pos[:, None] + np.arange(K * K)[None, :]).ravel()] = U_parts.sum(axis=0)[used].ravel()
            S = S_parts.sum(axis=0) + U
        elif self.backend == "numba":
            S, U = np.zeros(nnz), np.zeros(nnz)
            _kernels()["scatter"](st.ent_ptr, st.ent_size, st.cl_sn, st.cl_off, sn_size, st.bptr,
                                  st.bcol, st.bstart, self.a, Pc, self._E, self._E, S, U)
        else:
            Ua = np.matmul(_T(self.a), np.matmul(Pc, self.a))
            S, U = _scatter_np(st, Ua, self._E, self._E, nnz)
        if damping:
            dsel0 = st.flat_r == st.flat_c
            S = S.copy()
            S[dsel0] += damping * U[dsel0]
        self.Svals, self.Uvals = S, U
        nc_ = st.cam.size
        Smat = sp.csr_matrix((S, (st.flat_r, st.flat_c)), shape=(nc_, nc_))
        self._check_dense(Smat)
        try:
            self.S = SPDFactor(Smat, labels=None if st.labels is None else st.labels[st.cam],
                               pivot_tol=pivot_tol, perm=_order(Smat, st))
        except SingularError as err:
            raise self._singular(int(st.cam[err.index])) from None
        self.bandwidth = getattr(self.S, "bandwidth", 0)
        diag = np.empty(st.u)
        dsel = st.flat_r == st.flat_c
        diag[st.cam[st.flat_r[dsel]]] = U[dsel]
        okc = st.ent_cols >= 0
        diag[st.ent_cols[okc]] = dC[okc]
        self.diagonal = diag
        pflat = np.flatnonzero(st.ent_cols.ravel() >= 0)
        self._pflat, self._pcols = pflat, st.ent_cols.ravel()[pflat]
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
        _kernels()["E6"](st.ent_ptr, self._data, st.src_a, st.src_b, self.Ri, self.Pc,
                         self._diagonal_P, self._maxent(), E)
        if E.nbytes <= KEEP_E_BYTES:
            self._E = E
        return E

    @staticmethod
    def _cluster_weights(st, P):
        """P_c of every cluster position, (nc, M, M); P must be block diagonal by clusters."""
        P = sp.csr_matrix(P)
        if not P.has_canonical_format:
            P = P.copy()
            P.sum_duplicates()
        C = P.tocoo()
        p = st.cl_pos[st.cluster[C.row]]
        if not np.array_equal(p, st.cl_pos[st.cluster[C.col]]):
            raise ValueError("weight matrix couples observations of different clusters")
        Pc = np.zeros(st.cl_id.size * st.M * st.M)
        Pc[(p * st.M + st.rpos[C.row]) * st.M + st.rpos[C.col]] = C.data   # canonical: no duplicates
        return Pc.reshape(-1, st.M, st.M)

    def _singular(self, col):
        name = self.labels[col] if self.labels is not None else f"unknown {col}"
        return SingularError(unknown=name, index=col)

    def _check_dense(self, Smat):
        nc_ = Smat.shape[0]
        if nc_ <= DENSE_LIMIT:
            return
        perm = reverse_cuthill_mckee(Smat, symmetric_mode=True)
        iperm = np.empty_like(perm)
        iperm[perm] = np.arange(nc_)
        Cm = Smat.tocoo()
        band = int(np.abs(iperm[Cm.row] - iperm[Cm.col]).max(initial=0))
        if 2 * band >= nc_:
            raise MemoryError(f"the reduced camera system ({nc_} unknowns) has a band of {band}: "
                              f"its factor would be dense beyond DENSE_LIMIT = {DENSE_LIMIT}")

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
        yp = bmm(_T(self.Ri), bp.reshape(ne, 3, q))             # Ṽ⁻¹ b̃_p = R⁻ᵀ b_p  (ne, 3, q)
        E = self.E
        Wy = bmm(E, yp[st.cl_ent]).reshape(-1, q)                 # E_c y_e(c)  (nc·K, q)
        cols = st.col_S.ravel()
        ok = cols >= 0
        rhs = B[st.cam].copy()
        for j in range(q):
            rhs[:, j] -= np.bincount(cols[ok], weights=Wy[ok, j], minlength=st.cam.size)
        xc = self.S.solve(rhs).reshape(-1, q)
        xk = np.where(ok[:, None], xc[np.maximum(cols, 0)], 0.0).reshape(-1, st.K, q)
        t = _segment_sum(bmm(_T(E), xk), st.ent_ptr)            # W_jᵀ x_c  (ne, 3, q)
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
        """Σ and Σ_t on the block pattern of S, and the per-cluster blocks (module docstring)."""
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
            self._nuisance = _Permuted(T, np.argsort(red))
        nc, M, K = st.cl_id.size, st.M, st.K
        sn_size = np.diff(st.sn_ptr)
        if self.fused:
            # H, Ht by cluster id (the order of :meth:`hat_blocks` when all clusters have M rows:
            # the result takes them without a copy)
            H, Ht = np.empty((nc, M, M)), np.empty((nc, M, M))
            Spp = np.empty((st.ent_size.size, 3, 3))
            _kernels()["hat6"](st.ent_ptr, st.ent_size, st.cl_sn, st.sn_t, st.bptr, st.bcol, st.bstart,
                               self._data, st.src_a, st.src_b, self.Ri, self.Pc, self._diagonal_P, st.cl_id,
                               Sig, Sigt, H, Ht, Spp)
            self._blocks = (H, Ht, bmm(bmm(self.Ri, Spp), _T(self.Ri)), True)   # Σ_pp = R⁻¹ Σ̃ R⁻ᵀ
            return self._blocks
        Q = self._E
        if self.backend == "numba":
            Gc, SA, SAt = np.zeros((nc, K, 3)), np.zeros((nc, K, M)), np.zeros((nc, K, M))
            _kernels()["gather"](st.ent_ptr, st.ent_size, st.cl_sn, st.cl_off, sn_size, st.sn_t, st.bptr,
                                 st.bcol, st.bstart, Q, self.a, Sig, Sigt, Gc, SA, SAt)
        else:
            Gc, SA, SAt = _gather_np(st, Q, self.a, Sig, Sigt)
        a, b = self.a, self.b
        F = bmm(a, Gc)                                        # a_c Σ_{k_c p}  (nc, M, 3)
        I3 = np.broadcast_to(np.eye(3), (st.ent_size.size, 3, 3))
        Spp = I3 - _segment_sum(bmm(_T(Q), Gc), st.ent_ptr)      # Σ of p̃ (C̃ = I)
        FbT = bmm(F, _T(b))
        H = bmm(a, SA) + FbT + _T(FbT) + bmm(bmm(b, Spp[st.cl_ent]), _T(b))
        Ht = bmm(a, SAt)
        self._blocks = (H, Ht, bmm(bmm(self.Ri, Spp), _T(self.Ri)), False)   # (by cluster position)
        self.a = self.b = None             # only these blocks needed them (solve uses E and R)
        return self._blocks

    def hat_blocks(self, cov):
        """a_i Σ a_jᵀ and a_i Σ_t a_jᵀ (nuisance part) for all pairs within each covariance
        cluster, laid out as :func:`baarda.result.cluster_pairs` lays them out. When the factor's
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


# ------------------------------------------------------------------------------------------
# the step of one iteration: a fused compiled pass (no selected inverse, no reliability blocks)
# ------------------------------------------------------------------------------------------
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
    """One pass over the entities for N + λ diag(N) (the module docstring's formulas in normal-
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
                b1 = bstart[_find_block(bptr, bcol, min(g, h), max(g, h))]
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
            b2 = bstart[_find_block(bptr, bcol, h, g)]
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


if numba is not None:
    _load_cluster = numba.njit(cache=True)(_load_cluster)
    _mirror_blocks = numba.njit(cache=True)(_mirror_blocks)
    _cluster_E = numba.njit(cache=True)(_cluster_E)
    _stored_E = numba.njit(cache=True)(_stored_E)


def _step_kernels():
    if "step" not in _KERNELS:
        _KERNELS["step"] = numba.njit(cache=True)(_step_factor_kernel)
        _KERNELS["step_solve"] = numba.njit(cache=True)(_step_solve_kernel)
        _KERNELS["step_back"] = numba.njit(cache=True)(_step_back_kernel)
    return _KERNELS


class StepFactor:
    """N + λ diag(N) factored for the step of one iteration of :func:`baarda.adjust.adjust`:
    the same reduced camera system as :class:`SchurFactor`, by one fused compiled pass over the
    points in normal-equation form (3 × 3 point blocks by an equilibrated Cholesky factor), and
    nothing of what reliability needs (no square-root elimination, no selected inverse).

    For blocks whose every cluster sees one supernode (:func:`_uniform6`: an image's pose with
    its camera's constants) and a diagonal weight per cluster, with numba (:meth:`applicable`);
    otherwise :class:`SchurFactor` takes the step (and it stays the reference: the same steps,
    tests/test_adjust.py). Interface: ``solve``, ``diagonal`` (undamped diag(N)), ``m``.
    """

    def __init__(self, st: Structure, Ar, P, damping: float = 0.0, pivot_tol: float = PIVOT_TOL):
        Ar = _canonical(Ar)
        if not st.matches(Ar):
            raise ValueError("design matrix pattern differs from the analysed structure")
        self.st, self.m, self.labels = st, st.u, st.labels
        K = st.K
        Pd = self.cluster_diagonal(st, P)
        nsn = st.sn_ptr.size - 1
        sn_diag = st.__dict__.get("_sn_diag")
        if sn_diag is None:
            sn_diag = np.array([_find_block(st.bptr, st.bcol, g, g) for g in range(nsn)], dtype=np.int64)
            st.__dict__["_sn_diag"] = sn_diag
        ne = st.ent_size.size
        S = np.zeros(int(st.bstart[-1]))
        maxent = int(np.diff(st.ent_ptr).max(initial=1))
        nc = st.cl_sn.shape[0]
        keep = nc * K * 3 * 8 <= KEEP_E_BYTES              # every E_c, or one entity's at a time
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
            raise self._singular(int(st.ent_cols[e, bad[e]]))
        diag_c = self._camera_diagonal(st, dU)              # diag(U) by S index
        if damping:
            dsel = st.flat_r == st.flat_c
            S[dsel] += damping * diag_c[st.flat_r[dsel]]
        self.Ci, self._data, self._Pd = Ci, Ar.data, Pd
        self._Et = Et if keep else np.zeros((0, 3, K))     # (else E_c is made again by the solves)
        del Et, Z
        nc_ = st.cam.size
        Smat = sp.csr_matrix((S, (st.flat_r, st.flat_c)), shape=(nc_, nc_))
        try:
            self.S = SPDFactor(Smat, labels=None if st.labels is None else st.labels[st.cam],
                               pivot_tol=pivot_tol, perm=_order(Smat, st))
        except SingularError as err:
            raise self._singular(int(st.cam[err.index])) from None
        diag = np.empty(st.u)
        diag[st.cam] = diag_c
        okc = st.ent_cols >= 0
        diag[st.ent_cols[okc]] = dC[okc]
        self.diagonal = diag
        pflat = np.flatnonzero(st.ent_cols.ravel() >= 0)
        self._pflat, self._pcols = pflat, st.ent_cols.ravel()[pflat]

    @staticmethod
    def applicable(st: Structure, P) -> bool:
        """numba is there, every cluster sees one supernode, and P is diagonal (the answer kept
        with the structure for this P: asked at every step)."""
        cached = st.__dict__.get("_step_applicable")
        if cached is not None and cached[0] is P:
            return cached[1]
        ok = numba is not None and _uniform6(st) and bool((np.diff(st.sn_ptr) == st.K).all())
        if ok:
            Pc = sp.csr_matrix(P)
            rows = np.repeat(np.arange(Pc.shape[0]), np.diff(Pc.indptr))
            ok = not np.any(Pc.data[rows != Pc.indices])
        st.__dict__["_step_applicable"] = (P, ok)
        return ok

    @staticmethod
    def cluster_diagonal(st: Structure, P) -> np.ndarray:
        """The diagonal weights of every cluster position (nc, M): a view of the cluster weights
        kept with the structure (:func:`_weights`, which the reliability's factor uses too)."""
        return np.diagonal(_weights(st, P)[1], axis1=1, axis2=2)

    @staticmethod
    def _camera_diagonal(st, dU):
        """diag(U) per S index (supernodes in order, K each)."""
        return dU.ravel()[: st.cam.size] if dU.shape[1] * dU.shape[0] == st.cam.size else \
            np.concatenate([dU[g, : st.sn_ptr[g + 1] - st.sn_ptr[g]] for g in range(dU.shape[0])])

    def _singular(self, col):
        name = self.labels[col] if self.labels is not None else f"unknown {col}"
        return SingularError(unknown=name, index=col)

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


def schur_structure(problem, Ar, keep, solver: str = "auto"):
    """The point-elimination layout of this module for the reduced design matrix ``Ar``,
    or None when the generic solver is to be used (``solver``: see :class:`baarda.adjust.Options`)."""
    if solver not in SOLVERS:
        raise OptionError("solver", solver, SOLVERS, f"unknown solver {solver!r} (known: {', '.join(SOLVERS)})")
    if solver == "generic":
        return None
    params = problem.params
    fr = params.free[keep]
    kind = params.kind[fr]
    if solver == "auto" and int((kind == "k").sum()) < MIN_ELIMINATED:
        return None
    st = analyse(Ar, problem.cov, kind, params.point[fr], take(params.labels, fr))
    if st is None or (solver == "auto" and not st.worthwhile()):
        return None
    return st
