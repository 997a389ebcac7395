"""The elimination layout of one design-matrix pattern (:class:`Structure`, :func:`analyse`):
which points are eliminated, the clusters of each point, the camera supernodes and the block
pattern of the reduced camera system S (package docstring). Pattern only: computed once per
design-matrix pattern, with the numeric caches that depend on the pattern and the weights
(:class:`StructureCache`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ...errors import OptionError
from ...model.problem import LazySequence, take

#: Largest covariance cluster (observations) the padded per-cluster arrays accept.
MAX_CLUSTER = 6
#: Automatic choice: eliminate points when at least this many point unknowns ...
MIN_ELIMINATED = 2000
#: ... make up at least this share of the unknowns.
MIN_SHARE = 0.3
#: the solvers :func:`schur_structure` chooses between
SOLVERS = ("auto", "schur", "generic")


def canonical(A) -> sp.csr_matrix:
    """``A`` as CSR with sorted, summed duplicate entries (a copy only when it is not already)."""
    A = sp.csr_matrix(A)
    if not A.has_canonical_format:
        A = A.copy()
        A.sum_duplicates()
    return A


@dataclass(eq=False)
class StructureCache:
    """What the factors compute once per :class:`Structure` and keep for the next factor of the
    same pattern (the structure itself is frozen): the order of S (:func:`baarda.solve.schur.
    ordering.camera_order`), the cluster weights of the last P (:func:`weights`), the diagonal
    blocks of S per supernode and the step factor's applicability for the last P
    (:class:`baarda.solve.schur.step.StepFactor`), and :attr:`Structure.col_S`."""

    order: np.ndarray | None = None
    weights: tuple | None = None             # (P, P as CSR, P_c (nc, M, M), every P_c diagonal)
    sn_diag: np.ndarray | None = None
    step_applicable: tuple | None = None     # (P, bool)
    col_S: np.ndarray | None = None

    def arrays(self):
        """The arrays held (inside the tuples too)."""
        vals = [w for v in vars(self).values() for w in (v if isinstance(v, tuple) else (v,))]
        return [v for v in vals if isinstance(v, np.ndarray)]


@dataclass(frozen=True, eq=False)
class Structure:
    """The elimination layout of one design-matrix pattern (see the package docstring).

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
    cache: StructureCache = field(default_factory=StructureCache, init=False, repr=False)

    @property
    def n_eliminated(self) -> int:
        return int(self.ent_size[: self.n_points].sum())

    @property
    def n_cameras(self) -> int:
        return int(self.cam.size)

    def matches(self, Ar) -> bool:
        """Whether ``Ar`` has the pattern this structure was analysed for."""
        Ar = canonical(Ar)
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

    @property
    def col_S(self) -> np.ndarray:
        """(nc, K) S index of each local camera column, −1 padded (made when first asked for: the
        kernels of the iterations read it off cl_sn and sn_ptr; kept in :attr:`cache`)."""
        if self.cache.col_S is not None:
            return self.cache.col_S
        sn_size = np.diff(self.sn_ptr)
        col_S = np.full((self.cl_sn.shape[0], self.K), -1, dtype=_index_dtype(self.cam.size))
        for s_ in range(self.G):                 # a cluster sees every column of its supernodes
            g = self.cl_sn[:, s_]
            for i in range(int(sn_size.max(initial=0))):
                p_ = np.flatnonzero((g >= 0) & (i < sn_size[np.maximum(g, 0)]))
                col_S[p_, self.cl_off[p_, s_] + i] = self.sn_ptr[g[p_]] + i
        self.cache.col_S = col_S
        return col_S

    def nbytes(self) -> int:
        """Bytes of the arrays the layout holds, its cached ones too."""
        arrays = [v for v in vars(self).values() if isinstance(v, np.ndarray)] + self.cache.arrays()
        return sum(v.nbytes for v in arrays)

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
    Ar = canonical(Ar)
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


def cluster_weights(st: Structure, P) -> np.ndarray:
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


def weights(st: Structure, P):
    """(P as CSR, the weights P_c of every cluster position (nc, M, M), whether every P_c is
    diagonal). They depend on P only: kept with the structure (:attr:`Structure.cache`) for the
    next factor of the same P (every iteration, the reliability at the solution)."""
    cached = st.cache.weights
    if cached is not None and cached[0] is P:
        return cached[1:]
    Pcsr = sp.csr_matrix(P)
    Pc = cluster_weights(st, Pcsr)
    Pd = np.diagonal(Pc, axis1=1, axis2=2)
    diagonal = bool(st.M == 1 or not np.any(Pc - Pd[:, :, None] * np.eye(st.M)))
    st.cache.weights = (P, Pcsr, Pc, diagonal)
    return Pcsr, Pc, diagonal


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
