"""Datum: defect analysis, minimum constraints and S-transformations (Molenaar 1984, §2).

A network or block without enough fixed or weighted points has a datum defect d: the
observations do not change under a d-parameter family of similarity transformations. The null
space of the design matrix is spanned by the columns of G (u × d):

- levelling: a common height shift (d = 1);
- planimetric: translations in x and y, a rotation, a scale (d ≤ 4: whatever the observations
  leave free — distances fix the scale, azimuths the rotation);
- spatial: three translations, three rotations, a scale (d ≤ 7).

Nuisance parameters follow the transformation of the points (an orientation unknown turns with
the network); their share of each null vector is found by least squares,
g_t = −(A_tᵀPA_t)⁻¹ A_tᵀPA_k g_k, so that any model type can be analysed without a formula of
its own.

The datum is explicit (:class:`Datum`): fixed points, weighted points (observations of
coordinates) or a free network whose datum is an *S-base* — points whose squared shifts from
their approximate coordinates are minimised (inner constraints over the S-base). Baarda's
S-transformation S = I − G (EᵀG)⁻¹ Eᵀ (M84 §2, E the S-base rows of G) maps any solution and
its covariance to that base: x_S = S x, Σ_S = S Σ Sᵀ. Redundancy numbers, w-tests and λ̄ do not
depend on the base; coordinate covariances and deformation fields do.

Baarda's S-base in three dimensions (M84 §2.2): two points with non-stochastic coordinates and,
"in addition, the direction ... fixed for the normal vector of the plane containing these two
points and a third one". Two points leave the rotation about the line through them free; the
third condition holds the third point's displacement along the normal n = (B − A) × (C − A) of
that plane, which is exactly what that rotation moves. The S-base conditions are then the rows
of Fᵀ (the base coordinates and the function nᵀ Δx_C), and S = I − G (FᵀG)⁺ Fᵀ. C is given as
``normal=C`` among the S-base ids, or else the point farthest from the line AB
(:func:`normal_condition`).

A defect the user did not resolve raises :class:`baarda.errors.DatumDefectError` naming the
free transformations and the points they move; a parameter that no observation determines
(a local defect) is named by the factorisation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

from .errors import DatumDefectError
from .solve.compiled import NUMBA, compiled
from .solve.linalg import SPDFactor

TRANSFORMS = {
    1: ("translation z",),
    2: ("translation x", "translation y", "rotation", "scale"),
    3: ("translation x", "translation y", "translation z",
        "rotation about x", "rotation about y", "rotation about z", "scale xy", "scale z"),
}

NULL_TOL = 1e-9


@dataclass(frozen=True)
class Datum:
    """How the datum is defined.

    kind: ``"fixed"`` — fixed and weighted points define it; a remaining defect is an error.
    ``"free"`` — a free network: the S-base (point ids, or parameter labels such as ``"A.x"``;
    empty = every estimated coordinate) takes the minimum sum of squared shifts from its
    approximate coordinates (inner constraints over the S-base). In 3D two points and the
    normal of the plane through them and a third point (M84 §2.2; ``"normal=C"`` names C,
    module docstring).
    """

    kind: str = "fixed"
    sbase: tuple[str, ...] = ()
    #: what defines a "fixed" datum when it is not points alone (GNSS projection centres)
    by: str = ""

    def describe(self) -> str:
        if self.kind == "fixed":
            return self.by or "fixed and weighted points"
        base = ", ".join(self.sbase) if self.sbase else "all points"
        return f"free network, minimum-norm S-base: {base}"


def split_normal(sbase) -> tuple[list[str], str | None]:
    """The S-base ids and the point named by a ``normal=C`` entry (None without one)."""
    ids, normal = [], None
    for b in sbase:
        b = str(b)
        if b.startswith("normal="):
            normal = b[len("normal="):]
        else:
            ids.append(b)
    return ids, normal


def normal_condition(xyz: np.ndarray, base: list[int], candidates, normal: int | None = None):
    """Baarda's third condition of a 3D S-base (M84 §2.2; module docstring): the point C and the
    unit normal n of the plane through the base points A, B (the two farthest apart of ``base``)
    and C. ``xyz``: m × 3 point positions (metres); ``candidates``: the point indices C may be
    (with three coordinates); ``normal``: C if the user named it. Returns (C, n), or None when no
    candidate spans a plane with AB (all collinear)."""
    base = list(base)
    P = xyz[base]
    d = np.linalg.norm(P[:, None] - P[None], axis=2)
    i, j = np.unravel_index(np.argmax(d), d.shape)
    a, b = xyz[base[i]], xyz[base[j]]
    u = (b - a) / max(np.linalg.norm(b - a), 1e-300)
    cands = np.array([normal] if normal is not None else
                     [c for c in np.asarray(candidates).tolist() if c not in base], dtype=np.int64)
    if cands.size == 0:
        return None
    r = xyz[cands] - a
    off = r - np.outer(r @ u, u)
    dist = np.linalg.norm(off, axis=1)
    k = int(np.argmax(dist))
    if not dist[k] > 1e-9 * max(np.linalg.norm(b - a), 1e-300):
        return None
    n = np.cross(b - a, xyz[cands[k]] - a)
    return int(cands[k]), n / np.linalg.norm(n)


def similarity_candidates(problem, x: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    """Columns of infinitesimal similarity transformations of all point coordinates (u_all × c).

    Rotation and scale columns are divided by the extent of the points so that all columns have
    comparable size. Nuisance rows are zero here (filled in by :func:`null_space`).
    """
    pts = problem.points
    dim = pts.dim
    u = problem.params.size
    idx = pts.index
    has = idx >= 0
    X = np.zeros(idx.shape)
    X[has] = x[idx[has]]
    used = has.any(axis=1)
    # median centre and a quantile extent: a few far, weakly determined points (a bundle block's
    # points near infinity) must not make the rotation and scale columns of the others vanish
    centre = np.array([np.median(X[has[:, a], a]) if has[:, a].any() else 0.0 for a in range(3)])
    Xc = np.where(has, X - centre, 0.0)
    ext = float(np.quantile(np.abs(Xc[used]).max(axis=1), 0.9)) if used.any() else 1.0
    ext = ext if ext > 0 else 1.0
    Xc = Xc / ext
    names = TRANSFORMS[dim]
    cols = []
    if dim == 1:
        cols.append(np.array([[0, 0, 1.0]]).repeat(len(idx), 0))
    elif dim == 2:
        ones = np.ones(len(idx))
        zeros = np.zeros(len(idx))
        cols.append(np.stack([ones, zeros, zeros], 1))
        cols.append(np.stack([zeros, ones, zeros], 1))
        cols.append(np.stack([-Xc[:, 1], Xc[:, 0], zeros], 1))
        cols.append(np.stack([Xc[:, 0], Xc[:, 1], zeros], 1))
    else:
        ones = np.ones(len(idx))
        zeros = np.zeros(len(idx))
        cols.append(np.stack([ones, zeros, zeros], 1))
        cols.append(np.stack([zeros, ones, zeros], 1))
        cols.append(np.stack([zeros, zeros, ones], 1))
        cols.append(np.stack([zeros, -Xc[:, 2], Xc[:, 1]], 1))
        cols.append(np.stack([Xc[:, 2], zeros, -Xc[:, 0]], 1))
        cols.append(np.stack([-Xc[:, 1], Xc[:, 0], zeros], 1))
        cols.append(np.stack([Xc[:, 0], Xc[:, 1], zeros], 1))
        cols.append(np.stack([zeros, zeros, Xc[:, 2]], 1))
    G = np.zeros((u, len(cols)))
    for c, disp in enumerate(cols):
        G[idx[has], c] = disp[has]
    return G, names


#: the default S-base leaves out points further from the block's median than FAR times the
#: 90 % quantile of the point distances (points near infinity of a structure-from-motion block,
#: whose depth the rays hardly determine: as a datum they would fix nothing and swamp the rest)
FAR = 1000.0


def point_distances(problem, x: np.ndarray) -> tuple[np.ndarray, float]:
    """Distances of the points from the median of all points, and their 90 % quantile."""
    idx = problem.points.index
    has = idx >= 0
    used = has.any(axis=1)
    X = np.where(has, x[np.maximum(idx, 0)], 0.0)
    centre = np.array([np.median(X[has[:, a], a]) if has[:, a].any() else 0.0 for a in range(3)])
    dist = np.linalg.norm(np.where(has, X - centre, 0.0), axis=1)
    return dist, float(np.quantile(dist[used], 0.9)) if used.any() else 0.0


def far_points(problem, x: np.ndarray) -> np.ndarray:
    """Boolean mask over the problem's points: the points near infinity (see :data:`FAR`)."""
    used = (problem.points.index >= 0).any(axis=1)
    if used.sum() < 10:
        return np.zeros(used.size, dtype=bool)
    dist, ref = point_distances(problem, x)
    return used & (dist > FAR * ref) if ref > 0 else np.zeros(used.size, dtype=bool)


