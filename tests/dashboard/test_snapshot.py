"""Live retests (issue 29 item 1) and the state's shape (issue 24 item 4) without a browser.

- a hypothesis' outcome under another test policy, rescaled without testing again
  (:meth:`baarda.dashboard.outcomes.Outcome.under`), equals a fresh test under that policy
  (F80 eq. 13-17: only α_q, the critical values and δ0(q) change);
- toggling a hypothesis and changing α0 test nothing again and rebuild only the policy's
  columns of the tables (the policy-free ones shared), and the tables equal those made anew;
- an exclusion answers at once from a downdate of the factor (Woodbury) that equals the
  re-adjustment to round-off on a linear network, and the exact re-adjustment (warm-started)
  replaces it, equal to a fresh adjustment without the observation.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("panel")

from baarda.adjust import Options, adjust  # noqa: E402
from baarda.analysis import analyze  # noqa: E402
from baarda.dashboard import frames, measures, specs  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402
from baarda.model.problem import without  # noqa: E402
from baarda.stats.policy import TestPolicy  # noqa: E402
from baarda.stats.reliability import Reliability  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def demo():
    return State(DATA / "demo-block.json")


def transfer(st) -> dict:
    by_point: dict = {}
    for ids in st.problem.info.ids:
        if "point" in ids and "image" in ids:
            by_point.setdefault(str(ids["point"]), set()).add(str(ids["image"]))
    pid = max(by_point, key=lambda p: (len(by_point[p]), p))
    return {"kind": "transfer", "point": pid, "images": sorted(by_point[pid])[:3]}


POLICIES = [TestPolicy(alpha0=0.01, beta0=0.9), TestPolicy(alpha0=0.001, beta0=0.8, b_method=True),
            TestPolicy(alpha0=0.05, beta0=0.6, sigma0="aposteriori")]


@pytest.mark.parametrize("policy", POLICIES)
def test_outcome_under_policy_equals_a_fresh_test(demo, policy):
    st = demo
    spec_obs = {"kind": "observation", "index": int(np.nanargmax(np.abs(st.expand(st.results.w))))}
    for spec in (transfer(st), spec_obs):
        first = st.snapshot.outcome(spec)
        assert first.status == "test"
        moved = st.snapshot.with_policy(policy)
        got = moved.outcome(spec)
        a = st.analysis.with_policy(policy)
        ref = specs.evaluate(st.problem, a.adjustment, a.reliability, a.kept, spec, st.problem_index())
        for name in ("q", "T", "R", "alpha", "critical_T", "critical_R", "delta0", "delta0_prime_max"):
            assert getattr(got.test, name) == pytest.approx(getattr(ref.test, name), rel=1e-12, nan_ok=True), name
        np.testing.assert_allclose(got.test.ellipse_axes, ref.test.ellipse_axes, rtol=1e-12)
        assert got.external.max == pytest.approx(ref.external.max, rel=1e-12)
        assert got.external.delta0 == pytest.approx(ref.external.delta0, rel=1e-12)
        assert got.rejected == ref.rejected and got.policy == policy


def test_toggle_and_alpha_test_nothing_again_and_share_the_policy_free_tables(demo, monkeypatch):
    st = State(problem=demo.problem)
    k = st.add_hypothesis(transfer(st))
    T = st.outcomes[k].T
    base = st.snapshot.shared.base_frames
    calls = []
    real = specs.evaluate
    monkeypatch.setattr(specs, "evaluate", lambda *a, **kw: calls.append(1) or real(*a, **kw))
    st.toggle_hypothesis(k, False)
    assert st.outcomes[k].status == "inactive"
    st.toggle_hypothesis(k, True)
    st.alpha0 = 0.01
    st.beta0 = 0.9
    assert calls == [] and st.outcomes[k].T == T
    assert st.snapshot.shared.base_frames is base          # v, w, r, σ not made again
    obs, pts = st.frames()
    a = st.analysis
    ref_obs, ref_pts = frames.frames(st.problem, a.adjustment, a.reliability, a.kept, st.excluded,
                                     st.problem_index())
    pd.testing.assert_frame_equal(obs, ref_obs)
    pd.testing.assert_frame_equal(pts, ref_pts)
    assert st.summary()["n_rejected"] == int(ref_obs["rejected"].sum())


def test_downdate_equals_the_readjustment_on_a_linear_network():
    st = State(DATA / "demo-levelling.gkf")
    assert st.error == "", st.error
    i = int(np.argmax(st.results.r))
    full = st.analysis
    quick = measures.downdated(full, {i})
    reduced, kept = without(full.problem, {i})
    ref = adjust(replace(reduced, sigma_act=full.adjustment.problem.sigma_act), full.options)
    np.testing.assert_array_equal(quick.kept, kept)
    for name in ("x", "v", "w", "r"):
        np.testing.assert_allclose(getattr(quick.adjustment, name), getattr(ref, name), rtol=1e-9, atol=1e-12,
                                   err_msg=name)
    np.testing.assert_allclose(quick.reliability.mdb, Reliability(ref, full.policy).mdb, rtol=1e-9)
    assert quick.adjustment.dof == ref.dof


def test_exclusion_answers_from_the_downdate_then_the_exact_readjustment_replaces_it(demo):
    st = State(problem=demo.problem)
    st.background = True                   # served: the exact re-adjustment on a worker thread
    i = int(np.nanargmax(np.where(st.problem.info.kind == "image-x", st.expand(st.results.r), -1)))
    x_before = st.results.x.copy()
    fut = st.exclude(i)
    # answered at once: the downdate is shown while the re-adjustment runs
    assert st.excluded == {i} and st.results.n == st.problem.n - 1
    assert fut.result(timeout=300) is True
    assert st.exact and st.excluded == {i} and st.task == ""
    ref = analyze(demo.problem).without({i})
    for name in ("x", "v", "w", "r"):
        np.testing.assert_allclose(getattr(st.results, name), getattr(ref.adjustment, name), rtol=1e-7, atol=1e-9,
                                   err_msg=name)
    assert not np.array_equal(st.results.x, x_before)
    fut = st.include(i)                    # back to every observation: the first analysis again
    assert fut.result(timeout=300) is True and st.excluded == frozenset()
    np.testing.assert_allclose(st.results.x, x_before, rtol=0, atol=1e-8)
