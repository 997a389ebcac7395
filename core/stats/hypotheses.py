"""Alternative hypotheses and their multi-dimensional tests (Förstner 1980, eq. 10-15).

A hypothesis is a matrix H (n × q): E(l | Hₐ) = A x + H ∇s. For an adjusted model with
P = C⁻¹ (σ0 absorbed, so that quadratic forms are already divided by σ0²):

    W_s  = Hᵀ P C_vv P H = HᵀPH − (AᵀPH)ᵀ Σ (AᵀPH)            (q × q)
    ∇ŝ  = −W_s⁻¹ HᵀPv                                          (F80 eq. 10; v = Ax̂ − l)
    T    = vᵀPH W_s⁻¹ HᵀPv  ~ χ'²(q, δ²)                         (F80 eq. 12)
    R    = (T/q) / ((vᵀPv − T)/(r − q)) ~ F'(q, r − q, δ²)       (σ0 not trusted)
    δ²   = ∇sᵀ W_s ∇s                                            (F80 eq. 11)

The lower bound of detectable errors is the ellipse/ellipsoid ∇0sᵀ W_s ∇0s = δ0²
(F80 eq. 13) with semi-axes δ0/√eig(W_s); the standardised sensitivity
δ0'(s) = δ0 √(sᵀHᵀPHs / sᵀW_s s) (F80 eq. 14) is largest, δ0 √λmax, in the weakest direction of
the pencil (HᵀPH, W_s) (F80 §7.3). Computing W_s takes q solves with the cached factor.

An undetectable error ∇0s moves the coordinates by ∇0k = Q_kk C̄ᵀ P H ∇0s (F80 eq. 16, C̄ the
coordinate columns reduced for the nuisance parameters); its standardised length
δ̄0(s) = δ0 √(sᵀ M s / sᵀ W_s s), M = HᵀP C̄ Q_kk C̄ᵀ P H (F80 eq. 17), bounds the effect on any
function f = gᵀk: ∇0f ≤ σ_f δ̄0(s) (F80 eq. 18). Its maximum over s, δ0 √λmax of the pencil
(M, W_s), and the direction that reaches it come from :func:`external_reliability`; Baarda's
λ̄ = ∇0kᵀ Q_kk⁻ ∇0k (M84 §3.2) is δ̄0(s)².
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

from ..errors import HypothesisError, NotFoundError
from ..model.bundle import control_rows, gnss_rows, image_rows, problem_of
from ..model.problem import image_point_index
from ..observations.collinearity import AP_GROUPS, BASES, CollinearitySet
from ..solve.linalg import SPDFactor
from .policy import TestPolicy


#: slack of the bound T_j ≤ vᵀPv of :func:`counted_directions` (relative, absolute)
T_BOUND_SLACK = (1e-6, 1e-9)


def counted_directions(lam: np.ndarray, V: np.ndarray, g: np.ndarray, tol, vPv: float):
    """The eigen-directions of W_s that a test counts, and their statistics T_j (F80 eq. 10-12).

    λ_j above the round-off floor ``tol`` and T_j = (v_jᵀg)²/λ_j within what the data hold,
    T_j ≤ vᵀPv: an exact W_s holds g in its range and every test of a subspace is a part of Ω/σ0²
    (R's denominator Ω0 − T ≥ 0, F80 eq. 12), so a direction claiming more is the round-off
    eigenvalue of a rank-deficient W_s (e.g. two keypoints of one far point in one image).

    Parameters
    ----------
    lam : numpy.ndarray
        (..., m) eigenvalues of W_s (units of the observations to the power −2, σ0 absorbed).
    V : numpy.ndarray
        (..., m, m) eigenvectors, dimensionless.
    g : numpy.ndarray
        (..., m) HᵀPv, units of the observations to the power −1.
    tol : float or numpy.ndarray
        Round-off floor of λ, scalar or (...,).
    vPv : float
        Ω/σ0², dimensionless.

    Returns
    -------
    mask : numpy.ndarray of bool
        (..., m) the counted directions; their number is the rank q of the test.
    Tj : numpy.ndarray
        (..., m) T_j, dimensionless (0 where not counted).
    """
    lam = np.asarray(lam, dtype=float)
    proj = np.einsum("...ji,...j->...i", V, g)
    pos = lam > np.asarray(tol, dtype=float)[..., None]
    Tj = np.where(pos, proj * proj / np.where(pos, lam, 1.0), 0.0)
    rel, ab = T_BOUND_SLACK
    pos &= Tj <= max(float(vPv), 0.0) * (1.0 + rel) + ab
    return pos, np.where(pos, Tj, 0.0)


def selection(n: int, members, weights=None) -> sp.csc_matrix:
    """H that adds an independent error to each listed observation (columns e_i; F80 §2.2).

    Parameters
    ----------
    n : int
        Number of observations.
    members : array_like of int
        The q observation rows.
    weights : array_like of float, optional
        Entries of the columns instead of 1.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × q hypothesis matrix, dimensionless; ∇s in the units of the observations.
    """
    members = np.asarray(members, dtype=np.int64)
    q = members.size
    data = np.ones(q) if weights is None else np.asarray(weights, dtype=float)
    return sp.csc_matrix((data, (members, np.arange(q))), shape=(n, q))


def common_error(n: int, rows_per_component: list[np.ndarray]) -> sp.csc_matrix:
    """H for one error vector common to several observations (F80 §2.2, point transfer).

    For a point-transfer error in images i..j: the x rows and the y rows of that point in those
    images, H = (0 … I₂ … I₂ … I₂ … 0)ᵀ.

    Parameters
    ----------
    n : int
        Number of observations.
    rows_per_component : list of numpy.ndarray
        ``rows_per_component[c]`` the observations that the c-th component of ∇s enters.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × q hypothesis matrix of ones, dimensionless.
    """
    rows, cols = [], []
    for c, rr in enumerate(rows_per_component):
        rr = np.asarray(rr, dtype=np.int64)
        rows.append(rr)
        cols.append(np.full(rr.size, c))
    r = np.concatenate(rows)
    return sp.csc_matrix((np.ones(r.size), (r, np.concatenate(cols))), shape=(n, len(rows_per_component)))


@dataclass(frozen=True, eq=False)
class HypothesisTest:
    """A tested hypothesis. Units of ∇ŝ are those of the observations (SI)."""

    label: str
    H: object
    q: int
    W: np.ndarray
    T: float
    R: float
    dof: int
    alpha: float
    critical_T: float
    critical_R: float
    nabla: np.ndarray
    nabla_cov: np.ndarray
    delta0: float
    ellipse_axes: np.ndarray
    ellipse_dirs: np.ndarray
    delta0_prime_max: float
    weakest: np.ndarray
    extra: dict = field(default_factory=dict)

    @property
    def rejected_T(self) -> bool:
        return bool(self.T > self.critical_T)

    @property
    def rejected_R(self) -> bool:
        return bool(self.R > self.critical_R)

    @property
    def nabla_sigma(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.nabla_cov), 0.0))

    def lower_bound(self, direction) -> np.ndarray:
        """∇0s in a direction s: s δ0 / √(sᵀW s) (F80 eq. 13).

        sᵀW s is taken over the eigenvalues of W the test counts (q of them; the others are
        round-off, possibly negative): a direction the test cannot see at all (sᵀW s = 0 there)
        has no finite lower bound (±inf along s)."""
        s = np.asarray(direction, dtype=float)
        s = s / np.linalg.norm(s)
        pos = np.isfinite(self.ellipse_axes)
        lam = (self.delta0 / self.ellipse_axes[pos]) ** 2          # axes = δ0/√λ (F80 eq. 14)
        sws = float(lam @ (self.ellipse_dirs[:, pos].T @ s) ** 2)
        if not sws > 0:
            return np.where(s == 0, 0.0, np.copysign(np.inf, s))
        return s * self.delta0 / np.sqrt(sws)

    def ellipse(self, n: int = 73) -> np.ndarray:
        """Points of the lower-bound ellipse ∇0sᵀ W ∇0s = δ0² (q = 2), n × 2."""
        t = np.linspace(0, 2 * np.pi, n)
        return (self.ellipse_dirs @ (self.ellipse_axes[:, None] * np.vstack([np.cos(t), np.sin(t)]))).T

    def as_dict(self) -> dict:
        return {"label": self.label, "dimension": self.q, "T": self.T, "R": self.R,
                "critical_T": self.critical_T, "critical_R": self.critical_R, "alpha": self.alpha,
                "rejected": self.rejected_T, "nabla": self.nabla.tolist(),
                "nabla_sigma": self.nabla_sigma.tolist(), "delta0": self.delta0,
                "ellipse_axes": self.ellipse_axes.tolist(),
                "delta0_prime_max": self.delta0_prime_max}


def test(adj, H, label: str = "", policy=None) -> HypothesisTest:
    """Test hypothesis H against the adjustment ``adj`` (F80 eq. 10-15; see module docstring).

    W_s = HᵀPQ_vvPH, ∇ŝ = −W_s⁻¹HᵀPv (eq. 10), T (eq. 12), R, the lower-bound ellipse with
    semi-axes δ0/√eig(W_s) (eq. 13) and δ0′max = δ0 √λmax(HᵀPH, W_s) (eq. 14, §7.3).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    H : scipy.sparse matrix or array_like
        n × q hypothesis matrix, dimensionless.
    label : str
        Name of the hypothesis.
    policy : baarda.stats.policy.TestPolicy, optional
        Gives α_q, the critical values and δ0 (the B-method rule); default the policy of ``adj.options``.

    Returns
    -------
    HypothesisTest
        T, R, δ0 dimensionless; ∇ŝ, its covariance and the ellipse axes in the units of the
        observations (σ0 absorbed in P).

    Raises
    ------
    baarda.errors.HypothesisError
        When H does not have one row per observation.
    """
    H = sp.csc_matrix(H) if not sp.issparse(H) else H.tocsc()
    n, q_cols = H.shape
    if n != adj.n:
        raise HypothesisError(f"H has {n} rows for {adj.n} observations", rows=n, n=adj.n)
    PH = (adj.P @ H).toarray() if sp.issparse(adj.P @ H) else np.asarray(adj.P @ H)
    AtPH = adj.Ar.T @ PH
    Y = adj.factor.solve(AtPH)
    HPH = np.asarray(H.T @ PH)
    W = HPH - AtPH.T @ Y.reshape(AtPH.shape)
    W = 0.5 * (W + W.T)
    lam, V = la.eigh(W)
    tol = 1e-10 * max(lam.max(initial=0.0), np.abs(np.diag(HPH)).max(initial=0.0), 1e-300)
    g = np.asarray(H.T @ adj.Pv).ravel()
    dof = adj.dof
    vPv = adj.vPv
    pos, Tj = counted_directions(lam, V, g, tol, vPv)      # q = rank W_s, T within vᵀPv
    q = int(pos.sum())
    Winv = (V[:, pos] / lam[pos]) @ V[:, pos].T
    nabla = -Winv @ g
    T = float(Tj.sum())
    R = float((T / q) / ((vPv - T) / (dof - q))) if (q and dof > q and vPv > T) else float("nan")
    policy = TestPolicy.from_options(adj.options) if policy is None else policy
    alpha = policy.alpha(q)
    d0 = policy.delta0(q)
    crit_T = policy.critical_T(q)
    crit_R = policy.critical_R(q, dof)
    axes = np.where(pos, d0 / np.sqrt(np.where(pos, lam, 1.0)), np.inf)
    # weakest direction: largest generalized eigenvalue of (HᵀPH, W) (F80 §7.3)
    if q == q_cols:
        mu, U = la.eigh(HPH, W)
        dmax = float(d0 * np.sqrt(max(mu.max(), 0.0)))
        weakest = U[:, -1] / np.linalg.norm(U[:, -1])
    else:
        dmax, weakest = float("inf"), V[:, 0]
    return HypothesisTest(label=label, H=H, q=q, W=W, T=T, R=R, dof=dof, alpha=alpha,
                          critical_T=crit_T, critical_R=crit_R, nabla=nabla, nabla_cov=Winv,
                          delta0=d0, ellipse_axes=axes, ellipse_dirs=V, delta0_prime_max=dmax,
                          weakest=weakest)


def deformation(adj, h: HypothesisTest, nabla_s=None) -> np.ndarray:
    """∇0x = Σ AᵀP H ∇0s over the free parameters (F80 §6, eq. 16 for the k-part).

    ``nabla_s`` defaults to the lower bound in the direction of the smallest eigenvalue of W_s
    the test counts (the largest error the test cannot see at power β0).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    h : HypothesisTest
        The tested hypothesis (:func:`test`).
    nabla_s : array_like of float, optional
        The error ∇0s, q values in the units of the observations.

    Returns
    -------
    numpy.ndarray
        ∇0x, one value per free parameter in its own units (metres for coordinates).

    Raises
    ------
    baarda.errors.HypothesisError
        When the test sees no error (q = 0) or ``nabla_s`` is infinite.
    """
    if nabla_s is None:
        pos = np.flatnonzero(np.isfinite(h.ellipse_axes))
        if not pos.size:
            raise HypothesisError("the test sees no error of this hypothesis (q = 0): no lower bound", q=0)
        nabla_s = h.lower_bound(h.ellipse_dirs[:, pos[0]])   # smallest eigenvalue the test counts
    nabla_s = np.asarray(nabla_s, dtype=float)
    if not np.isfinite(nabla_s).all():
        raise HypothesisError("the test cannot see this error (infinite lower bound)")
    err = np.asarray(h.H @ nabla_s).ravel()
    return adj.deformation(err)


def coordinate_norm(adj, D: np.ndarray, exclude=()) -> np.ndarray:
    """Dᵀ (C̄ᵀPC̄) D for displacements D of the coordinates, F80 eq. 16.

    C̄ = (I − B(BᵀPB)⁻¹BᵀP)C with B the nuisance columns except ``exclude`` (an AP group under test,
    :func:`baarda.stats.ap_tests.ap_test`). The form is datum invariant: with D = ∇0k it is
    Baarda's λ̄ (M84 §3.2) and δ̄0(s)² (F80 eq. 17).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    D : numpy.ndarray
        k_free × q displacements of the free coordinates, metres.
    exclude : sequence of int
        Free positions of nuisance parameters left out of B.

    Returns
    -------
    numpy.ndarray
        q × q symmetric form, dimensionless (σ0 absorbed in P).
    """
    kind = adj.problem.params.kind[adj.problem.params.free]
    k = np.flatnonzero(kind == "k")
    t = np.setdiff1d(np.flatnonzero(kind == "t"), np.asarray(exclude, dtype=np.int64))
    E = adj.A[:, k] @ D
    PE = adj.P @ E
    M = E.T @ PE
    if t.size:
        B = adj.A[:, t].tocsr()
        F = B.T @ PE
        M = M - F.T @ SPDFactor((B.T @ adj.P @ B).tocsr()).solve(F).reshape(F.shape)
    return 0.5 * (M + M.T)


@dataclass(frozen=True, eq=False)
class ExternalReliability:
    """F80 eq. 17-18 for a hypothesis: ``M`` = HᵀP C̄ Q_kk C̄ᵀ P H and ``W`` = W_s (q × q, in the
    test's ∇s units), δ0 of the test; ``max`` = max_s δ̄0(s) = δ0 √λmax(M, W_s) and ``direction``
    the unit s that reaches it; ``Dk`` the coordinate effect ∇k of a unit ∇s per column
    (k_free × q, F80 eq. 16, in the problem's datum)."""

    delta0: float
    M: np.ndarray
    W: np.ndarray
    max: float
    direction: np.ndarray
    Dk: np.ndarray

    def delta_bar0(self, s) -> float:
        """δ̄0(s) = δ0 √(sᵀMs / sᵀW_s s) (F80 eq. 17); inf where the test cannot see s."""
        s = np.asarray(s, dtype=float)
        sws = float(s @ self.W @ s)
        if not sws > 1e-12 * max(float(np.abs(np.diag(self.W)).max(initial=0.0)), 1e-300) * float(s @ s):
            return float("inf")
        return float(self.delta0 * np.sqrt(max(float(s @ self.M @ s), 0.0) / sws))

    @property
    def lambda_bar_max(self) -> float:
        """Baarda's λ̄ of the most influential undetectable error, δ̄0max² (M84 §3.2)."""
        return self.max ** 2


def external_reliability(adj, h: HypothesisTest) -> ExternalReliability:
    """δ̄0(s) of hypothesis ``h`` (F80 eq. 17), its maximum and direction (F80 §7.3).

    ∇k per unit ∇s from q solves with the cached factor (Σ AᵀP H, its coordinate part);
    M = Dkᵀ (C̄ᵀPC̄) Dk (:func:`coordinate_norm`), the maximum from the generalised
    eigenproblem of (M, W_s) on the directions the test sees (q of them).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    h : HypothesisTest
        The tested hypothesis (:func:`test`).

    Returns
    -------
    ExternalReliability
        δ̄0max (dimensionless), its unit direction s, M and W_s, and ∇k per unit ∇s (metres per
        unit of the observations).
    """
    H = h.H
    PH = adj.P @ H
    rhs = adj.A.T @ (PH.toarray() if sp.issparse(PH) else np.asarray(PH))
    Y = adj.solve_normal(np.asarray(rhs))
    kind = adj.problem.params.kind[adj.problem.params.free]
    Dk = Y[kind == "k"]
    M = coordinate_norm(adj, Dk)
    V, pos = h.ellipse_dirs, np.isfinite(h.ellipse_axes)
    if not pos.any():
        return ExternalReliability(h.delta0, M, h.W, float("inf"), V[:, 0], Dk)
    U = V[:, pos] * (h.ellipse_axes[pos] / h.delta0)     # axes = δ0/√λ(W_s): Uᵀ W_s U = I
    mu, Z = la.eigh(U.T @ M @ U)
    s = U @ Z[:, -1]
    s = s / np.linalg.norm(s)
    return ExternalReliability(h.delta0, M, h.W, float(h.delta0 * np.sqrt(max(mu[-1], 0.0))), s, Dk)


# --------------------------------------------------------------------------------------------
# hypotheses for blocks (F80 §2.2)
# --------------------------------------------------------------------------------------------
def h_image_coordinate(problem, image: str, point: str, component: str):
    """H (n × 1) of a gross error in one image coordinate (F80 §2.2).

    Parameters
    ----------
    problem : baarda.model.problem.Problem or baarda.result.Adjustment
        The block (or its adjustment).
    image, point : str
        Image and point ids.
    component : str
        "x" or "y".

    Returns
    -------
    scipy.sparse.csc_matrix
        n × 1, dimensionless; ∇s in pixels (image units).
    """
    problem = problem_of(problem)
    r = image_rows(problem, image, point)["xy".index(component)]
    return selection(problem.n, [r])


def h_image_point(problem, image: str, point: str):
    """H (n × 2) of a 2D error in one image point (F80 §2.2, q = 2).

    Parameters
    ----------
    problem : baarda.model.problem.Problem or baarda.result.Adjustment
        The block (or its adjustment).
    image, point : str
        Image and point ids.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × 2, dimensionless; ∇s in pixels (image units).
    """
    problem = problem_of(problem)
    return selection(problem.n, image_rows(problem, image, point))


def h_control_point(problem, point: str):
    """H (n × q) of an error in a control point's observed coordinates (F80 §2.2; q = 2 or 3).

    Parameters
    ----------
    problem : baarda.model.problem.Problem or baarda.result.Adjustment
        The block (or its adjustment).
    point : str
        Control point id.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × q, dimensionless; ∇s in metres.
    """
    problem = problem_of(problem)
    return selection(problem.n, control_rows(problem, point))


def h_point_transfer(problem, point: str, images) -> sp.csc_matrix:
    """H (n × 2) of a point-transfer error common to the measurements of ``point`` in ``images``.

    F80 §2.2; H = (0 … I₂ … I₂ … 0)ᵀ via :func:`common_error`.

    Parameters
    ----------
    problem : baarda.model.problem.Problem or baarda.result.Adjustment
        The block (or its adjustment).
    point : str
        Tie point id.
    images : iterable of str
        The image ids after the wrong transfer.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × 2, dimensionless; ∇s in image units (pixels, x and y).
    """
    problem = problem_of(problem)
    rows = np.array([image_rows(problem, im, point) for im in images])
    return common_error(problem.n, [rows[:, 0], rows[:, 1]])


def h_exchanged(adj, image: str, point_a: str, point_b: str, both: bool = True) -> sp.csc_matrix:
    """H (n × 1) of a misidentification in one image (F80 §2.2, §7.1; test F80 eq. 12 with q = 1).

    Point a was measured where point b is imaged, e_a = p_b − p_a, with p the predicted
    (adjusted) image positions ``adj.f``; if ``both`` (an *exchange*), b was measured at a as
    well, e_b = p_a − p_b. ∇ŝ ≈ 1 means the full exchange and ∇ŝ ≈ 0 none. The column depends on
    the solution (linearised about x̂).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    image, point_a, point_b : str
        Image id and the ids of the two points.
    both : bool
        An exchange (both measurements swapped) rather than one misidentification.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × 1 in pixels (image units); ∇s dimensionless.
    """
    ra = image_rows(adj.problem, image, point_a)
    rb = image_rows(adj.problem, image, point_b)
    d = adj.f[rb] - adj.f[ra]
    rows = np.r_[ra, rb] if both else ra
    vals = np.r_[d, -d] if both else d
    return sp.csc_matrix((vals, (rows, np.zeros(rows.size, dtype=np.int64))), shape=(adj.n, 1))


def h_ap_group(adj, camera: str, group: str) -> sp.csc_matrix:
    """H (n × q) of an AP group *not* in the model: ∂f/∂a at the solution (F80 eq. 6-7).

    Columns are the basis functions of ``group`` ("brown" or "ebner", module docstring) at the
    adjusted ideal image coordinates of every measurement of ``camera``.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment of a bundle block.
    camera : str
        Camera id.
    group : str
        A key of ``AP_GROUPS``.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × q, image units per unit of each AP.
    """
    problem = adj.problem
    geo = problem.geometry
    cam = geo.camera_by_id(camera)
    q = len(AP_GROUPS[group])
    rows, cols, vals = [], [], []
    full = adj.x
    cam_images = geo.images_of(camera)
    for s in problem.sets:
        if not isinstance(s, CollinearitySet):
            continue
        xr = s.rows[0::2]
        if problem.info.ids[xr[0]]["image"] not in cam_images:
            continue
        xb, yb, *_ = s.ideal(full)
        Fx, Fy, *_ = BASES[group](xb / cam.ap_scale, yb / cam.ap_scale)
        for k in range(q):
            rows += [xr, s.rows[1::2]]
            cols += [np.full(xr.size, k)] * 2
            vals += [Fx[:, k], Fy[:, k]]
    return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(adj.n, q))


# --------------------------------------------------------------------------------------------
# hypotheses for independent-model blocks
# --------------------------------------------------------------------------------------------
def h_model_point(problem, model: str, point: str):
    """H (n × 2) of a 2D error in one point's model coordinates (F80 §2.2).

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        An independent-model block.
    model, point : str
        Model and point ids.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × 2, dimensionless; ∇s in the units of the model coordinates.

    Raises
    ------
    baarda.errors.NotFoundError
        When the model holds no x and y of the point.
    """
    rows = [None, None]
    for i, (k, ids) in enumerate(zip(problem.info.kind, problem.info.ids)):
        if k.startswith("model-") and ids["model"] == model and ids["point"] == point:
            rows["xy".index(ids["component"])] = i
    if None in rows:
        raise NotFoundError("model point", {"model": model, "point": point},
                            f"no model coordinates of point {point} in model {model}")
    return selection(problem.n, rows)


# --------------------------------------------------------------------------------------------
# hypotheses named by a specification (``baarda test``; the dashboard's hypothesis dicts)
# --------------------------------------------------------------------------------------------
#: The kinds of :func:`hypothesis_matrix`, with the fields each specification needs.
KINDS = {
    "observation": ("index",),
    "group": ("group",),
    "image-point": ("image", "point"),
    "control": ("point",),
    "transfer": ("point", "images"),
    "ap-group": ("camera", "group"),
    "exchanged": ("image", "a", "b"),
    "model-point": ("model", "point"),
    "gnss": ("image",),
    "gnss-strip": ("strip",),
}


def _id(problem, field: str, value):
    """The id object of ``problem.info.ids`` whose text is ``value`` (ids read from a command
    line are text; a file may hold numbers), or NotFoundError."""
    want = str(value)
    for ids in problem.info.ids:
        v = ids.get(field)
        if v is not None and str(v) == want:
            return v
    raise NotFoundError(field, {field: value}, f"no {field} {value} in the observations")


def hypothesis_rows(problem, spec: dict, index: dict | None = None) -> list[np.ndarray]:
    """The observations a hypothesis specification acts on (F80 §2.2; see :func:`hypothesis_matrix`).

    One array per component of ∇s for a point transfer (its x rows, its y rows in the images
    listed), else one array of the rows H selects. The one place both ``baarda test`` and the
    dashboard find them; ids are matched by their text.

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The problem.
    spec : dict
        ``{"kind": ..., fields}`` with the fields of :data:`KINDS`.
    index : dict, optional
        :func:`baarda.model.problem.image_point_index` of ``problem`` if already built.

    Returns
    -------
    list of numpy.ndarray
        Observation rows (int64), one array per component or one in all.

    Raises
    ------
    baarda.errors.NotFoundError
        For ids the problem does not have.
    baarda.errors.HypothesisError
        For an ambiguous image point or a kind built from the solution.
    """
    info = problem.info
    kind = spec["kind"]
    if kind == "observation":
        i = int(spec["index"])
        if not 0 <= i < problem.n:
            raise NotFoundError("observation", {"index": i}, f"no observation {i} (0 … {problem.n - 1})")
        return [np.array([i], dtype=np.int64)]
    if kind == "group":
        rows = np.flatnonzero(np.asarray(info.group) == int(spec["group"]))
        if not rows.size:
            raise NotFoundError("test group", {"group": spec["group"]}, f"no test group {spec['group']}")
        return [rows]
    if kind == "control":
        point = _id(problem, "id", spec["point"])
        return [np.array([i for i, ids in enumerate(info.ids) if ids.get("id") == point], dtype=np.int64)]
    if kind == "gnss":
        return [gnss_rows(problem, spec["image"])]
    if kind == "gnss-strip":
        rows = [np.array([i for i, (k, ids) in enumerate(zip(info.kind, info.ids))
                          if k == f"gnss-{a}" and str(ids.get("strip")) == str(spec["strip"])], dtype=np.int64)
                for a in "xyz"]
        if not rows[0].size:
            raise NotFoundError("GNSS strip", {"strip": spec["strip"]}, f"no GNSS centre in strip {spec['strip']}")
        return rows
    if kind == "ap-group":
        geo = problem.geometry
        images = {str(im.id) for im in (geo.images if geo is not None else ())
                  if str(im.camera) == str(spec["camera"])}
        return [np.array([i for i, ids in enumerate(info.ids) if str(ids.get("image")) in images], dtype=np.int64)]
    index = image_point_index(problem) if index is None else index
    point = str(spec["point"])
    if kind == "image-point":
        image = str(spec["image"])
        found = {kp: r for (im, pt, kp), r in index.items() if im == image and pt == point}
        if spec.get("keypoint") is not None:
            want = str(spec["keypoint"])
            found = {kp: r for kp, r in found.items() if kp == want}
            if not found:
                raise NotFoundError("image point", {"image": image, "point": point, "keypoint": want},
                                    f"image {image} does not observe point {point} by keypoint {want}")
        if len(found) > 1:
            raise HypothesisError(f"image {image} observes point {point} by keypoints "
                                  f"{', '.join(sorted(map(str, found)))}: name one (image-point:IMAGE:POINT:KEYPOINT)")
        if not found:
            raise NotFoundError("image point", {"image": image, "point": point},
                                f"no measurement of point {point} in image {image}")
        return [np.array(next(iter(found.values())), dtype=np.int64)]
    if kind == "transfer":
        images = {str(j) for j in spec["images"]}
        rows = sorted(i for (im, pt, _), r in index.items() if im in images and pt == point for i in r)
        missing = images - {im for (im, pt, _) in index if pt == point}
        if missing:
            raise NotFoundError("image point", {"images": sorted(missing), "point": point},
                                f"no measurement of point {point} in image {', '.join(sorted(missing))}")
        comps: dict = {}
        for i in rows:
            comp = info.ids[i].get("component") or info.kind[i].rsplit("-", 1)[-1]
            comps.setdefault(str(comp), []).append(i)
        return [np.array(comps[c], dtype=np.int64) for c in sorted(comps)]
    raise HypothesisError(f"{kind}: no observation rows (a hypothesis built from the solution)")


def hypothesis_matrix(adj, spec: dict) -> sp.csc_matrix:
    """H (n × q) of a hypothesis specification (F80 §2.2, §7.1).

    A dict ``{"kind": ..., fields}`` with the fields of :data:`KINDS`: one observation (``index``),
    a test group of the problem (``group``), an image point (``keypoint`` optional, for COLMAP
    images observing a point by several keypoints), a control (or observed-coordinate) point, a
    point transfer in ``images``, an AP group not in the model (H = ∂f/∂s, :func:`h_ap_group`), a
    misidentification of points ``a`` and ``b`` in ``image`` (:func:`h_exchanged`), a model point.
    Ids are matched by their text.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    spec : dict
        The specification.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × q, dimensionless for selections (∇s in the units of the observations); see
        :func:`h_exchanged` and :func:`h_ap_group` for theirs.

    Raises
    ------
    baarda.errors.NotFoundError
        For what the model does not have.
    baarda.errors.HypothesisError
        For a bad specification.
    """
    kind = spec.get("kind")
    if kind not in KINDS:
        raise HypothesisError(f"unknown hypothesis kind {kind!r} (one of {', '.join(KINDS)})")
    missing = [f for f in KINDS[kind] if spec.get(f) in (None, "", [])]
    if missing:
        raise HypothesisError(f"{kind}: missing {', '.join(missing)}")
    problem = adj.problem
    if kind in ("observation", "group", "control", "image-point", "transfer", "gnss", "gnss-strip"):
        rows = hypothesis_rows(problem, spec)
        return common_error(problem.n, rows) if kind in ("transfer", "gnss-strip") else selection(problem.n, rows[0])
    if kind == "exchanged":
        image = _id(problem, "image", spec["image"])
        return h_exchanged(adj, image, _id(problem, "point", spec["a"]), _id(problem, "point", spec["b"]))
    if kind == "model-point":
        return h_model_point(problem, _id(problem, "model", spec["model"]), _id(problem, "point", spec["point"]))
    cameras = [c.id for c in (problem.geometry.cameras if problem.geometry is not None else ())]
    camera = next((c for c in cameras if str(c) == str(spec["camera"])), None)
    if camera is None:
        raise NotFoundError("camera", {"camera": spec["camera"]}, f"no camera {spec['camera']} in the block")
    if spec["group"] not in AP_GROUPS:
        raise HypothesisError(f"ap-group: unknown AP group {spec['group']!r} (one of {', '.join(AP_GROUPS)})")
    return h_ap_group(adj, camera, spec["group"])
