"""Size of the default global test on error-free data, r from 10 to 40,000 (issue 27, item 9).

Under H0 vᵀPv = Ω/σ0² ~ χ²(r) (F80 eq. 3, §4.1). The default test is one-sided at α = (1 − conf-pr)/2
= 2.5 %: σ0 a priori below σ̂0's 95 % confidence interval. References, independent of baarda's
distributions module: (1) for huge r the statistic drawn directly from χ²(r) (exact for a linear
model), (2) real error-free blocks of baarda.simulate, adjusted, pooled through the probability
integral transform u = F_χ²(r)(vᵀPv) ~ U(0, 1) (Kolmogorov-Smirnov) and counted against the
binomial interval of α. The B-method's α_r (F80 §7.2), kept as ``b-method``, exceeds 50 % from
r ≈ 200 on — which is why it is not the default.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats as sps

from baarda.adjust import adjust
from baarda.model.bundle import build_block_problem
from baarda.simulate import simulate_block
from baarda.stats.policy import TestPolicy

ALPHA = 0.025                       # (1 − 0.95)/2


def binomial_ok(k: int, n: int, p: float, level: float = 1e-4) -> bool:
    """k rejections of n within the two-sided binomial interval of rate p at ``level``."""
    lo, hi = sps.binom.ppf(level / 2, n, p), sps.binom.isf(level / 2, n, p)
    return lo <= k <= hi


@pytest.mark.parametrize("r", [10, 100, 1_000, 10_000, 38_783])
def test_default_rejects_error_free_statistics_at_its_alpha_for_any_redundancy(r):
    """20,000 draws of vᵀPv ~ χ²(r): the default rejects at 2.5 % within the binomial interval at
    every r; its decision on single values agrees with the bound; the JSON-bound order holds."""
    pol = TestPolicy()
    g = pol.global_decision(float(r), r)
    assert g["test"] == "one-sided" and g["alpha"] == pytest.approx(ALPHA, rel=1e-12)
    assert g["upper"] == pytest.approx(sps.chi2.isf(ALPHA, r), rel=1e-12)
    assert g["lower"] < r < g["upper"]
    rng = np.random.default_rng(r)
    draws = rng.chisquare(r, 20_000)
    k = int((draws > g["upper"]).sum())
    assert binomial_ok(k, draws.size, ALPHA), (r, k)
    for t in draws[:20]:            # the decision itself, not only its bound
        assert pol.global_decision(float(t), r)["passed"] is bool(t <= g["upper"])
    # the confidence interval of σ/σ0 holds σ̂0/σ0 and excludes 1 exactly when the test fails high
    lo, hi = g["ratio_interval"]
    assert lo < g["ratio"] < hi and lo <= 1.0 <= hi
    high = pol.global_decision(g["upper"] * 1.0001, r)
    assert high["passed"] is False and high["ratio_interval"][0] > 1.0


def test_b_method_fails_most_large_error_free_blocks():
    """The B-method's α_r (F80 §7.2): 52 % at r = 216, 78 % at 38,783 — error-free large blocks fail
    more often than not; its bounds stay ordered in the JSON (``lower`` < ``upper``), and a
    rejection σ̂0's interval does not confirm says so."""
    pol = TestPolicy(global_test="b-method")
    for r, a in ((216, 0.52), (38_783, 0.78)):
        g = pol.global_decision(float(r), r)
        assert g["alpha"] == pytest.approx(a, abs=0.01)
        assert g["lower"] is None or g["lower"] < g["upper"]
        draws = np.random.default_rng(1).chisquare(r, 4_000)
        assert binomial_ok(int((draws > g["upper"]).sum()), draws.size, g["alpha"])
        assert g["passed"] is False and "not significant" in g["verdict"]      # vᵀPv = r: σ̂0 = σ0


def _clean_blocks():
    """Error-free simulated blocks: (redundancy, vᵀPv) of 160 small (r = 17, 32) and 24 medium
    (r = 216) blocks, each adjusted by baarda."""
    out = []
    for seed in range(160):
        blk, truth = simulate_block(seed=seed, strips=2, images_per_strip=3 + seed % 2)
        assert not truth["errors"]
        adj = adjust(build_block_problem(blk))
        assert adj.converged
        out.append((adj.dof, adj.vPv))
    for seed in range(24):
        blk, _ = simulate_block(seed=1000 + seed, strips=4, images_per_strip=10)
        adj = adjust(build_block_problem(blk))
        assert adj.converged
        out.append((adj.dof, adj.vPv))
    return out


def test_error_free_simulated_blocks_pass_at_the_stated_rate():
    """Real adjustments of error-free blocks (baarda.simulate): vᵀPv follows χ²(r) (KS on the pooled
    u = F(vᵀPv)) and the default's rejections stay within the binomial interval of 2.5 %."""
    pol = TestPolicy()
    res = _clean_blocks()
    u = np.array([sps.chi2.cdf(t, r) for r, t in res])
    assert sps.kstest(u, "uniform").pvalue > 1e-3
    k = sum(pol.global_decision(t, r)["passed"] is False for r, t in res)
    assert binomial_ok(k, len(res), ALPHA), k
    k_two = sum(TestPolicy(global_test="two-sided").global_decision(t, r)["passed"] is False for r, t in res)
    assert binomial_ok(k_two, len(res), 0.05), k_two


def test_report_and_json_on_an_error_free_block(tmp_path):
    """The issue's clean8 block (4 strips × 10 images, seed 8, r = 216): the default passes, the
    client report's verdict is not "Not acceptable", the JSON's bounds and σ̂0 interval are ordered;
    with ``--global-test b-method`` it fails only the B-method's bound, which the report says."""
    from baarda.cli import main
    from baarda.dashboard.report import verdict
    from baarda.dashboard.state import State
    from baarda.io.native import read_native

    path = tmp_path / "clean8.json"
    assert main(["simulate", str(path), "--strips", "4", "--images", "10", "--seed", "8"]) == 0
    out = tmp_path / "c.json"
    assert main(["analyze", str(path), "--json", str(out), "--top", "1"]) == 0
    g = json.loads(out.read_text())["summary"]["global_test"]
    assert g["passed"] is True and g["lower"] < g["upper"]
    iv = g["sigma0_interval"]
    assert iv["confidence"] == 0.95 and iv["lower"] < 1.0 < iv["upper"]
    st = State.from_adjustment(adjust(build_block_problem(read_native(path))))
    obs, _ = st.frames()
    level, head, said = verdict(st.summary(), obs)
    assert level != "bad" and "Not acceptable" not in head, head
    assert any("agree with their stated precision" in x for x in said)
    st.global_test = "b-method"
    s = st.summary()
    assert s["global_test"]["passed"] is False      # α_216 = 52 %: σ̂0 = 1.01 fails the B-method's bound
    level, head, said = verdict(s, st.frames()[0])
    assert "Not acceptable" not in head and any("B-method's strict bound" in x for x in said)