@dataclass(frozen=True, eq=False)
class DatumPlan:
    """The outcome of the datum analysis at a linearisation point.

    G: null-space basis over the free parameters (u_free × d; d = 0 when there is no defect).
    names: a description of each null direction. eliminate: positions (in the free-parameter
    vector) held fixed in the regularised solve (d of them). E: the S-base rows of G
    (u_free × d, zero outside the S-base).
    """

    G: np.ndarray
    names: tuple[str, ...]
    eliminate: np.ndarray
    base: np.ndarray           # bool per free parameter: in the S-base (E = G there, 0 elsewhere)
    normal_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # C's x, y, z (3D S-base)
    normal: np.ndarray = field(default_factory=lambda: np.zeros(0))   # the unit normal n (M84 §2.2), or empty

    @property
    def E(self) -> np.ndarray:
        """The S-base rows of G (u_free × d, zero outside the S-base), made on demand."""
        return np.where(self.base[:, None], self.G, 0.0)

    @property
    def defect(self) -> int:
        return self.G.shape[1]

    def transform(self, dx: np.ndarray) -> np.ndarray:
        """S-transformation of a solution vector (or matrix of columns) to the S-base (M84 §2)."""
        if self.defect == 0:
            return dx
        return dx - self.G @ (self.K @ dx)

    @property
    def K(self) -> np.ndarray:
        """(FᵀG)⁺Fᵀ (d × u): the pseudo-inverse of G on the S-base rows (the least squares shift over
        the base; EᵀG itself has the square of the base's condition), with the row nᵀG_C of the
        normal condition of a 3D S-base (module docstring)."""
        K = self.__dict__.get("_K")
        if K is None:
            K = sbase_K(self.G, self.base, self.normal_rows, self.normal)
            object.__setattr__(self, "_K", K)
        return K


