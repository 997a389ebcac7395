"""baarda.hypotheses: the multi-dimensional test of a hypothesis H (F80 eq. 10-15) against the
dense oracle: W_s = HᵀP C_vv P H, ∇ŝ = −W_s⁻¹ HᵀPv, T, R, the lower-bound ellipse and the
weakest direction from numpy's dense matrices and eigen-decompositions."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as la

from baarda.adjust import Options, adjust
from baarda.errors import HypothesisError
from baarda.stats import distributions
from baarda.stats.hypotheses import common_error, deformation, external_reliability, selection
from baarda.stats.reliability import reliability_of

from tests.networks import grid_network, problem, vector_network
from tests.oracle import dense, reduced_design


@pytest.fixture(scope="module")
def adj():
    return adjust(problem(grid_network(3, 3, noise_seed=5)))


def _hypotheses(n):
    return {"one": selection(n, [4]), "pair": selection(n, [2, 9]), "weighted": selection(n, [0, 5, 7], [1.0, 2.0, 0.5]),
            "common": common_error(n, [np.array([1, 3]), np.array([6, 8, 10])])}


@pytest.mark.parametrize("name", ["one", "pair", "weighted", "common"])
def test_statistics_equal_the_dense_formulas(adj, name):
    H = _hypotheses(adj.n)[name]
    ref = dense(adj)
    Hd = H.toarray()
    P, Cvv, v = ref.P, ref.Cvv, ref.v
    W = Hd.T @ P @ Cvv @ P @ Hd                                   # F80 eq. 10
    g = Hd.T @ P @ v
    T = g @ np.linalg.solve(W, g)                                 # F80 eq. 12
    q, r, vPv = Hd.shape[1], adj.dof, v @ P @ v
    h = reliability_of(adj).test(H)
    assert h.q == q
    np.testing.assert_allclose(h.W, W, rtol=1e-8, atol=1e-10 * np.abs(W).max())
    np.testing.assert_allclose(h.nabla, -np.linalg.solve(W, g), rtol=1e-7, atol=1e-12)
    assert h.T == pytest.approx(T, rel=1e-8)
    assert h.R == pytest.approx((T / q) / ((vPv - T) / (r - q)), rel=1e-8)
    np.testing.assert_allclose(h.nabla_cov, np.linalg.inv(W), rtol=1e-7, atol=1e-10 * np.abs(np.linalg.inv(W)).max())


def test_one_observation_gives_w_squared(adj):
    """For H = e_i the test is the w-test: T = w_i² (F80 §4)."""
    for i in (0, 7, 15):
        assert reliability_of(adj).test(selection(adj.n, [i])).T == pytest.approx(adj.w[i] ** 2, rel=1e-9)


def test_lower_bound_lies_on_the_ellipse_and_the_weakest_direction_is_the_pencils(adj):
    """∇0sᵀ W ∇0s = δ0² in every direction (F80 eq. 13); δ0'(s) = δ0 √(sᵀHᵀPHs / sᵀWs) is at most
    δ0 √λmax of the pencil (HᵀPH, W) and reaches it in ``weakest`` (F80 eq. 14, §7.3)."""
    H = _hypotheses(adj.n)["common"]
    h = reliability_of(adj).test(H)
    Hd, P = H.toarray(), dense(adj).P
    HPH = Hd.T @ P @ Hd
    for s in np.random.default_rng(0).normal(size=(5, 2)):
        b = h.lower_bound(s)
        assert b @ h.W @ b == pytest.approx(h.delta0 ** 2, rel=1e-9)
        assert abs(b[0] * s[1] - b[1] * s[0]) <= 1e-12 * np.abs(b).max() * np.abs(s).max()   # along s
    lam_max = la.eigh(HPH, h.W, eigvals_only=True).max()
    assert h.delta0_prime_max == pytest.approx(h.delta0 * np.sqrt(lam_max), rel=1e-9)
    s = h.weakest
    assert h.delta0 * np.sqrt((s @ HPH @ s) / (s @ h.W @ s)) == pytest.approx(h.delta0_prime_max, rel=1e-9)


def test_b_method_sets_the_size_of_the_q_dimensional_test():
    a = adjust(problem(grid_network(3, 3, noise_seed=5)), Options(b_method=True))
    h = reliability_of(a).test(selection(a.n, [2, 9]))
    assert h.alpha == pytest.approx(distributions.alpha_b_method(a.options.alpha0, a.options.beta0, 2))
    assert h.delta0 == pytest.approx(distributions.delta0(a.options.alpha0, a.options.beta0, 1))


def test_deformation_is_the_dense_normal_solution():
    """∇0x = N⁻¹ AᵀP H ∇0s (F80 §6) for a fixed-datum network (N regular)."""
    adj = adjust(problem(vector_network(2)))
    h = reliability_of(adj).test(selection(adj.n, [3, 4, 5]))
    d = deformation(adj, h)
    ref = dense(adj)
    nabla0 = h.lower_bound(h.ellipse_dirs[:, np.flatnonzero(np.isfinite(h.ellipse_axes))[0]])
    e = h.H.toarray() @ nabla0
    expected = np.linalg.solve(ref.A.T @ ref.P @ ref.A, ref.A.T @ ref.P @ e)
    np.testing.assert_allclose(d, expected, rtol=1e-8, atol=1e-12 * np.abs(expected).max())


def test_wrong_number_of_rows_is_a_hypothesis_error(adj):
    with pytest.raises(HypothesisError):
        reliability_of(adj).test(selection(adj.n + 2, [0]))


def _dense_eq17(adj, H):
    """M = HᵀP C̄ Q_kk C̄ᵀ P H and W_s = HᵀP C_vv P H from dense matrices (F80 eq. 16-17), with
    C̄ = (I − B(BᵀPB)⁻¹BᵀP)C and Q_kk = (C̄ᵀPC̄)⁺ (pseudo-inverse: any datum)."""
    ref = dense(adj)
    kind = adj.problem.params.kind[adj.problem.params.free]
    t, k = np.flatnonzero(kind == "t"), np.flatnonzero(kind == "k")
    Cbar = reduced_design(ref.A, ref.P, t, k)
    Qkk = np.linalg.pinv(Cbar.T @ ref.P @ Cbar, rcond=1e-12, hermitian=True)
    Hd = H.toarray()
    G = Cbar.T @ ref.P @ Hd
    return G.T @ Qkk @ G, Hd.T @ ref.P @ ref.Cvv @ ref.P @ Hd, Cbar, Qkk


@pytest.mark.parametrize("datum", ["fixed", "free"])
@pytest.mark.parametrize("name", ["one", "pair", "weighted", "common"])
def test_external_reliability_of_any_hypothesis_equals_the_dense_eq17(datum, name):
    """δ̄0(s) = δ0 √(sᵀMs / sᵀW_s s) (F80 eq. 17): M, W_s, the maximum δ0 √λmax(M, W_s) and its
    direction against dense matrices, on a network with orientation unknowns (B ≠ 0), fixed and
    free (the form is datum invariant)."""
    adj = adjust(problem(grid_network(3, 3, noise_seed=5, datum=datum)))
    H = _hypotheses(adj.n)[name]
    h = reliability_of(adj).test(H)
    ext = external_reliability(adj, h)
    M, W, _, _ = _dense_eq17(adj, H)
    np.testing.assert_allclose(ext.M, M, rtol=1e-7, atol=1e-9 * np.abs(M).max())
    mu = la.eigh(M, W, eigvals_only=True)
    assert ext.max == pytest.approx(h.delta0 * np.sqrt(mu.max()), rel=1e-7)
    s = ext.direction
    assert h.delta0 * np.sqrt((s @ M @ s) / (s @ W @ s)) == pytest.approx(ext.max, rel=1e-7)
    for s in np.random.default_rng(1).normal(size=(20, H.shape[1])):
        assert ext.delta_bar0(s) <= ext.max * (1 + 1e-9)
        assert ext.delta_bar0(s) == pytest.approx(h.delta0 * np.sqrt((s @ M @ s) / (s @ W @ s)), rel=1e-7)


def test_external_reliability_of_one_observation_is_eq18s():
    """For H = e_i, δ̄0 is the per-observation external reliability δ0 √((PH_kP)_ii/(PC_vvP)_ii)."""
    adj = adjust(problem(grid_network(3, 3, noise_seed=5)))
    for i in (0, 7, 15):
        ext = external_reliability(adj, reliability_of(adj).test(selection(adj.n, [i])))
        assert ext.max == pytest.approx(reliability_of(adj).external[i], rel=1e-8)
        assert ext.lambda_bar_max == pytest.approx(reliability_of(adj).external[i] ** 2, rel=1e-8)


def test_eq18_is_reached_with_equality_in_the_maximising_direction():
    """∇0f(s) ≤ σ_f δ̄0(s) for any f = gᵀk (F80 eq. 18, Cauchy-Schwarz), with equality for
    g = (C̄ᵀPC̄) ∇0k when ∇0s lies in the maximising direction; random g stay below."""
    adj = adjust(problem(grid_network(3, 3, noise_seed=5, datum="free")))
    H = _hypotheses(adj.n)["common"]
    h = reliability_of(adj).test(H)
    ext = external_reliability(adj, h)
    _, _, Cbar, Qkk = _dense_eq17(adj, H)
    nabla0 = h.lower_bound(ext.direction)                       # on the ellipse, F80 eq. 13
    dk = Qkk @ Cbar.T @ dense(adj).P @ (H.toarray() @ nabla0)   # F80 eq. 16
    g = np.linalg.pinv(Qkk, rcond=1e-12, hermitian=True) @ dk
    sigma_f = np.sqrt(g @ Qkk @ g)
    assert (g @ dk) / sigma_f == pytest.approx(ext.max, rel=1e-7)
    for g in np.random.default_rng(2).normal(size=(50, dk.size)):
        assert abs(g @ dk) <= np.sqrt(g @ Qkk @ g) * ext.max * (1 + 1e-9)
