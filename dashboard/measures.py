"""The dashboard's computations beyond the tables, each a thin layer over the core: the
adjustment without the excluded observations, deformation fields of the external-reliability
map, the criterion-matrix comparison and the risk curve (M84 §2, §3.3), the injected error of
the teaching view, iterative data snooping with its leave-one-out view, and the variance
components (per family or the radial model of a block).

Plain functions of the core's objects (the problem, its :class:`~baarda.result.Adjustment`
``adj`` and :class:`~baarda.stats.reliability.Reliability` ``rel``, ``kept``: the full index of
each observation of the reduced problem). Nothing here keeps state; the dashboard's
:class:`~baarda.dashboard.state.State` keeps the results.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from baarda.adjust import adjust
from baarda.analysis import Analysis
from baarda.errors import BaardaError
from baarda.exclusion import exclude
from baarda.model.problem import without
from baarda.stats import analyses, risk, snooping, variance
from baarda.stats.hypotheses import deformation
from baarda.stats.reliability import Reliability

from .geometry import observation_label, reduced_index

#: How many of the largest |w| the leave-one-out ("find the error") view tries.
LOO_SUSPECTS = 5


def adjust_without(problem, excluded, sigma_act: str, options, progress=None, x0=None) -> tuple:
    """The core's adjustment of ``problem`` without the ``excluded`` observations (full indices,
    :func:`baarda.model.problem.without`) with σ0 ``sigma_act`` ("apriori" or "aposteriori"),
    started at ``x0`` (default: the file's values): ``(Adjustment, kept)``, ``kept[k]`` the full
    index of the reduced observation k."""
    reduced, kept = without(problem, excluded)
    if reduced.sigma_act != sigma_act:
        reduced = replace(reduced, sigma_act=sigma_act)
    if x0 is not None:          # the unknowns held (a set without observations) at the file's values
        start, free = reduced.params.x0.astype(float).copy(), reduced.params.free
        start[free] = np.asarray(x0, dtype=float)[free]
        x0 = start
    return adjust(reduced, options, x0=x0, progress=progress), kept


# -- deformation fields (external reliability) -----------------------------------------------------
def observation_field(adj, rel, kept, n_full: int, m: int, index: int | None) -> np.ndarray:
    """∇0x of an error of MDB size in observation ``index`` (full) as point shifts (m × 3,
    metres), from the core's :meth:`Adjustment.deformation`; zeros without an observation or
    for an excluded one or one without a finite MDB."""
    mdb = rel.mdb
    if index is None:
        return np.zeros((m, 3))
    k = int(reduced_index(kept, n_full, [index])[0])
    if k < 0 or not np.isfinite(mdb[k]):
        return np.zeros((m, 3))
    err = np.zeros(adj.n)
    err[k] = mdb[k]
    return adj.point_shifts(adj.deformation(err))


def hypothesis_field(adj, outcome, m: int) -> np.ndarray:
    """∇0x of a tested hypothesis (its :class:`~baarda.dashboard.outcomes.Outcome`) as point
    shifts (m × 3, metres): the core's :func:`baarda.stats.hypotheses.deformation` — the lower
    bound ∇0s in the direction the test sees worst. Zero for anything but a hypothesis test with
    finite δ0 and q > 0."""
    h = outcome.test if outcome is not None else None
    if h is None or not np.isfinite(h.delta0) or h.q == 0:
        return np.zeros((m, 3))
    return adj.point_shifts(deformation(adj, h))


# -- criterion matrices and risk (M84 §2, §3.3) ----------------------------------------------------
def criterion_reason(adj) -> str:
    """Why the criterion comparison does not apply to this adjustment ("" if it does)."""
    reason = analyses.criterion_reason(adj)
    return f"{reason[0].upper()}{reason[1:]}." if reason else ""


def criterion(adj, m: int, base: list, kind: str = "logarithmic", C1: float | None = None,
              C2: float = 1.0) -> dict:
    """Compare the coordinate covariance in the S-base ``base`` with a chaotic criterion matrix.

    Without ``C1`` the criterion is fitted (:func:`baarda.stats.precision.fit_criterion`, M84 §2.3:
    C1 so that λmax = 1, C2 so that λmax/λmin is smallest); with ``C1`` (m²/m) and ``C2`` (m)
    the user's criterion is compared (:func:`~baarda.stats.precision.compare`). Returns λmax,
    λmin, "satisfied" (λmax < 1) and the eigenvector of λmax as a displacement pattern per point
    (m × 2, x, y, largest component 1). Raises BaardaError, ValueError or LinAlgError if the
    core refuses.
    """
    reason = criterion_reason(adj)
    if reason:
        raise BaardaError(reason)
    setup = analyses.criterion_setup(adj, base)      # as ``baarda analyze --criterion``
    fitted = C1 is None
    if fitted:
        fit = analyses.criterion_fit(setup, kind)
        C1, C2 = fit["C1"], fit["C2"]
    cmp_ = analyses.criterion_compare(setup, kind, C1, C2)
    cc = setup.cov
    pattern = np.zeros((m, 2))
    plan = cc.axis < 2                       # the map shows x, y (heights and Z are not drawn)
    pattern[cc.point[plan], cc.axis[plan]] = cmp_.worst_pattern()[plan]
    return {"kind": kind, "sbase": base, "fitted": fitted, "C1": float(C1), "C2": float(C2),
            "units": analyses.criterion_units(kind), "C2_at_bound": bool(fitted and fit["C2_at_bound"]),
            "lam_max": cmp_.lam_max, "lam_min": cmp_.lam_min, "ratio": cmp_.lam_max / cmp_.lam_min,
            "satisfied": cmp_.satisfied, "pattern": pattern}


def risk_curve(p: float, L1: float, L2: float, lam: float, n: int = 300) -> dict:
    """The risk-minimising critical value C (:func:`baarda.stats.risk.critical_value`, M84 §3.3),
    its α_C = 1 − Φ(C) and β_C = 1 − Φ(C − √λtol) (the definitions of :mod:`baarda.stats.risk`),
    and r_C (:func:`baarda.stats.risk.risk`) over C for the plot, for λtol = ``lam``. Raises
    ValueError for p ∉ (0, 1) or non-positive L1, L2, λtol."""
    lam = float(lam)
    out = analyses.risk_analysis(p, L1, L2, lam)
    C, s = out["C"], math.sqrt(lam)
    grid = np.linspace(min(C, 0.0) - 2.0, max(C, s) + 3.0, n)
    r = np.array([risk.risk(c, p, L1, L2, lam) for c in grid])
    return {**out, "grid": grid, "r": r}


# -- teaching: inject an error ---------------------------------------------------------------------
def injected_error(adj, rel, kept, n_full: int, index: int, size: float, unit: str = "sigma") -> np.ndarray:
    """The error vector (reduced problem, SI) of ``size`` σ or MDB in observation ``index`` (full)."""
    k = int(reduced_index(kept, n_full, [index])[0])
    if k < 0:
        raise ValueError(f"observation {index} is excluded")
    scale = adj.problem.cov.sigma()[k] if unit == "sigma" else rel.mdb[k]
    if not np.isfinite(scale):
        raise ValueError(f"observation {index} has no finite MDB (r = {adj.r[k]:.3g})")
    e = np.zeros(adj.n)
    e[k] = float(size) * float(scale)
    return e


def with_error(problem, kept, e: np.ndarray):
    """``problem`` (full) with the error ``e`` (reduced problem, :func:`injected_error`) added to
    its kept observations: an injected error made part of the data."""
    l = np.array(problem.l, dtype=float)
    l[kept] += e
    return replace(problem, l=l)


def adjust_with_error(adj, e: np.ndarray, options):
    """The core's adjustment of ``adj``'s problem with the error ``e`` added to its observations."""
    return adjust(replace(adj.problem, l=adj.problem.l + e), options)


def injection(problem, adj, rel, kept, new, e: np.ndarray, index: int, size: float, unit: str,
              display_factor) -> dict:
    """What the tests see of the error ``e`` injected into observation ``index`` (full): the
    statistic before (``adj``, ``rel``) and after (``new``: :func:`adjust_with_error`), the
    decision, the largest statistic, the group test and the global test of ``new``."""
    k = int(reduced_index(kept, problem.n, [index])[0])
    new_rel = Reliability(new, rel.policy)
    stat = np.abs(np.nan_to_num(new_rel.statistic))
    crit = new_rel.critical
    top = int(np.argmax(stat))
    group = next((g for g in new_rel.groups if k in g["members"]), None)
    factor, units = display_factor
    return {"index": int(index), "size": float(size), "unit": unit,
            "error": float(e[k] * factor[index]), "error_unit": units[index],
            "statistic": rel.policy.statistic_name,
            "w_before": float(rel.statistic[k]),
            "w_after": float(new_rel.statistic[k]),
            "critical": float(crit), "rejected": bool(stat[k] > crit),
            "largest": float(stat[top]), "largest_index": int(kept[top]),
            "largest_label": observation_label(problem, int(kept[top])),
            "group_T": None if group is None else float(group["T"]),
            "group_critical": None if group is None else float(group["critical"]),
            "global_passed": new_rel.global_test.get("passed"),
            "sigma0_post": float(new.sigma0_post), "error_vector": e}


# -- data snooping ----------------------------------------------------------------------------------
def snoop(adj, options, use_tau: bool, progress=None, check=None) -> tuple:
    """Iterative data snooping (:func:`baarda.stats.snooping.iterate`) of ``adj``'s problem with
    w (σ0 a priori) or τ (``use_tau``), and σ̂0 with each of the :data:`LOO_SUSPECTS` largest |w|
    left out in turn (:func:`baarda.stats.snooping.leave_one_out`): ``(SnoopResult, loo)``.
    ``check()`` is called between the steps (it raises to stop)."""
    res = snooping.iterate(adj.problem, options, use_tau=use_tau, progress=progress, check=check)
    if check is not None:
        check()
    top = np.argsort(-np.abs(np.nan_to_num(adj.w)), kind="stable")[:LOO_SUSPECTS]
    loo = snooping.leave_one_out(adj, [int(i) for i in top], check=check)
    return res, loo


# -- variance components ----------------------------------------------------------------------------
def variance_components(problem, options, model: str) -> tuple:
    """Variance components of ``problem``: ``(VarianceComponents, None)`` per observation family
    (:func:`baarda.stats.variance.estimate`) for ``model`` "families", ``(None, ComponentEstimate)``
    of the radial model σ² = a² + b²c²/cos⁴α of a block for "radial" (or its isotropic variant
    for "radial-isotropic"; :func:`baarda.stats.analyses.radial_variance`, F80 §2.1)."""
    if model.startswith("radial"):
        structure = "isotropic" if model == "radial-isotropic" else "radial"
        return None, analyses.radial_variance(problem, options, structure)
    return variance.estimate(problem, options=options), None


# -- exclusion: an exact downdate at once, the exact re-adjustment after it --------------------------
#: :func:`downdated` answers an exclusion of at most this many observations (more: re-adjusted).
DOWNDATE_MAX = 64


def downdated(base, excluded) -> "Analysis | None":
    """``base`` (an :class:`~baarda.analysis.Analysis`) without the observations ``excluded``
    (full indices, a superset of ``base.excluded``) from a rank-k downdate of its factor
    (:func:`baarda.exclusion.exclude`, Woodbury's identity): one Gauss-Newton step of the reduced
    problem at ``base``'s solution, so for a linear model the exact adjustment without them, for
    a non-linear one its first iteration from ``base``. None when it does not apply (nothing
    added to the exclusions, more than :data:`DOWNDATE_MAX` added)."""
    excluded = frozenset(int(i) for i in excluded)
    added = excluded - base.excluded
    if not added or not base.excluded <= excluded or len(added) > DOWNDATE_MAX:
        return None
    kept = np.asarray(base.kept)
    red = reduced_index(kept, base.problem.n, sorted(added))
    if (red < 0).any():
        return None
    adj = exclude(base.adjustment, red)
    mask = np.ones(kept.size, dtype=bool)
    mask[red] = False
    return Analysis(base.problem, adj, base.policy, base.solver, name=base.name, excluded=excluded,
                    kept=kept[mask])


def readjusted(analysis, excluded=None, x0=None, progress=None) -> "Analysis":
    """The exact adjustment of ``analysis``' problem without the observations ``excluded`` (full
    indices; default: its own exclusions) with the σ0 of its adjustment, iterated to convergence
    from ``x0`` (default: its solution) — the re-adjustment that replaces a :func:`downdated`
    answer, or an exclusion started from the current solution."""
    problem = analysis.problem
    excluded = analysis.excluded if excluded is None else frozenset(int(i) for i in excluded)
    adj, kept = adjust_without(problem, excluded, analysis.adjustment.problem.sigma_act, analysis.options,
                               progress=progress, x0=analysis.adjustment.x if x0 is None else x0)
    return Analysis(problem, adj, analysis.policy, analysis.solver, name=analysis.name, excluded=excluded,
                    kept=np.asarray(kept))