def sbase_K(G: np.ndarray, base: np.ndarray, normal_rows=(), normal=()) -> np.ndarray:
    """K = (FᵀG)⁺Fᵀ (d × u) of the S-base (module docstring): Fᵀ the rows ``base`` (bool per row of G)
    and, for a 3D S-base of two points, the normal condition nᵀΔx_C (``normal_rows`` the rows of C's
    x, y, z, ``normal`` n). S = I − G K (M84 §2); the pseudo-inverse is the least squares shift
    over a base with more conditions than d."""
    normal_rows = np.asarray(normal_rows, dtype=np.int64)
    normal = np.asarray(normal, dtype=float)
    rows = np.flatnonzero(np.asarray(base, dtype=bool) & (np.abs(G).max(axis=1, initial=0.0) > 0))
    FG = G[rows]
    if normal.size:
        FG = np.vstack([FG, normal @ G[normal_rows]])
    Kf = la.pinv(FG)
    K = np.zeros((G.shape[1], G.shape[0]))
    K[:, rows] = Kf[:, :rows.size]
    if normal.size:
        K[:, normal_rows] += np.outer(Kf[:, -1], normal)
    return K


def normal_diagonal(A: sp.csr_matrix, P: sp.csr_matrix) -> np.ndarray:
    """diag(AᵀPA) without forming it (P diagonal: Σ_i p_i a_ij²)."""
    P = sp.csr_matrix(P)
    rows = np.repeat(np.arange(P.shape[0]), np.diff(P.indptr))
    if not np.any(P.data[rows != P.indices]):              # diagonal (stored zeros aside)
        A = sp.csr_matrix(A)
        Pdiag = P.diagonal()
        out = np.zeros(A.shape[1])
        step = 1 << 17                                      # rows per chunk: no n·k temporaries (~12 MB)
        for s in range(0, A.shape[0], step):
            a, b = A.indptr[s], A.indptr[min(s + step, A.shape[0])]
            Pd = np.repeat(Pdiag[s:s + step], np.diff(A.indptr[s:s + step + 1]))
            np.add.at(out, A.indices[a:b], Pd * A.data[a:b] ** 2)   # the order of one bincount
        return out
    return np.asarray((A.multiply(P @ A)).sum(axis=0)).ravel()


