"""baarda.problem: the block-diagonal covariance by clusters and the problem restricted to some
observations, against dense numpy matrices assembled here (P = C⁻¹, F80 eq. 1-3)."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.model.problem import Covariance, subset

from tests.networks import grid_network, problem, vector_network


def _clusters(seed=3, sizes=(1, 2, 3, 2, 1, 3, 3)):
    """Random SPD blocks of the given sizes over shuffled observation indices."""
    rng = np.random.default_rng(seed)
    n = sum(sizes)
    order = rng.permutation(n)
    members, blocks, at = [], [], 0
    for m in sizes:
        members.append(np.sort(order[at:at + m]))
        L = rng.normal(size=(m, m))
        blocks.append(L @ L.T + m * np.eye(m))
        at += m
    return n, members, blocks


def _dense(n, members, blocks):
    C = np.zeros((n, n))
    for idx, B in zip(members, blocks):
        C[np.ix_(idx, idx)] = B
    return C


def _stacked(n, members, blocks):
    groups = {}
    for c, (idx, B) in enumerate(zip(members, blocks)):
        groups.setdefault(idx.size, []).append((c, idx, B))
    return Covariance.from_groups(n, [(m, [g[0] for g in gs], np.array([g[1] for g in gs]),
                                       np.array([g[2] for g in gs])) for m, gs in groups.items()])


@pytest.fixture(params=["blocks", "groups"])
def cov(request):
    n, members, blocks = _clusters()
    make = Covariance.from_blocks if request.param == "blocks" else _stacked
    return make(n, members, blocks), _dense(n, members, blocks), members


def test_matrix_weight_and_sigma_against_dense(cov):
    c, C, _ = cov
    np.testing.assert_array_equal(c.matrix().toarray(), C)
    np.testing.assert_allclose(c.weight().toarray(), np.linalg.inv(C), rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(c.sigma(), np.sqrt(np.diag(C)), rtol=1e-15)
    assert c.cluster_count == 7


def test_scaled_and_weight_with_scale_against_dense(cov):
    """Variance-component factors per cluster (F80 eq. 9): C_c → f_c C_c, P_c → P_c / f_c."""
    c, C, members = cov
    f = np.linspace(0.5, 3.5, len(members))
    Cf = C.copy()
    for idx, fc in zip(members, f):
        Cf[np.ix_(idx, idx)] *= fc
    np.testing.assert_allclose(c.scaled(f).matrix().toarray(), Cf, rtol=1e-15)
    np.testing.assert_allclose(c.weight(scale=f).toarray(), np.linalg.inv(Cf), rtol=1e-10, atol=1e-14)


def test_subset_is_the_dense_submatrix(cov):
    """Leaving out observations keeps whole clusters and cuts the others to their sub-blocks."""
    c, C, members = cov
    drop = [members[1][0], members[2][1], members[4][0]]       # part of a 2- and a 3-cluster, a 1-cluster
    keep = np.setdiff1d(np.arange(C.shape[0]), drop)
    s = c.subset(keep)
    np.testing.assert_array_equal(s.matrix().toarray(), C[np.ix_(keep, keep)])
    assert s.cluster_count == 6
    np.testing.assert_allclose(s.weight().toarray(), np.linalg.inv(C[np.ix_(keep, keep)]), rtol=1e-10, atol=1e-14)


def test_diagonal():
    s = np.array([0.1, 2.0, 3e-5])
    np.testing.assert_array_equal(Covariance.diagonal(s).matrix().toarray(), np.diag(s * s))


@pytest.mark.parametrize("net", [grid_network(3, 3, noise_seed=2), vector_network(1)], ids=["grid", "vectors"])
def test_problem_subset_is_the_rows_of_the_full_problem(net):
    """f, J, l and C of the subset equal the kept rows (and rows × columns) of the full problem,
    with the parameters unchanged."""
    pr = problem(net)
    rng = np.random.default_rng(4)
    keep = np.sort(rng.choice(pr.n, pr.n - 4, replace=False))
    sub = subset(pr, keep)
    f, J = pr.evaluate(pr.params.x0)
    f2, J2 = sub.evaluate(sub.params.x0)
    assert sub.n == keep.size and sub.params.size == pr.params.size
    np.testing.assert_array_equal(f2, f[keep])
    np.testing.assert_array_equal(J2.toarray(), J.toarray()[keep])
    np.testing.assert_array_equal(sub.l, pr.l[keep])
    C = pr.cov.matrix().toarray()
    np.testing.assert_array_equal(sub.cov.matrix().toarray(), C[np.ix_(keep, keep)])
    np.testing.assert_array_equal(np.asarray(sub.info.line), np.asarray(pr.info.line)[keep])


def test_problem_notes_are_typed_and_never_changed_in_place():
    """Issue 24: a Problem carries typed, immutable notes (no ``extra`` dict read by key in
    twenty files); ``with_notes`` makes a new problem and leaves the old one as it was."""
    import dataclasses

    from baarda.defects import LocalDefect
    from baarda.model.problem import Problem, ProblemNotes
    from tests.networks import levelling_loop, problem as network_problem

    assert "extra" not in {f.name for f in dataclasses.fields(Problem)}
    problem = network_problem(levelling_loop())
    defect = LocalDefect("point", "X", ("z",), "no height difference to it")
    marked = problem.with_notes(local_defects=(defect,))
    assert marked.notes.local_defects == (defect,) and problem.notes.local_defects == ()
    assert marked.l is problem.l and marked.sets is problem.sets        # nothing else copied
    with pytest.raises(dataclasses.FrozenInstanceError):
        marked.notes.local_defects = ()                                 # type: ignore[misc]
    assert isinstance(ProblemNotes().ap_groups, dict)
