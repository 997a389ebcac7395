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

A defect the user did not resolve raises :class:`baarda.errors.DatumDefectError` naming the
free transformations and the points they move; a parameter that no observation determines
(a local defect) is named by the factorisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

from .errors import DatumDefectError
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
    approximate coordinates (inner constraints over the S-base).
    """

    kind: str = "fixed"
    sbase: tuple[str, ...] = ()

    def describe(self) -> str:
        if self.kind == "fixed":
            return "fixed and weighted points"
        base = ", ".join(self.sbase) if self.sbase else "all points"
        return f"free network, minimum-norm S-base: {base}"


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
        """(EᵀG)⁻¹Eᵀ (d × u), computed as the pseudo-inverse of G on the S-base rows (the least
        squares shift over the base; EᵀG itself has the square of the base's condition)."""
        K = self.__dict__.get("_K")
        if K is None:
            rows = np.flatnonzero(self.base & (np.abs(self.G).max(axis=1, initial=0.0) > 0))
            K = np.zeros((self.defect, self.G.shape[0]))
            K[:, rows] = la.pinv(self.G[rows])
            object.__setattr__(self, "_K", K)
        return K


def normal_diagonal(A: sp.csr_matrix, P: sp.csr_matrix) -> np.ndarray:
    """diag(AᵀPA) without forming it (P diagonal: Σ_i p_i a_ij²)."""
    P = sp.csr_matrix(P)
    rows = np.repeat(np.arange(P.shape[0]), np.diff(P.indptr))
    if not np.any(P.data[rows != P.indices]):              # diagonal (stored zeros aside)
        A = sp.csr_matrix(A)
        Pdiag = P.diagonal()
        out = np.zeros(A.shape[1])
        step = 1 << 20                                      # rows per chunk: no n·k temporaries
        for s in range(0, A.shape[0], step):
            a, b = A.indptr[s], A.indptr[min(s + step, A.shape[0])]
            Pd = np.repeat(Pdiag[s:s + step], np.diff(A.indptr[s:s + step + 1]))
            np.add.at(out, A.indices[a:b], Pd * A.data[a:b] ** 2)   # the order of one bincount
        return out
    return np.asarray((A.multiply(P @ A)).sum(axis=0)).ravel()


def null_space(problem, x, A: sp.csr_matrix, P: sp.csr_matrix, free: np.ndarray):
    """Null directions of the design matrix among similarity transformations.

    Returns (G, names) over the free parameters; G spans {g : A g = 0} ∩ span(similarities).
    """
    Gall, names = similarity_candidates(problem, x)
    G = Gall[free]
    kind = problem.params.kind[free]
    t = np.flatnonzero(kind == "t")
    k = np.flatnonzero(kind != "t")
    G[t] = 0.0
    R = A @ G                                   # = A_k G_k (G_t = 0)
    if t.size:
        At = A[:, t]
        Ntt = (At.T @ P @ At).tocsr()
        try:
            Gt = -SPDFactor(Ntt).solve(At.T @ (P @ R))
        except Exception:
            Gt = -np.linalg.lstsq(Ntt.toarray(), At.T @ (P @ R), rcond=None)[0]
        G = G.copy()
        G[t] = Gt.reshape(t.size, -1)
        R = A @ G
    diagN = normal_diagonal(A, P)
    num = R.T @ (P @ R)
    Gk = G[k]
    den = Gk.T @ (Gk * diagN[k, None])      # size of each combination by the point motion alone
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
        ok = (sr[: coef.shape[1] - alone.size] > 1e-6 * max(sr.max(initial=0.0), 1e-300)).all()
        if ok and np.linalg.matrix_rank(check / np.abs(check).max(axis=0), tol=1e-8) == coef.shape[1]:
            coef = new
    Gn = G @ coef
    Gn = Gn / np.abs(Gn).max(axis=0)              # unit size: the scale of N is irrelevant here
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
    moved = sorted({ids[p] for p in point_of[np.abs(G).max(axis=1) > 1e-9] if p >= 0})
    if datum.kind != "free":
        raise DatumDefectError(
            d, list(names),
            f"datum defect {d}: the observations leave {'; '.join(names)} undetermined "
            f"(points {', '.join(moved[:12])}{' ...' if len(moved) > 12 else ''}); "
            "fix or weight enough points, or declare a free network with an S-base")
    if datum.sbase:
        wanted = set(datum.sbase)
        labels = problem.params.labels
        in_base = np.array([(p >= 0 and (ids[p] in wanted or labels[j] in wanted))
                            for p, j in zip(point_of.tolist(), free.tolist())], dtype=bool)
    else:
        in_base = (point_of >= 0) & (problem.params.kind[free] == "k")
        far = far_points(problem, x)
        if far.any() and not far[point_of[in_base]].all():
            in_base &= ~far[np.maximum(point_of, 0)]
    Gb = G[in_base]
    sv = la.svdvals(Gb / np.maximum(np.abs(Gb).max(axis=0), 1e-300)) if Gb.size else np.zeros(1)
    if Gb.shape[0] < d or sv.min() <= 1e-9 * sv.max():
        base = sorted(ids[p] for p in set(point_of[in_base]))
        raise DatumDefectError(
            d, list(names),
            f"datum defect {d} ({'; '.join(names)}): the S-base points "
            f"{', '.join(base[:12])}{' ...' if len(base) > 12 else ''} do not fix it")
    cand = np.flatnonzero(in_base)
    # the held coordinates only regularise the solve (the result is S-transformed to the S-base),
    # but they decide its conditioning: hold points that many observations determine (a 2-ray
    # point next to a camera, or a point near infinity, makes the regularised system needlessly
    # ill-conditioned), spread so that they fix the transformations best (pivoted QR of G)
    nobs = np.bincount(sp.csr_matrix(A).indices, minlength=A.shape[1])[cand]
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
    return DatumPlan(G, names, eliminate, np.asarray(in_base, dtype=bool))