def _gram(a_ptr, a_idx, a_val, w_ptr, w_idx, w_val, out):
    """out += AᵀW for two CSR matrices of the same rows, into a dense ``out`` (the nuisance
    block AₜᵀPAₜ of :func:`null_space` with W = PAₜ: compiled where numba is installed and the
    block is small, :data:`DENSE_NTT`; scipy's sparse product otherwise, the same sums)."""
    for r in range(a_ptr.size - 1):
        for p in range(a_ptr[r], a_ptr[r + 1]):
            i, v = a_idx[p], a_val[p]
            for q in range(w_ptr[r], w_ptr[r + 1]):
                out[i, w_idx[q]] += v * w_val[q]


_GRAM = compiled(_gram, cache=True) if NUMBA else None
#: nuisance unknowns up to which :func:`null_space` sums AₜᵀPAₜ into a dense matrix (8 · n² bytes)
DENSE_NTT = 2000


def row_view(A: sp.csr_matrix, s: int, e: int) -> sp.csr_matrix:
    """Rows s:e of a CSR matrix on views of its data and indices (``A[s:e]`` copies them: the
    same matrix, without the copy)."""
    a, b = int(A.indptr[s]), int(A.indptr[e])
    out = sp.csr_matrix((A.data[a:b], A.indices[a:b], A.indptr[s:e + 1] - A.indptr[s]),
                        shape=(e - s, A.shape[1]), copy=False)
    out.has_canonical_format = A.has_canonical_format
    return out


def column_counts(A: sp.csr_matrix, step: int = 1 << 22) -> np.ndarray:
    """Entries per column (``np.bincount(A.indices)``, in chunks: bincount casts int32 indices to
    int64, a copy of them all at once)."""
    out = np.zeros(A.shape[1], dtype=np.int64)
    for s in range(0, A.indices.size, step):
        out += np.bincount(A.indices[s:s + step], minlength=A.shape[1])
    return out


#: rows per block of :func:`null_space`'s sums (a block's temporaries are ~ 300 B per row)
BLOCK_ROWS = 1 << 18


