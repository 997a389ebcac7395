"""Leaving observations out of an adjustment at the same linearisation point.

The left-out observations' clusters are a low-rank update of the normal equations: the factor
and the per-cluster blocks a_iΣa_jᵀ of :class:`baarda.result.Adjustment` are updated by
Woodbury's identity (:class:`baarda.solve.linalg.LowRankUpdate`) or the reduced problem is
factored anew (F80 §5 for the statistics that follow).
"""

from __future__ import annotations

import time

import numpy as np

from .adjust import adjust
from .errors import OptionError
from .model.problem import by_size, cluster_sizes, subset, weight_matrix
from .result import Adjustment
from .solve.pairs import cluster_pairs
from .solve.linalg import LowRankUpdate

#: :func:`exclude` updates by Woodbury when the left-out clusters hold at most this
#: many observations (k solves with the cached factor and O(n·k) for the statistics); more are
#: refactored, which costs about as much as the first analysis.
WOODBURY_MAX = 64


def exclude(adj: Adjustment, rows, method: str = "auto") -> Adjustment:
    """The adjustment ``adj`` without the observations ``rows``, at the same linearisation point.

    One Gauss-Newton step from x̂ with A held: Δx = Σ' A'ᵀP'(l' − f'), x' = x̂ + Δx
    (S-transformed to the datum), f' = f + A'Δx, so v' are the residuals of the model
    linearised at x̂ — what a full readjustment started at x̂ gives after its first step.

    ``method``: ``"woodbury"`` updates the cached factor, N' = N + VᵀMV with V the design
    rows of the covariance clusters touched and M = −P_c (+ the weight of the members that
    stay), N'⁻¹ = N⁻¹ − Y T Yᵀ (:class:`baarda.solve.linalg.LowRankUpdate`); the blocks a_iΣ'a_jᵀ
    of every cluster are the cached ones minus (a_iY) T (a_jY)ᵀ, so all statistics follow
    in O(n·k) after k solves. ``"refactor"`` builds and factors N' anew. ``"auto"`` takes
    Woodbury when the touched clusters hold at most :data:`WOODBURY_MAX` observations —
    then k solves cost far less than a new factorisation and selected inverse. When leaving
    out the rows orphans a nuisance parameter (all observations of an image), the unknowns
    change and the problem is readjusted from x̂ (:func:`baarda.adjust.adjust`).
    """
    t0 = time.perf_counter()
    rows = np.unique(np.asarray(rows, dtype=np.int64))
    cov = adj.problem.cov
    mask = np.ones(adj.n, dtype=bool)
    mask[rows] = False
    keep_obs = np.flatnonzero(mask)
    A = adj.A[keep_obs].tocsr()
    free = adj.problem.params.free
    observed = np.zeros(adj.problem.params.size, dtype=bool)
    observed[free] = np.bincount(A.indices[A.data != 0], minlength=free.size) > 0
    problem = subset(adj.problem, keep_obs, observed=observed)
    if not np.array_equal(problem.params.fixed, adj.problem.params.fixed):
        return adjust(problem, adj.options, x0=adj.x)
    touched = np.unique(cov.cluster[rows])
    Rc = np.sort(np.concatenate([cov.members[c] for c in touched])) if touched.size else rows
    if method == "auto":
        method = "woodbury" if Rc.size <= WOODBURY_MAX else "refactor"
    if method not in ("woodbury", "refactor"):
        raise OptionError("method", method, ("woodbury", "refactor"), f"unknown method {method!r}")
    P = weight_matrix(problem.cov)
    new = Adjustment(problem=problem, options=adj.options, x=adj.x, f=adj.f[keep_obs], A=A, P=P,
                     plan=adj.plan, converged=True, iterations=0, history=(), timings={},
                     solver=adj.solver)
    if method == "woodbury":
        new_index = np.full(adj.n, -1, dtype=np.int64)
        new_index[keep_obs] = np.arange(keep_obs.size)
        stay = new_index[Rc] >= 0
        M = -adj.P[Rc][:, Rc].toarray()
        ks = np.flatnonzero(stay)
        M[np.ix_(ks, ks)] += P[new_index[Rc[ks]]][:, new_index[Rc[ks]]].toarray()
        V = adj.Ar[Rc]
        factor = LowRankUpdate(adj.factor, V, M)
        H, Ht = adj.hat_blocks
        I, J, _ = cluster_pairs(problem.cov)
        old = _pair_index(cov, keep_obs[I], keep_obs[J])
        AY = new.Ar @ factor.Y
        H = H[old] - np.einsum("pa,ab,pb->p", AY[I], factor.T, AY[J])
        t = adj.nuisance_columns
        if t.size:
            nf = LowRankUpdate(adj.nuisance_factor, V[:, t], M)
            BY = new.Ar[:, t] @ nf.Y
            Ht = Ht[old] - np.einsum("pa,ab,pb->p", BY[I], nf.T, BY[J])
            new.seed(nuisance_factor=nf)
        else:
            Ht = np.zeros(I.size)
        new.seed(factor=factor, hat_blocks=(H, Ht))
    dx = new.expand(new.factor.solve(-(new.Ar.T @ new.Pv)))
    dx = adj.plan.transform(dx)
    x = adj.x.copy()
    x[adj.problem.params.free] += dx
    f = new.f + A @ dx
    out = Adjustment(problem=problem, options=adj.options, x=x, f=f, A=A, P=P, plan=adj.plan,
                     converged=True, iterations=0, history=(),
                     timings={"solve": time.perf_counter() - t0}, solver=adj.solver)
    out.seed(**new.computed("keep", "Ar", "factor", "schur_structure", "hat_blocks", "nuisance_factor"))
    return out


def _pair_index(cov, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Position of the pair (i, j) (same cluster) in the layout of :func:`cluster_pairs`."""
    sizes = cluster_sizes(cov)
    order = np.lexsort((np.arange(sizes.size), sizes))
    start = np.empty(sizes.size, dtype=np.int64)
    start[order] = np.concatenate([[0], np.cumsum(sizes[order] ** 2)[:-1]])
    n = cov.cluster.size
    rpos = np.empty(n, dtype=np.int64)
    for m, _, members in by_size(cov):
        rpos[members] = np.arange(m)[None, :]
    c = cov.cluster[i]
    return start[c] + rpos[i] * sizes[c] + rpos[j]
