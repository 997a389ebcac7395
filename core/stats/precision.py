"""Precision of the coordinates: S-transformations, ellipses and criterion matrices (M84 §2).

S-transformation (Baarda; M84 §2). The coordinates of a network are defined only up to the
similarity transformations its observations leave free (G, u × d). Choosing an S-base — points
whose coordinates are held non-stochastic — fixes them: with E the S-base rows of G,

    S = I − G (EᵀG)⁻¹ Eᵀ,   x_S = S x,   Σ_S = S Σ Sᵀ.

Every generalised inverse of N gives the same Σ_S, so the covariance of any adjustment (fixed
points, weighted points, a free network) can be carried to any S-base. Here G is the null space of
the design matrix with *all* points released (fixed ones too), so a network adjusted on fixed
points can be shown in the S-base of other points.

Criterion matrix of chaotic structure (M84 eq. 2; the OCR of M84 prints d² − d_ij²,
which only rescales the parameters, the ½ makes d_ij² the variance of a difference):
var(x_i) = var(y_i) = d², cov(x_i, x_j) = cov(y_i, y_j) = d² − ½ d_ij², cov(x, y) = 0, so
that a coordinate difference has variance d_ij², with d_ij² a function of the distance l_ij
(linear, logarithmic, exponential). The real covariance G is judged against the criterion H in
the same S-base by the generalised eigenvalues of |G − λH| = 0 on the non-base coordinates:
λmax < 1 ("satisfication", M84 eq. 3) means every function F of the coordinates satisfies
G_FF < H_FF; λmin H_FF ≤ G_FF ≤ λmax H_FF.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as la
from ..lazy import lazy
from .. import datum as datum_mod
from ..errors import BaardaError

optimize = lazy("scipy.optimize")        # imported when first used (start-up)


@dataclass(frozen=True, eq=False)
class SBase:
    """The conditions of an S-base over a vector of coordinates (M84 §2.2; :mod:`baarda.datum`):
    ``in_base`` flags the coordinates held non-stochastic; a 3D S-base of two points adds the normal
    condition nᵀΔx_C (``normal_rows`` the positions of C's x, y, z, ``normal`` n)."""

    in_base: np.ndarray
    normal_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    normal: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def matrix(self, G: np.ndarray) -> np.ndarray:
        """S = I − G (FᵀG)⁺Fᵀ (:func:`baarda.datum.sbase_K`)."""
        return np.eye(G.shape[0]) - G @ datum_mod.sbase_K(G, self.in_base, self.normal_rows, self.normal)


def as_sbase(base) -> SBase:
    """An :class:`SBase` from S-base flags per coordinate (or an SBase; M84 §2.2).

    Parameters
    ----------
    base : SBase or array_like of bool
        The S-base, or flags of the coordinates held non-stochastic.

    Returns
    -------
    SBase
        ``base`` itself, or an SBase of those flags.
    """
    return base if isinstance(base, SBase) else SBase(np.asarray(base, dtype=bool))


@dataclass(frozen=True, eq=False)
class CoordinateCovariance:
    """Covariance of point coordinates in an S-base.

    params: parameter indices (into Problem.params) of the coordinates, in order; point, axis:
    the point index and axis of each; cov: the covariance (m²), σ0 as the adjustment uses;
    sbase: the S-base ids (with ``normal=C`` for the third condition of a 3D base); base: its
    conditions over these coordinates (None: the adjustment's own datum).
    """

    params: np.ndarray
    point: np.ndarray
    axis: np.ndarray
    cov: np.ndarray
    sbase: tuple[str, ...]
    base: SBase | None = None

    def block(self, p: int) -> np.ndarray:
        sel = np.flatnonzero(self.point == p)
        return self.cov[np.ix_(sel, sel)]

    def ellipses(self, scale: float = 1.0) -> np.ndarray:
        """Standard ellipses of the points (m × 3: semi-major a, semi-minor b, bearing of a from
        the x axis in radians), from the planimetric 2 × 2 blocks (:func:`standard_ellipses`)."""
        pts = np.unique(self.point)
        out = np.full((pts.max() + 1 if pts.size else 0, 3), np.nan)
        for p in pts:
            sel = np.flatnonzero((self.point == p) & (self.axis < 2))
            if sel.size != 2:
                continue
            out[p] = standard_ellipses(self.cov[np.ix_(sel, sel)][None], scale)[0]
        return out


def standard_ellipses(cov2: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Standard ellipses of m planimetric 2 × 2 covariances: a² and b² their eigenvalues.

    Parameters
    ----------
    cov2 : numpy.ndarray
        m × 2 × 2 covariances, m² (any unit squared).
    scale : float
        Factor on the semi-axes (e.g. a confidence multiple), dimensionless.

    Returns
    -------
    numpy.ndarray
        m × 3: semi-major a, semi-minor b (metres, the unit of √cov), bearing of a from the x axis
        (radians).
    """
    lam, V = np.linalg.eigh(np.asarray(cov2, dtype=float))
    lam = np.maximum(lam, 0.0)
    return np.stack([scale * np.sqrt(lam[:, 1]), scale * np.sqrt(lam[:, 0]),
                     np.arctan2(V[:, 1, 1], V[:, 0, 1])], axis=1)


def ellipse_points(ellipses: np.ndarray, n: int = 49) -> np.ndarray:
    """Points of ellipses centred at 0 (:func:`standard_ellipses`).

    Parameters
    ----------
    ellipses : numpy.ndarray
        m × 3: a, b (metres) and bearing (radians).
    n : int
        Points per ellipse.

    Returns
    -------
    numpy.ndarray
        m × n × 2 points, metres (the unit of a and b).
    """
    e = np.asarray(ellipses, dtype=float)
    t = np.linspace(0, 2 * np.pi, n)
    u = e[:, 0:1] * np.cos(t)[None, :]
    v = e[:, 1:2] * np.sin(t)[None, :]
    c, s = np.cos(e[:, 2:3]), np.sin(e[:, 2:3])
    return np.stack([c * u - s * v, s * u + c * v], axis=2)


def release_null_space(adj):
    """G over all coordinate parameters, fixed ones included (M84 §2.2).

    The transformations that the observations leave free once every point is released.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.

    Returns
    -------
    params : numpy.ndarray
        Parameter indices (into ``Problem.params``) of G's rows: coordinates, then free nuisance
        parameters.
    G : numpy.ndarray
        len(params) × d null-space basis; rows in the units of their parameters (metres for
        coordinates) per unit of each transformation.
    names : list of str
        The d transformations' names.
    """
    problem = adj.problem
    params = problem.params
    coords = np.flatnonzero(params.kind == "k")
    t = np.flatnonzero((params.kind == "t") & ~params.fixed)
    cols = np.concatenate([coords, t])
    f, J = problem.evaluate(adj.x)
    A = J[:, cols].tocsr()
    G, names = datum_mod.null_space(problem, adj.x, A, adj.P, cols)
    return cols, G, names


def covariance(adj, sbase=None) -> CoordinateCovariance:
    """Coordinate covariance in the S-base ``sbase`` (M84 §2.2: Q_S = S Q Sᵀ).

    None keeps the adjustment's datum. The dense coordinate covariance is formed here, so this is for
    networks and blocks of up to a few thousand points; per-point blocks of big blocks come from
    ``Adjustment.point_cov``.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    sbase : iterable of str, optional
        Point ids of the S-base (3D: optionally ``normal=C``).

    Returns
    -------
    CoordinateCovariance
        Covariance of all coordinates (σ̂0² or σ0² applied by ``adj.variance_factor``), m².

    Raises
    ------
    baarda.errors.BaardaError
        When the S-base has no coordinates or does not fix the datum.
    """
    problem = adj.problem
    params = problem.params
    coords = np.flatnonzero(params.kind == "k")
    fpos = np.full(params.size, -1)
    fpos[params.free] = np.arange(params.free.size)
    loc = fpos[coords]
    est = loc >= 0
    i, j = np.meshgrid(loc[est], loc[est], indexing="ij")
    Sigma = np.zeros((coords.size, coords.size))
    Sigma[np.ix_(est, est)] = adj.cov_entries(i, j) * adj.variance_factor
    base = None
    if sbase is not None:
        cols, G, _ = release_null_space(adj)
        Gk = G[: coords.size]
        names, normal_id = datum_mod.split_normal(sbase)
        ids = problem.points.ids
        wanted = set(names)
        in_base = np.array([ids[params.point[c]] in wanted for c in coords])
        if not in_base.any():
            raise BaardaError(f"S-base {sorted(wanted)} has no coordinates in this problem")
        base = SBase(in_base)
        sb = tuple(sorted(wanted))
        if Gk.shape[1] and np.linalg.matrix_rank(Gk[in_base]) < Gk.shape[1]:
            base, third = _with_normal(adj, coords, in_base, wanted, normal_id)
            if base is None or np.linalg.matrix_rank(
                    np.vstack([Gk[in_base], base.normal @ Gk[base.normal_rows]])) < Gk.shape[1]:
                raise BaardaError(f"the S-base {sorted(wanted)} does not fix the datum ({Gk.shape[1]} "
                                  "transformations free)")
            sb = sb + (f"normal={third}",)
        if Gk.shape[1]:
            S = base.matrix(Gk)
            Sigma = S @ Sigma @ S.T
    else:
        sb = tuple(problem.datum.sbase) if problem.datum.kind == "free" else ()
    return CoordinateCovariance(coords, params.point[coords], params.axis[coords], Sigma, sb, base)


def _with_normal(adj, coords, in_base, wanted, normal_id):
    """The S-base with the normal condition of a 3D base of two points (M84 §2.2,
    :func:`baarda.datum.normal_condition`) over the coordinates ``coords``: (SBase, C's id), or
    (None, None) where it does not apply (not 3D, C unknown, all points collinear)."""
    problem = adj.problem
    params = problem.params
    ids = problem.points.ids
    pos = np.full((len(ids), 3), -1, dtype=np.int64)
    pos[params.point[coords], params.axis[coords]] = np.arange(coords.size)
    full = (pos >= 0).all(axis=1)
    base_pts = [k for k, i in enumerate(ids) if i in wanted]
    if normal_id is not None and normal_id not in ids:
        raise BaardaError(f"S-base: unknown point {normal_id} for the normal direction")
    if len(base_pts) < 2 or not full[base_pts].all():
        return None, None
    normal = None if normal_id is None else ids.index(normal_id)
    if normal is not None and not full[normal]:
        return None, None
    found = datum_mod.normal_condition(adj.coordinates, base_pts, np.flatnonzero(full), normal)
    if found is None:
        return None, None
    c, n = found
    return SBase(in_base, pos[c], n), ids[c]


def lambda_bar(adj, error: np.ndarray) -> float:
    """Baarda's datum-invariant measure λ̄ = ∇0kᵀ Q_kk⁻ ∇0k (M84 §3.2) of an observation error.

    ∇0k is the effect of the error on the coordinates; Q_kk⁻ a generalised inverse of their
    covariance in any S-base (here the pseudo-inverse of the released-network covariance).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    error : numpy.ndarray
        n values ∇0l, same units as the observations.

    Returns
    -------
    float
        λ̄, dimensionless.
    """
    dx = adj.deformation(error)
    cc = covariance(adj)
    fpos = np.full(adj.problem.params.size, -1)
    fpos[adj.problem.params.free] = np.arange(adj.problem.params.free.size)
    loc = fpos[cc.params]
    dk = np.where(loc >= 0, dx[np.maximum(loc, 0)], 0.0)
    return float(dk @ np.linalg.pinv(cc.cov / adj.variance_factor, rcond=1e-10, hermitian=True) @ dk)


# -- criterion matrices (M84 §2) -------------------------------------------------------------------

def chaotic_d2(l: np.ndarray, kind: str, C0: float, C1: float, C2: float = 1.0) -> np.ndarray:
    """d_ij² of the chaotic criterion matrix as a function of the distance l (M84 eq. 2, §2.3).

    Linear C0 + C1 l; logarithmic C0 + C1 C2 ln(1 + l/C2); exponential C0² + C1 (1 − exp(−C2² l)).

    Parameters
    ----------
    l : numpy.ndarray
        Distances, metres.
    kind : str
        "linear", "logarithmic" or "exponential".
    C0, C1, C2 : float
        Parameters in the units of :func:`baarda.stats.analyses.criterion_units`.

    Returns
    -------
    numpy.ndarray
        d², m², shaped as ``l``.

    Raises
    ------
    baarda.errors.BaardaError
        For an unknown ``kind``.
    """
    l = np.asarray(l, dtype=float)
    if kind == "linear":
        return C0 + C1 * l
    if kind == "logarithmic":
        return C0 + C1 * C2 * np.log1p(l / C2)
    if kind == "exponential":
        return C0 ** 2 + C1 * (1.0 - np.exp(-(C2 ** 2) * l))
    raise BaardaError(f"unknown criterion structure '{kind}' (linear, logarithmic, exponential)")


def distances(xy: np.ndarray) -> np.ndarray:
    """l_ij between the points ``xy``.

    Parameters
    ----------
    xy : numpy.ndarray
        m × 2 or m × 3 positions, metres.

    Returns
    -------
    numpy.ndarray
        m × m distances, metres.
    """
    xy = np.asarray(xy, dtype=float)
    return np.sqrt(((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=2))


def criterion_matrix(xy: np.ndarray, kind: str = "linear", C0: float = 0.0, C1: float = 1e-6,
                     C2: float = 1.0, d2: float | None = None, axes: int = 2) -> np.ndarray:
    """Chaotic criterion matrix H for points ``xy``, ordered point by point (M84 eq. 2, §2.2-2.3).

    var = d², cov = d² − ½ d_ij² with l_ij the distances. ``axes`` 2 for planimetry, 3 for 3D blocks
    and networks (the homogeneous and isotropic structure in R3, M84 §2.2), 1 for heights (the
    variance of a height difference d_ij² over the planimetric distance, M84 §2.3). d² defaults to the
    largest d_ij² so that H is positive semidefinite on the differences; it cancels in any S-base.

    Parameters
    ----------
    xy : numpy.ndarray
        m × 2 planimetric or m × 3 spatial positions, metres.
    kind : str
        "linear", "logarithmic" or "exponential" (:func:`chaotic_d2`).
    C0, C1, C2 : float
        Parameters of d² in the units of :func:`baarda.stats.analyses.criterion_units`.
    d2 : float, optional
        The variance d² of each coordinate, m².
    axes : int
        Coordinates per point (1, 2 or 3).

    Returns
    -------
    numpy.ndarray
        (m·axes) × (m·axes) matrix, m².
    """
    xy = np.asarray(xy, dtype=float)
    L = distances(xy)
    D2 = chaotic_d2(L, kind, C0, C1, C2)
    np.fill_diagonal(D2, 0.0)
    base = D2.max() if d2 is None else d2
    Cp = base - 0.5 * D2
    return np.kron(Cp, np.eye(axes))


def sbase_matrix(G: np.ndarray, in_base) -> np.ndarray:
    """Baarda's S-transformation S = I − G (EᵀG)⁻¹ Eᵀ, E the rows of G on the S-base (M84 §2).

    Parameters
    ----------
    G : numpy.ndarray
        u × d null space of the coordinates.
    in_base : SBase or array_like of bool
        S-base flags per coordinate or an :class:`SBase` (3D: with the normal condition).

    Returns
    -------
    numpy.ndarray
        u × u matrix S, dimensionless.
    """
    return as_sbase(in_base).matrix(G)


def sbase_transform(H: np.ndarray, G: np.ndarray, in_base: np.ndarray) -> np.ndarray:
    """S H Sᵀ, H transformed to the S-base (:func:`sbase_matrix`, M84 §2).

    Parameters
    ----------
    H : numpy.ndarray
        u × u covariance or criterion matrix, m².
    G : numpy.ndarray
        u × d null space.
    in_base : SBase or numpy.ndarray of bool
        The S-base.

    Returns
    -------
    numpy.ndarray
        u × u, same units as ``H``.
    """
    S = sbase_matrix(G, in_base)
    return S @ H @ S.T


def null_complement(G: np.ndarray) -> np.ndarray:
    """An orthonormal basis B of the complement of the null space spanned by G (M84 §2.2).

    BᵀG = 0, so that Bᵀ S = Bᵀ for every S-transformation S of :func:`sbase_matrix`.

    Parameters
    ----------
    G : numpy.ndarray
        u × d null space.

    Returns
    -------
    numpy.ndarray
        u × (u − d) basis, dimensionless.
    """
    return np.eye(G.shape[0]) if G.shape[1] == 0 else la.null_space(G.T)


@dataclass(frozen=True, eq=False)
class Comparison:
    """Generalised eigenvalues of |G − λH| = 0 (M84 eq. 3) on the complement of the null space:
    the same in every S-base (M84 §2.2). ``vectors`` are the eigenvectors as coordinate
    displacements (u × k, defined up to the null space); ``null`` the null space, ``in_base`` the
    S-base flags in which :meth:`worst_pattern` shows them."""

    lam: np.ndarray
    vectors: np.ndarray
    null: np.ndarray
    in_base: np.ndarray

    @property
    def lam_max(self) -> float:
        return float(self.lam[-1])

    @property
    def lam_min(self) -> float:
        return float(self.lam[0])

    @property
    def satisfied(self) -> bool:
        """λmax < 1: every function of the coordinates is more precise than the criterion."""
        return self.lam_max < 1.0

    def worst_pattern(self) -> np.ndarray:
        """The eigenvector of λmax as a displacement pattern in the S-base (S v, largest component 1;
        the S-base points of a minimal S-base do not move)."""
        v = self.vectors[:, -1]
        if self.null.shape[1]:
            v = sbase_matrix(self.null, self.in_base) @ v
            v[np.abs(v) < 1e-12 * np.abs(v).max()] = 0.0
        return v / np.abs(v).max()


def compare(G: np.ndarray, H: np.ndarray, null: np.ndarray, in_base: np.ndarray) -> Comparison:
    """λ of |G − λH| = 0 for a covariance G and a criterion H over the coordinates (M84 eq. 3, §2.2).

    Both matrices are taken on the complement of the null space, B (:func:`null_complement`):
    BᵀGB and BᵀHB are the same whatever S-base G and H are in (BᵀS = Bᵀ), so the judgement does
    not depend on the S-base (M84 §2.2). Dropping the S-base coordinates instead gives the same
    eigenvalues only for a minimal S-base; with more it works on a subspace and the result changes
    with the base. Where G is singular on that complement (control points fix the datum), the
    S-base coordinates are dropped.

    Parameters
    ----------
    G : numpy.ndarray
        u × u coordinate covariance, m².
    H : numpy.ndarray
        u × u criterion matrix, m².
    null : numpy.ndarray
        u × d null space of the datum.
    in_base : numpy.ndarray of bool or SBase
        S-base flags per coordinate.

    Returns
    -------
    Comparison
        The eigenvalues λ (dimensionless) and eigenvectors (coordinate displacements).

    Raises
    ------
    baarda.errors.BaardaError
        When G is singular on the coordinates compared.
    """
    null = np.asarray(null, dtype=float).reshape(G.shape[0], -1)
    flags = as_sbase(in_base).in_base
    B = null_complement(null)
    Gb = B.T @ G @ B
    g = np.linalg.eigvalsh(0.5 * (Gb + Gb.T))
    if g.size and g[0] <= 1e-12 * g[-1]:
        # G is not the S-transform of a free network's covariance: control points outside the
        # S-base fix the datum (their coordinates have no variance of their own), and G is
        # singular on the complement. The datum is given; compare on the coordinates outside
        # the S-base, as the S-base coordinates carry no variance.
        # Coordinates without variance of their own (fixed points: data, not estimates) are left
        # out too: on them G is zero and every λ would be 0 (a ratio of ±1e16 before).
        var = np.diag(G)
        B = np.eye(G.shape[0])[:, ~flags & (var > 1e-12 * max(float(var.max(initial=0.0)), 1e-300))]
        Gb = B.T @ G @ B
    Hb = B.T @ H @ B
    lam, V = la.eigh(0.5 * (Gb + Gb.T), 0.5 * (Hb + Hb.T))
    if lam.size and not lam[0] > 1e-12 * abs(lam[-1]):
        # a function of the compared coordinates without variance: no criterion can be fitted
        # to it and λmax/λmin is meaningless (it came out as −1e16)
        raise BaardaError(f"the coordinate covariance is singular on the coordinates compared (λmin = {lam[0]:.3g}, "
                          f"λmax = {lam[-1]:.3g}): some function of them has no variance, so the ratio "
                          "λmax/λmin is not defined")
    return Comparison(lam, B @ V, null, in_base)


def c2_bounds(kind: str, xy: np.ndarray) -> tuple[float, float]:
    """The range searched for C2 (M84 §2.3), from the network's own distances l.

    Logarithmic, C2 a length, in [l_min/1000, 1000 l_max]; exponential, C2² an inverse length
    (C2 in m^-½), 1/C2² in [l_min/1000, 1000 l_max]. Any C2 outside makes d² proportional to l or
    constant over the network.

    Parameters
    ----------
    kind : str
        "logarithmic" or "exponential" (any other kind gets the logarithmic range).
    xy : numpy.ndarray
        m × 2 or m × 3 positions, metres.

    Returns
    -------
    tuple of float
        Lower and upper bound of C2: metres (logarithmic) or m^-½ (exponential).

    Raises
    ------
    baarda.errors.BaardaError
        With fewer than two distinct points.
    """
    L = distances(xy)
    l = L[L > 0]
    if not l.size:
        raise BaardaError("a criterion matrix needs at least two distinct points")
    lo, hi = l.min() / 1e3, l.max() * 1e3
    if kind == "exponential":
        return 1.0 / np.sqrt(hi), 1.0 / np.sqrt(lo)
    return lo, hi


def fit_criterion(G: np.ndarray, xy: np.ndarray, in_base: np.ndarray, Gnull: np.ndarray,
                  kind: str = "logarithmic", axes: int = 2, C0: float = 0.0) -> dict:
    """Fit a chaotic criterion to a covariance G (M84 §2.3).

    C0 is chosen first (given; it belongs to the precision of the measurements), then C1 makes
    λmax = 1 and C2 makes λmax/λmin smallest. C2 is searched on a grid of 61 values over
    :func:`c2_bounds` and refined by Brent's method around the best grid value; ``C2_at_bound`` says
    the smallest ratio lies at the end of that range (for the plateau where d² is the same for every
    pair, the end of the plateau is given). With C0 = 0, H scales with C1 and C1 = λmax(C1 = 1);
    otherwise λmax falls as C1 grows and C1 is its root in [0, λmax of the C1 part alone at C1 = 1];
    when C0 alone already bounds G (λmax < 1 at C1 = 0) the condition λmax = 1 cannot be met: C1 = 0,
    ``C1_zero`` true and ``note`` says so.

    Parameters
    ----------
    G : numpy.ndarray
        u × u coordinate covariance in the S-base, m².
    xy : numpy.ndarray
        m × 2 or m × 3 positions, metres.
    in_base : numpy.ndarray of bool or SBase
        The S-base.
    Gnull : numpy.ndarray
        u × d null space of the datum.
    kind : str
        "linear", "logarithmic" or "exponential".
    axes : int
        Coordinates per point (1, 2 or 3).
    C0 : float
        m² (linear, logarithmic) or m (exponential: d² = C0² + …).

    Returns
    -------
    dict
        kind; C0; C1 in m²/m (linear, logarithmic) or m² (exponential); C2 in m (logarithmic) or
        m^-½ (exponential); ratio, lam_max, lam_min (dimensionless); C2_range; C2_at_bound; C1_zero;
        note.
    """
    null = np.asarray(Gnull, dtype=float)

    def lam(C1, C2, c0=C0):
        H = criterion_matrix(xy, kind, c0, C1, C2, axes=axes)
        return compare(G, sbase_transform(H, null, in_base), null, in_base)

    def fitted(C2):
        # the C1 part alone: H scales with C1, λmax(C1) = λmax(1)/C1, so at C1 = λmax(1) it alone
        # reaches λmax = 1, and with the C0 part added (positive semidefinite: a nugget, d_ij² = C0
        # or C0² for i ≠ j) λmax ≤ 1 there — the root lies in [0, λmax(1)]
        c1 = lam(1.0, C2, 0.0)
        if C0 == 0.0:
            return c1.lam_max, c1
        c0 = lam(0.0, C2)
        if c0.lam_max <= 1.0:               # C0 alone bounds G: C1 = 0, λmax < 1 (see "C1_zero")
            return 0.0, c0
        hi = max(c1.lam_max, 1e-300)
        for _ in range(60):                 # round-off at the end of the bracket: widen it
            if lam(hi, C2).lam_max <= 1.0:
                break
            hi *= 2.0
        C1 = optimize.brentq(lambda c: lam(c, C2).lam_max - 1.0, 0.0, hi, xtol=1e-14 * hi, rtol=1e-12)
        return C1, lam(C1, C2)

    def ratio(lc2):
        _, c = fitted(np.exp(lc2))
        return c.lam_max / max(c.lam_min, 1e-300)

    bounds, at_bound = (1.0, 1.0), False
    if kind == "linear":
        C2 = 1.0
    else:
        bounds = c2_bounds(kind, np.asarray(xy, dtype=float))
        grid = np.linspace(*np.log(bounds), 61)
        vals = np.array([ratio(g) for g in grid])
        k = int(np.argmin(vals))
        # the end where d² no longer varies over the network (exp(−C2² l) ≈ 0; C2 ≪ l): the
        # ratio is flat there, and a minimum on that plateau is the bound, not a C2 of its own
        flat = grid.size - 1 if kind == "exponential" else 0
        if vals[flat] <= vals[k] * (1.0 + 1e-9):
            C2, at_bound = float(np.exp(grid[flat])), True
        else:
            a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
            res = optimize.minimize_scalar(ratio, bounds=(a, b), method="bounded", options={"xatol": 1e-6})
            C2 = float(np.exp(res.x)) if res.fun <= vals[k] else float(np.exp(grid[k]))
            at_bound = k in (0, grid.size - 1)
    C1, c = fitted(C2)
    if C0 == 0.0:
        C1 = c.lam_max          # H scales with C1 when C0 = 0: λ(C1) = λ(1) / C1
        c = lam(C1, C2)
    zero = bool(C0 != 0.0 and C1 == 0.0)
    note = (f"C0 alone bounds the covariance (λmax = {c.lam_max:.4g} < 1 at C1 = 0): the fit's condition "
            "λmax = 1 (M84 §2.3) cannot be met with this C0, so C1 = 0 and C2 is not determined; a smaller C0 "
            "leaves room for C1" if zero else "")
    return {"kind": kind, "C0": float(C0), "C1": float(C1), "C2": float(C2),
            "ratio": float(c.lam_max / c.lam_min), "C2_range": [float(bounds[0]), float(bounds[1])],
            "C2_at_bound": bool(at_bound), "lam_max": float(c.lam_max), "lam_min": float(c.lam_min),
            "C1_zero": zero, "note": note}