def row_blocks(P: sp.csr_matrix, step: int | None = None) -> list[tuple[int, int]]:
    """Row ranges [s, e) of about ``step`` rows (default :data:`BLOCK_ROWS`) that no covariance
    cluster of the block-diagonal weight matrix ``P`` straddles (P[s:e, s:e] holds the whole
    weight of rows s:e), so that AᵀPB = Σ A[s:e]ᵀ P[s:e, s:e] B[s:e]."""
    step = step or BLOCK_ROWS
    n = P.shape[0]
    if n <= step:
        return [(0, n)]
    rows = np.arange(n)
    lo, hi = rows.copy(), rows.copy()
    has = np.flatnonzero(np.diff(P.indptr) > 0)
    if has.size:          # (segments between non-empty rows' starts are exactly their entries)
        lo[has] = np.minimum.reduceat(P.indices, P.indptr[has])
        hi[has] = np.maximum.reduceat(P.indices, P.indptr[has])
    # a cut before row b is clean when no row above reaches b or beyond and no row from b on
    # reaches before b
    reach = np.maximum.accumulate(np.maximum(hi, rows))
    back = np.minimum.accumulate(np.minimum(lo, rows)[::-1])[::-1]
    clean = np.flatnonzero((reach[:-1] < rows[1:]) & (back[1:] >= rows[1:])) + 1
    out, s = [], 0
    while n - s > step:
        k = np.searchsorted(clean, s + step, side="right") - 1
        e = int(clean[k]) if k >= 0 and clean[k] > s else None
        if e is None:
            k = np.searchsorted(clean, s + step)
            if k >= clean.size:
                break
            e = int(clean[k])
        out.append((s, e))
        s = e
    out.append((s, n))
    return out


