"""The analyses ``baarda analyze`` and the dashboard share: one setup each, used by both.

- criterion matrices (Molenaar 1984, §2): the coordinate covariance in an S-base, the point
  positions, the S-base flags and the null space that :func:`baarda.stats.precision.fit_criterion` and
  :func:`baarda.stats.precision.compare` take (:func:`criterion_setup`), the fitted criterion
  (:func:`criterion_fit`) and the comparison with a given one (:func:`criterion_compare`);
- the radial variance model σ² = a² + b²c²/cos⁴α of a block (Förstner 1980, §2.1) started at
  θ0 = (σ²/2, σ²/2, 1), σ² the median a priori variance of the image observations
  (:func:`radial_theta0`, :func:`radial_variance`);
- the risk-minimising critical value (Molenaar 1984, §3.3) with its α_C, β_C and r_C
  (:func:`risk_analysis`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

from . import precision, risk, variance
from ..errors import BaardaError


@dataclass(frozen=True, eq=False)
class CriterionSetup:
    """What a criterion comparison needs (Molenaar 1984, §2): ``cov`` the coordinate covariance
    in the S-base (:class:`baarda.stats.precision.CoordinateCovariance`), ``xy`` the adjusted point
    positions (m × 2, metres), ``in_base`` per coordinate whether its point is in the S-base, ``G``
    the null space over the coordinates (the transformations the S-base fixes)."""

    cov: precision.CoordinateCovariance
    xy: np.ndarray
    in_base: np.ndarray
    G: np.ndarray


def planimetric_reason(adj) -> str:
    """Why criterion matrices do not apply to ``adj`` ("" if they do): they compare planimetric
    networks, x and y for every point and no heights (Molenaar 1984, §2)."""
    params = adj.problem.params
    xy = adj.coordinates[:, :2]
    if np.isnan(xy).any() or (params.axis[params.kind == "k"] == 2).any():
        return ("criterion matrices compare planimetric networks (M84 §2): this problem has "
                "heights (levelling or 3D), not x, y for every point")
    return ""


def criterion_setup(adj, sbase, cov=None) -> CriterionSetup:
    """The coordinate covariance of ``adj`` in the S-base ``sbase`` (point ids) with the point
    positions, S-base flags and null space (``cov``: that covariance if already computed).
    Raises :class:`baarda.errors.BaardaError` for a problem that is not planimetric."""
    reason = planimetric_reason(adj)
    if reason:
        raise BaardaError(reason)
    cc = precision.covariance(adj, list(sbase)) if cov is None else cov
    _, G, _ = precision.release_null_space(adj)
    in_base = np.isin(np.array(adj.problem.points.ids)[cc.point], list(sbase))
    return CriterionSetup(cc, adj.coordinates[:, :2], in_base, G[: cc.params.size])


def criterion_fit(setup: CriterionSetup, kind: str = "logarithmic", C0: float = 0.0) -> dict:
    """The chaotic criterion fitted to the covariance (:func:`baarda.stats.precision.fit_criterion`,
    Molenaar 1984, §2.3: C0 given first, C1 so that λmax = 1, C2 so that λmax/λmin is smallest)."""
    return precision.fit_criterion(setup.cov.cov, setup.xy, setup.in_base, setup.G, kind=kind, C0=C0)


def criterion_compare(setup: CriterionSetup, kind: str, C1: float, C2: float = 1.0,
                      C0: float = 0.0) -> precision.Comparison:
    """The covariance against the chaotic criterion (units in :func:`criterion_units`) transformed
    to the S-base: the generalised eigenvalues λ on the complement of the null space, the same in
    every S-base (Molenaar 1984, §2.2; :func:`baarda.stats.precision.compare`)."""
    H = precision.sbase_transform(precision.criterion_matrix(setup.xy, kind, float(C0), float(C1), float(C2)),
                                  setup.G, setup.in_base)
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


def radial_variance(problem, options=None):
    """The radial variance model of a block (Förstner 1980, §2.1) estimated from
    :func:`radial_theta0` (:func:`baarda.stats.variance.estimate_components`)."""
    comps = variance.radial_components(problem)
    return variance.estimate_components(problem, comps, theta0=radial_theta0(problem), options=options)


def risk_analysis(p: float, L1: float, L2: float, lam_tol: float) -> dict:
    """The risk-minimising critical value C (Molenaar 1984, §3.3; :func:`baarda.stats.risk.critical_value`),
    its risk r_C, α_C = 1 − Φ(C) and β_C = 1 − Φ(C − √λtol) (the definitions of :mod:`baarda.stats.risk`).
    Raises ValueError for p ∉ (0, 1) or non-positive L1, L2, λtol."""
    C = risk.critical_value(p, L1, L2, lam_tol)
    return {"C": C, "r_C": risk.risk(C, p, L1, L2, lam_tol), "alpha": float(sps.norm.sf(C)),
            "beta": float(sps.norm.sf(C - np.sqrt(lam_tol))), "lam_tol": float(lam_tol)}
