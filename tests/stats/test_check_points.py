"""The check-point test (baarda.stats.check_points): dense reference, a planted error, χ²(3) under H0."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda import adjust
from baarda.model.bundle import build_block_problem, check_points
from baarda.simulate import simulate_block
from baarda.stats.check_points import check_point_tests
from baarda.stats.policy import TestPolicy
from tests import oracle


def _block(seed, **kw):
    block, _ = simulate_block(strips=2, images_per_strip=5, check=5, seed=seed, **kw)
    return block


def _tests(block):
    adj = adjust(build_block_problem(block))
    return adj, check_point_tests(adj, check_points(adj, block), TestPolicy())


def test_statistic_equals_the_dense_reference():
    block = _block(1)
    pts = list(block.points)
    k = next(i for i, p in enumerate(pts) if p.status == "check")
    pts[k] = dataclasses.replace(pts[k], sigma_h=0.03, sigma_v=0.06)       # a known σ of the reference
    block = block.replace(points=tuple(pts))
    adj, rep = _tests(block)
    Q = oracle.normal_inverse(adj.A, adj.P) * adj.variance_factor
    fpos = np.full(adj.problem.params.size, -1)
    fpos[adj.problem.params.free] = np.arange(adj.problem.params.free.size)
    ids = list(adj.problem.points.ids)
    assert rep["n"] == 5
    for p in rep["points"]:
        i = ids.index(p["id"])
        loc = fpos[adj.problem.points.index[i]]
        S = Q[np.ix_(loc, loc)] + np.diag(np.square(p["ref_sigma"]))
        d = adj.coordinates[i] - np.asarray(p["ref"])
        assert p["T"] == pytest.approx(d @ np.linalg.solve(S, d), rel=1e-9)
    assert [p["ref_sigma"] for p in rep["points"] if p["id"] == pts[k].id] == [[0.03, 0.03, 0.06]]
    assert rep["critical"] == pytest.approx(16.266236196238129, rel=1e-12)      # χ²_0.999(3)
    locs = [fpos[adj.problem.points.index[ids.index(p["id"])]] for p in rep["points"]]
    var = np.array([np.diag(Q[np.ix_(loc, loc)]) + np.square(p["ref_sigma"]) for loc, p in zip(locs, rep["points"])])
    assert rep["expected_rms"] == pytest.approx(np.sqrt(var.mean(axis=0)), rel=1e-9)


def test_a_wrong_reference_is_rejected():
    block = _block(2)
    pts = list(block.points)
    k = next(i for i, p in enumerate(pts) if p.status == "check")
    ref = pts[k].ref
    pts[k] = dataclasses.replace(pts[k], ref=(ref[0] + 1.0, ref[1], ref[2]))
    _, rep = _tests(block.replace(points=tuple(pts)))
    bad = [p for p in rep["points"] if p["rejected"]]
    assert [p["id"] for p in bad] == [pts[k].id]
    assert rep["n_rejected"] == 1


def test_statistic_is_chi2_3_under_h0():
    """Mean of T over 10 simulated blocks × 5 check points (exact references): 3 within 4 standard
    errors of a χ²(3) mean (√(6/50); the points of one block are correlated, hence the margin)."""
    T = np.concatenate([[p["T"] for p in _tests(_block(seed))[1]["points"]] for seed in range(10, 20)])
    assert T.size == 50
    assert abs(T.mean() - 3.0) < 4 * np.sqrt(6 / T.size)


def test_free_block_has_no_test():
    block = _block(3).replace(datum="free")
    _, rep = _tests(block)
    assert "free block" in rep["note"]
    assert not any(p["rejected"] for p in rep["points"]) and np.isnan(rep["critical"])
