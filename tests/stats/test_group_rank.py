"""Group tests of any rank (issue 27, item 7): q = rank W_s and T within what the data hold.

F80 eq. 10-12: T = gᵀ W_s⁻ g with g = HᵀPv, r_s = rank W_s, and T is a part of Ω/σ0² (R's
denominator Ω0 − T ≥ 0), so T ≤ vᵀPv for every H; each eigen-direction's own T_j too. The
reference is the dense formula over the exact rank-1 W_s (the direction the data see only).
"""

from __future__ import annotations

import numpy as np
import pytest

from baarda.stats.groups import group_statistics
from baarda.stats.hypotheses import counted_directions
from baarda.stats.reliability import reliability_of

from tests.extdata import EXTDATA, require_extdata


def test_round_off_eigenvalue_of_a_rank_one_group_is_not_counted():
    """W_s = λ uuᵀ exactly (two tests perfectly correlated); the computed W_s has a round-off
    eigenvalue 1.2e-10 along n ⊥ u, and g = HᵀPv an O(1) part along n (Ladybug: T = 1.06e10,
    ∇ŝ ≈ 9e9 px). The test counts q = 1 and T = (uᵀg)²/λ, the dense rank-1 formula."""
    rng = np.random.default_rng(5)
    u = rng.normal(size=2)
    u /= np.linalg.norm(u)
    n = np.array([-u[1], u[0]])
    lam_u, lam_n = 0.4819, 1.2349e-10
    W = lam_u * np.outer(u, u) + lam_n * np.outer(n, n)
    g = 3.1 * u + 1.13 * n
    vPv = 26688.6
    lam, V = np.linalg.eigh(W)
    pos, Tj = counted_directions(lam, V, g, 1e-10 * lam.max(), vPv)
    assert int(pos.sum()) == 1
    assert Tj.sum() == pytest.approx((u @ g) ** 2 / lam_u, rel=1e-9)
    naive = g @ np.linalg.pinv(W, rcond=1e-10) @ g                 # the old count: q = 2
    assert naive > 1e9 > vPv
    # a genuine small eigenvalue whose statistic stays within vᵀPv is counted (rank 2)
    g2 = 3.1 * u + 1e-6 * n
    pos2, Tj2 = counted_directions(lam, V, g2, 1e-10 * lam.max(), vPv)
    assert int(pos2.sum()) == 2 and Tj2.sum() == pytest.approx(g2 @ np.linalg.solve(W, g2), rel=1e-6)
    # stacks: the same per row
    pos3, Tj3 = counted_directions(np.stack([lam, lam]), np.stack([V, V]), np.stack([g, g2]),
                                   1e-10 * lam.max(), vPv)
    np.testing.assert_array_equal(pos3.sum(axis=1), [1, 2])


@pytest.fixture(scope="module")
def ladybug():
    from baarda.adjust import adjust
    from baarda.build import read_problem

    path = require_extdata(EXTDATA / "bal" / "problem-49-7776-pre.txt")
    return adjust(read_problem(path))


def test_ladybug_groups_stay_within_vpv_and_the_keypoint_pair_is_one_dimensional(ladybug):
    """BAL Ladybug: no group test above vᵀPv (the image point of point 7125 in image 11 had
    T = 1.06e10 with q = 2); that image point's test has q = 1 and a finite ∇ŝ, the same in the
    general hypothesis test (one solve per column) and in the cluster stacks."""
    from baarda.stats import hypotheses

    adj = ladybug
    g = group_statistics(adj)
    keys, ptr, members, T, q = g.keys, g.ptr, g.members, g.T, g.q
    assert np.nanmax(T) <= adj.vPv
    groups = reliability_of(adj).groups
    assert np.nanmax(groups.T) < 1e4
    ids = adj.problem.info.ids
    k = next(k for k in range(keys.size)
             if ids[int(members[ptr[k]])].get("image") == "11" and ids[int(members[ptr[k]])].get("point") == "7125")
    mem = members[ptr[k]:ptr[k + 1]]
    assert q[k] == 1 and T[k] < 1e3
    h = hypotheses.test(adj, hypotheses.selection(adj.n, mem))
    assert h.q == 1 and h.T == pytest.approx(T[k], rel=1e-6)
    assert np.abs(h.nabla).max() < 1e3                  # px; it was 9e9


def test_ladybug_report_rejected_groups_table_shows_no_1e10(ladybug):
    """The client report's table of rejected group tests (``baarda report``, page 3) on Ladybug: it
    showed the keypoint pair first with T = 1.06e10; every T it shows is now within vᵀPv and below
    1e4, with q its rank (1 or 2)."""
    import re

    import pandas as pd

    from baarda.dashboard.report import _groups_html

    adj = ladybug

    class Session:                    # what the table reads of the dashboard's State
        reliability = reliability_of(adj)

        def frames(self):
            return pd.DataFrame({"ids": [str(d) for d in adj.problem.info.ids]}), None

    html = _groups_html(Session())
    rows = re.findall(r"<td class='n'>(\d+)</td><td class='n'>([^<]+)</td><td class='n'>([^<]+)</td>", html)
    assert rows, html[:300]
    for q, T, crit in rows:
        assert int(q) in (1, 2) and float(crit) < float(T) < min(1e4, adj.vPv)
