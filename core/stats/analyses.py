"""The analyses ``baarda analyze`` and the dashboard share: one setup each, used by both.

- criterion matrices (Molenaar 1984, §2): the coordinate covariance in an S-base, the point
  positions, the S-base flags and the null space that :func:`baarda.stats.precision.fit_criterion` and
  :func:`baarda.stats.precision.compare` take (:func:`criterion_setup`), the fitted criterion
  (:func:`criterion_fit`) and the comparison with a given one (:func:`criterion_compare`);
- the radial variance model σ² = a² + b²c²/cos⁴α of a block (Förstner 1980, §2.1) started at
  θ0 = (σ²/2, σ²/2, 1), σ² the median a priori variance of the image observations
  (:func:`radial_theta0`, :func:`radial_variance`);
- the risk-minimising critical value (Molenaar 1984, §3.3) with its α_C, β_C and r_C
  (:func:`risk_analysis`);
- a hypothesis tested in full (Förstner 1980, eq. 10-18; :func:`hypothesis_analysis`): T, R,
  the decision, ∇ŝ ± σ∇ŝ, the lower-bound ellipse, δ0′max, δ̄0(s) at its maximum with λ̄ and the
  deformation field of that undetectable error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ..lazy import lazy
from . import hypotheses, precision, risk, variance
from ..errors import BaardaError

sps = lazy("scipy.stats")                # imported when first used (start-up)


#: the largest number of coordinates whose dense covariance a criterion comparison forms
MAX_CRITERION_COORDINATES = 6000


@dataclass(frozen=True, eq=False)
class CriterionSetup:
    """What a criterion comparison needs (Molenaar 1984, §2): ``cov`` the coordinate covariance
    in the S-base (:class:`baarda.stats.precision.CoordinateCovariance`), ``xy`` the adjusted point
    positions whose distances d_ij² depends on (m × 2 planimetric for planimetry and heights, m × 3
    for 3D; metres), ``axes`` the coordinates per point (2, 1 for heights, 3), ``in_base`` the
    S-base (:class:`baarda.stats.precision.SBase`: its coordinates, and the normal condition of a 3D
    base of two points, M84 §2.2), ``G`` the null space over the coordinates (the transformations
    the S-base fixes)."""

    cov: precision.CoordinateCovariance
    xy: np.ndarray
    in_base: precision.SBase
    G: np.ndarray
    axes: int = 2


def criterion_axes(adj) -> tuple[int, str]:
    """The coordinates per point a criterion matrix of ``adj`` has (2 planimetric, 1 heights, 3
    spatial: M84 §2.2-2.3) and "" — or 0 and why criterion matrices do not apply: every point needs
    the same coordinates, and heights need planimetric positions for their distances."""
    params = adj.problem.params
    k = params.kind == "k"
    if k.sum() > MAX_CRITERION_COORDINATES:
        return 0, (f"a criterion comparison forms the dense covariance of the coordinates: at most "
                   f"{MAX_CRITERION_COORDINATES} coordinates (this problem has {int(k.sum())})")
    mask = np.zeros((len(adj.problem.points.ids), 3), dtype=bool)
    mask[params.point[k], params.axis[k]] = True
    used = mask.any(axis=1)
    patterns = {tuple(r) for r in mask[used]}
    if len(patterns) != 1:
        return 0, ("criterion matrices need the same coordinates for every point (M84 §2): this problem "
                   "mixes planimetric points, heights and 3D points")
    pattern = patterns.pop()
    if pattern == (True, True, False):
        return 2, ""
    if pattern == (True, True, True):
        return 3, ""
    if pattern == (False, False, True):
        if np.isnan(planimetric_positions(adj)[used]).any():
            return 0, ("a criterion matrix for heights needs the points' planimetric positions (d_ij² is "
                       "a function of their distance, M84 §2.3): this levelling network has none")
        return 1, ""
    return 0, "criterion matrices compare planimetric, height or 3D coordinates (M84 §2)"


def planimetric_positions(adj) -> np.ndarray:
    """x, y of every point (m × 2, metres): the adjusted ones, else those the file gives
    (``Problem.positions``, a levelling network's benchmarks), NaN where neither."""
    xy = adj.coordinates[:, :2].copy()
    given = adj.problem.positions
    if given is not None:
        xy = np.where(np.isnan(xy), given, xy)
    return xy


def criterion_reason(adj) -> str:
    """Why criterion matrices do not apply to ``adj`` ("" if they do; :func:`criterion_axes`)."""
    return criterion_axes(adj)[1]


def criterion_setup(adj, sbase, cov=None) -> CriterionSetup:
    """The coordinate covariance of ``adj`` in the S-base ``sbase`` (point ids; in 3D two points
    and, optionally, ``normal=C``) with the point positions, S-base conditions and null space
    (``cov``: that covariance if already computed). Raises :class:`baarda.errors.BaardaError`
    where criterion matrices do not apply (:func:`criterion_axes`)."""
    axes, reason = criterion_axes(adj)
    if reason:
        raise BaardaError(reason)
    cc = precision.covariance(adj, list(sbase)) if cov is None else cov
    _, G, _ = precision.release_null_space(adj)
    base = cc.base if cc.base is not None else precision.SBase(
        np.isin(np.array(adj.problem.points.ids)[cc.point], list(sbase)))
    by_point = cc.point.reshape(-1, axes)
    if (by_point != by_point[:, :1]).any():        # criterion_matrix orders H point by point
        raise BaardaError("criterion matrices need the coordinates ordered point by point")
    xy = adj.coordinates[by_point[:, 0]] if axes == 3 else planimetric_positions(adj)[by_point[:, 0]]
    return CriterionSetup(cc, xy, base, G[: cc.params.size], axes)


def criterion_fit(setup: CriterionSetup, kind: str = "logarithmic", C0: float = 0.0) -> dict:
    """The chaotic criterion fitted to the covariance (:func:`baarda.stats.precision.fit_criterion`,
    Molenaar 1984, §2.3: C0 given first, C1 so that λmax = 1, C2 so that λmax/λmin is smallest)."""
    return precision.fit_criterion(setup.cov.cov, setup.xy, setup.in_base, setup.G, kind=kind, axes=setup.axes,
                                   C0=C0)


def criterion_compare(setup: CriterionSetup, kind: str, C1: float, C2: float = 1.0,
                      C0: float = 0.0) -> precision.Comparison:
    """The covariance against the chaotic criterion (units in :func:`criterion_units`) transformed
    to the S-base: the generalised eigenvalues λ on the complement of the null space, the same in
    every S-base (Molenaar 1984, §2.2; :func:`baarda.stats.precision.compare`)."""
    H = precision.sbase_transform(precision.criterion_matrix(setup.xy, kind, float(C0), float(C1), float(C2),
                                                             axes=setup.axes), setup.G, setup.in_base)
    return precision.compare(setup.cov.cov, H, setup.G, setup.in_base)


def criterion_units(kind: str) -> dict:
    """The units of C0, C1, C2 for each structure of d² (M84 eq. 2; l in metres, d² in m²)."""
    if kind == "exponential":      # d² = C0² + C1 (1 − exp(−C2² l))
        return {"C0": "m", "C1": "m²", "C2": "m^-½"}
    if kind == "logarithmic":      # d² = C0 + C1 C2 ln(1 + l / C2)
        return {"C0": "m²", "C1": "m²/m", "C2": "m"}
    return {"C0": "m²", "C1": "m²/m", "C2": ""}     # linear: d² = C0 + C1 l


def radial_theta0(problem) -> list[float]:
    """θ0 = (σ²/2, σ²/2, 1) of the radial model, σ² the median a priori variance of the image
    observations (1 without any)."""
    image = np.char.startswith(np.asarray(problem.info.kind).astype(str), "image")
    sig2 = float(np.median(problem.cov.sigma()[image]) ** 2) if image.any() else 1.0
    return [sig2 / 2, sig2 / 2, 1.0]


def radial_variance(problem, options=None, structure: str = "radial"):
    """The radial variance model of a block (Förstner 1980, §2.1) estimated from
    :func:`radial_theta0` (:func:`baarda.stats.variance.estimate_components`); ``structure``
    "radial" (b acts on the radial component, the paper's reading) or "isotropic" (on x and y
    alike; :func:`baarda.stats.variance.radial_cofactor`)."""
    comps = variance.radial_components(problem, structure)
    return variance.estimate_components(problem, comps, theta0=radial_theta0(problem), options=options)


def risk_analysis(p: float, L1: float, L2: float, lam_tol: float) -> dict:
    """The risk-minimising critical value C (Molenaar 1984, §3.3; :func:`baarda.stats.risk.critical_value`),
    its risk r_C, α_C = 1 − Φ(C) and β_C = 1 − Φ(C − √λtol) (the definitions of :mod:`baarda.stats.risk`).
    Raises ValueError for p ∉ (0, 1) or non-positive L1, L2, λtol."""
    C = risk.critical_value(p, L1, L2, lam_tol)
    return {"C": C, "r_C": risk.risk(C, p, L1, L2, lam_tol), "alpha": float(sps.norm.sf(C)),
            "beta": float(sps.norm.sf(C - np.sqrt(lam_tol))), "lam_tol": float(lam_tol)}


def hypothesis_analysis(adj, H, label: str = "", reliability=None) -> dict:
    """Everything F80 says about hypothesis H (n × q) of ``adj`` under ``reliability``'s policy
    (default ``adj.reliability``), as plain numbers (SI units of the observations for ∇s,
    of the coordinates for the deformation):

    T and R with their critical values and the decision (on T with σ0 a priori, on R with σ0 a
    posteriori; eq. 10-12), ∇ŝ and σ∇ŝ (eq. 10), the semi-axes and directions of the
    lower-bound ellipse (eq. 13), δ0′max and its direction (eq. 14, §7.3), δ̄0max, its direction
    and λ̄ = δ̄0max² (eq. 17, M84 §3.2), and the deformation ∇0x of the undetectable error
    ∇0s = s δ0/√(sᵀW_s s) in that direction (eq. 16): per point dx, dy, dz and their norm,
    largest first. ``rows`` are the observations H acts on.
    """
    rel = adj.reliability if reliability is None else reliability
    h = rel.test(H, label=label)
    decide_R = rel.policy.sigma0 == "aposteriori"
    seen = np.isfinite(h.ellipse_axes)
    H = h.H.tocsc()
    out = {"label": label, "rows": np.unique(H.nonzero()[0]).tolist(), "dimension": h.q, "T": h.T,
           "R": h.R, "alpha": h.alpha, "critical_T": h.critical_T, "critical_R": h.critical_R,
           "decided_on": "R" if decide_R else "T",
           "rejected": bool(h.rejected_R if decide_R else h.rejected_T),
           "nabla": h.nabla.tolist(), "nabla_sigma": h.nabla_sigma.tolist(), "delta0": h.delta0,
           "ellipse_axes": h.ellipse_axes[seen].tolist(),
           "ellipse_directions": h.ellipse_dirs[:, seen].T.tolist(),
           "delta0_prime_max": h.delta0_prime_max, "weakest": h.weakest.tolist()}
    if not seen.any():
        out.update(delta_bar0_max=None, delta_bar0_direction=None, lambda_bar_max=None, deformation=None)
        return out
    ext = hypotheses.external_reliability(adj, h)
    nabla0 = h.lower_bound(ext.direction)
    shifts = adj.point_shifts(hypotheses.deformation(adj, h, nabla0))
    norm = np.sqrt((shifts ** 2).sum(axis=1))
    ids = adj.problem.points.ids
    order = np.argsort(-norm, kind="stable")
    points = [{"id": str(ids[i]), "dx": float(shifts[i, 0]), "dy": float(shifts[i, 1]), "dz": float(shifts[i, 2]),
               "norm": float(norm[i])} for i in order.tolist() if norm[i] > 0]
    out.update(delta_bar0_max=ext.max, delta_bar0_direction=ext.direction.tolist(),
               lambda_bar_max=ext.lambda_bar_max,
               deformation={"nabla0_s": nabla0.tolist(), "points": points})
    return out
