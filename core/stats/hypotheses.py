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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

from ..errors import HypothesisError, NotFoundError
from ..model.bundle import AP_GROUPS, BASES, CollinearitySet, control_rows, image_rows, problem_of


def selection(n: int, members, weights=None) -> sp.csc_matrix:
    """H that adds an independent error to each listed observation (columns e_i)."""
    members = np.asarray(members, dtype=np.int64)
    q = members.size
    data = np.ones(q) if weights is None else np.asarray(weights, dtype=float)
    return sp.csc_matrix((data, (members, np.arange(q))), shape=(n, q))


def common_error(n: int, rows_per_component: list[np.ndarray]) -> sp.csc_matrix:
    """H for one error vector common to several observations (F80 §2.2, point transfer).

    ``rows_per_component[c]`` lists the observations that the c-th component of ∇s enters,
    e.g. for a point-transfer error in images i..j: the x rows and the y rows of that point in
    those images, H = (0 … I₂ … I₂ … I₂ … 0)ᵀ.
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

    ``policy`` (:class:`baarda.stats.policy.TestPolicy`; default ``adj.policy``) gives the size α_q,
    the critical values and δ0 (the B-method rule)."""
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
    pos = lam > tol
    q = int(pos.sum())
    Winv = (V[:, pos] / lam[pos]) @ V[:, pos].T
    g = np.asarray(H.T @ adj.Pv).ravel()
    nabla = -Winv @ g
    T = float(g @ Winv @ g)
    dof = adj.dof
    vPv = adj.vPv
    R = float((T / q) / ((vPv - T) / (dof - q))) if (q and dof > q and vPv > T) else float("nan")
    policy = adj.policy if policy is None else policy
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
    the test counts (the largest error the test cannot see at power β0); a hypothesis the test
    cannot see at all (q = 0) or an infinite ``nabla_s`` has no deformation (HypothesisError).
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


# --------------------------------------------------------------------------------------------
# hypotheses for blocks (F80 §2.2, THEORY.md §3)
# --------------------------------------------------------------------------------------------
def h_image_coordinate(problem, image: str, point: str, component: str):
    """H (n × 1) of a gross error in one image coordinate (``component`` "x" or "y")."""
    problem = problem_of(problem)
    r = image_rows(problem, image, point)["xy".index(component)]
    return selection(problem.n, [r])


def h_image_point(problem, image: str, point: str):
    """H (n × 2) of a 2D error in one image point (F80 §2.2, q = 2)."""
    problem = problem_of(problem)
    return selection(problem.n, image_rows(problem, image, point))


def h_control_point(problem, point: str):
    """H (n × q) of an error in a control point's observed coordinates (q = 2 or 3)."""
    problem = problem_of(problem)
    return selection(problem.n, control_rows(problem, point))


def h_point_transfer(problem, point: str, images) -> sp.csc_matrix:
    """H (n × 2) of a point-transfer error: one 2D error common to the measurements of
    ``point`` in every image of ``images`` (F80 §2.2; H = (0 … I₂ … I₂ … 0)ᵀ via
    :func:`baarda.stats.hypotheses.common_error`). ∇s is in image units (x, y)."""
    problem = problem_of(problem)
    rows = np.array([image_rows(problem, im, point) for im in images])
    return common_error(problem.n, [rows[:, 0], rows[:, 1]])


def h_exchanged(adj, image: str, point_a: str, point_b: str, both: bool = True) -> sp.csc_matrix:
    """H (n × 1) of a misidentification in one image.

    Model: point a was measured where point b is imaged, e_a = p_b − p_a, with p the predicted
    (adjusted) image positions ``adj.f``; if ``both`` (an *exchange*), b was measured at a as
    well, e_b = p_a − p_b. One column, so ∇ŝ ≈ 1 means the full exchange and ∇ŝ ≈ 0 none.
    The column depends on the solution (linearised about x̂); the test is F80 eq. 12 with q = 1.
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
    """
    problem = adj.problem
    block = problem.extra["block"]
    cam = next(c for c in block["cameras"] if c["id"] == camera)
    q = len(AP_GROUPS[group])
    rows, cols, vals = [], [], []
    full = adj.x
    cam_images = {im["id"] for im in block["images"] if im["camera"] == camera}
    for s in problem.sets:
        if not isinstance(s, CollinearitySet):
            continue
        xr = s.rows[0::2]
        if problem.info.ids[xr[0]]["image"] not in cam_images:
            continue
        xb, yb, *_ = s.ideal(full)
        Fx, Fy, *_ = BASES[group](xb / cam["ap_scale"], yb / cam["ap_scale"])
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
    """H (n × 2) of a 2D error in one point's model coordinates (F80 §2.2)."""
    rows = [None, None]
    for i, (k, ids) in enumerate(zip(problem.info.kind, problem.info.ids)):
        if k.startswith("model-") and ids["model"] == model and ids["point"] == point:
            rows["xy".index(ids["component"])] = i
    if None in rows:
        raise NotFoundError("model point", {"model": model, "point": point},
                            f"no model coordinates of point {point} in model {model}")
    return selection(problem.n, rows)
