"""GNSS projection centres, IMU attitudes and check points in the dashboard (issue 28, item 6),
without a browser: the state reads a block with its companion files as ``baarda.analyze`` does,
the maps draw the GNSS and check-point residual vectors, the suspects list holds every centre's
3-D test and the strip tests (a planted 1 m centre error ranks in the first ten), the check-point
table and its download, the summary cards and the report's verdict. The served page is tested
in tests/browser/test_gnss.py.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pandas as pd
import pytest
from openpyxl import load_workbook

import baarda
from baarda.cli import main
from baarda.cli_options import parse_error
from baarda.dashboard import auxdata
from baarda.dashboard.jobs import file_key
from baarda.dashboard.report import report_html, verdict
from baarda.dashboard.state import State
from baarda.dashboard.suspects import suspects
from baarda.dashboard.tables import TABLES, table_csv, tables_xlsx
from baarda.io.gnss import GnssOptions, ImuOptions
from baarda.simulate import gnss_path, simulate_to_files
from baarda.stats.gnss import h_gnss_centre, h_gnss_strip

#: 3 strips × 6 images, GNSS σ 5 cm, IMU σ 0.01°, 3 check points, 1 m (20 σ) error at centre 203
RECIPE = {"seed": 3, "strips": 3, "images_per_strip": 6, "control": "corners", "check": 3, "gnss_sigma": 0.05,
          "imu_sigma": 0.01, "errors": [parse_error("gnss:20:image=203")]}


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    d = tmp_path_factory.mktemp("auxdash")
    simulate_to_files(RECIPE, d / "b.json", d / "b.truth.json")
    return d / "b.json"


@pytest.fixture(scope="module")
def inputs(block):
    return {"gnss": GnssOptions(gnss_path(block)), "imu": ImuOptions(gnss_path(block, ".imu.csv"))}


@pytest.fixture(scope="module")
def levelling(data_dir):
    """A network: no GNSS, no check points."""
    st = State()
    assert st.load(data_dir / "demo-levelling.gkf"), st.error
    return st


@pytest.fixture(scope="module")
def state(block, inputs):
    st = State()
    assert st.load(block, inputs=inputs), st.error
    return st


def test_state_reads_the_companion_files_as_analyze_does(state, block, inputs):
    a = baarda.analyze(block, gnss=inputs["gnss"], imu=inputs["imu"])
    np.testing.assert_allclose(state.results.v, a.adjustment.v, rtol=1e-9, atol=1e-12)
    assert state.results.sigma0_post == pytest.approx(a.adjustment.sigma0_post, rel=1e-10)
    kinds = set(state.problem.info.kind)
    assert {"gnss-x", "gnss-y", "gnss-z", "imu-omega", "imu-phi", "imu-kappa"} <= kinds
    # the cache key names the companion files: the same block without them is another entry
    assert file_key(block, state.options(), inputs) != file_key(block, state.options())
    doc = json.loads(block.read_text(encoding="utf-8"))        # simulate writes the centres into the block too
    for key in ("gnss", "gnss_centres", "imu", "imu_attitudes"):
        doc.pop(key, None)
    bare = block.with_name("bare.json")
    bare.write_text(json.dumps(doc), encoding="utf-8")
    plain = State()
    assert plain.load(bare) and not auxdata.has_gnss(plain.problem)


def test_unknown_input_is_refused(block):
    with pytest.raises(ValueError, match="unknown inputs"):
        State().load(block, inputs={"gps": "x.csv"})


def test_bad_companion_file_is_a_message_and_nothing_changes(state, block, tmp_path):
    bad = tmp_path / "g.csv"
    bad.write_text("image,x,y,z,sx,sy,sz\n999,0,0,0,1,1,1\n")
    st = State()
    assert st.load(block)
    before, results = st.problem, st.results
    assert not st.load(block, inputs={"gnss": str(bad)})
    assert "image 999 is not an image of the block" in st.error and "\n" not in st.error
    assert st.problem is before and st.results is results                  # the block loaded before stays


def test_gnss_centres_are_the_cores_residuals_and_3d_tests(state):
    g = auxdata.gnss_centres(state)
    assert len(g) == 18 and g["image"].tolist()[:2] == ["101", "102"]
    info, v, w = state.problem.info, state.results.v, state.results.w
    rows = {(str(ids["image"]), k[-1]): i for i, (k, ids) in enumerate(zip(info.kind, info.ids)) if k.startswith("gnss-")}
    for r in g.itertuples():
        for a in "xyz":
            i = rows[(r.image, a)]
            assert getattr(r, f"v{a}") == pytest.approx(v[i]) and getattr(r, f"w{a}") == pytest.approx(w[i])
        assert r.x == pytest.approx(state.problem.l[rows[(r.image, "x")]])
    # the centre's group test is the test of H = the selection of its three rows (F80 eq. 10-12)
    h = state.reliability.test(h_gnss_centre(state.results, "203"))
    row = g.set_index("image").loc["203"]
    assert row["T"] == pytest.approx(h.T, rel=1e-8) and bool(row["rejected"]) and h.q == 3
    assert int(g["rejected"].sum()) == 1


def test_planted_centre_error_ranks_in_the_first_ten(state):
    df = suspects(state)
    centres = df[df["what"] == "GNSS centre"]
    assert len(centres) == 18                      # every centre's 3-D test is a row
    top = centres[centres["hypothesis"].str.startswith("image 203")]
    assert len(top) == 1 and int(top["rank"].iat[0]) <= 10 and top["decision"].iat[0] == "rejected"
    assert int(top["q"].iat[0]) == 3
    # one scale: the p-value of χ²(3) at the centre's T
    from scipy import stats
    assert top["p"].iat[0] == pytest.approx(stats.chi2.sf(top["T"].iat[0], 3), rel=1e-6)
    # the GNSS observations are rows too, named by their image
    assert any(h.endswith("gnss-x image 203") for h in df["hypothesis"])
    assert (df["what"] == "IMU attitude").sum() == 18


def test_strip_tests_are_rows_with_the_cores_numbers(state):
    df = suspects(state)
    strips = df[df["what"] == "GNSS strip"]
    core = {t["strip"]: t for t in state.analysis.gnss_strip_tests()}
    assert len(strips) == len(core) == 3
    for r in strips.itertuples():
        s = r.hypothesis.split()[3]
        assert r.T == pytest.approx(core[s]["T"]) and r.q == 3
        # the same hypothesis tested through its H (F80 §2.2: one shift for the strip's centres)
        images = core[s]["images"]
        assert state.reliability.test(h_gnss_strip(state.results, images)).T == pytest.approx(r.T, rel=1e-8)


def test_estimated_strip_shift_is_an_ap_group_row(block):
    st = State()
    assert st.load(block, inputs={"gnss": GnssOptions(gnss_path(block), shift=True)}), st.error
    df = suspects(st)
    aps = df[df["hypothesis"].str.contains(r"shift of strip \d \(estimated\)")]
    assert len(aps) == 3 and set(aps["q"]) == {3}
    from baarda.stats.ap_tests import ap_test
    t = ap_test(st.results, "2", "gnss-shift", policy=st.reliability.policy)
    row = aps[aps["hypothesis"].str.contains("strip 2")].iloc[0]
    assert row["T"] == pytest.approx(t.T) and row["k"] == pytest.approx(t.critical)


def test_check_point_table_and_rmse(state, block):
    df = auxdata.check_table(state)
    assert df["id"].tolist()[-1] == "RMSE" and len(df) == 4
    # independent: the known coordinates of the file against the adjusted ones of the points table
    doc = json.loads(block.read_text())
    known = {p["id"]: p for p in doc["points"] if p.get("status") == "check"}
    ids = list(state.problem.points.ids)
    diffs = []
    for r in df.iloc[:-1].itertuples():
        adj = state.results.coordinates[ids.index(r.id)]
        ref = np.asarray(known[r.id].get("ref") or known[r.id]["xyz"], dtype=float)
        diffs.append(adj - ref)
        np.testing.assert_allclose([r.dX, r.dY, r.dZ], adj - ref, atol=1e-9)
    np.testing.assert_allclose(df.iloc[-1][["dX", "dY", "dZ"]].to_numpy(dtype=float),
                               np.sqrt(np.mean(np.square(diffs), axis=0)), rtol=1e-12)
    s = state.summary()
    assert s["check_points"]["n"] == 3 and s["gnss"] == {"centres": 18, "rejected": 1, "strips": 3,
                                                         "strips_rejected": sum(t["rejected"] for t in
                                                                                state.analysis.gnss_strip_tests())}


def test_check_points_download_csv_and_xlsx(state, levelling):
    assert "check-points" in TABLES
    back = pd.read_csv(io.BytesIO(table_csv(state, "check-points").getvalue()), encoding="utf-8-sig")
    assert list(back.columns) == ["id", "dX [m]", "dY [m]", "dZ [m]", "sX [m]", "sY [m]", "sZ [m]"]
    assert back["id"].iat[-1] == "RMSE"
    np.testing.assert_allclose(back["dX [m]"], auxdata.check_table(state)["dX"])
    wb = load_workbook(tables_xlsx(state))
    assert "check-points" in wb.sheetnames
    # a network without check points: no such sheet
    assert auxdata.check_table(levelling).empty
    assert "check-points" not in load_workbook(tables_xlsx(levelling)).sheetnames


def test_maps_draw_gnss_and_check_vectors(state, levelling):
    import holoviews as hv

    from baarda.dashboard.views.maps import LayoutMap, ResidualMap

    hv.extension("bokeh", logo=False)
    m = ResidualMap(state=state)
    assert m.aux_legend()
    seg, scale = m._gnss_data()
    g = auxdata.gnss_centres(state)
    np.testing.assert_allclose(seg["x1"] - seg["x0"], scale * g["vx"])
    np.testing.assert_allclose(seg["y1"] - seg["y0"], scale * g["vy"])
    # the largest vector drawn at about VECTOR_FRACTION of the map (a round exaggeration below it)
    from baarda.dashboard.mapgeometry import extent
    top = np.hypot(seg["x1"] - seg["x0"], seg["y1"] - seg["y0"]).max() / extent(m.points())
    assert auxdata.VECTOR_FRACTION / 10 < top <= auxdata.VECTOR_FRACTION
    el = m._gnss()
    labels = {e.label for e in el}
    assert labels == {f"GNSS residuals ×{scale:g}"}
    assert set(el.get(1).vdims) >= {hv.Dimension(d) for d in ("image", "vx", "vy", "vz", "wx", "wy", "wz")}
    # the rejected centre outlined in red
    assert seg.set_index("image").loc["203", "edge"] == "#b2182b"
    cp = m._checks()
    pts = cp.get(1).data
    assert sorted(pts["id"]) == sorted(auxdata.check_table(state)["id"].iloc[:-1])
    assert all(e.label.startswith("check points, adjusted − known ×") for e in cp)
    assert len(LayoutMap(state=state).aux_layers()) == 2
    # a network without them: no layer, no legend on the residual map
    plain = ResidualMap(state=levelling)
    assert plain.aux_layers() == [] and not plain.aux_legend()


def test_report_verdict_names_gnss_tests_and_check_rmse(state):
    s, obs = state.summary(), state.frames()[0]
    level, head, said = verdict(s, obs)
    text = " ".join(said)
    strips = state.analysis.gnss_strip_tests()
    assert (f"GNSS: the 3-D test of 1 of 18 projection centres rejects (q = 3); a shift common to a strip's "
            f"centres (cycle slip) is rejected in {sum(t['rejected'] for t in strips)} of 3 strips") in text
    rms = s["check_points"]["rms"]
    assert f"Check points (3, not in the adjustment): RMSE of adjusted − known X {rms[0]:.3g}" in text
    html = report_html(state.results, state=state)
    # (the table itself is the download's: the report's third page has no room for it)
    assert "Check points (3, not in the adjustment)" in html and "GNSS: the 3-D test of 1 of 18" in html


def test_verdict_warns_on_a_rejected_centre_test_alone():
    base = {"converged": True, "global_test": {"passed": True, "statistic": 1.0, "dof": 10, "upper": 2.0},
            "statistic": "w", "critical_w": 3.29, "critical_tau": 3.0, "sigma0_aposteriori": 1.0,
            "sigma0_apriori": 1.0, "n_rejected": 0, "n_uncontrolled": 0, "n_excluded": 0, "alpha0": 0.001,
            "beta0": 0.8, "gnss": {"centres": 4, "rejected": 1, "strips": 0, "strips_rejected": 0}}
    obs = pd.DataFrame({"w": [0.1], "tau": [0.1], "r": [0.5], "ext": [1.0], "excluded": [False],
                        "kind": ["gnss-x"], "ids": ["image 1"]})
    level, head, said = verdict(base, obs)
    assert level == "warn" and head.startswith("GNSS: 1 rejected test")


def test_serve_refuses_a_bad_companion_file_in_one_line(block, tmp_path, capsys):
    bad = tmp_path / "g.csv"
    bad.write_text("image,x,y,z,sx,sy,sz\n101,0,0,zz,1,1,1\n")
    before = block.read_bytes()
    assert main(["serve", str(block), "--gnss", str(bad), "--port", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {bad}:2: ") and err.count("\n") == 1 and "zz" in err
    assert block.read_bytes() == before
    assert main(["serve", "--gnss-shift"]) == 2
    assert "--gnss-shift need(s) --gnss CSV" in capsys.readouterr().err


def test_precision_map_draws_the_centres_ellipses_from_the_pose_covariance(state, data_dir):
    import holoviews as hv

    from baarda.dashboard.views.precision import PrecisionMap
    from baarda.stats.pose import pose_covariance, pose_values

    hv.extension("bokeh", logo=False)
    m = PrecisionMap(state=state)
    paths, c = m.centre_ellipses()
    ids = [im.id for im in state.results.problem.geometry.images]
    np.testing.assert_allclose(c[["x", "y"]].to_numpy(dtype=float), pose_values(state.results, ids)[:, :2])
    cov = pose_covariance(state.results, ids)
    np.testing.assert_allclose(c["sX0_mm"], 1000 * np.sqrt(cov[:, 0, 0]))
    # each closed path (NaN-separated) reaches scale·√λmax of its 2 × 2 covariance from its centre
    scale = m._ellipses()[1]
    xy = np.asarray(paths[0], dtype=float)
    parts = np.split(xy, np.flatnonzero(np.isnan(xy[:, 0])))
    parts = [p[~np.isnan(p[:, 0])] for p in parts if np.isfinite(p).any()]
    assert len(parts) == len(c)
    for part, (_, r) in zip(parts, c.iterrows()):
        k = ids.index(r["image"])
        top = np.sqrt(np.linalg.eigvalsh(cov[k, :2, :2]).max())
        reach = np.hypot(part[:, 0] - r["x"], part[:, 1] - r["y"]).max()
        assert reach == pytest.approx(scale * top, rel=1e-3)
    assert m.aux_legend()
    # in a chosen S-base they are not drawn (the pose covariance is the own datum's)
    state.sbase = [str(i) for i in state.problem.points.ids[:2]]
    try:
        assert m.centre_ellipses()[0] == []
    finally:
        state.sbase = []
    # a block without GNSS or IMU: no centre ellipses (they would cover the map at the points' scale)
    demo = State()
    assert demo.load(data_dir / "demo-block.json")
    assert PrecisionMap(state=demo).centre_ellipses()[0] == [] and not PrecisionMap(state=demo).aux_legend()


def test_strip_names_from_the_file_are_text(block, tmp_path):
    g = pd.read_csv(gnss_path(block), dtype=str)
    g["strip"] = g["strip"].replace({"2": "<b>2</b>"})
    path = tmp_path / "g.csv"
    g.to_csv(path, index=False)
    st = State()
    assert st.load(block, inputs={"gnss": str(path)}), st.error
    df = suspects(st)
    assert "shift of strip <b>2</b> (6 centres)" in set(df["hypothesis"])
    assert "image 203 (strip <b>2</b>)" in set(df["hypothesis"])
    assert set(auxdata.gnss_centres(st)["strip"]) == {"1", "<b>2</b>", "3"}
    html = report_html(st.results, state=st)
    assert "<b>2</b>" not in html and "strip &lt;b&gt;2&lt;/b&gt;" in html     # (a suspect on page 3)
