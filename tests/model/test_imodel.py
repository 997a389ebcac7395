"""Planimetric independent-model blocks (PAT-M): Jacobian, reliability oracle, datum, tests."""

from __future__ import annotations

import numpy as np
import statsmodels.api as sm
from statsmodels.stats.outliers_influence import OLSInfluence

from baarda import adjust
from baarda.io.native import read_native, write_native
from baarda.model.imodel import build_imodel_problem
from baarda.simulate import simulate_imodel
from baarda.stats.hypotheses import h_model_point
from baarda.stats.reliability import reliability_of


def test_jacobian_matches_finite_differences():
    blk, _ = simulate_imodel(seed=1)
    pr = build_imodel_problem(blk)
    x = pr.params.x0
    _, J = pr.evaluate(x)
    J = J.toarray()
    for j in range(pr.params.size):
        h = 1e-6 * max(1.0, abs(x[j]))
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        fd = (pr.evaluate(xp)[0] - pr.evaluate(xm)[0]) / (2 * h)
        assert np.abs(fd - J[:, j]).max() <= 1e-6 * max(1.0, np.abs(J[:, j]).max())


def test_redundancy_equals_ols_leverage_and_datum_invariance():
    blk, _ = simulate_imodel(seed=2, control="corners")
    adj = adjust(build_imodel_problem(blk))
    A = adj.A.toarray()
    sig = np.sqrt(np.array([C[0, 0] for C in adj.problem.cov.blocks for _ in range(C.shape[0])]))
    order = np.concatenate(adj.problem.cov.members)
    Aw = np.empty_like(A)
    Aw[order] = A[order] / sig[:, None]
    h = OLSInfluence(sm.OLS(np.arange(A.shape[0]) % 5, Aw).fit()).hat_matrix_diag
    assert np.abs(adj.r - (1 - h)).max() <= 1e-8
    assert abs(adj.r.sum() - adj.dof) < 1e-8
    free = adjust(build_imodel_problem(IModel_free(blk)))
    assert free.defect == 4
    m = 2 * blk.obs.size
    # corner control over-determines the datum, so compare a free block with itself re-based
    base = tuple(p.id for p in blk.points[::3])
    rebased = adjust(build_imodel_problem(IModel_free(blk, base)))
    assert np.abs(rebased.r - free.r).max() <= 1e-9
    assert free.dof == adj.dof - (adj.n - m) + 4         # 4 corners × 2 coordinates − defect 4


def IModel_free(blk, sbase=()):
    from dataclasses import replace
    return replace(blk, datum="free", sbase=tuple(sbase))


def test_model_point_error_is_found():
    blk, truth = simulate_imodel(seed=3, errors=[{"kind": "model-point", "size": 25}])
    adj = adjust(build_imodel_problem(blk))
    e = truth["errors"][0]
    worst = max(reliability_of(adj).groups, key=lambda g: g["T"])
    assert sorted(worst["members"].tolist()) == e["rows"]
    h = reliability_of(adj).test(h_model_point(adj.problem, e["ids"]["model"], e["ids"]["point"]))
    assert h.rejected_T and np.isclose(h.T, worst["T"])
    assert np.all(np.abs(h.nabla - e["vector"]) < 3 * h.nabla_sigma)


def test_native_round_trip(tmp_path):
    blk, _ = simulate_imodel(seed=4)
    write_native(blk, tmp_path / "m.json")
    back = read_native(tmp_path / "m.json")
    assert np.array_equal(back.obs.xy, blk.obs.xy)
    assert [m.__dict__ | {"line": 0} for m in back.models] == [m.__dict__ | {"line": 0} for m in blk.models]
    a1 = adjust(build_imodel_problem(blk))
    a2 = adjust(build_imodel_problem(back))
    assert np.allclose(a1.r, a2.r, atol=1e-12)
