"""GNSS projection centres in a simulated block (issue 28, "What it must show"): r and w of the
GNSS observations against a dense reference built from the equations; a planted 1 m centre error
is the largest |w| among the GNSS observations and rejected, with its 3-D test; a 0.5 m shift of
one strip is found by the strip test; without control points the block is determined by GNSS,
the datum stated and its MDBs reported; variance components recover the σ of the GNSS noise."""

from __future__ import annotations

import numpy as np
import pytest

import baarda
from baarda.adjust import adjust
from baarda.build import build
from baarda.io.gnss import GnssOptions
from baarda.model.gnss import GnssSpec
from baarda.simulate import simulate_block, simulate_to_files
from baarda.model.bundle import gnss_rows
from baarda.stats import gnss
from baarda.stats.ap_tests import ap_test
from tests import oracle


def _gnss_rows(problem):
    return np.flatnonzero(np.asarray(problem.info.kind).astype(str) == np.array("gnss-x")) + np.arange(3)[:, None]


@pytest.mark.parametrize("estimate_lever,shift,drift,control", [(True, False, False, "corners"),
                                                                 (False, True, True, "perimeter")],
                         ids=["lever-arm-estimated", "strip-shift-and-drift"])
def test_r_and_w_against_a_dense_reference_from_the_equations(estimate_lever, shift, drift, control):
    """(A lever arm and a shift per strip together are not determinable: e_z and a_s,z enter
    alike, and with κ = 0 and π in alternate strips e_x, e_y too. Shifts and drifts of two strips
    with four corner control points leave N with a condition of 10¹²: the reference's
    pseudo-inverse would drop a direction, so that case has perimeter control.)"""
    blk, _ = simulate_block(seed=4, strips=2, images_per_strip=4, control=control, gnss_sigma=0.05,
                            gnss_lever=[0.3, -0.2, 1.1],
                            errors=[{"kind": "gnss", "size": 8, "image": "103", "axis": "z"}])
    blk = blk.replace(gnss=GnssSpec(blk.gnss.centres, (0.3, -0.2, 1.1), estimate_lever, shift, drift))
    problem = build(blk)
    adj = adjust(problem)
    p = problem.params
    free = p.free
    x = adj.x.copy()
    # A by central differences of f(x) (not the analytic Jacobian), C, P and v: F80 eq. 8, §4-5
    A = np.zeros((problem.n, free.size))
    for j, q in enumerate(free):
        h = 1e-6 * max(1.0, abs(x[q]))
        xp, xm = x.copy(), x.copy()
        xp[q] += h
        xm[q] -= h
        A[:, j] = (problem.evaluate(xp)[0] - problem.evaluate(xm)[0]) / (2 * h)
    ref = oracle.Dense.of(A, problem.cov.matrix(), adj.v)
    g = np.sort(_gnss_rows(problem).ravel())
    assert g.size == 3 * 8
    np.testing.assert_allclose(adj.r[g], ref.r[g], rtol=0, atol=1e-6)
    np.testing.assert_allclose(adj.w[g], ref.w[g], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(adj.r.sum(), problem.n - free.size, rtol=1e-9)
    lever = [p.labels.index(f"gnss.lever.{a}") for a in "xyz"]
    assert (~p.fixed[lever]).all() == estimate_lever
    assert ({"1:gnss-shift", "2:gnss-shift"} <= set(problem.notes.ap_groups)) == shift
    assert ({"1:gnss-drift", "2:gnss-drift"} <= set(problem.notes.ap_groups)) == drift
    if estimate_lever:
        assert np.abs(adj.x[lever] - [0.3, -0.2, 1.1]).max() < 0.3


@pytest.fixture(scope="module")
def planted(tmp_path_factory):
    """The issue's block: σ 5 cm GNSS, 4 control points, 1 m error at centre 205 (x), a 0.5 m
    shift of strip 3 along the strip (x). (Across the strip, y, the shift of a whole strip is
    nearly absorbed by the roll ω of its images — ∇ŝ_y = 0.50 ± 0.14 m against ± 0.05 m in x,
    T = 14.6 < 16.3 on this block: GNSS alone does not find it; that needs IMU attitudes.)"""
    d = tmp_path_factory.mktemp("gnss")
    simulate_to_files({"seed": 2, "control": "corners", "gnss_sigma": 0.05,
                       "errors": [{"kind": "gnss", "size": 20, "image": "205", "axis": "x"},
                                  {"kind": "gnss-strip", "size": 10, "strip": "3", "axis": "x"}]},
                      d / "b.json", d / "b.truth.json")
    return d


def test_planted_centre_error_is_the_largest_gnss_w_and_rejected_with_its_3d_test(planted):
    a = baarda.analyze(planted / "b.json", gnss=planted / "b.gnss.csv")
    adj, rel = a.adjustment, a.reliability
    g = np.sort(_gnss_rows(adj.problem).ravel())
    worst = g[np.argmax(np.abs(adj.w[g]))]
    assert adj.problem.info.ids[worst] == {"image": "205", "strip": "2", "component": "x"}
    assert rel.rejected[worst]
    t = rel.test(gnss.h_gnss_centre(adj.problem, "205"), label="GNSS 205")
    assert t.q == 3 and t.rejected_T
    assert abs(t.nabla[0] - 1.0) < 3 * t.nabla_sigma[0]      # ∇ŝ estimates the planted +1 m in x
    # its group test in the document: the 3-D test of the centre
    groups = a.to_dict()["groups"]
    grp = [gr for gr in groups if set(gr["members"]) == set(gnss_rows(adj.problem, "205").tolist())]
    assert len(grp) == 1 and grp[0]["dimension"] == 3 and grp[0]["rejected"]
    found = {f["kind"]: f for f in a.planted(planted / "b.truth.json")}
    assert found["gnss"]["found"] and found["gnss-strip"]["found"]


def test_strip_shift_is_found_by_the_strip_test(planted):
    a = baarda.analyze(planted / "b.json", gnss=planted / "b.gnss.csv")
    images = [im.id for im in a.problem.notes.local_model.images if im.strip == "3"]
    t = a.reliability.test(gnss.h_gnss_strip(a.adjustment.problem, images), label="strip 3")
    assert t.q == 3 and t.rejected_T
    assert abs(t.nabla[0] - 0.5) < 3 * t.nabla_sigma[0]
    others = [a.reliability.test(gnss.h_gnss_strip(a.adjustment.problem, [im.id for im in
                                 a.problem.notes.local_model.images if im.strip == s])) for s in ("1", "2")]
    assert all(o.T < t.T for o in others)
    # reported: the strip tests in the text and the document, and baarda test's gnss-strip:STRIP
    reported = {d["strip"]: d for d in a.to_dict()["gnss_strip_tests"]}
    assert reported["3"]["rejected"] and reported["3"]["T"] == pytest.approx(t.T)
    assert not reported["1"]["rejected"] and not reported["2"]["rejected"]
    assert "GNSS strip tests" in a.text(top=1)
    assert a.test("gnss-strip:3")["T"] == pytest.approx(t.T)
    # modelled as a shift per strip (an AP group, F80 §7.2): strip 3's shift is the largest of the three
    b = baarda.analyze(planted / "b.json", gnss=GnssOptions(planted / "b.gnss.csv", shift=True))
    T = {s: ap_test(b.adjustment, s, "gnss-shift").T for s in ("1", "2", "3")}
    assert max(T, key=T.get) == "3"
    est = ap_test(b.adjustment, "3", "gnss-shift")
    assert abs(est.estimate[0] - 0.5) < 3 * est.sigma[0]
    assert "GNSS shift of strip 3 (F80 §7.2-7.3)" in b.text(top=1)


def test_without_control_the_block_is_determined_by_gnss(tmp_path):
    simulate_to_files({"seed": 6, "control": "none", "gnss_sigma": 0.05}, tmp_path / "b.json")
    a = baarda.analyze(tmp_path / "b.json", gnss=tmp_path / "b.gnss.csv")
    s = a.summary()
    assert s["datum"] == "GNSS projection centres (24), no control points" and s["datum_defect"] == 0
    assert s["global_test"]["passed"]
    g = np.sort(_gnss_rows(a.adjustment.problem).ravel())
    mdb = a.reliability.mdb[g]
    assert np.isfinite(mdb).all() and (mdb > 0).all()
    assert "datum defect 0 (GNSS projection centres (24), no control points)" in a.text(top=1)


def test_variance_components_recover_the_gnss_sigma(tmp_path):
    """GNSS noise of σ 5 cm declared as 10 cm: the GNSS factor σ̂²/σ² is 0.25 within 3 rigorous
    standard errors (F80 eq. 9)."""
    simulate_to_files({"seed": 11, "strips": 4, "control": "none", "gnss_sigma": 0.05}, tmp_path / "b.json")
    csv = tmp_path / "b.gnss.csv"
    csv.write_text(csv.read_text().replace(",0.05,0.05,0.05,", ",0.1,0.1,0.1,"))
    a = baarda.analyze(tmp_path / "b.json", gnss=csv)
    vc = {d["group"]: d for d in a.variance_components().as_dict()}
    assert abs(vc["GNSS"]["factor"] - 0.25) < 3 * vc["GNSS"]["std_error"]
    assert abs(vc["image observations"]["factor"] - 1.0) < 3 * vc["image observations"]["std_error"]
