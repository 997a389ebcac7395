"""Risk minimisation of the critical value (Molenaar 1984, §3.3).

An observation is erroneous with probability p. Rejecting a good one costs L1, accepting a bad
one costs L2. For a one-sided test value W ~ N(0, 1) under H0 and N(√λtol, 1) under Ha (an error
of the tolerance λtol), a critical value C has the risk

    r_C = (1 − p) α_C L1 + p (1 − β_C) L2,   α_C = 1 − Φ(C),  β_C = 1 − Φ(C − √λtol),

which is smallest at (M84 §3.3)

    C = (ln((1 − p)/p) + ln(L1/L2)) / √λtol + √λtol / 2.

Applied to the data (:func:`per_observation`), every observation's w-test gets its own λtol from a
tolerance on the distortion of the coordinates (M84 §3.3: "first set a tolerance for those
distortions"), hence its own C_i, α_C, β_C and r_C:

- general purpose, a tolerance λ̄tol of Baarda's datum-invariant λ̄ = ∇kᵀ Q_kk⁻¹ ∇k (M84 §3.2): an
  error ∇l_i gives λ̄ = ∇l_i² (P H_k P)_ii and the non-centrality λ = ∇l_i² (P C_vv P)_ii of w_i, so

      λtol,i = λ̄tol (P C_vv P)_ii / (P H_k P)_ii = λ̄tol (δ0 / δ̄0,i)²        (F80 eq. 18);

- special purpose, a tolerance t (metres) for every point coordinate in the datum of the
  adjustment: the unit error in l_i moves the coordinates by Σ AᵀP e_i (F80 §6), so

      ∇tol l_i = t / max_k |(Σ AᵀP e_i)_k|,   λtol,i = ∇tol l_i² (P C_vv P)_ii.

An observation that cannot move the coordinates ((P H_k P)_ii = 0) has λtol = ∞: C = ∞, r_C = 0
(never worth rejecting). As in M84 the test value is taken one-sided, W ~ N(0, 1) under H0 and
N(√λtol, 1) under Ha (the sign of the error is that of the alternative); observation i is rejected
where |w_i| > C_i.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ..lazy import lazy
from ..errors import OptionError

optimize, stats = lazy("scipy.optimize"), lazy("scipy.stats")     # imported when first used (start-up)


def risk(C: float, p: float, L1: float, L2: float, lam_tol: float) -> float:
    """The risk r_C = (1 − p) α_C L1 + p (1 − β_C) L2 of the critical value C (M84 §3.3).

    α_C = 1 − Φ(C), β_C = 1 − Φ(C − √λtol).

    Parameters
    ----------
    C : float
        Critical value of the one-sided test value W, dimensionless.
    p : float
        Error rate, in (0, 1).
    L1, L2 : float
        Costs of rejecting a good and of accepting a bad observation (any one unit).
    lam_tol : float
        Tolerance λtol, dimensionless non-centrality.

    Returns
    -------
    float
        r_C, in the units of L1 and L2.
    """
    alpha = stats.norm.sf(C)
    beta = stats.norm.sf(C - np.sqrt(lam_tol))
    return float((1 - p) * alpha * L1 + p * (1 - beta) * L2)


def critical_value(p: float, L1: float, L2: float, lam_tol: float) -> float:
    """The C that minimises r_C, C = (ln((1 − p)/p) + ln(L1/L2)) / √λtol + √λtol / 2 (M84 §3.3).

    Parameters
    ----------
    p : float
        Error rate, in (0, 1).
    L1, L2 : float
        Costs of rejecting a good and of accepting a bad observation (> 0, any one unit).
    lam_tol : float
        Tolerance λtol (> 0), dimensionless.

    Returns
    -------
    float
        C, dimensionless.

    Raises
    ------
    baarda.errors.OptionError
        For p ∉ (0, 1) or non-positive L1, L2, λtol.
    """
    if not (0 < p < 1) or L1 <= 0 or L2 <= 0 or lam_tol <= 0:
        bad = next(k for k, ok in (("p", 0 < p < 1), ("L1", L1 > 0), ("L2", L2 > 0), ("lam_tol", lam_tol > 0)) if not ok)
        raise OptionError(bad, {"p": p, "L1": L1, "L2": L2, "lam_tol": lam_tol}[bad], (),
                          "need 0 < p < 1 and positive L1, L2, λtol")
    s = np.sqrt(lam_tol)
    return float((np.log((1 - p) / p) + np.log(L1 / L2)) / s + s / 2)


def critical_value_numeric(p: float, L1: float, L2: float, lam_tol: float) -> float:
    """The same C by minimising r_C numerically (M84 §3.3; a check of the closed form).

    Parameters
    ----------
    p : float
        Error rate, in (0, 1).
    L1, L2 : float
        Costs (> 0, any one unit).
    lam_tol : float
        Tolerance λtol (> 0), dimensionless.

    Returns
    -------
    float
        C, dimensionless.
    """
    s = np.sqrt(lam_tol)
    res = optimize.minimize_scalar(lambda c: risk(c, p, L1, L2, lam_tol), bounds=(-10 - s, 20 + s),
                                   method="bounded", options={"xatol": 1e-10})
    return float(res.x)


def _check(p: float, L1: float, L2: float) -> None:
    for name, ok in (("p", 0 < p < 1), ("L1", L1 > 0), ("L2", L2 > 0)):
        if not ok:
            raise OptionError(name, {"p": p, "L1": L1, "L2": L2}[name], (), "need 0 < p < 1 and positive L1, L2")


def critical_values(p: float, L1: float, L2: float, lam_tol) -> np.ndarray:
    """C for each λtol (the closed form of :func:`critical_value`, M84 §3.3); ∞ where λtol = ∞.

    Parameters
    ----------
    p : float
        Error rate, in (0, 1).
    L1, L2 : float
        Costs (> 0, any one unit).
    lam_tol : array_like of float
        Tolerances λtol, dimensionless.

    Returns
    -------
    numpy.ndarray
        C per λtol, dimensionless.

    Raises
    ------
    baarda.errors.OptionError
        For p ∉ (0, 1) or non-positive L1, L2.
    """
    _check(p, L1, L2)
    lam = np.asarray(lam_tol, dtype=float)
    s = np.sqrt(lam)
    with np.errstate(divide="ignore", invalid="ignore"):
        C = (np.log((1 - p) / p) + np.log(L1 / L2)) / s + s / 2
    return np.where(np.isinf(lam), np.inf, C)


def lambda_tol_general(adj, lambda_bar_tol: float) -> np.ndarray:
    """λtol,i = λ̄tol (P C_vv P)_ii / (P H_k P)_ii per observation (M84 §3.2-3.3; F80 eq. 18).

    ∞ where the observation cannot move the coordinates, NaN where it is uncontrolled.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    lambda_bar_tol : float
        Tolerance λ̄tol of Baarda's λ̄ (> 0), dimensionless.

    Returns
    -------
    numpy.ndarray
        n values λtol,i, dimensionless.

    Raises
    ------
    baarda.errors.OptionError
        For λ̄tol ≤ 0.
    """
    if not lambda_bar_tol > 0:
        raise OptionError("lambda_bar_tol", lambda_bar_tol, (), "the tolerance λ̄tol must be positive")
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = lambda_bar_tol * adj.qvv_pp / adj.php_k
    lam[adj.php_k <= 0] = np.inf
    lam[adj.uncontrolled] = np.nan
    return lam


def coordinate_effects(adj, batch: int = 256) -> np.ndarray:
    """max_k |(Σ AᵀP e_i)_k| over the point coordinates, per observation i (F80 §6).

    The largest coordinate shift of a unit error in l_i, in the datum of the adjustment; one solve
    per observation, in batches of ``batch`` columns.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    batch : int
        Columns solved at once.

    Returns
    -------
    numpy.ndarray
        n values, metres per unit of the observation (dimensionless for coordinate observations).
    """
    idx = adj.problem.points.index
    fpos = np.full(adj.problem.params.size, -1)
    fpos[adj.problem.params.free] = np.arange(adj.problem.params.free.size)
    coord = fpos[idx[idx >= 0]]
    coord = coord[coord >= 0]
    AtP = (adj.P @ adj.A).T.tocsc()                       # u × n: column i is AᵀP e_i
    out = np.zeros(adj.n)
    for s in range(0, adj.n, batch):
        cols = AtP[:, s:s + batch].toarray()
        dx = adj.solve_normal(cols)
        out[s:s + batch] = np.abs(dx[coord]).max(axis=0, initial=0.0)
    return out


def lambda_tol_coordinates(adj, tol: float) -> np.ndarray:
    """λtol,i = (t / max_k |(Σ AᵀP e_i)_k|)² (P C_vv P)_ii for a coordinate tolerance t (M84 §3.3).

    ∞ where l_i cannot move a coordinate, NaN where it is uncontrolled.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    tol : float
        Tolerance t (> 0), metres.

    Returns
    -------
    numpy.ndarray
        n values λtol,i, dimensionless.

    Raises
    ------
    baarda.errors.OptionError
        For t ≤ 0.
    """
    if not tol > 0:
        raise OptionError("coordinate_tol", tol, (), "the coordinate tolerance must be positive (metres)")
    e = coordinate_effects(adj)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (tol / e) ** 2 * adj.qvv_pp
    lam[e <= 0] = np.inf
    lam[adj.uncontrolled] = np.nan
    return lam


@dataclass(frozen=True, eq=False)
class ObservationRisk:
    """Risk-minimising tests of every observation (module docstring; arrays of length n)."""

    p: float
    L1: float
    L2: float
    tolerance: str               # "lambda_bar=…" or "coordinate=… m"
    lam_tol: np.ndarray          # λtol,i
    C: np.ndarray                # critical value C_i of |w_i|
    alpha: np.ndarray            # α_C = 1 − Φ(C)
    beta: np.ndarray             # β_C = 1 − Φ(C − √λtol)
    r_C: np.ndarray              # (1 − p) α_C L1 + p (1 − β_C) L2
    rejected: np.ndarray         # |w_i| > C_i


def per_observation(adj, p: float, L1: float, L2: float, lambda_bar_tol: float | None = None,
                    coordinate_tol: float | None = None) -> ObservationRisk:
    """C and r_C of every observation's w-test from a tolerance on the coordinates (M84 §3.3).

    λ̄tol (general purpose) or ``coordinate_tol`` (special purpose), exactly one (module docstring).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    p : float
        Error rate, in (0, 1).
    L1, L2 : float
        Costs (> 0, any one unit).
    lambda_bar_tol : float, optional
        Tolerance λ̄tol, dimensionless.
    coordinate_tol : float, optional
        Tolerance t, metres.

    Returns
    -------
    ObservationRisk
        Per observation λtol, C, α_C, β_C (dimensionless), r_C (units of L1, L2) and the decision.

    Raises
    ------
    baarda.errors.OptionError
        For both or neither tolerance, or bad p, L1, L2.
    """
    if (lambda_bar_tol is None) == (coordinate_tol is None):
        raise OptionError("tolerance", None, ("lambda_bar_tol", "coordinate_tol"),
                          "give exactly one tolerance: λ̄tol or a coordinate tolerance")
    _check(p, L1, L2)
    if lambda_bar_tol is not None:
        lam, what = lambda_tol_general(adj, lambda_bar_tol), f"lambda_bar={lambda_bar_tol:g}"
    else:
        lam, what = lambda_tol_coordinates(adj, coordinate_tol), f"coordinate={coordinate_tol:g} m"
    C = critical_values(p, L1, L2, lam)
    alpha = stats.norm.sf(C)
    beta = np.where(np.isinf(lam), 1.0, stats.norm.sf(C - np.sqrt(np.where(np.isinf(lam), 0.0, lam))))
    r_C = (1 - p) * alpha * L1 + p * (1 - beta) * L2
    with np.errstate(invalid="ignore"):
        rejected = np.abs(np.nan_to_num(adj.w)) > C
    return ObservationRisk(p, L1, L2, what, lam, C, alpha, beta, r_C, rejected)
