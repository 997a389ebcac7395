"""The test policy (baarda.stats.policy) against scipy's distributions directly, and the reliability
over a result and a policy (baarda.stats.reliability) against a fresh adjustment at that policy."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats as sps

from baarda.adjust import Options, adjust
from baarda.errors import OptionError
from baarda.model.bundle import build_block_problem
from baarda.stats.policy import TestPolicy
from baarda.stats.reliability import Reliability, policy_of, reliability_of
from baarda.simulate import simulate_block


@pytest.mark.parametrize("q", [1, 2, 3, 6])
def test_b_method_gives_every_dimension_the_delta0_and_power_of_the_1d_test(q):
    p = TestPolicy(alpha0=0.001, beta0=0.8, b_method=True)
    lam1 = sps.norm.isf(0.0005) + sps.norm.ppf(0.8)            # δ0 of the 1D test, normal form
    d0 = p.delta0(q)
    assert d0 == p.delta0(1) == pytest.approx(lam1, abs=2e-3)  # the far tail only (THEORY §4)
    a = p.alpha(q)
    power = sps.ncx2.sf(sps.chi2.isf(a, q), q, d0 ** 2)
    assert power == pytest.approx(0.8, abs=1e-9)
    assert p.critical_T(q) == pytest.approx(sps.chi2.isf(a, q), rel=1e-12)
    assert (a > 0.001) == (q > 1) and (q > 1 or a == 0.001)


@pytest.mark.parametrize("q", [1, 2, 4])
def test_without_b_method_alpha0_for_every_dimension_and_delta0_of_power_beta0(q):
    p = TestPolicy(alpha0=0.01, beta0=0.9)
    assert p.alpha(q) == 0.01
    c = sps.chi2.isf(0.01, q)
    assert p.critical_T(q) == pytest.approx(c, rel=1e-12)
    assert sps.ncx2.sf(c, q, p.delta0(q) ** 2) == pytest.approx(0.9, abs=1e-9)
    assert p.critical_R(q, 20) == pytest.approx(sps.f.isf(0.01, q, 20 - q), rel=1e-12)
    assert p.critical_R(q, q) == np.inf and p.critical_T(0) == np.inf and p.alpha(0) == 0.01


def test_critical_values_and_the_decision_follow_sigma0():
    w = np.array([0.5, -3.4, 3.2, np.nan])
    tau = np.array([0.5, -2.9, 3.0, np.nan])
    pri, post = TestPolicy(0.001), TestPolicy(0.001, sigma0="aposteriori")
    assert pri.critical_w == pytest.approx(sps.norm.isf(0.0005), rel=1e-12)
    r = 12
    t = sps.t.isf(0.0005, r - 1)        # τ²/r ~ Beta(1/2, (r−1)/2): τ_c through Student's t
    tc = np.sqrt(r * t * t / (r - 1 + t * t))
    assert post.critical(r) == pytest.approx(tc, rel=1e-12)
    assert sps.beta.sf(tc ** 2 / r, 0.5, (r - 1) / 2) == pytest.approx(0.001, rel=1e-9)
    np.testing.assert_array_equal(pri.rejected(w, tau, r), [False, True, False, False])
    np.testing.assert_array_equal(post.rejected(w, tau, r), np.abs(np.nan_to_num(tau)) > tc)
    assert (pri.statistic_name, post.statistic_name) == ("w", "τ")


@pytest.mark.parametrize("bad", [dict(alpha0=0.0), dict(beta0=1.0), dict(sigma0="both"), dict(global_test="left")])
def test_bad_policy_is_refused(bad):
    """A bad policy is an OptionError naming the option and the value given (and a ValueError)."""
    with pytest.raises(OptionError) as err:
        TestPolicy(**bad)
    (name, value), = bad.items()
    assert (err.value.option, err.value.value) == (name, value)
    assert isinstance(err.value, ValueError)


def test_reliability_under_another_policy_equals_a_fresh_adjustment():
    """The same result under a new policy: MDB, δ̄0, decisions, group tests and a hypothesis test
    equal those of a new adjustment with that policy's options; nothing is solved again."""
    from baarda.stats.hypotheses import selection

    block, _ = simulate_block(strips=2, images_per_strip=4, seed=3)
    problem = build_block_problem(block)
    adj = adjust(problem)
    factor = adj.factor
    policy = TestPolicy(alpha0=0.05, beta0=0.9, b_method=True)
    rel = Reliability(adj, policy)
    ref = reliability_of(adjust(problem, Options(alpha0=0.05, beta0=0.9, b_method=True)))
    assert rel.result is adj and adj.factor is factor
    np.testing.assert_allclose(rel.mdb, ref.mdb, rtol=1e-9)
    np.testing.assert_allclose(rel.external, ref.external, rtol=1e-9)
    np.testing.assert_allclose(rel.external_all, ref.external_all, rtol=1e-9)
    np.testing.assert_array_equal(rel.rejected, ref.rejected)
    assert rel.critical_w == ref.critical_w and rel.critical_tau == ref.critical_tau
    g, gr = rel.groups, ref.groups
    assert len(g) == len(gr) > 0
    np.testing.assert_array_equal(g.dimension, gr.dimension)
    np.testing.assert_array_equal(g.alpha, gr.alpha)
    np.testing.assert_array_equal(g.critical, gr.critical)
    np.testing.assert_array_equal(g.rejected, gr.rejected)
    H = selection(adj.n, g[0]["members"])
    h, hr = rel.test(H), ref.test(H)
    assert h.alpha == hr.alpha and h.critical_T == hr.critical_T and h.delta0 == hr.delta0
    assert h.T == pytest.approx(hr.T, rel=1e-9)
    # the adjustment knows no policy: reliability_of gives its options' policy (σ0 a priori), one
    # Reliability per result and policy, kept with the result
    assert not hasattr(adj, "reliability") and not hasattr(adj, "mdb")
    assert reliability_of(adj).policy == policy_of(adj) == TestPolicy.from_options(Options())
    assert reliability_of(adj) is reliability_of(adj, policy_of(adj))
    other = reliability_of(adj, rel.policy)
    assert other is not reliability_of(adj) and np.array_equal(other.mdb, rel.mdb, equal_nan=True)
    # a result made from this one by dataclasses.replace keeps none of its reliabilities
    copy = dataclasses.replace(adj, timings={})
    assert copy.memo == {} and reliability_of(copy).result is copy
