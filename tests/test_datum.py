"""Datum analysis helpers and the covariance subset: second implementations as references."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from hypothesis import given, settings, strategies as st

from baarda import datum
from baarda.adjust import adjust
from baarda.model.bundle import build_block_problem
from baarda.model.problem import weight_matrix
from baarda.model.problem import Covariance
from baarda.simulate import simulate_block

from tests.networks import grid_network, problem, vector_network


def test_normal_diagonal_equals_the_diagonal_of_the_normal_matrix():
    """diag(AᵀPA) by the diagonal-P shortcut and by the general product, against AᵀPA itself."""
    for net in (grid_network(3, 3, seed=1), vector_network()):
        pr = problem(net)
        f, J = pr.evaluate(pr.params.x0)
        A = J[:, pr.params.free].tocsr()
        P = weight_matrix(pr.cov)
        ref = (A.T @ P @ A).diagonal()
        np.testing.assert_allclose(datum.normal_diagonal(A, P), ref, rtol=1e-12, atol=1e-300)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(1, 3), min_size=1, max_size=12), st.data())
def test_covariance_subset_matches_cutting_each_block(sizes, data):
    """Covariance.subset against a block-by-block reference (np.ix_ on every cluster)."""
    rng = np.random.default_rng(len(sizes))
    members, blocks, start = [], [], 0
    for m in sizes:
        members.append(np.arange(start, start + m))
        L = rng.normal(size=(m, m))
        blocks.append(L @ L.T + m * np.eye(m))
        start += m
    cov = Covariance.from_blocks(start, members, blocks)
    keep = np.flatnonzero(data.draw(st.lists(st.booleans(), min_size=start, max_size=start)))
    sub = cov.subset(keep)
    new_index = np.full(start, -1)
    new_index[keep] = np.arange(keep.size)
    ref_m, ref_b = [], []
    for idx, b in zip(members, blocks):
        m = new_index[idx] >= 0
        if m.any():
            ref_m.append(new_index[idx[m]])
            ref_b.append(b[np.ix_(m, m)])
    ref = Covariance.from_blocks(keep.size, ref_m, ref_b)
    np.testing.assert_array_equal(sub.cluster, ref.cluster)
    assert all(np.array_equal(a, b) for a, b in zip(sub.members, ref.members))
    assert all(np.array_equal(a, b) for a, b in zip(sub.blocks, ref.blocks))
    assert (sp.csr_matrix(sub.matrix()) != ref.matrix()).nnz == 0


def test_far_points_are_left_out_of_the_default_s_base():
    """A tie point moved far along its ray (as structure-from-motion points drift) is a far point;
    the free datum is still the 7 named transformations and is not held by that point."""
    block, _ = simulate_block(strips=2, images_per_strip=4, seed=2, datum="free")
    pr = build_block_problem(block)
    adj = adjust(pr)
    x = adj.x.copy()
    idx = pr.points.index
    ids = pr.points.ids
    tie = next(i for i in range(len(ids)) if (idx[i] >= 0).all())
    dist, ref = datum.point_distances(pr, x)
    centre = np.median(np.where(idx >= 0, x[np.maximum(idx, 0)], 0.0), axis=0)
    x[idx[tie]] = centre + (x[idx[tie]] - centre) * 5000.0 * ref / max(dist[tie], 1e-9)
    far = datum.far_points(pr, x)
    assert far[tie] and far.sum() == 1
    f, J = pr.evaluate(x)
    A = J[:, pr.params.free].tocsr()
    plan = datum.plan(pr, x, A, weight_matrix(pr.cov), pr.params.free)
    assert plan.names == ("translation x", "translation y", "translation z", "rotation about x",
                          "rotation about y", "rotation about z", "scale")
    held_points = set(pr.params.point[pr.params.free][plan.eliminate].tolist())
    assert tie not in held_points
    free_pos = np.full(pr.params.size, -1)
    free_pos[pr.params.free] = np.arange(pr.params.free.size)
    assert np.abs(plan.E[free_pos[idx[tie]]]).max() == 0.0     # not in the S-base


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12), st.data())
def test_keep_columns_equals_scipy_column_indexing(n, u, data):
    from baarda.solve.linalg import keep_columns

    rng = np.random.default_rng(n * 13 + u)
    A = sp.random(n, u, density=0.4, format="csr", random_state=rng)
    keep = np.flatnonzero(data.draw(st.lists(st.booleans(), min_size=u, max_size=u)))
    B = keep_columns(A, keep)
    ref = A[:, keep].tocsr()
    assert B.shape == ref.shape and (B != ref).nnz == 0
    ref.sort_indices()
    np.testing.assert_array_equal(B.indptr, ref.indptr)
    np.testing.assert_array_equal(B.indices, ref.indices)


def test_nuisance_block_dense_and_sparse_give_the_same_null_space(monkeypatch):
    """null_space's AₜᵀPAₜ summed densely by the compiled kernel (small blocks) and by scipy's
    sparse product (large blocks, or no numba): the same null space and S-base, to round-off;
    and the dense sum against AₜᵀPAₜ itself, with a correlated (non-diagonal) P."""
    block, _ = simulate_block(strips=2, images_per_strip=4, seed=2, datum="free", rho=0.3)
    pr = build_block_problem(block)
    f, J = pr.evaluate(pr.params.x0)
    A = J[:, pr.params.free].tocsr()
    P = sp.csr_matrix(weight_matrix(pr.cov))
    assert P.nnz > P.shape[0]                                   # correlated: P not diagonal
    free = pr.params.free
    if datum._GRAM is not None:
        t = np.flatnonzero(pr.params.kind[free] == "t")
        At = A[:, t]
        out = np.zeros((t.size, t.size))
        W = sp.csr_matrix(P @ At)
        datum._GRAM(At.indptr, At.indices, At.data, W.indptr, W.indices, W.data, out)
        ref = (At.T @ P @ At).toarray()
        assert np.abs(out - ref).max() <= 1e-12 * np.abs(ref).max()
    dense = datum.plan(pr, pr.params.x0, A, P, free)
    monkeypatch.setattr(datum, "DENSE_NTT", -1)
    sparse = datum.plan(pr, pr.params.x0, A, P, free)
    assert dense.names == sparse.names and len(dense.names) == 7
    assert np.array_equal(dense.eliminate, sparse.eliminate)
    sign = np.sign(np.sum(dense.G * sparse.G, axis=0))          # (each null vector up to its sign)
    assert np.abs(dense.G * sign - sparse.G).max() <= 1e-10 * np.abs(sparse.G).max()
