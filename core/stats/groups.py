"""The policy-free statistics of a problem's observation groups (image points, GNSS vectors, the
groups of a network): T, q, ∇ŝ, σ∇ŝ, the eigenvalues of W_s and μmax of each group (Förstner 1980,
eq. 10, 13, 14), made once per adjustment and kept with it (``adj.memo``); the test policy adds
α_q, the critical values and δ0 in :attr:`baarda.stats.reliability.Reliability.groups`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import result
from ..model.problem import size_weights
from ..solve import heap
from ..solve.pairs import cluster_blocks
from . import hypotheses



class GroupStatistics(NamedTuple):
    """The policy-free statistics of a problem's observation groups (F80 eq. 10, 13, 14), group k's
    members at ``members[ptr[k]:ptr[k + 1]]``; per-member arrays in the members' order."""

    keys: np.ndarray            # group ids, ascending
    ptr: np.ndarray             # (groups + 1,) offsets into members
    members: np.ndarray         # observation indices, sorted within each group
    T: np.ndarray               # T = ĝᵀ W_s⁻¹ ĝ (F80 eq. 10), dimensionless
    q: np.ndarray               # counted dimension of the test (rank of W_s)
    redundancy: np.ndarray      # Σ r_i over the group's members
    nabla: np.ndarray           # ∇ŝ per member, SI units of the observation
    nabla_sigma: np.ndarray     # σ∇ŝ = √diag(W_s⁻¹) per member, SI units
    w_eigenvalues: np.ndarray   # eigenvalues of W_s ascending (NaN where not counted)
    mu_max: np.ndarray          # largest eigenvalue of the pencil (HᵀPH, W_s) (F80 eq. 14)


def group_statistics(adj) -> GroupStatistics | None:
    """The policy-free statistics of the problem's observation groups, made once per adjustment.

    T, q and ∇ŝ of the problem's observation groups (vectors, image points), which do not
    depend on the test policy: a :class:`GroupStatistics` (group ids, ptr, members, T, q,
    redundancy, ∇ŝ, σ∇ŝ, λ(W_s), μmax) ordered by group id, members of group k at ``members[ptr[k]:ptr[k + 1]]`` (sorted,
    ∇ŝ and σ∇ŝ = √diag(W_s⁻¹) in their order, F80 eq. 10); at the same positions the
    eigenvalues of W_s ascending (NaN for those the test does not count), whose δ0/√λ are the
    semi-axes of the lower-bound ellipse (F80 eq. 13); per group μmax, the largest eigenvalue
    of the pencil (HᵀPH, W_s), δ0′max = δ0 √μmax (F80 eq. 14, §7.3; inf when q is below the
    group's size). None without groups. A block of a million image points holds a few
    arrays, not a million dicts; :attr:`baarda.stats.reliability.Reliability.groups` adds α_q,
    δ0 and the decisions.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        An adjustment result; the statistics are kept in ``adj.memo``.

    Returns
    -------
    GroupStatistics or None
        T (dimensionless), q, ∇ŝ and σ∇ŝ (units of the observations) per group; None without groups.
    """
    if "group_statistics" not in adj.memo:
        adj.memo["group_statistics"] = _group_statistics(adj)
    return adj.memo["group_statistics"]


def _group_statistics(adj) -> GroupStatistics | None:
    gid = adj.problem.info.group
    if (gid < 0).all():
        return None
    order = np.argsort(gid, kind="stable")
    g_sorted = gid[order]
    starts = np.flatnonzero(np.r_[True, g_sorted[1:] != g_sorted[:-1]])
    ends = np.r_[starts[1:], g_sorted.size]
    valid = g_sorted[starts] >= 0
    starts, ends = starts[valid], ends[valid]
    keys = g_sorted[starts].astype(np.int64)
    del g_sorted
    ng = keys.size
    ptr = np.concatenate([[0], np.cumsum(ends - starts)]).astype(np.int64)
    members = np.empty(int(ptr[-1]), dtype=np.int64)
    members_ok = np.zeros(ng, dtype=bool)
    T, red = np.full(ng, np.nan), np.full(ng, np.nan)
    q = np.zeros(ng, dtype=np.int64)
    nabla = np.full(members.size, np.nan)
    nabla_sigma = np.full(members.size, np.nan)
    wlam = np.full(members.size, np.nan)
    mu_max = np.full(ng, np.inf)
    r = adj.r
    # groups that are exactly one covariance cluster: all at once from the cluster blocks
    for mem, Tf, qf, nf, sf, lf, mf in _cluster_group_stacks(adj):
        pos = np.searchsorted(keys, gid[mem[:, 0]])
        msz = mem.shape[1]
        dest = ptr[pos][:, None] + np.arange(msz)[None, :]
        members[dest] = mem                               # sorted members
        nabla[dest], nabla_sigma[dest], wlam[dest] = nf, sf, lf
        T[pos], q[pos], mu_max[pos] = Tf, qf, mf
        red[pos] = r[mem].sum(axis=1)
        members_ok[pos] = True
    for k in np.flatnonzero(~members_ok).tolist():
        mem = np.sort(order[starts[k]:ends[k]])
        h = hypotheses.test(adj, hypotheses.selection(adj.n, mem), label=f"group {keys[k]}")
        sl = slice(ptr[k], ptr[k + 1])
        members[sl] = mem
        nabla[sl] = np.asarray(h.nabla, dtype=float).ravel()
        nabla_sigma[sl] = h.nabla_sigma
        seen = np.isfinite(h.ellipse_axes)
        wlam[sl] = np.where(seen, (h.delta0 / np.where(seen, h.ellipse_axes, 1.0)) ** 2, np.nan)
        mu_max[k] = (h.delta0_prime_max / h.delta0) ** 2
        T[k], q[k] = h.T, h.q
        red[k] = float(r[mem].sum())
    heap.trim(adj.n)
    return GroupStatistics(keys, ptr, members, T, q, red, nabla, nabla_sigma, wlam, mu_max)

