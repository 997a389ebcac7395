"""The global test (F80 §4.1, §7.2; B68): one-sided at (1 − conf-pr)/2 by default (σ0 a priori
below σ̂0's conf-pr interval), the B-method's α_r and gama-local's two-sided interval at conf-pr on
request; a low value is σ0 a priori too pessimistic.

The critical values are computed here from the paper's definitions with scipy's χ² and
non-central χ² and a root finder of this file, not through baarda's distributions module:
λ0 = δ0² solves P(χ'²(1, λ0) > χ²_{1−α0}(1)) = β0, and α_r solves
P(χ'²(r, λ0) > χ²_{1−α_r}(r)) = β0 (the same λ0 and β0 as the 1D test, F80 §7.2).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
from scipy import optimize
from scipy import stats as sps

from baarda.adjust import Options, adjust
from baarda.build import read_problem
from baarda.cli import main
from baarda.dashboard.state import State
from baarda.dashboard.views import Controls
from baarda.dashboard.views.summary import summary_html
from baarda.io.results import summary
from baarda.stats import distributions
from baarda.stats.reliability import Reliability, policy_of, reliability_of

from tests.extdata import GAMA, require_extdata

DATA = Path(__file__).resolve().parents[2] / "data"
WOLF = GAMA / "krumm" / "2D" / "Wolf_DistanceDirectionAngle_free.gkf"


def lambda0(alpha0: float, beta0: float) -> float:
    c = sps.chi2.isf(alpha0, 1)
    return optimize.brentq(lambda lam: sps.ncx2.sf(c, 1, lam) - beta0, 1e-6, 200.0, xtol=1e-13)


def alpha_r(alpha0: float, beta0: float, r: int) -> float:
    lam = lambda0(alpha0, beta0)
    return optimize.brentq(lambda a: sps.ncx2.sf(sps.chi2.isf(a, r), r, lam) - beta0, 1e-12, 0.999,
                           xtol=1e-15)


def test_b_method_alpha_of_the_global_test_from_the_definition():
    a14 = alpha_r(0.001, 0.80, 14)
    assert a14 == pytest.approx(0.0664, abs=5e-5)            # issue 14: α₁₄ = 6.64 %
    g = distributions.global_test(2.33, 14, test="b-method", alpha=a14)
    assert g["upper"] == pytest.approx(sps.chi2.isf(a14, 14), rel=1e-12)
    assert g["lower"] == pytest.approx(sps.chi2.ppf(0.025, 14), rel=1e-12)     # the 95 % interval's, a note


def test_one_sided_rejects_only_the_high_side():
    a = 0.05
    hi, lo = sps.chi2.isf(a, 6), sps.chi2.ppf(a, 6)
    high = distributions.global_test(hi * 1.01, 6, test="one-sided", alpha=a)
    low = distributions.global_test(lo * 0.5, 6, test="one-sided", alpha=a)
    mid = distributions.global_test(6.0, 6, test="one-sided", alpha=a)
    assert (high["passed"], high["side"]) == (False, "high")
    assert (low["passed"], low["side"]) == (True, "low") and "too pessimistic" in low["verdict"]
    assert (mid["passed"], mid["side"], mid["verdict"]) == (True, None, "accepted")
    two = distributions.global_test(lo * 0.01, 6, 0.95)
    assert (two["passed"], two["side"], two["test"]) == (False, "low", "two-sided")
    assert "too pessimistic" in two["verdict"]
    with pytest.raises(ValueError):
        distributions.global_test(1.0, 6, test="both")


def test_wolf_free_network_passes_one_sided_and_fails_two_sided_low(tmp_path, capsys):
    """Wolf's free network: Ω/σ0² = 2.33, r = 14. One-sided at 2.5 % (and at the B-method's α₁₄ =
    6.64 %) it passes; gama-local's interval at 0.95 starts at 5.63, so two-sided it fails — on the
    low side: σ0 a priori is too pessimistic, not an error in the data."""
    require_extdata(WOLF)
    adj = adjust(read_problem(WOLF))
    assert adj.dof == 14 and adj.vPv == pytest.approx(2.33, abs=0.005)
    a14 = alpha_r(0.001, 0.80, 14)
    g = reliability_of(adj).global_test
    assert (g["test"], g["passed"], g["side"]) == ("one-sided", True, "low")
    assert g["alpha"] == pytest.approx(0.025, rel=1e-12)
    assert g["upper"] == pytest.approx(sps.chi2.isf(0.025, 14), rel=1e-12)
    b = Reliability(adj, replace(policy_of(adj), global_test="b-method")).global_test
    assert (b["passed"], b["side"]) == (True, "low") and b["alpha"] == pytest.approx(a14, rel=1e-8)
    assert b["upper"] == pytest.approx(sps.chi2.isf(a14, 14), rel=1e-8)
    two = Reliability(adj, replace(policy_of(adj), global_test="two-sided")).global_test
    assert two["lower"] == pytest.approx(sps.chi2.ppf(0.025, 14), rel=1e-12)
    assert round(two["lower"], 2) == 5.63
    assert (two["passed"], two["side"]) == (False, "low")
    out = tmp_path / "w.json"
    assert main(["analyze", str(WOLF), "--json", str(out), "--top", "1"]) == 0
    text = capsys.readouterr().out
    assert "one-sided (F80 §4.1) at α = 2.5 %" in text and "σ0 a priori too pessimistic" in text
    assert "σ0 a priori above it (σ̂0 significantly smaller)" in text
    assert main(["analyze", str(WOLF), "--global-test", "b-method", "--top", "1"]) == 0
    assert "B-method's α_14 = 6.64 %" in capsys.readouterr().out
    doc = json.loads(out.read_text())["summary"]["global_test"]
    assert (doc["test"], doc["passed"], doc["side"]) == ("one-sided", True, "low")
    assert main(["analyze", str(WOLF), "--global-test", "two-sided", "--json", str(out), "--top", "1"]) == 0
    text = capsys.readouterr().out
    assert "two-sided at conf-pr 0.95" in text and "FAILED: σ0 a priori too pessimistic" in text
    doc = json.loads(out.read_text())["summary"]["global_test"]
    assert (doc["test"], doc["passed"], doc["side"]) == ("two-sided", False, "low")
    assert doc["alpha"] == pytest.approx(0.05)


def test_demo_levelling_verdict(tmp_path):
    """The demo levelling network (r = 5, α0 = 0.1 %, β0 = 80 %): the one-sided test at 2.5 %, the
    B-method's at α₅ and the two-sided interval at 0.95 all reject vᵀPv on the high side (the
    planted 1 cm error)."""
    adj = adjust(read_problem(DATA / "demo-levelling.gkf"))
    r, T = adj.dof, adj.vPv
    a5 = alpha_r(0.001, 0.80, r)
    assert r == 5
    g = reliability_of(adj).global_test
    assert g["alpha"] == pytest.approx(0.025, rel=1e-12) and g["upper"] == pytest.approx(sps.chi2.isf(0.025, r), rel=1e-12)
    assert T > sps.chi2.isf(0.025, r)
    assert (g["passed"], g["side"]) == (False, "high") and "too large" in g["verdict"]
    b = Reliability(adj, replace(policy_of(adj), global_test="b-method")).global_test
    assert b["alpha"] == pytest.approx(a5, rel=1e-8)
    assert b["upper"] == pytest.approx(sps.chi2.isf(a5, r), rel=1e-8) and T > b["upper"]
    assert (b["passed"], b["side"]) == (False, "high") and "too large" in b["verdict"]
    two = Reliability(adj, replace(policy_of(adj), global_test="two-sided")).global_test
    assert two["upper"] == pytest.approx(sps.chi2.isf(0.025, r), rel=1e-12)
    assert (two["passed"], two["side"]) == (T <= sps.chi2.isf(0.025, r), "high")


def test_global_test_option_reaches_the_policy():
    o = Options(global_test="two-sided")
    adj = adjust(read_problem(DATA / "demo-levelling.gkf"), o)
    assert reliability_of(adj).global_test["test"] == "two-sided" and reliability_of(adj).global_test["alpha"] == pytest.approx(0.05)


def test_dashboard_summary_says_which_test(tmp_path):
    """The summary card names the test, its α and critical value(s), and a low value as σ0 a
    priori too pessimistic (not as a failure of the data)."""
    adj = adjust(read_problem(DATA / "demo-levelling.gkf"))
    s = {**summary(adj), "n_uncontrolled": 0, "n_weak": 0, "n_excluded": 0, "n_points": 8}
    html = summary_html(s)
    assert reliability_of(adj).global_test["statistic"] > reliability_of(adj).global_test["upper"]       # 14.98 > 12.83: failed
    assert "one-sided, α = 2.5 %" in html and f"> {reliability_of(adj).global_test['upper']:.4g}" in html
    iv = summary(adj)["global_test"]["sigma0_interval"]
    assert f"95 % interval [{iv['lower']:.4g}, {iv['upper']:.4g}]" in html
    low = {**s, "global_test": distributions.global_test(0.5, 5, 0.95)}
    html = summary_html(low)
    assert "two-sided at conf-pr 0.95" in html and "FAILED: σ0 a priori too pessimistic" in html
    assert "vᵀPv = 0.5 ∉ [" in html


def test_dashboard_summary_shows_a_failed_test_beyond_its_bound():
    """A failed one-sided test reads "vᵀPv = T > bound" (it read "383 ≤ 125.9" on the demo
    block); a passed one "≤"; a two-sided pass "∈"."""
    adj = adjust(read_problem(DATA / "demo-block.json"))
    g = reliability_of(adj).global_test
    assert g["passed"] is False and g["statistic"] > g["upper"]
    s = {**summary(adj), "n_uncontrolled": 0, "n_weak": 0, "n_excluded": 0, "n_points": 60}
    html = summary_html(s)
    assert f"vᵀPv = {g['statistic']:.4g} > {g['upper']:.4g}" in html and "≤" not in html
    r = g["dof"]
    ok = {**s, "global_test": {**distributions.global_test(float(r), r, 0.95), "test": "two-sided"}}
    assert f"vᵀPv = {r:.4g} ∈ [" in summary_html(ok)


def test_report_follows_the_command_lines_global_test(tmp_path):
    out = tmp_path / "r.html"
    assert main(["report", str(DATA / "demo-levelling.gkf"), "-o", str(out), "--quiet", "--global-test", "two-sided"]) == 0
    html = out.read_text()
    assert "two-sided at conf-pr 0.95" in html and "one-sided, " not in html
    assert main(["report", str(DATA / "demo-levelling.gkf"), "-o", str(out), "--quiet"]) == 0
    assert "one-sided, α = 2.5 %" in out.read_text()
    assert main(["report", str(DATA / "demo-levelling.gkf"), "-o", str(out), "--quiet", "--global-test", "b-method"]) == 0
    assert "one-sided, B-method α = 1.3 %" in out.read_text()


def test_dashboard_control_switches_the_global_test():
    """The sidebar's global-test select drives the state's policy: the reliability is rebuilt over
    the same result (nothing solved again) and the summary says which test."""
    adj = adjust(read_problem(DATA / "demo-levelling.gkf"))
    st = State.from_adjustment(adj)
    c = Controls(state=st)
    assert st.summary()["global_test"]["test"] == "one-sided"
    c.global_test.value = "two-sided"
    assert st.results is adj and st.reliability.policy.global_test == "two-sided"
    g = st.summary()["global_test"]
    assert g["test"] == "two-sided" and g["upper"] == pytest.approx(sps.chi2.isf(0.025, 5), rel=1e-12)


def test_cli_line_shows_the_statistics_relation_to_its_bounds():
    """The CLI's global-test line says "T > bound" for a failed one-sided test and "not in" for
    a value outside the two-sided interval (it said "≤" and "in" whatever the value was)."""
    from baarda.io.summary_text import global_test_text
    s = {"sigma0_apriori": 1.0, "sigma0_aposteriori": 2.0}
    high = distributions.global_test(40.0, 10, test="one-sided", alpha=0.01)
    assert high["passed"] is False and f"40 > {high['upper']:.4g}" in global_test_text(high, s)
    ok = distributions.global_test(9.0, 10, test="one-sided", alpha=0.01)
    assert ok["passed"] is True and "9 ≤ " in global_test_text(ok, s)
    low = distributions.global_test(0.5, 5, 0.95)
    assert "0.5 not in [" in global_test_text(low, s)
    mid = distributions.global_test(5.0, 5, 0.95)
    assert "5 in [" in global_test_text(mid, s) and "not in" not in global_test_text(mid, s)
