"""Variance components (F80 eq. 9): simulated group factors are recovered."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda.adjust import adjust
from baarda.errors import BaardaError
from baarda.model.network import Cluster
from baarda.stats import variance

from networks import grid_network, problem


def _network_with_true_factors(seed, f_dist=2.0, f_dir=0.5, sd=0.002, sr=1e-5):
    noisy = grid_network(7, 7, sigma_d=sd * np.sqrt(f_dist), sigma_r=sr * np.sqrt(f_dir), noise_seed=seed)
    nominal = tuple(Cluster((i,), np.array([[(sd if o.kind == "distance" else sr) ** 2]]))
                    for i, o in enumerate(noisy.observations))
    return dataclasses.replace(noisy, clusters=nominal)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recovers_group_factors(seed):
    p = problem(_network_with_true_factors(seed))
    vc = variance.estimate(p)
    assert vc.converged
    est = dict(zip(vc.names, vc.factors))
    se = dict(zip(vc.names, vc.std_error))
    assert abs(est["distances"] - 2.0) < 3 * se["distances"]
    assert abs(est["angles"] - 0.5) < 3 * se["angles"]
    # after the iteration every group's estimate is 1 with the rescaled covariances
    adj = vc.adjustment
    for name, ix in variance.groups_by_kind(p).items():
        assert abs(adj.v[ix] @ adj.Pv[ix] / adj.r[ix].sum() - 1.0) < 1e-3
    # the redundancies of the groups add up to the total redundancy
    assert abs(vc.redundancy.sum() - adj.dof) < 1e-8


def test_single_group_factor_is_the_variance_factor():
    p = problem(_network_with_true_factors(4))
    adj = adjust(p)
    vc = variance.estimate(p, {"all": np.arange(p.n)})
    assert abs(vc.factors[0] - (adj.sigma0_post / adj.sigma0) ** 2) < 1e-3 * vc.factors[0]


def test_split_cluster_is_refused():
    from networks import vector_network
    p = problem(vector_network())
    with pytest.raises(BaardaError, match="cluster"):
        variance.estimate(p, {"a": np.arange(0, 4), "b": np.arange(4, p.n)})


def test_additive_components_agree_with_group_factors():
    """With components that do not overlap (one per observation family) the additive estimator
    θ_j ← θ_j vᵀPQ_jPv / tr(C_vv P Q_j P) is the group estimator: same factors."""
    p = problem(_network_with_true_factors(5))
    groups = variance.groups_by_kind(p)
    comps = {}
    for name, ix in groups.items():
        inside = np.zeros(p.n, dtype=bool)
        inside[ix] = True
        comps[name] = tuple(np.asarray(b) if inside[m[0]] else np.zeros_like(b)
                            for m, b in zip(p.cov.members, p.cov.blocks))
    add = variance.estimate_components(p, comps, tol=1e-8, max_iter=200)
    grp = variance.estimate(p, groups, tol=1e-8, max_iter=200)
    np.testing.assert_allclose(add.theta, grp.factors, rtol=1e-5)
    np.testing.assert_allclose(add.redundancy, grp.redundancy, rtol=1e-5)


def test_radial_components_shape():
    """The radial model's C_j (F80 §2.1): a² on image coordinates, b²c²/cos⁴α growing with the
    radius, control kept apart."""
    from baarda.model.bundle import build_block_problem
    from baarda.simulate import simulate_block

    block, _ = simulate_block(strips=2, images_per_strip=4, design=True, seed=3, approx_sigma=0.0)
    p = build_block_problem(block)
    comps = variance.radial_components(p)
    kinds = np.array(p.info.kind)
    for c, idx in enumerate(p.cov.members):
        a, b, o = comps["a²"][c], comps["b²c²"][c], comps["other"][c]
        if kinds[idx[0]].startswith("image-"):
            assert np.allclose(a, np.eye(idx.size)) and (np.diag(b) >= 1.0).all() and not o.any()
            cam = p.extra["block"]["camera"]
            x, y = p.l[idx[0]] - cam["x0"], p.l[idx[1]] - cam["y0"]
            assert b[0, 0] == pytest.approx(((cam["c"] ** 2 + x * x + y * y) / cam["c"] ** 2) ** 2, rel=1e-12)
        else:
            assert not a.any() and not b.any() and np.allclose(o, p.cov.blocks[c])


def test_radial_model_recovers_a_and_b():
    """F80 §2.1: image noise with σ² = a² + b²c²/cos⁴α is recovered within its standard errors."""
    from baarda.model.bundle import build_block_problem
    from baarda.simulate import simulate_block

    # the two components are nearly collinear (1/cos⁴α from 1 to 3.1 in a 153 mm camera): a block
    # of 4 × 10 images with 15 points each and a dominant radial term separates them
    block, _ = simulate_block(strips=4, images_per_strip=10, design=True, seed=3, control="dense",
                              approx_sigma=0.0, pattern=[5, 3])
    p = build_block_problem(block)
    comps = variance.radial_components(p)
    a2_true, b2c2_true = 0.002 ** 2, 0.005 ** 2
    for seed in (12, 13):
        rng = np.random.default_rng(seed)
        e = np.zeros(p.n)
        for c, idx in enumerate(p.cov.members):
            C = a2_true * comps["a²"][c] + b2c2_true * comps["b²c²"][c] + comps["other"][c]
            e[idx] = np.linalg.cholesky(C) @ rng.normal(size=idx.size)
        est = variance.estimate_components(dataclasses.replace(p, l=p.l + e), comps, theta0=[2.5e-5, 2.5e-5, 1.0])
        assert est.converged and est.iterations < 20
        th = dict(zip(est.names, est.theta))
        se = dict(zip(est.names, est.std_error))
        assert abs(th["a²"] - a2_true) < 3 * se["a²"]
        assert abs(th["b²c²"] - b2c2_true) < 3 * se["b²c²"]
        assert abs(est.redundancy.sum() - est.adjustment.dof) < 1e-6 * est.adjustment.dof


def test_std_errors_rigorous_at_convergence():
    """At convergence D(σ̂_j²) = 2 (S⁻¹)_jj with S_jk = tr(W C_j W C_k), W = P C_vv P and C_j the
    groups' covariances as they stand (Förstner 1979; F80 eq. 9): checked against the dense
    oracle's C_vv. f √(2 / r_j) is only its diagonal approximation, and differs here."""
    from oracle import dense

    p = problem(_network_with_true_factors(5))
    vc = variance.estimate(p)
    assert vc.converged and vc.std_error_method == "rigorous"
    d = dense(vc.adjustment)
    W = d.P @ d.Cvv @ d.P
    C = np.linalg.inv(d.P)
    masks = [np.isin(np.arange(p.n), ix) for ix in variance.groups_by_kind(p).values()]
    WC = [W @ (C * (m[:, None] & m[None, :])) for m in masks]
    S = np.array([[np.trace(X @ Y) for Y in WC] for X in WC])
    expected = vc.factors * np.sqrt(2.0 * np.diag(np.linalg.inv(S)))
    np.testing.assert_allclose(vc.std_error, expected, rtol=1e-8)
    approx = vc.factors * np.sqrt(2.0 / vc.redundancy)
    assert np.abs(vc.std_error / approx - 1.0).max() > 1e-3
    assert vc.summary() == {"kind": "families", "converged": True, "iterations": vc.iterations,
                            "std_error": "rigorous"}
