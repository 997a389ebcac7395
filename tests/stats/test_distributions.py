"""baarda.stats.distributions: critical values, δ0 and Baarda's B-method (F80 §4-§5, §7.2; P76)
against scipy's distributions and closed forms that do not go through the code under test."""

from __future__ import annotations

import math

import pytest
from scipy import stats as sps

from baarda.stats import distributions


def test_delta0_one_dimensional_matches_normal_formula():
    assert abs(distributions.critical_normal(0.001) - 3.2905) < 1e-4
    d = distributions.delta0(0.001, 0.80, 1)
    assert abs(d - distributions.delta0_normal(0.001, 0.80)) < 1e-6
    assert round(d, 2) == 4.13 and abs(d * d - 17.07) < 0.01


@pytest.mark.parametrize("q", [1, 2, 3, 6])
def test_delta0_has_the_asked_power(q):
    d = distributions.delta0(0.01, 0.9, q)
    c = sps.chi2.isf(0.01, q)
    assert abs(sps.ncx2.sf(c, q, d * d) - 0.9) < 1e-9


@pytest.mark.parametrize("alpha, beta", [(0.001, 0.8), (0.05, 0.5), (0.2, 0.95)])
def test_delta0_q1_power_from_the_normal_distribution(alpha, beta):
    """For q = 1 the test |w| > c with w ~ N(δ, 1) has power Φ(δ − c) + Φ(−δ − c) exactly (the
    normal approximation drops the second term): no non-central χ² involved."""
    d, c = distributions.delta0(alpha, beta, 1), distributions.critical_normal(alpha)
    Phi = lambda x: 0.5 * math.erfc(-x / math.sqrt(2.0))  # noqa: E731
    assert Phi(d - c) + Phi(-d - c) == pytest.approx(beta, abs=1e-9)


@pytest.mark.parametrize("q", [2, 3, 7])
def test_b_method_gives_the_one_dimensional_delta0(q):
    a_q = distributions.alpha_b_method(0.001, 0.80, q)
    assert a_q > 0.001
    assert abs(distributions.delta0(a_q, 0.80, q) - distributions.delta0(0.001, 0.80, 1)) < 1e-6


def test_b_method_in_one_dimension_is_the_identity():
    assert distributions.alpha_b_method(0.001, 0.80, 1) == pytest.approx(0.001, rel=1e-8)


def test_tau_critical_value_matches_beta_distribution():
    r, alpha = 12, 0.01
    c = distributions.critical_tau(alpha, r)
    # τ²/r ~ Beta(1/2, (r−1)/2): P(|τ| > c) = α
    assert abs(sps.beta.sf(c * c / r, 0.5, (r - 1) / 2) - alpha) < 1e-10


def test_tau_tends_to_the_normal_critical_value_and_is_undefined_for_one_redundancy():
    assert distributions.critical_tau(0.001, 10**7) == pytest.approx(distributions.critical_normal(0.001), rel=1e-5)
    assert distributions.critical_tau(0.001, 1) == math.inf
    # |τ| ≤ √r always: the critical value stays below it
    assert all(distributions.critical_tau(0.001, r) < math.sqrt(r) for r in (2, 3, 5, 50))


@pytest.mark.parametrize("q", [1, 2, 5])
def test_critical_f_times_q_tends_to_chi2(q):
    """R = (T/q) / (Ω'/(r − q)) ~ F(q, r − q): for r → ∞, q F_{1−α}(q, ∞) = χ²_{1−α}(q)."""
    assert q * distributions.critical_f(0.001, q, 1e9) == pytest.approx(distributions.critical_chi2(0.001, q), rel=1e-6)
    assert distributions.critical_f(0.001, q, 0) == math.inf


def test_global_test_interval_for_two_degrees_of_freedom():
    """χ²(2) is exponential with mean 2: the two-sided interval at 95 % is
    [−2 ln(1 − 0.025), −2 ln(0.025)]."""
    g = distributions.global_test(3.0, 2, 0.95)
    assert g["lower"] == pytest.approx(-2.0 * math.log(0.975), rel=1e-12)
    assert g["upper"] == pytest.approx(-2.0 * math.log(0.025), rel=1e-12)
    assert g["passed"] is True
    assert distributions.global_test(7.5, 2, 0.95)["passed"] is False          # above −2 ln 0.025 = 7.38
    assert distributions.global_test(0.0, 0, 0.95)["passed"] is None