def null_space(problem, x, A: sp.csr_matrix, P: sp.csr_matrix, free: np.ndarray):
    """Null directions of the design matrix among similarity transformations.

    Returns (G, names) over the free parameters; G spans {g : A g = 0} ∩ span(similarities).
    """
    Gall, names = similarity_candidates(problem, x)
    if free.size == Gall.shape[0] and np.array_equal(free, np.arange(free.size)):
        G = Gall                   # every parameter free: the candidates are this function's own
    else:
        G = Gall[free]             # (a copy: the candidates of every parameter go at once)
    del Gall
    kind = problem.params.kind[free]
    t = np.flatnonzero(kind == "t")
    k = np.flatnonzero(kind != "t")
    G[t] = 0.0
    A, P = sp.csr_matrix(A), sp.csr_matrix(P)
    blocks = row_blocks(P)
    if t.size:
        # N_tt = A_tᵀPA_t and A_tᵀP(A_k G_k) (G_t = 0), summed over row blocks: no copy of A_t
        # or of R = A G over all observations is held
        dense = _GRAM is not None and t.size <= DENSE_NTT
        Ntt, AtPR = np.zeros((t.size, t.size)) if dense else None, np.zeros((t.size, G.shape[1]))
        for s, e in blocks:
            Ab, Pb = row_view(A, s, e), P[s:e, s:e]
            At = Ab[:, t]
            if dense:
                W = sp.csr_matrix(Pb @ At)
                _GRAM(At.indptr, At.indices, At.data, W.indptr, W.indices, W.data, Ntt)
                del W
            else:
                Ntt = At.T @ Pb @ At if Ntt is None else Ntt + At.T @ Pb @ At
            AtPR += At.T @ (Pb @ (Ab @ G))
            del Ab, At
        Ntt = sp.csr_matrix(Ntt)
        try:
            Gt = -SPDFactor(Ntt).solve(AtPR)
        except Exception:
            Gt = -np.linalg.lstsq(Ntt.toarray(), AtPR, rcond=None)[0]
        G[t] = Gt.reshape(t.size, -1)  # (G is this function's own copy)
    diagN = normal_diagonal(A, P)
    num = np.zeros((G.shape[1], G.shape[1]))
    for s, e in blocks:
        R = row_view(A, s, e) @ G
        num += R.T @ (P[s:e, s:e] @ R)
    del R
    Gk = G[k]
    den = Gk.T @ (Gk * diagN[k, None])      # size of each combination by the point motion alone
    del Gk, diagN
    # equilibrate: each candidate's own size must not decide whether it counts (far points)
    dd = np.sqrt(np.maximum(np.diag(den), 0.0))
    on = dd > 1e-150
    D = np.where(on, 1.0 / np.where(on, dd, 1.0), 0.0)
    s, U = la.eigh(den * D[:, None] * D[None, :])
    keep = s > 1e-10 * max(s.max(initial=0.0), 1e-300)
    if not keep.any():
        return np.zeros((free.size, 0)), ()
    Bm = D[:, None] * U[:, keep] / np.sqrt(s[keep])   # den-orthonormal combinations of candidates
    lam, V = la.eigh(Bm.T @ num @ Bm)
    null = lam < NULL_TOL
    if not null.any():
        return np.zeros((free.size, 0)), ()
    coef = Bm @ V[:, null]                          # candidate coefficients of each null vector
    # where the null space is spanned by single candidates (the usual case: "translation x",
    # "scale"), use them: the named transformations are the ones the user knows
    # (a candidate counts as null alone when it is as null as the null space itself: with free
    # focal lengths a one-axis stretch can be nearly, but not quite, a null direction)
    thresh = min(NULL_TOL, 1e-14)
    alone = np.flatnonzero(on & (np.diag(num) < thresh * np.maximum(np.diag(den), 1e-300)))
    if 0 < alone.size <= coef.shape[1]:
        single = np.eye(G.shape[1])[:, alone]
        rest = coef.copy()
        rest[alone] = 0.0                 # what the single candidates leave of the null space
        Ur, sr, _ = la.svd(rest * D[:, None] if D.size else rest, full_matrices=False)
        extra = Ur[:, : coef.shape[1] - alone.size] / np.where(on, D, 1.0)[:, None]
        new = np.hstack([single, extra])
        check = G @ new
        check /= np.abs(check).max(axis=0)
        ok = (sr[: coef.shape[1] - alone.size] > 1e-6 * max(sr.max(initial=0.0), 1e-300)).all()
        if ok and np.linalg.matrix_rank(check, tol=1e-8) == coef.shape[1]:
            coef = new
        del check
    Gn = G @ coef
    del G
    Gn /= np.abs(Gn).max(axis=0)                  # unit size: the scale of N is irrelevant here
    desc = []
    for c in range(coef.shape[1]):
        w = np.abs(coef[:, c]) * np.sqrt(np.maximum(np.diag(den), 0.0))
        w = w / w.max()
        used = [n for n, wi in zip(names, w) if wi > 0.05]
        both = coef[[i for i, n in enumerate(names) if n.startswith("scale")], c]
        if used and all(n.startswith("scale") for n in used) and len(both) == 2 and (np.abs(both) > 0).all():
            desc.append("scale")            # the uniform scale: the two scale candidates together
        else:
            desc.append(" + ".join(used))
    return Gn, tuple(desc)


