"""Reliability measures against independent references: statsmodels' regression diagnostics, a
dense implementation of F80's formulas, closed forms, and identities (F80 §4-§6, eq. 8, eq. 16)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as la
from hypothesis import given, settings, strategies as st

from baarda.adjust import Options, adjust
from baarda.stats import distributions
from baarda.stats.groups import cluster_group_tests
from baarda.stats.hypotheses import selection
from baarda.stats.reliability import reliability_of

from tests.networks import grid_network, levelling_loop, problem, vector_network, with_values
from tests.oracle import dense, reduced_design


# -- closed forms --------------------------------------------------------------------------------

@pytest.mark.parametrize("m", [3, 4, 7])
def test_levelling_loop(m):
    """One condition among m equal-weight height differences: r_i = 1/m, Σ r_i = 1.

    (Σ r_i equals the one condition, so each of the m equal observations has 1/m.)"""
    adj = adjust(problem(levelling_loop(m)))
    assert adj.dof == 1
    np.testing.assert_allclose(adj.r, 1.0 / m, atol=1e-12)


# -- statsmodels oracle ------------------------------------------------------------------------

def test_statsmodels_hat_matrix_and_studentized_residuals():
    sm = pytest.importorskip("statsmodels.api")
    from statsmodels.stats.outliers_influence import OLSInfluence

    adj = adjust(problem(grid_network(4, 3, noise_seed=3)))
    sq = np.sqrt(adj.P.diagonal())
    Aw = adj.Ar.toarray() * sq[:, None]
    # at the solution the linearised model has zero correction: y = l − f(x̂) = −v
    res = sm.OLS(-adj.v * sq, Aw).fit()
    infl = OLSInfluence(res)
    np.testing.assert_allclose(adj.r, 1.0 - infl.hat_matrix_diag, atol=1e-10)
    np.testing.assert_allclose(adj.tau, -infl.resid_studentized_internal, atol=1e-8)
    s = np.sqrt(res.scale)
    np.testing.assert_allclose(adj.w, -infl.resid_studentized_internal * s / adj.sigma0, atol=1e-8)


# -- dense reference, correlated clusters ------------------------------------------------------

def test_correlated_clusters_against_dense_formulas():
    net = vector_network()
    rng = np.random.default_rng(5)
    vals = [o.value for o in net.observations]
    for c in net.clusters:
        e = np.linalg.cholesky(c.cov) @ rng.normal(size=3)
        for i, ei in zip(c.indices, e):
            vals[i] += ei
    adj = adjust(problem(with_values(net, vals)))
    ref = dense(adj)
    np.testing.assert_allclose(adj.r, ref.r, atol=1e-10)
    np.testing.assert_allclose(adj.w, ref.w, atol=1e-8)
    assert abs(adj.r.sum() - adj.dof) < 1e-9
    # the 3D group test of every vector: T = (Pv)_gᵀ (P C_vv P)_gg⁻¹ (Pv)_g
    P, Cvv = ref.P, ref.Cvv
    Pv = P @ adj.v
    for g in reliability_of(adj).groups:
        m = g["members"]
        W = (P @ Cvv @ P)[np.ix_(m, m)]
        assert abs(g["T"] - Pv[m] @ np.linalg.solve(W, Pv[m])) < 1e-8 * max(1, g["T"])
        assert g["dimension"] == 3


@pytest.mark.parametrize("make", [lambda: grid_network(4, 4, seed=2), vector_network])
def test_hat_blocks_with_round_off_are_recomputed_by_solves(make):
    """Cluster blocks of A Σ Aᵀ that betray round-off (r_i < 0, asymmetry) are recomputed by
    direct solves; untouched blocks stay as they were."""
    from baarda.model.problem import size_groups

    adj = adjust(problem(make()))
    H, Ht = adj.hat_blocks
    assert adj.repaired_clusters == 0
    spoiled = H.copy()
    pos, touched = 0, 0
    for m, _, members, C in size_groups(adj.problem.cov):
        k = members.shape[0]
        block = spoiled[pos:pos + k * m * m].reshape(k, m, m)
        block[0] = 1.01 * C[0]                    # r < 0 (trace too)
        if k > 1 and m > 1:
            block[1, 0, m - 1] += 1e-3 * np.abs(C[1]).max()   # asymmetric
            touched += 1
        touched += 1
        pos += k * m * m
    H2, Ht2 = adj.repair_hat_blocks(spoiled, Ht)
    assert adj.repaired_clusters == touched
    np.testing.assert_allclose(H2, H, atol=1e-10 * np.abs(H).max())
    np.testing.assert_allclose(Ht2, Ht, atol=1e-10 * max(np.abs(Ht).max(), 1e-300))


@pytest.mark.parametrize("b_method", [False, True])
def test_group_tests_from_cluster_blocks_equal_the_general_test(b_method):
    """Groups that are one covariance cluster (image points) are tested from the cluster blocks
    of C_vv at once; the general test with H the selection gives the same T, q, ∇ŝ."""
    from baarda.model.bundle import build_block_problem
    from baarda.stats.hypotheses import test
    from baarda.simulate import simulate_block

    block, _ = simulate_block(strips=3, images_per_strip=6, seed=4)
    adj = adjust(build_block_problem(block), Options(b_method=b_method))
    groups = reliability_of(adj).groups
    fast = cluster_group_tests(adj)
    sizes = np.array([m.size for m in adj.problem.cov.members])
    one_cluster = [g for g in groups
                   if sizes[adj.problem.cov.cluster[g["members"][0]]] == g["members"].size
                   and np.unique(adj.problem.cov.cluster[g["members"]]).size == 1]
    assert len(fast) == len(one_cluster) > 150
    assert {1, 2} <= {g["dimension"] for g in one_cluster}     # 2-ray points: rank-deficient W
    for g in groups[:: max(1, len(groups) // 60)]:
        h = test(adj, selection(adj.n, g["members"]))
        assert g["dimension"] == h.q and g["alpha"] == h.alpha and g["critical"] == h.critical_T
        assert abs(g["T"] - h.T) <= 1e-9 * max(1.0, h.T)
        np.testing.assert_allclose(g["nabla"], h.nabla, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(g["nabla_sigma"], h.nabla_sigma, rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(g["ellipse_axes"], np.sort(h.ellipse_axes[np.isfinite(h.ellipse_axes)])[::-1],
                                   rtol=1e-7)
        assert g["delta0_prime_max"] == pytest.approx(h.delta0_prime_max, rel=1e-7)
        assert (np.isnan(g["R"]) and np.isnan(h.R)) or g["R"] == pytest.approx(h.R, rel=1e-8)
        assert g["critical_R"] == h.critical_R and g["delta0"] == h.delta0


# -- identities ---------------------------------------------------------------------------------

def test_error_of_mdb_size_gives_w_equal_delta0():
    net = grid_network(3, 3)
    base = adjust(problem(net))
    assert np.abs(base.w).max() < 1e-6
    for i in (0, 5, 11):
        vals = [o.value for o in net.observations]
        vals[i] += reliability_of(base).mdb[i]
        adj = adjust(problem(with_values(net, vals)))
        assert abs(abs(adj.w[i]) - reliability_of(base).delta0) < 1e-4 * reliability_of(base).delta0


def test_T_of_one_observation_is_w_squared_and_nabla_is_the_error():
    adj = adjust(problem(grid_network(3, 3, noise_seed=11)))
    for i in (1, 7, 20):
        h = reliability_of(adj).test(selection(adj.n, [i]))
        assert abs(h.T - adj.w[i] ** 2) < 1e-8 * max(1, h.T)
        # ∇ŝ = −v_i / r_i for an uncorrelated observation (Gama's err-obs up to sign)
        assert abs(h.nabla[0] + adj.v[i] / adj.r[i]) < 1e-8 * abs(adj.v[i] / adj.r[i]) + 1e-15


def test_external_reliability_equals_deformation_quadratic_form():
    """δ̄0,i² (all unknowns) = ∇0xᵀ N ∇0x / σ0² for ∇0l = MDB_i e_i (F80 eq. 18)."""
    adj = adjust(problem(grid_network(3, 4, noise_seed=2)))
    A, P = adj.A, adj.P
    for i in (0, 9, 17):
        err = np.zeros(adj.n)
        err[i] = reliability_of(adj).mdb[i]
        dx = adj.deformation(err)
        lam = dx @ (A.T @ (P @ (A @ dx)))
        assert abs(np.sqrt(lam) - reliability_of(adj).external_all[i]) < 1e-6 * reliability_of(adj).external_all[i]


def test_u_t_and_u_k_split_the_leverage():
    adj = adjust(problem(grid_network(3, 3, noise_seed=1)))
    np.testing.assert_allclose(adj.r + adj.u_k + adj.u_t, 1.0, atol=1e-9)
    # directions feed the orientation unknowns, distances do not
    kinds = np.array(adj.problem.info.kind)
    assert (adj.u_t[kinds == "distance"] < 1e-9).all() and (adj.u_t[kinds == "direction"] > 1e-3).all()
    assert (reliability_of(adj).external <= reliability_of(adj).external_all + 1e-9).all()


@settings(max_examples=25, deadline=None)
@given(nx=st.integers(2, 4), ny=st.integers(2, 4), seed=st.integers(0, 10_000))
def test_redundancy_invariants_and_datum_invariance(nx, ny, seed):
    fixed = adjust(problem(grid_network(nx, ny, noise_seed=seed, seed=seed, jitter=0.05)))
    free = adjust(problem(grid_network(nx, ny, noise_seed=seed, seed=seed, datum="free", jitter=0.05)))
    assert fixed.dof == free.dof
    assert abs(fixed.r.sum() - fixed.dof) < 1e-7
    assert (fixed.r >= 0).all() and (fixed.r <= 1).all()
    np.testing.assert_allclose(fixed.r, free.r, atol=1e-9)
    np.testing.assert_allclose(fixed.w, free.w, atol=1e-6)
    np.testing.assert_allclose(reliability_of(fixed).external, reliability_of(free).external, rtol=1e-6)


def test_free_network_covariance_is_the_s_transformed_one():
    """Σ_S = S Σ Sᵀ (M84 §2) from the selected inverse equals the dense pseudo-inverse route,
    and the trace over the S-base is minimal (inner constraints: Σ_S = N⁺ when all points are
    in the base)."""
    adj = adjust(problem(grid_network(3, 3, noise_seed=4, datum="free")))
    ref = dense(adj)
    u = adj.A.shape[1]
    i, j = np.meshgrid(np.arange(u), np.arange(u), indexing="ij")
    S = adj.cov_entries(i, j)
    k = np.flatnonzero(adj.problem.params.kind[adj.problem.params.free] == "k")
    # N⁺ restricted to coordinates after eliminating orientations equals the inner solution
    P = ref.P
    t = np.setdiff1d(np.arange(u), k)
    Cbar = reduced_design(ref.A, P, t, k)
    Qkk = np.linalg.pinv(Cbar.T @ P @ Cbar, rcond=1e-12, hermitian=True)
    np.testing.assert_allclose(S[np.ix_(k, k)], Qkk, atol=1e-12 + 1e-7 * np.abs(Qkk).max())


# -- Monte Carlo of the tests' size and power (F80 §4-§5) ----------------------------------

@pytest.mark.slow
def test_monte_carlo_size_and_power_of_w_and_2d_tests():
    adj = adjust(problem(grid_network(3, 3)))
    ref = dense(adj)
    P, Cvv = ref.P, ref.Cvv
    R = P @ Cvv @ P            # Pv = −R e for an error vector e (linear model, v = Ax̂ − l)
    sd = np.sqrt(np.diag(R))
    L = np.linalg.cholesky(adj.problem.cov.matrix().toarray())
    rng = np.random.default_rng(2026)
    n_sim = 100_000
    E = L @ rng.normal(size=(adj.n, n_sim))
    W = -(R @ E) / sd[:, None]
    crit = reliability_of(adj).critical_w
    i = 4
    size = np.mean(np.abs(W[i]) > crit)
    se = np.sqrt(0.001 * 0.999 / n_sim)
    assert abs(size - 0.001) < 3 * se
    # an error of exactly MDB size on observation i: rejected at rate β0
    Wb = W[i] - (R[i, i] * reliability_of(adj).mdb[i]) / sd[i]
    power = np.mean(np.abs(Wb) > crit)
    assert abs(power - 0.80) < 3 * np.sqrt(0.8 * 0.2 / n_sim)
    # a 2D test (two observations together) with δ0 from the non-central χ²
    m = np.array([0, 1])
    Wg = R[np.ix_(m, m)]
    d0 = distributions.delta0(0.001, 0.80, 2)
    lam, V = la.eigh(Wg)
    nab = V[:, 0] * d0 / np.sqrt(lam[0])      # lower bound in the weakest direction
    G = -(R[m] @ E)
    G_err = G - (R[np.ix_(m, m)] @ nab)[:, None]
    T0 = np.einsum("in,ij,jn->n", G, np.linalg.inv(Wg), G)
    T1 = np.einsum("in,ij,jn->n", G_err, np.linalg.inv(Wg), G_err)
    c2 = distributions.critical_chi2(0.001, 2)
    assert abs(np.mean(T0 > c2) - 0.001) < 3 * se
    assert abs(np.mean(T1 > c2) - 0.80) < 3 * np.sqrt(0.8 * 0.2 / n_sim)