def cluster_group_tests(adj) -> dict:
    """The tests of the groups that are exactly one covariance cluster, by group (F80 eq. 10).

    Those :func:`group_statistics` takes from the cluster blocks of C_vv at once (an image point, a
    GNSS vector), without a test per group; for inspection.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        An adjustment result.

    Returns
    -------
    dict
        group id → (T dimensionless, q, ∇ŝ in the order of the sorted members, units of the observations).
    """
    gid = adj.problem.info.group
    out = {}
    for mem, T, q, nabla, *_ in _cluster_group_stacks(adj):
        for k in range(T.size):
            out[int(gid[mem[k, 0]])] = (float(T[k]), int(q[k]), nabla[k])
    return out

def _cluster_group_stacks(adj):
    """Tests of the groups that are exactly one covariance cluster (an image point, a GNSS
    vector), all at once from the cluster blocks of C_vv: W = P_c C_vv P_c, T = gᵀW⁺g with
    g = (Pv)_c, ∇ŝ = −W⁺g, q = rank W (:func:`baarda.stats.hypotheses.counted_directions`: the
    eigenvalues above round-off whose statistic stays within vᵀPv) — the formulas of :func:`baarda.stats.hypotheses.test` with H the
    selection of the cluster, without a solve per group. Yields, per cluster size and chunk of
    at most :data:`baarda.result.GROUP_CHUNK` clusters (their temporaries are a chunk's), stacks (members (k, m) sorted per row, T (k,), q (k,), ∇ŝ (k, m) and σ∇ŝ (k, m) in the order of
    the sorted members, the eigenvalues of W (k, m) ascending with NaN for those not counted,
    μmax (k,) of the pencil (P_c, W), inf where q < m) — HᵀPH = P_c for the cluster's selection.
    """
    gid = adj.problem.info.group
    Pv, vPv = adj.Pv, adj.vPv
    counts = np.bincount(gid[gid >= 0])
    H, _ = adj.hat_blocks
    for (_, members, C, Hc), Pall in zip(cluster_blocks(adj.problem.cov, H), size_weights(adj.problem.cov)):
        g0 = gid[members]
        same = (g0 >= 0).all(axis=1) & (g0 == g0[:, :1]).all(axis=1)
        same &= counts[np.maximum(g0[:, 0], 0)] == members.shape[1]
        if not same.any():
            continue
        sel = np.flatnonzero(same)
        for s in range(0, sel.size, result.GROUP_CHUNK):     # (the temporaries of a chunk only)
            part = sel[s:s + result.GROUP_CHUNK]
            # C_vv = C − H of the chunk's clusters (not of all at once: the same numbers)
            mem, Cv, Pc = members[part], C[part] - Hc[part], Pall[part]    # P_c: the cached cluster weights
            W = Pc @ Cv @ Pc
            del Cv
            W = 0.5 * (W + np.swapaxes(W, 1, 2))
            lam, V = np.linalg.eigh(W)
            del W
            tol = 1e-10 * np.maximum(np.maximum(lam.max(axis=1), np.abs(np.diagonal(Pc, axis1=1, axis2=2)).max(axis=1)), 1e-300)
            g = Pv[mem]
            pos, Tj = hypotheses.counted_directions(lam, V, g, tol, vPv)   # q = rank W_s, T ≤ vᵀPv
            inv = np.where(pos, 1.0 / np.where(pos, lam, 1.0), 0.0)
            Winv = np.einsum("kij,kj,klj->kil", V, inv, V)
            U = V * np.sqrt(inv)[:, None, :]              # Uᵀ W U = I on the counted directions
            mu = np.linalg.eigvalsh(np.einsum("kji,kjl,klm->kim", U, Pc, U))[:, -1]
            q = pos.sum(axis=1)
            mu = np.where(q == mem.shape[1], mu, np.inf)
            lam = np.where(pos, lam, np.nan)
            del V, inv, U
            nabla = -np.einsum("kij,kj->ki", Winv, g)
            sig = np.sqrt(np.maximum(np.diagonal(Winv, axis1=1, axis2=2), 0.0))
            del Winv
            T = Tj.sum(axis=1)
            srt = np.argsort(mem, axis=1)
            yield (np.take_along_axis(mem, srt, 1), T, q, np.take_along_axis(nabla, srt, 1),
                   np.take_along_axis(sig, srt, 1), lam, mu)
