"""The S-base lesson on any problem: a controlled block seen as a free block (M84 §2).

An S-transformation changes the coordinate covariance of a *free* network: Σ_S = S Σ Sᵀ with
S = I − G (EᵀG)⁻¹ Eᵀ over the datum's null space G (M84 §2.1-2.2). A block or network whose datum
is its control (fixed and weighted points) has no datum defect: G is empty, S = I, and choosing
another S-base changes nothing — which is why the precision map of the demo block stays the same
to the last digit. The lesson needs a free network: :func:`free_block` adjusts the current
(reduced) problem again without its control observations as a free network (inner constraints
over every point), and :func:`free_point_cov2` gives its planimetric point covariances in a
chosen S-base (the core's :func:`baarda.stats.precision.covariance`). Nothing is computed here
that the core does not compute.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from baarda.adjust import adjust
from baarda.datum import Datum
from baarda.errors import BaardaError
from baarda.model.problem import without
from baarda.stats import precision

#: Why the S-base does not change a controlled problem's covariance (shown beside the control).
WHY_NOT = ("The datum of this problem is its control (fixed and weighted points): it has no datum "
           "defect, so an S-transformation is the identity (S = I − G (EᵀG)⁻¹Eᵀ with an empty null "
           "space G, M84 §2) and the covariance does not change with the S-base. Tick the free-block "
           "view to leave the control out and see the same points as a free network, whose "
           "covariance does depend on the S-base.")


def control_rows(problem) -> np.ndarray:
    """Indices of the control observations (the kinds ``control-*``) of a problem."""
    return np.flatnonzero(np.char.startswith(np.asarray(problem.info.kind, dtype=str), "control"))


def free_block_reason(state) -> str:
    """Why the free-block view cannot be offered ("" if it can)."""
    p = state.results.problem if state.results is not None else None
    if p is None:
        return "no adjustment"
    if getattr(p.datum, "kind", "") == "free":
        return "the problem is a free network already"
    if not control_rows(p).size:
        return "its datum is given by fixed points (not estimated), which a free view cannot release"
    if np.any(np.asarray(state.problem.points.status) == "fixed"):
        return "it has fixed points (not estimated), which a free view cannot release"
    return ""


def free_block(state):
    """The current (reduced) problem without its control observations, adjusted as a free network
    (the core's :func:`baarda.adjust.adjust` with ``Datum("free")``: inner constraints over every
    point). Kept in the state's ``free_block_cache`` per adjustment."""
    adj = state.results
    hit = state.free_block_cache
    if "free" in hit and hit["results"] is adj:
        return hit["free"]
    reduced, _ = without(adj.problem, control_rows(adj.problem))
    free = adjust(replace(reduced, datum=Datum("free", ())), state.options())
    state.free_block_cache = {"results": adj, "free": free}
    return free


def free_point_cov2(state, sbase) -> np.ndarray:
    """Planimetric 2 × 2 covariance per point (m × 2 × 2, m²) of :func:`free_block` in the S-base
    ``sbase`` (point ids; empty: the inner constraints over every point)."""
    free = free_block(state)
    cc = precision.covariance(free, list(sbase) or None)
    return planimetric(cc, len(state.problem.points.ids))


def planimetric(cc, m: int) -> np.ndarray:
    """The planimetric 2 × 2 blocks (m × 2 × 2) of the core's CoordinateCovariance ``cc``; zero
    for a point without both x and y."""
    out = np.zeros((m, 2, 2))
    plan = cc.axis < 2
    for p in np.unique(cc.point[plan]):
        sel = np.flatnonzero((cc.point == p) & plan)
        if sel.size == 2:
            out[p] = cc.cov[np.ix_(sel, sel)]
    return out


def datum_points(problem) -> list[str]:
    """Point ids of the problem's own S-base (a free network's), else [] (fixed points)."""
    d = problem.datum
    if getattr(d, "kind", "") != "free":
        return []
    ids = problem.points.ids
    if not d.sbase:
        return list(ids)
    named = {str(b).rsplit(".", 1)[0] if str(b) not in ids else str(b) for b in d.sbase}
    return [pid for pid in ids if pid in named]


def sbase_check(problem, adj, sbase, sbase_error: str, options) -> str:
    """The note beside the S-base control: r and w do not depend on the S-base.

    For a free network the problem is adjusted again with the chosen S-base as its datum
    and the core's r and w compared; otherwise the S-transformation acts on the covariance
    alone (Σ_S = S Σ Sᵀ, M84 §2) and the adjustment is not repeated.
    """
    if not sbase:
        return "S-base: the problem's own datum."
    if sbase_error:
        return sbase_error
    if getattr(problem.datum, "kind", "") != "free":
        return ("r and w unchanged: the S-transformation acts on the covariance only "
                "(Σ_S = S Σ Sᵀ); the adjustment, its r and w are the same.")
    try:
        other = adjust(replace(adj.problem, datum=Datum("free", tuple(sbase))), options)
    except BaardaError as err:
        return f"S-base {', '.join(sbase)}: {err}"
    dr = float(np.nanmax(np.abs(other.r - adj.r), initial=0.0))
    dw = float(np.nanmax(np.abs(other.w - adj.w), initial=0.0))
    return (f"r and w unchanged (free network adjusted again in this S-base): "
            f"max |Δr| = {dr:.1e}, max |Δw| = {dw:.1e}")
