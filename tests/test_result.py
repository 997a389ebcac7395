"""baarda.result.Adjustment: what does not depend on the test policy — the fit, Σ = N⁻¹ in the
datum, C_vv per cluster, r, u_k, u_t — against the dense oracle (F80 eq. 3, 8, 16; §5-§6)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda import result
from baarda.adjust import Options, adjust
from baarda.exclusion import exclude
from baarda.model.problem import subset
from baarda.stats.reliability import reliability_of

from tests.networks import grid_network, problem, vector_network
from tests.oracle import dense, normal_inverse, nuisance_share, redundancy, reduced_design


@pytest.fixture(scope="module", params=["grid", "vectors"])
def adj(request):
    net = grid_network(3, 3, noise_seed=6) if request.param == "grid" else vector_network(3)
    return adjust(problem(net))


def test_the_solution_satisfies_the_normal_equations(adj):
    """x̂ solves AᵀP v = 0 at the solution (F80 eq. 3), v = f(x̂) − l; vᵀPv, r and σ̂0 follow."""
    ref = dense(adj)
    g = ref.A.T @ ref.P @ ref.v
    scale = np.abs(ref.A.T @ ref.P).sum(axis=1) * np.abs(ref.v).max()
    assert (np.abs(g) <= 1e-8 * scale).all()
    assert adj.vPv == pytest.approx(ref.v @ ref.P @ ref.v, rel=1e-12)
    assert adj.dof == adj.n - np.linalg.matrix_rank(ref.A)
    assert adj.sigma0_post == pytest.approx(adj.sigma0 * np.sqrt(adj.vPv / adj.dof), rel=1e-12)


def test_covariance_of_the_unknowns_is_the_dense_inverse(adj):
    """Σ = N⁻¹ (fixed datum: N regular), entry by entry, and the point blocks built from it."""
    Ninv = normal_inverse(adj.A, adj.P)
    u = Ninv.shape[0]
    i, j = np.meshgrid(np.arange(u), np.arange(u), indexing="ij")
    np.testing.assert_allclose(adj.cov_entries(i, j), Ninv, rtol=1e-8, atol=1e-10 * np.abs(Ninv).max())
    free = np.full(adj.problem.params.size, -1)
    free[adj.problem.params.free] = np.arange(u)
    idx = adj.problem.points.index
    for p in range(idx.shape[0]):
        loc = free[idx[p][idx[p] >= 0]]
        if loc.size and (loc >= 0).all():
            k = np.flatnonzero(idx[p] >= 0)
            np.testing.assert_allclose(adj.point_cov[p][np.ix_(k, k)], Ninv[np.ix_(loc, loc)],
                                       rtol=1e-8, atol=1e-10 * np.abs(Ninv).max())


def test_redundancy_numbers_and_the_split_of_the_leverage(adj):
    """r_i = (C_vv P)_ii (F80 §5), u_t,i = (B (BᵀPB)⁻¹ BᵀP)_ii and u_k,i = (C̄ Q_kk C̄ᵀ P)_ii with
    C̄ of F80 eq. 16, Q_kk = (C̄ᵀPC̄)⁻¹; Σ r_i = r."""
    A, P = adj.A.toarray(), adj.P.toarray()
    kind = adj.problem.params.kind[adj.problem.params.free]
    t, k = np.flatnonzero(kind == "t"), np.flatnonzero(kind == "k")
    np.testing.assert_allclose(adj.r, redundancy(A, P), atol=1e-10)
    assert adj.r.sum() == pytest.approx(adj.dof, abs=1e-8)
    if t.size:
        np.testing.assert_allclose(adj.u_t, nuisance_share(A, P, t), atol=1e-10)
        Cbar = reduced_design(A, P, t, k)
    else:
        np.testing.assert_allclose(adj.u_t, 0.0, atol=1e-12)
        Cbar = A[:, k]
    uk = np.diag(Cbar @ np.linalg.solve(Cbar.T @ P @ Cbar, Cbar.T @ P))
    np.testing.assert_allclose(adj.u_k, uk, atol=1e-10)


def test_cluster_blocks_of_cvv(adj):
    """C_vv = C − A N⁻¹ Aᵀ (F80 eq. 8) per covariance cluster."""
    ref = dense(adj)
    for members, C, Cvv in adj.cluster_cvv():
        for mem, c, cvv in zip(members, C, Cvv):
            np.testing.assert_allclose(c, ref.C[np.ix_(mem, mem)], rtol=1e-15)
            np.testing.assert_allclose(cvv, ref.Cvv[np.ix_(mem, mem)], rtol=1e-7, atol=1e-9 * np.abs(c).max())


def test_exclude_equals_one_step_of_the_reduced_problem():
    """Leaving observations out at the same linearisation point (Woodbury) gives the x̂ of one
    Gauss-Newton step of the problem without them started at x̂, and r of the kept rows of A
    at x̂ (the linearisation point of the exclusion)."""
    pr = problem(grid_network(3, 3, noise_seed=6))
    adj = adjust(pr)
    rows = [3, 11]
    ex = exclude(adj, rows)
    keep = np.setdiff1d(np.arange(pr.n), rows)
    one = adjust(subset(pr, keep), Options(max_iter=1), x0=adj.x)
    assert np.abs(ex.x - one.x).max() <= 1e-9
    assert ex.n == pr.n - 2
    np.testing.assert_allclose(ex.r, redundancy(adj.A.toarray()[keep], one.P), atol=1e-10)


def test_a_posteriori_sigma_scales_the_point_covariance():
    net = grid_network(3, 3, noise_seed=6)
    a = adjust(problem(net))
    b = adjust(problem(dataclasses.replace(net, sigma_act="aposteriori")))
    factor = (a.sigma0_post / a.sigma0) ** 2
    assert b.variance_factor == pytest.approx(factor, rel=1e-12)
    np.testing.assert_allclose(b.point_cov, a.point_cov * factor, rtol=1e-10, atol=1e-20)
    np.testing.assert_allclose(b.r, a.r, atol=1e-12)                 # r does not depend on σ0


def test_correlated_component_with_negative_r_is_tested():
    """F80 §4: w_i = (Pv)_i / √(P C_vv P)_ii is defined wherever (P C_vv P)_ii > 0. A component of a
    correlated GNSS vector can have r_i = (C_vv P)_ii < 0 (only the cluster's trace is bounded):
    it is not uncontrolled, and its w and MDB equal the dense oracle's."""
    net = vector_network(seed=5)
    noise = np.random.default_rng(1).normal(scale=0.002, size=len(net.observations))
    net = dataclasses.replace(net, observations=tuple(dataclasses.replace(o, value=o.value + e)
                                                      for o, e in zip(net.observations, noise)))
    adj = adjust(problem(net))
    i = int(np.argmin(adj.r))
    assert adj.r[i] < 0 and not adj.uncontrolled[i]
    d = dense(adj)
    pcp = np.diag(d.P @ d.Cvv @ d.P)
    assert adj.w[i] == pytest.approx((d.P @ d.v)[i] / np.sqrt(pcp[i]), rel=1e-8)
    assert np.isfinite(reliability_of(adj).mdb[i])
    # the rule's scale: P_ii, so that for an uncorrelated observation it reads r_i ≤ R_EPS
    np.testing.assert_allclose(adj.weight_diagonal, np.diag(d.P), rtol=1e-12)


def test_seed_hands_over_cached_properties_only_once():
    """Adjustment.seed: the one way to hand a result values computed elsewhere (the solver's Ar,
    an exclusion's factor); a name that is not a cached property, or one already computed, is
    refused, so a result cannot be given an inconsistent cache."""
    fresh = adjust(problem(grid_network(3, 3, noise_seed=6)))
    with pytest.raises(TypeError, match="not a cached property"):
        fresh.seed(vPv_total=1.0)
    fresh.r                                        # computes factor, hat blocks, ...
    with pytest.raises(TypeError, match="already computed"):
        fresh.seed(factor=None)
    twin = dataclasses.replace(fresh)
    twin.seed(factor=fresh.factor, hat_blocks=fresh.hat_blocks)
    assert twin.factor is fresh.factor
    np.testing.assert_array_equal(twin.r, fresh.r)


def test_computed_lists_the_cached_properties_already_computed():
    """Adjustment.computed: what seed can hand to another result — the computed values among
    the names asked for, nothing computed on the way; a name that is not a cached property is
    refused."""
    fresh = adjust(problem(grid_network(3, 3, noise_seed=6)))
    assert fresh.computed("hat_blocks") == {}
    assert fresh.computed("hat_blocks") == {}          # asking computed nothing
    fresh.r
    got = fresh.computed("factor", "hat_blocks")
    assert set(got) == {"factor", "hat_blocks"} and got["factor"] is fresh.factor
    assert got["hat_blocks"] is fresh.hat_blocks
    with pytest.raises(TypeError, match="not a cached property"):
        fresh.computed("n")
    twin = dataclasses.replace(fresh).seed(**got)
    assert twin.factor is fresh.factor
    np.testing.assert_array_equal(twin.r, fresh.r)


def test_json_document_streams_one_record_per_line(tmp_path):
    """dump_json: the document read back is the document; each record of a list of records on a
    line of its own (grep-able, and written by the compiled encoder); NaN refused (strict JSON);
    strings from files stay text (escaped, no raw control characters)."""
    import json

    from baarda.io.results import dump_json

    doc = {"schema": "baarda-analysis/1.0",
           "summary": {"title": "t\u001b[31mred\n", "nested": {"a": [1, 2.5, None]}},
           "observations": [{"index": i, "id": f"p{i}\"", "w": i / 3} for i in range(5)],
           "points": [], "inseparable": [[1, 2]]}
    path = tmp_path / "r.json"
    dump_json(doc, path)
    text = path.read_text()
    assert json.loads(text) == doc
    lines = text.splitlines()
    assert sum(1 for s in lines if s.startswith('  {"index": ')) == 5
    assert "\u001b" not in text and all(c.isprintable() for s in lines for c in s)
    with pytest.raises(ValueError):
        dump_json({"observations": [{"w": float("nan")}]}, tmp_path / "nan.json")


def test_one_cluster_pass_gives_the_two_passes_numbers(demo_problem, monkeypatch):
    """A small block's cluster statistics in one pass (result.ONE_PASS_N, issue 29: fixed
    costs) are those of the two passes a large block makes, bit for bit."""
    one = adjust(demo_problem, Options())
    keys = ("r", "u_k", "u_t", "php", "php_k", "w")
    a = {k: np.array(getattr(one, k)) for k in keys}
    assert "_cluster_extra" in one.__dict__
    monkeypatch.setattr(result, "ONE_PASS_N", 0)
    two = adjust(demo_problem, Options())
    _ = two.r
    assert "_cluster_extra" not in two.__dict__          # (the second pass not made yet)
    for k in keys:
        np.testing.assert_array_equal(np.array(getattr(two, k)), a[k], err_msg=k)