def plan(problem, x, A, P, free) -> DatumPlan:
    """Analyse the datum at ``x`` and decide how to regularise the normal equations.

    Raises DatumDefectError for a defect that the problem's datum does not resolve.
    """
    G, names = null_space(problem, x, A, P, free)
    d = G.shape[1]
    u = free.size
    if d == 0:
        return DatumPlan(np.zeros((u, 0)), (), np.zeros(0, dtype=np.int64), np.zeros(u, dtype=bool))
    datum = problem.datum
    point_of = problem.params.point[free]
    ids = problem.points.ids
    if datum.kind != "free":
        moved = sorted({ids[p] for p in point_of[np.abs(G).max(axis=1) > 1e-9] if p >= 0})
        raise DatumDefectError(
            d, list(names),
            f"datum defect {d}: the observations leave {'; '.join(names)} undetermined "
            f"(points {', '.join(moved[:12])}{' ...' if len(moved) > 12 else ''}); "
            "fix or weight enough points, or declare a free network with an S-base")
    normal_rows, normal = np.zeros(0, dtype=np.int64), np.zeros(0)
    if datum.sbase:
        names_b, normal_id = split_normal(datum.sbase)
        wanted = set(names_b)
        labels = problem.params.labels
        in_base = np.array([(p >= 0 and (ids[p] in wanted or labels[j] in wanted))
                            for p, j in zip(point_of.tolist(), free.tolist())], dtype=bool)
        normal_rows, normal = _normal_rows(problem, x, free, G, in_base, wanted, normal_id)
    else:
        in_base = (point_of >= 0) & (problem.params.kind[free] == "k")
        far = far_points(problem, x)
        if far.any() and not far[point_of[in_base]].all():
            in_base &= ~far[np.maximum(point_of, 0)]
    Gb = G[in_base] if not normal.size else np.vstack([G[in_base], normal @ G[normal_rows]])
    sv = la.svdvals(Gb / np.maximum(np.abs(Gb).max(axis=0), 1e-300)) if Gb.size else np.zeros(1)
    if Gb.shape[0] < d or sv.min() <= 1e-9 * sv.max():
        base = sorted(ids[p] for p in set(point_of[in_base]))
        raise DatumDefectError(
            d, list(names),
            f"datum defect {d} ({'; '.join(names)}): the S-base points "
            f"{', '.join(base[:12])}{' ...' if len(base) > 12 else ''} do not fix it")
    cand = np.union1d(np.flatnonzero(in_base), normal_rows)
    # the held coordinates only regularise the solve (the result is S-transformed to the S-base),
    # but they decide its conditioning: hold points that many observations determine (a 2-ray
    # point next to a camera, or a point near infinity, makes the regularised system needlessly
    # ill-conditioned), spread so that they fix the transformations best (pivoted QR of G)
    nobs = column_counts(sp.csr_matrix(A))[cand]
    dist, ref = point_distances(problem, x)
    strong = (nobs >= np.quantile(nobs, 0.9)) & (dist[point_of[cand]] <= ref)
    def equilibrated(rows):
        g = G[rows]
        return g / np.maximum(np.linalg.norm(g, axis=0), 1e-300)

    sub = cand[strong]
    if sub.size < d or la.svdvals(equilibrated(sub)).min() <= 1e-6:
        sub = cand
    _, _, piv = la.qr(equilibrated(sub).T, pivoting=True, mode="economic")
    cand = sub
    eliminate = np.sort(cand[piv[:d]])
    return DatumPlan(G, names, eliminate, np.asarray(in_base, dtype=bool), normal_rows, normal)


def _normal_rows(problem, x, free, G, in_base, wanted, normal_id):
    """The normal condition of a 3D S-base (M84 §2.2) where the base points alone leave a rotation
    free: (free positions of C's x, y, z, n), else empty arrays. Needs every base point and C with
    three estimated coordinates."""
    none = np.zeros(0, dtype=np.int64), np.zeros(0)
    Gb = G[in_base]
    if Gb.shape[0] and np.linalg.matrix_rank(Gb, tol=NULL_TOL * max(np.abs(Gb).max(), 1e-300)) == G.shape[1]:
        return none
    params = problem.params
    point_of = params.point[free]
    kind_k = params.kind[free] == "k"
    pos = np.full((len(problem.points.ids), 3), -1, dtype=np.int64)
    pos[point_of[kind_k], params.axis[free][kind_k]] = np.flatnonzero(kind_k)
    full = (pos >= 0).all(axis=1)
    ids = problem.points.ids
    base = [k for k, i in enumerate(ids) if i in wanted]
    if len(base) < 2 or not full[base].all():
        return none
    xyz = np.zeros(pos.shape)
    xyz[full] = x[free[pos[full]]]
    if normal_id is not None and normal_id not in ids:
        raise DatumDefectError(G.shape[1], [], f"S-base: unknown point {normal_id} for the normal direction")
    normal = None if normal_id is None else ids.index(normal_id)
    found = normal_condition(xyz, base, np.flatnonzero(full), normal)
    if found is None:
        return none
    c, n = found
    return pos[c], n
