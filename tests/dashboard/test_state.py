"""The dashboard's state and views without a browser (issue 4).

- toggling a hypothesis gives exactly the core's ``adj.test(H)``;
- excluding an observation equals a fresh core adjustment without it (and the "weight zero"
  limit of the full problem);
- α0 changes δ0 and the MDB data of the plot's ColumnDataSource;
- every view builds its Bokeh model; map clicks and table rows select each other;
- bad files give a message, never a traceback; the HTML report is self-contained.

The tiny block (2 strips × 3 images, 25 points; :func:`tiny_block_problem`) is built with the
core's :mod:`baarda.model.bundle`; ``data/demo-block.json`` is used as well when it exists.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("panel")
pytest.importorskip("holoviews")

import holoviews as hv  # noqa: E402
import panel as pn  # noqa: E402
import param  # noqa: E402
from bokeh.document import Document  # noqa: E402
from bokeh.models import ColumnDataSource  # noqa: E402

from baarda.stats import distributions
from baarda.adjust import Options, adjust  # noqa: E402
from baarda.dashboard import frames, geometry, measures, sbase, specs  # noqa: E402
from baarda.dashboard.geometry import observation_points  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402
from baarda.stats.hypotheses import selection  # noqa: E402
from baarda.model.problem import subset, without  # noqa: E402
from tests.extdata import GAMA, require_extdata  # noqa: E402

hv.extension("bokeh", logo=False)

DEMO_BLOCK = Path(__file__).resolve().parents[2] / "data" / "demo-block.json"
NETWORKS = ["gama-local.gkf", "krumm/1D/Niemeier_Height_free.gkf", "tetrahedron.gkf",
            "krumm/2D/Grossmann_Direction_fix.gkf"]


from baarda.model.bundle import Block, Camera, Image, ImageObservations, ObjectPoint, build_block_problem
from baarda.observations.collinearity import project
from baarda.stats.reliability import reliability_of


def tiny_block_problem(seed: int = 1):
    rng = np.random.default_rng(seed)
    cam = Camera("cam", c=150.0, width=230.0, height=230.0, unit="mm")
    H = 1500.0
    images = []
    for s, Y0 in enumerate((0.0, 1400.0)):
        for j in range(3):
            images.append(Image(f"{s + 1}{j + 1:02d}", "cam", 920.0 * j, Y0, H, 0.0, 0.0, 0.0,
                                strip=str(s + 1)))
    points = []
    k = 0
    for Y in (-300.0, 300.0, 700.0, 1100.0, 1700.0):
        for X in (100.0, 460.0, 920.0, 1380.0, 1740.0):
            k += 1
            corner = X in (100.0, 1740.0) and Y in (-300.0, 1700.0)
            status = "control" if corner or k == 13 else ("check" if k == 7 else "tie")
            Z = 10.0 * np.sin(X / 500.0) + 5.0 * np.cos(Y / 400.0)
            ref = (X, Y, Z) if status != "tie" else None
            points.append(ObjectPoint(f"P{k}", X, Y, Z, status=status, ref=ref, sigma_h=0.05,
                                      sigma_v=0.05))
    im_idx, pt_idx = [], []
    P = np.array([[p.X, p.Y, p.Z] for p in points])
    for i, im in enumerate(images):
        for j, p in enumerate(points):
            xy = project(cam, [im], P[j])[0]
            if abs(xy[0]) < 115 and abs(xy[1]) < 115:
                im_idx.append(i)
                pt_idx.append(j)
    im_idx, pt_idx = np.array(im_idx), np.array(pt_idx)
    xy = project(cam, [images[i] for i in im_idx], P[pt_idx])
    xy = xy + rng.normal(0, 0.005, xy.shape)
    xy[3, 0] += 0.040
    m = im_idx.size
    obs = ImageObservations(im_idx, pt_idx, xy, np.repeat((0.005 ** 2 * np.eye(2))[None], m, 0),
                            np.zeros(m, dtype=np.int64))
    approx_pts = tuple(ObjectPoint(p.id, p.X + 3.0, p.Y - 2.0, p.Z + 1.0, p.status, p.ref, p.sigma_h,
                                   p.sigma_v) for p in points)
    approx_imgs = tuple(Image(im.id, im.camera, im.X0 + 2.0, im.Y0 - 1.0, im.Z0 + 1.0, 0.001, -0.001,
                              0.002, im.strip) for im in images)
    block = Block((cam,), approx_imgs, approx_pts, obs, title="tiny test block", source="tiny-block")
    return build_block_problem(block)


# --------------------------------------------------------------------------------------------
# fixtures
# --------------------------------------------------------------------------------------------
def network_state(name: str) -> State:
    path = require_extdata(GAMA) / name
    st = State(path)
    assert st.error == "" and st.results is not None, st.error
    return st


@pytest.fixture(scope="module")
def block_problem():
    return tiny_block_problem()


def fresh(problem, excluded=(), sigma_act=None, options=None):
    reduced, kept = without(problem, excluded)
    if sigma_act:
        reduced = replace(reduced, sigma_act=sigma_act)
    return adjust(reduced, options or Options()), kept


# --------------------------------------------------------------------------------------------
# hypotheses
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", NETWORKS)
def test_toggle_observation_hypothesis_is_core_test(name):
    st = network_state(name)
    adj = st.results
    i = int(np.nanargmax(np.abs(adj.w)))
    k = st.add_hypothesis({"kind": "observation", "index": i})
    h = st.outcomes[k].test
    ref = reliability_of(adj).test(selection(adj.n, [i]))
    assert h.T == pytest.approx(ref.T, rel=1e-12)
    assert h.T == pytest.approx(adj.w[i] ** 2, rel=1e-9)
    assert h.critical_T == ref.critical_T and h.rejected_T == ref.rejected_T
    st.toggle_hypothesis(k)
    assert st.outcomes[k].status == "inactive"
    st.toggle_hypothesis(k)
    assert st.outcomes[k].test.T == pytest.approx(ref.T, rel=1e-12)


def test_group_hypothesis_matches_core_groups():
    st = network_state("tetrahedron.gkf")
    adj = st.results
    g = reliability_of(adj).groups[0]
    k = st.add_hypothesis({"kind": "group", "group": g["group"]})
    assert st.outcomes[k].test.T == pytest.approx(g["T"], rel=1e-12)
    assert st.outcomes[k].test.q == g["dimension"]


def test_block_hypotheses_match_bundle_builders(block_problem):
    from baarda.stats import hypotheses

    st = State(problem=block_problem)
    adj = st.results
    k1 = st.add_hypothesis({"kind": "transfer", "point": "P8", "images": ["101", "102"]})
    k2 = st.add_hypothesis({"kind": "control", "point": "P1"})
    k3 = st.add_hypothesis({"kind": "image-point", "image": "101", "point": "P8"})
    refs = [reliability_of(adj).test(hypotheses.h_point_transfer(adj.problem, "P8", ["101", "102"])),
            reliability_of(adj).test(hypotheses.h_control_point(adj.problem, "P1")),
            reliability_of(adj).test(hypotheses.h_image_point(adj.problem, "101", "P8"))]
    for k, ref in zip((k1, k2, k3), refs):
        assert st.outcomes[k].test.T == pytest.approx(ref.T, rel=1e-10)
        assert st.outcomes[k].test.q == ref.q
    assert st.outcomes[k1].test.q == 2 and st.outcomes[k1].test.ellipse().shape[1] == 2


def test_hypothesis_table_shows_delta_bar0_of_the_core(block_problem):
    """The hypothesis panel's δ̄0max is the core's F80 eq. 17 maximum (external_reliability), the
    same hypothesis as baarda test builds (hypothesis_matrix: one owner of the rows)."""
    from baarda.dashboard.views import HypothesisPanel
    from baarda.stats import hypotheses

    st = State(problem=block_problem)
    spec = {"kind": "transfer", "point": "P8", "images": ["101", "102"]}
    k = st.add_hypothesis(spec)
    ref = reliability_of(st.results).test(hypotheses.hypothesis_matrix(st.results, spec))
    ext = hypotheses.external_reliability(st.results, ref)
    assert st.outcomes[k].test.T == pytest.approx(ref.T, rel=1e-12)
    row = HypothesisPanel(state=st).frame().iloc[k]
    assert row["δ̄0max"] == round(ext.max, 2) and row["δ0'max"] == round(ref.delta0_prime_max, 2)


def test_hypothesis_follows_exclusion_and_alpha():
    st = network_state("gama-local.gkf")
    k = st.add_hypothesis({"kind": "observation", "index": 10})
    st.exclude(3)
    adj = st.results
    j = int(st.reduced_index([10])[0])
    assert st.outcomes[k].test.T == pytest.approx(reliability_of(adj).test(selection(adj.n, [j])).T, rel=1e-12)
    st.alpha0 = 0.05
    assert st.outcomes[k].test.critical_T == pytest.approx(distributions.critical_chi2(0.05, 1))
    st.exclude(10)
    assert st.outcomes[k].status == "refused" and "no (included) observations" in st.outcomes[k].message


# --------------------------------------------------------------------------------------------
# exclusion
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", NETWORKS)
def test_exclusion_equals_fresh_adjustment(name):
    st = network_state(name)
    n = st.problem.n
    i = int(np.argmax(st.results.r))           # the best controlled one can go
    assert st.exclude(i), st.error
    ref, kept = fresh(st.problem, [i], sigma_act=st.sigma0_mode)
    adj = st.results
    assert adj.n == n - 1 and list(st.kept) == list(kept)
    assert adj.dof == ref.dof
    np.testing.assert_allclose(adj.r, ref.r, atol=1e-12)
    np.testing.assert_allclose(adj.w, ref.w, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(reliability_of(adj).mdb, reliability_of(ref).mdb, rtol=1e-9)
    obs, _ = st.frames()
    assert obs["excluded"].sum() == 1 and np.isnan(obs["r"].iat[i])
    assert st.include(i)
    assert st.results.n == n


def test_exclusion_is_the_weight_zero_limit():
    """Independent of the subset code: the full problem with the excluded observation's variance
    multiplied by 1e12 has the same r and w in the other observations."""
    st = network_state("gama-local.gkf")
    p = st.problem
    i = 7
    st.exclude(i)
    factors = np.ones(len(p.cov.blocks))
    factors[p.cov.cluster[i]] = 1e12
    assert p.cov.members[p.cov.cluster[i]].size == 1
    heavy = adjust(replace(p, cov=p.cov.scaled(factors), sigma_act=st.sigma0_mode), Options())
    others = np.setdiff1d(np.arange(p.n), [i])
    np.testing.assert_allclose(st.results.r, heavy.r[others], atol=1e-7)
    np.testing.assert_allclose(st.results.w, heavy.w[others], atol=1e-5)
    assert st.results.dof == heavy.dof - 1   # the weight-zero observation is still counted there


def test_failed_exclusion_is_reverted_with_a_message():
    st = network_state("krumm/2D/Grossmann_Direction_fix.gkf")
    weakest = int(np.argmin(st.results.r))
    adj0 = st.results
    rows = geometry.observations_of_point(st.problem_index(), st.problem_index()["obs_points"][weakest][-1])
    ok = True
    for i in rows:
        ok = st.exclude(i)
        if not ok:
            break
    if ok:
        pytest.skip("no exclusion made this network singular")
    assert "Adjustment failed" in st.error
    assert st.results.n == adj0.n - (len(st.excluded))


# --------------------------------------------------------------------------------------------
# α0, β0, σ0 and the plot data
# --------------------------------------------------------------------------------------------
def split_paths(xs) -> list[np.ndarray]:
    """The pieces of a path broken by NaN (the maps join many ellipses into one path)."""
    xs = np.asarray(xs, dtype=float)
    cut = np.flatnonzero(np.isnan(xs))
    pieces = [piece[~np.isnan(piece)] for piece in np.split(xs, cut)]
    return [piece for piece in pieces if len(piece)]


def sources_with(root, column):
    return [m for m in root.select({"type": ColumnDataSource}) if column in m.data]


def test_alpha_changes_delta0_and_mdb_plot_data():
    from baarda.dashboard.views import MDBMap

    st = network_state("gama-local.gkf")
    view = MDBMap(state=st)
    root = pn.panel(view).get_root(Document())
    d_old = st.reliability.delta0
    before = [np.asarray(s.data["mdb_sigma"], dtype=float).copy() for s in sources_with(root, "mdb_sigma")]
    assert before and d_old == pytest.approx(distributions.delta0(0.001, 0.8, 1))
    st.alpha0 = 0.01
    assert st.reliability.delta0 == pytest.approx(distributions.delta0(0.01, 0.8, 1))
    ref = adjust(replace(st.results.problem), Options(alpha0=0.01))
    np.testing.assert_allclose(st.reliability.mdb, reliability_of(ref).mdb, rtol=1e-9)
    after = [np.asarray(s.data["mdb_sigma"], dtype=float) for s in sources_with(root, "mdb_sigma")]
    ratio = st.reliability.delta0 / d_old
    for b, a in zip(before, after):
        np.testing.assert_allclose(a, b * ratio, rtol=1e-9)
    st.beta0 = 0.9
    assert st.reliability.delta0 == pytest.approx(distributions.delta0(0.01, 0.9, 1))


def test_sigma0_mode_switches_decision_and_covariance():
    st = network_state("gama-local.gkf")
    st.sigma0_mode = "apriori"
    cov_a = st.results.point_cov.copy()
    st.sigma0_mode = "aposteriori"
    f = (st.results.sigma0_post / st.results.sigma0) ** 2
    np.testing.assert_allclose(st.results.point_cov, cov_a * f, rtol=1e-8, atol=1e-18)
    obs, _ = st.frames()
    np.testing.assert_array_equal(obs["rejected"].to_numpy(),
                                  np.nan_to_num(np.abs(st.results.tau)) > st.reliability.critical_tau)


# --------------------------------------------------------------------------------------------
# views
# --------------------------------------------------------------------------------------------
def all_views(st):
    from baarda.dashboard import views as V

    out = [cls(state=st) for cls in V.MAP_VIEWS]
    out += [V.TestsTable(state=st), V.HypothesisPanel(state=st), V.TeachingView(state=st),
            V.AnalysisPanel(state=st), V.InjectPanel(state=st),
            V.Controls(state=st), V.SelectionPanel(state=st), V.FilePanel(state=st),
            V.SummaryHeader(state=st)]
    if geometry.images(st.problem):
        out.append(V.ImageResidualView(state=st))
    return out


@pytest.mark.parametrize("name", NETWORKS)
def test_network_views_build_bokeh_models(name):
    st = network_state(name)
    for view in all_views(st):
        root = pn.panel(view).get_root(Document())
        assert root is not None
    st.selected_obs = 0          # the deformation field and selection layers update
    st.add_hypothesis({"kind": "observation", "index": 0})


def test_block_views_build_bokeh_models(block_problem):
    from baarda.dashboard.views import ImageResidualView, LayoutMap

    st = State(problem=block_problem)
    for view in all_views(st):
        pn.panel(view).get_root(Document())
    root = pn.panel(LayoutMap(state=st)).get_root(Document())
    assert sources_with(root, "image"), "footprints / projection centres are drawn"
    img = ImageResidualView(state=st)
    root = pn.panel(img).get_root(Document())
    df = img.data()
    assert len(df) > 3
    src = [s for s in sources_with(root, "abs_w") if "x1" in s.data][0]
    x1 = np.asarray(src.data["x1"]).copy()
    st.exaggeration = 2 * st.exaggeration
    x1b = np.asarray(src.data["x1"])
    x = np.asarray(src.data["x"])
    np.testing.assert_allclose(x1b - x, 2 * (x1 - x), rtol=1e-9, atol=1e-12)


def test_maps_draw_on_the_canvas_unless_served_with_webgl(block_problem, monkeypatch):
    """The maps draw on the 2D canvas: in a browser without a GPU (headless Chromium here)
    WebGL runs in software, and one repaint of Ladybug's maps took 15-45 s. ``baarda serve
    --webgl`` draws them with WebGL; the report's figures are on the canvas either way."""
    from bokeh.models import Plot

    from baarda.cli import main
    from baarda.dashboard import app, render
    from baarda.dashboard.views import LayoutMap

    def backends():
        tpl = app.create_app(problem=block_problem, background=False)
        root = pn.panel(LayoutMap(state=tpl.state)).get_root(Document())
        return {p.output_backend for p in root.select({"type": Plot})}

    assert backends() == {"canvas"}
    try:
        monkeypatch.setattr(app, "WEBGL", True)
        assert backends() == {"webgl"}
        assert render.figure(hv.Points([(0, 0), (1, 1)])).output_backend == "canvas"
    finally:
        monkeypatch.setattr(app, "WEBGL", False)
        app.extensions()
    assert backends() == {"canvas"}
    served = []
    monkeypatch.setattr(app, "serve", lambda *a, **kw: served.append(kw))
    assert main(["serve", "--webgl"]) == 0 and main(["serve"]) == 0
    assert [kw["webgl"] for kw in served] == [True, False]


@pytest.mark.skipif(not DEMO_BLOCK.exists(), reason="data/demo-block.json not written yet")
def test_demo_block_app_builds():
    from baarda.dashboard.app import create_app

    tpl = create_app(DEMO_BLOCK)
    assert tpl.state.error == "" and geometry.images(tpl.state.problem)
    tpl.server_doc(Document())


def test_app_builds_with_network_and_reports_missing_default(tmp_path, monkeypatch):
    from baarda.dashboard import app

    tpl = app.create_app(require_extdata(GAMA) / "gama-local.gkf")
    tpl.server_doc(Document())
    assert app.default_path(tmp_path) is None
    (tmp_path / "demo-levelling.gkf").write_text("x")
    assert app.default_path(tmp_path).name == "demo-levelling.gkf"
    (tmp_path / "demo-block.json").write_text("{}")
    assert app.default_path(tmp_path).name == "demo-block.json"
    monkeypatch.setattr(app, "DATA", tmp_path / "nothing")
    tpl = app.create_app(None)
    assert "No file given" in tpl.state.error


def test_map_click_selects_table_rows_and_back():
    from baarda.dashboard.views import LayoutMap, TestsTable

    st = network_state("gama-local.gkf")
    m = LayoutMap(state=st)
    table = TestsTable(state=st)
    pn.panel(m).get_root(Document())
    _, pts = st.frames()
    k = 5
    m.tap.event(x=float(pts["x"].iat[k]), y=float(pts["y"].iat[k]))
    assert st.selected_point == k
    rows = geometry.observations_of_point(st.problem_index(), k)
    assert sorted(table.table.value.index[table.table.selection]) == sorted(rows)
    table.table.selection = [12]
    assert st.selected_obs == int(table.table.value.index[12]) and st.selected_point is None


def test_controls_drive_state():
    from baarda.dashboard.views import Controls

    st = network_state("gama-local.gkf")
    c = Controls(state=st)
    c.alpha.value = 0.05
    assert st.alpha0 == 0.05 and st.reliability.delta0 == pytest.approx(distributions.delta0(0.05, 0.8, 1))
    assert "δ0 = " in c.delta_text(st.reliability)
    st.beta0 = 0.9
    assert c.beta.value == 0.9


def test_bad_upload_gives_a_message(tmp_path):
    from baarda.dashboard.views import FilePanel

    st = network_state("gama-local.gkf")
    adj = st.results
    fp = FilePanel(state=st)
    fp.upload.value = {"broken.gkf": b"<gama-local><network><points-observations><obs"}
    assert st.error.startswith("Cannot read broken.gkf") and "Traceback" not in st.error
    assert "baarda-upload-" not in st.error and "/tmp" not in st.error
    assert fp.alert.visible and st.results is adj and fp.upload.value == {}
    fp.receive("photo.png", b"\x89PNG\r\n")
    assert "Cannot read photo.png" in st.error
    fp.receive("ok.gkf", (require_extdata(GAMA) / "triangle-1.gkf").read_bytes())
    assert st.error == "" and not fp.alert.visible and st.results is not adj


def test_upload_limits_and_odd_names(tmp_path, monkeypatch):
    """Empty, whitespace-only and too large files get a message; odd names (., .., paths,
    control characters, markup) are read under a name of the server's own and shown as text;
    no temporary directory is left behind."""
    import glob
    import tempfile

    from baarda.dashboard.views import FilePanel
    from baarda.dashboard import uploads as controls

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    st = network_state("gama-local.gkf")
    adj = st.results
    fp = FilePanel(state=st)
    assert not fp.receive("e.gkf", b"") and st.error == "e.gkf is empty (0 bytes)."
    assert not fp.receive("w.json", b" \n\t" * 1400) and "only whitespace" in st.error
    monkeypatch.setattr(controls, "MAX_UPLOAD_MB", 1)
    assert not fp.receive("big.gkf", b"x" * (1024 * 1024 + 1)) and "larger than 1 MB" in st.error
    assert fp.upload.max_file_size == f"{controls.MAX_UPLOAD_MB}MB" or fp.upload.max_file_size.endswith("MB")
    good = (require_extdata(GAMA) / "triangle-1.gkf").read_bytes()
    for name in (".", "..", "../../etc/passwd.gkf", "a/b.gkf", "x\x1b[2J\ny.gkf", "<b>b</b>.gkf"):
        assert controls.upload_name(name) not in (".", "..") and "/" not in controls.upload_name(name)
        fp.receive(name, b"<gama-local>broken")
        assert st.error.startswith("Cannot read ") and "\x1b" not in st.error and "\n" not in st.error
        assert str(tmp_path) not in st.error and "baarda-upload-" not in st.error
        assert st.results is adj
    assert fp.receive("<iframe srcdoc=x>.gkf", good) and st.results is not adj
    assert st.source == "<iframe srcdoc=x>.gkf" and "<iframe" not in fp.source.object
    assert glob.glob(str(tmp_path / "baarda-upload-*")) == []


def test_messages_and_selection_are_text_not_markup():
    """Ids with markup, Markdown and control characters reach every pane as text."""
    from baarda.dashboard.text import html_text, md_text
    from baarda.dashboard.views import SelectionPanel

    evil = '<iframe srcdoc="<script>parent.alert(1)</script>"> **b** [l](javascript:x) \x1b[31m\nz'
    assert "<" not in html_text(evil) and "\x1b" not in html_text(evil) and "\\x1b" in html_text(evil)
    md = md_text(evil)
    rendered = pn.pane.Markdown(md).get_root(Document()).text      # the HTML the model carries
    import html as _html
    out = _html.unescape(rendered)           # what the browser gets as HTML
    assert "<iframe" not in out and "<strong>" not in out and "<a " not in out and "\x1b" not in out
    assert "&lt;iframe" in out and "**b**" in out
    st = network_state("gama-local.gkf")
    sp = SelectionPanel(state=st)
    st.selected_point = 0
    assert "<b>Point " in sp.info.object and isinstance(sp.info, pn.pane.HTML)


def test_report_is_standalone(tmp_path, block_problem):
    from baarda.dashboard.report import write_report

    st = network_state("gama-local.gkf")
    st.exclude(2)
    st.add_hypothesis({"kind": "observation", "index": 4})
    path = write_report(st.results, tmp_path / "r.html", state=st)
    text = path.read_text(encoding="utf-8")
    assert "Bokeh" in text and "global test" in text.lower() and "Excluded observations" in text
    assert not re.search(r"<(script|link)[^>]+(src|href)=\"https?://", text)
    adj = adjust(block_problem)
    text = write_report(adj, tmp_path / "b.html").read_text(encoding="utf-8")
    assert "images in" in text


# --------------------------------------------------------------------------------------------
# issue 4 items 5, 7-9 and issue 7: S-base, hypothesis deformation, AP groups, robust,
# snooping, variance components, injected errors — each compared with the core's own result
# --------------------------------------------------------------------------------------------
FREE_2D = "krumm/2D/Hoepke_Distance_free.gkf"


def test_sbase_changes_ellipses_but_not_r_and_w():
    from baarda.stats import precision
    from baarda.dashboard.views import PrecisionMap

    st = network_state(FREE_2D)
    adj = st.results
    view = PrecisionMap(state=st)
    root = pn.panel(view).get_root(Document())
    ell = lambda: [e for s in sources_with(root, "xs") for x in s.data["xs"]  # noqa: E731
                   for e in split_paths(x) if len(e) == 49]
    obs0 = st.frames()[0][["r", "w"]].to_numpy().copy()
    before = ell()
    assert before and sbase.datum_points(st.problem) == sorted(sbase.datum_points(st.problem), key=list(st.problem.points.ids).index)
    ids = list(st.problem.points.ids)
    for base in (ids[:2], ids[3:6]):
        view.sbase.value = base
        assert st.sbase == base and st.sbase_error == ""
        cc = precision.covariance(adj, base)
        for p in range(len(ids)):
            np.testing.assert_allclose(st.point_cov2()[p], cc.block(p)[:2, :2], rtol=1e-12, atol=1e-18)
        after = ell()
        assert any(not np.allclose(a, b) for a, b in zip(after, before)), "ellipses changed"
        np.testing.assert_array_equal(st.frames()[0][["r", "w"]].to_numpy(), obs0)
        note = st.sbase_check()
        dr, dw = (float(x) for x in re.findall(r"max \|Δ[rw]\| = ([0-9.e+-]+)", note))
        assert dr < 1e-9 and dw < 1e-4, note
        assert view.note.object == note
        before = after
    assert "S-base" in view.title()
    view.sbase.value = [ids[0]]          # one point cannot fix rotation and translation
    assert "does not fix the datum" in st.sbase_error
    assert "fix" in view.note.object and "1 point" not in view.note.object
    np.testing.assert_allclose(st.point_cov2(), adj.point_cov[:, :2, :2])
    # issue 31, item 5: a second point chosen, the note says so (it kept the one-point message)
    view.sbase.value = [ids[0], ids[5]]
    assert "fix" not in view.note.object and "r and w unchanged" in view.note.object
    assert view.note.object == st.sbase_check()


def test_sbase_of_fixed_network_transforms_the_covariance_only():
    from baarda.stats import precision

    st = network_state("gama-local.gkf")
    free = [pid for pid, s in zip(st.problem.points.ids, st.problem.points.status) if s != "fixed"]
    st.sbase = free[:3]
    cc = precision.covariance(st.results, free[:3])
    k = geometry.point_index(st.problem)[free[5]]
    np.testing.assert_allclose(st.point_cov2()[k], cc.block(k)[:2, :2], rtol=1e-12)
    assert not np.allclose(st.point_cov2()[k], st.results.point_cov[k, :2, :2])
    assert "covariance only" in st.sbase_check()


def test_hypothesis_deformation_is_drawn_on_external_map():
    from baarda.stats.hypotheses import deformation
    from baarda.dashboard.views import ExternalMap

    st = network_state("gama-local.gkf")
    view = ExternalMap(state=st)
    root = pn.panel(view).get_root(Document())
    assert not any(len(s.data["shift_mm"]) for s in sources_with(root, "shift_mm"))
    k = st.add_hypothesis({"kind": "observation", "index": 20})
    ref = st.results.point_shifts(deformation(st.results, st.outcomes[k].test))
    label, shifts = st.external_field()
    assert label.startswith("hypothesis") and np.abs(ref).max() > 0
    np.testing.assert_allclose(shifts, ref, rtol=1e-12, atol=1e-15)
    data = [np.asarray(s.data["shift_mm"], dtype=float) for s in sources_with(root, "shift_mm")]
    size = 1000 * np.hypot(*(display_xy_shifts(st, ref)).T)
    assert any(np.allclose(np.sort(d), np.sort(size[size > 0])) for d in data if len(d))
    assert "hypothesis" in view.title()
    st.selected_obs = 3                  # a later observation selection takes over
    assert st.external_field()[0] == "obs 3"
    st.selected_hypothesis = None
    st.selected_hypothesis = k
    assert st.external_field()[0].startswith("hypothesis")


def display_xy_shifts(st, shifts):
    from baarda.dashboard.geometry import display_matrix

    return (display_matrix(st.problem) @ shifts[:, :2].T).T


@pytest.fixture(scope="module")
def ap_block():
    from baarda.model.bundle import build_block_problem
    from baarda.simulate import simulate_block

    blk, _ = simulate_block(strips=2, images_per_strip=4, ap=["brown"], seed=3)
    return build_block_problem(blk)


def test_ap_group_hypotheses_match_bundle(ap_block):
    from baarda.stats import ap_tests, hypotheses
    from baarda.dashboard.views import HypothesisPanel

    st = State(problem=ap_block)
    adj = st.results
    panel = HypothesisPanel(state=st)
    pn.panel(panel).get_root(Document())
    assert "ap-group" in panel.kind.options.values()
    panel.kind.value = "ap-group"
    panel.camera.value = "RC30"
    assert list(panel.ap_group.options.values())[0] == "brown"     # the estimated one first
    panel.ap_group.value = "brown"
    panel.add.clicks += 1                       # the "Test" button
    assert st.outcomes[-1].status == "ap-test"
    est = st.outcomes[-1].ap
    ref = ap_tests.ap_test(adj, "RC30", "brown")
    assert isinstance(est, ap_tests.APTest)
    assert est.T == pytest.approx(ref.T, rel=1e-10) and est.q == ref.q == 7
    row = panel.frame().iloc[-1]
    assert row["T"] == round(ref.T, 3) and "significant" in row["decision"].lower()
    k = st.add_hypothesis({"kind": "ap-group", "camera": "RC30", "group": "ebner"})
    ref2 = reliability_of(adj).test(hypotheses.h_ap_group(adj, "RC30", "ebner"))
    assert st.outcomes[k].test.T == pytest.approx(ref2.T, rel=1e-9) and st.outcomes[k].test.q == 12
    assert "not in the model" in st.hypotheses[k]["label"]
    st.selected_hypothesis = k          # its deformation field is drawn like any other
    assert np.abs(st.external_field()[1]).max() > 0


def test_ap_group_hypothesis_with_exclusions(block_problem):
    from baarda.stats import hypotheses

    st = State(problem=block_problem)
    st.exclude(5)
    k = st.add_hypothesis({"kind": "ap-group", "camera": "cam", "group": "brown"})
    adj = st.results
    # the core's builder at the full problem's solution, cut to the kept rows: H differs only
    # by the (small) change of the solution the exclusion causes
    ref = reliability_of(adj).test(hypotheses.h_ap_group(adjust(block_problem), "cam", "brown").tocsr()[st.kept])
    assert st.outcomes[k].test.q == 7 and st.outcomes[k].test.T == pytest.approx(ref.T, rel=1e-4)


def test_suspect_observations_take_a_left_out_point_whole():
    """A suspect whose point the robust step left out (R84 §7, a 2-ray point) marks all the point's
    observations (``left_out``), another suspect its own cluster; full indices through ``kept``."""
    from types import SimpleNamespace
    rr = SimpleNamespace(suspects=[{"members": [2, 3]}, {"members": [6, 7], "left_out": [4, 5, 6, 7]}])
    assert frames.suspect_observations(rr, np.arange(10) + 100) == [102, 103, 104, 105, 106, 107]


def test_robust_selector_runs_core_and_marks_suspects():
    from baarda.stats import robust
    from baarda.dashboard.views import AnalysisPanel, Controls, LayoutMap, TestsTable

    st = network_state(FREE_2D)
    c = Controls(state=st)
    table = TestsTable(state=st)
    panel = AnalysisPanel(state=st)
    lay = pn.panel(LayoutMap(state=st)).get_root(Document())
    assert st.robust is None and "robust_w" in table.table.hidden_columns
    c.robust.value = "danish"
    ref = robust.estimate(st.results.problem, "danish", st.options())
    np.testing.assert_allclose(st.robust.weights, ref.weights, rtol=1e-12)
    sus = frames.robust_suspects(st.robust, st.kept, st.frames()[0])
    assert list(sus["obs"]) == [int(st.kept[d["index"]]) for d in ref.suspects] and len(sus) > 0
    assert set(sus["class"]) <= {"random", "small", "medium", "large"}
    np.testing.assert_allclose(table.table.value["robust_w"].to_numpy(), st.expand(ref.weights))
    assert "robust_w" not in table.table.hidden_columns
    assert len(panel.robust_table.value) == len(sus) and "suspects" in panel.robust_info.object
    n_marked = len({k for i in frames.suspect_observations(st.robust, st.kept) for k in st.problem_index()["obs_points"][i]})
    marks = [s for s in lay.select({"type": ColumnDataSource}) if set(s.data) == {"x", "y"}
             and len(s.data["x"]) == n_marked]
    lines = [s for s in lay.select({"type": ColumnDataSource}) if set(s.data) == {"xs", "ys"}
             and len(s.data["xs"]) == len(frames.suspect_observations(st.robust, st.kept))]
    assert n_marked and marks and lines, "suspect points and lines drawn on the layout map"
    c.robust.value = "none"
    assert st.robust is None and np.isnan(st.frames()[0]["robust_w"]).all()


def test_snooping_log_leave_one_out_and_accept():
    from baarda.stats import snooping

    st = network_state(FREE_2D)
    st.sigma0_mode = "apriori"
    assert st.run_snooping()
    ref = snooping.iterate(st.results.problem, st.options())
    log = frames.snoop_log(st.snoop, st.kept, st.frames()[0], *st.problem_index()['factor'])
    assert list(log["obs"]) == [int(st.kept[i]) for i in ref.removed] and len(log) >= 2
    np.testing.assert_allclose(log["|w|"], [round(s.statistic, 3) for s in ref.steps])
    np.testing.assert_allclose(log["σ̂0 after"], [round(s.sigma0_after, 4) for s in ref.steps])
    top = np.argsort(-np.abs(st.results.w), kind="stable")[:5]
    loo = snooping.leave_one_out(st.results, list(top))
    assert [d["sigma0_without"] for d in st.snoop_loo] == pytest.approx([d["sigma0_without"] for d in loo])
    removed = set(log["obs"])
    assert st.accept_snooping()
    assert st.excluded == removed and st.snoop is None
    np.testing.assert_allclose(st.results.w, ref.adjustment.w, atol=1e-5)   # Gauss-Newton stops


def test_variance_components_and_core_errors_as_messages():
    from baarda.stats import variance
    from baarda.dashboard.views import AnalysisPanel

    st = network_state("gama-local.gkf")
    panel = AnalysisPanel(state=st)
    panel.variance_button.clicks += 1
    ref = variance.estimate(st.results.problem, options=st.options()).as_dict()
    tab = frames.variance_table(st.variance, st.components)
    assert list(tab["family"]) == [d["group"] for d in ref]
    np.testing.assert_allclose(tab["σ̂0j²"], [round(d["factor"], 4) for d in ref])
    np.testing.assert_allclose(tab["± s.e."], [round(d["std_error"], 4) for d in ref])
    assert len(panel.variance_table.value) == len(ref)
    st2 = network_state("triangle-1.gkf")
    panel2 = AnalysisPanel(state=st2)
    assert not st2.run_variance()
    assert "no redundancy" in st2.analysis_error and panel2.message.visible


def test_inject_error_on_a_copy_and_keep(block_problem):
    from baarda.dashboard.views import InjectPanel

    st = State(problem=block_problem)
    l0 = np.array(st.problem.l, copy=True)
    adj = st.results
    i = int(np.argmax(adj.r))
    st.selected_obs = i
    panel = InjectPanel(state=st)
    panel.size.value, panel.unit.value = 1.5, "mdb"
    panel.run.clicks += 1
    inj = st.injection
    e = np.zeros(adj.n)
    e[i] = 1.5 * reliability_of(adj).mdb[i]
    ref = adjust(replace(adj.problem, l=adj.problem.l + e), adj.options)
    assert inj["w_after"] == pytest.approx(ref.w[i], rel=1e-9)
    assert inj["w_before"] == pytest.approx(adj.w[i], rel=1e-12)
    assert inj["rejected"] == bool(abs(ref.w[i]) > reliability_of(ref).critical_w)
    assert inj["largest"] == pytest.approx(np.nanmax(np.abs(ref.w)))
    g = next(g for g in reliability_of(ref).groups if i in g["members"])
    assert inj["group_T"] == pytest.approx(g["T"])
    assert "**rejected**" in panel.result.object or "**not rejected**" in panel.result.object
    assert "δ0 (δ0 = " in panel.result.object
    # what the panel teaches: an error of k MDB moves w by k δ0 (linear model; F80 §5)
    assert abs(inj["w_after"] - inj["w_before"]) == pytest.approx(1.5 * st.reliability.delta0, rel=1e-2)
    np.testing.assert_array_equal(st.problem.l, l0)       # the loaded data are untouched
    assert st.results is adj
    st.inject(i, 10, "sigma")
    assert st.injection["error"] == pytest.approx(10 * block_problem.info.sigma_file[i], rel=1e-9)
    panel.keep.clicks += 1
    e10 = np.zeros(adj.n)
    e10[i] = 10 * adj.problem.cov.sigma()[i]
    np.testing.assert_allclose(st.problem.l, l0 + e10)
    ref10 = adjust(replace(block_problem, l=l0 + e10))
    np.testing.assert_allclose(st.results.w, ref10.w, atol=1e-8)


# --------------------------------------------------------------------------------------------
# criterion matrices, risk, radial variance model (M84 §2, §3.3; F80 §2.1) — against the core
# --------------------------------------------------------------------------------------------
def test_criterion_fit_and_given_c1_c2_match_the_core():
    from baarda.stats import precision
    from baarda.dashboard.views import CriterionView

    st = network_state(FREE_2D)
    view = CriterionView(state=st)
    root = pn.panel(view).get_root(Document())
    ids = list(st.problem.points.ids)
    assert view.sbase.value == ids[:2] and st.criterion["fitted"]        # fitted when opened
    adj = st.results
    cc = precision.covariance(adj, ids[:2])
    _, G, _ = precision.release_null_space(adj)
    Gk = G[: cc.params.size]
    in_base = np.isin(np.array(ids)[cc.point], ids[:2])
    xy = adj.coordinates[:, :2]
    for kind in ("linear", "logarithmic"):
        view.kind.value = kind
        view.fit.clicks += 1
        fit = precision.fit_criterion(cc.cov, xy, in_base, Gk, kind=kind)
        c = st.criterion
        assert c["C1"] == pytest.approx(fit["C1"], rel=1e-9) and c["C2"] == pytest.approx(fit["C2"], rel=1e-6)
        assert c["lam_max"] == pytest.approx(1.0, rel=1e-9) and c["ratio"] == pytest.approx(fit["ratio"], rel=1e-6)
        assert view.C1.value == c["C1"] and "λmax" in view.info.object
    view.C1.value, view.C2.value = 3 * fit["C1"], fit["C2"]
    view.check.clicks += 1
    H = precision.sbase_transform(precision.criterion_matrix(xy, "logarithmic", 0.0, 3 * fit["C1"], fit["C2"]),
                                  Gk, in_base)
    ref = precision.compare(cc.cov, H, Gk, in_base)
    c = st.criterion
    assert not c["fitted"] and c["satisfied"] and c["lam_max"] == pytest.approx(ref.lam_max, rel=1e-9)
    assert c["lam_min"] == pytest.approx(ref.lam_min, rel=1e-9) and "satisfied" in view.info.object
    pattern = ref.worst_pattern()
    np.testing.assert_allclose(c["pattern"][cc.point, cc.axis], pattern)
    base_rows = in_base                                      # the S-base as a whole does not move (Eᵀ S = 0)
    np.testing.assert_allclose(Gk[base_rows].T @ c["pattern"][cc.point, cc.axis][base_rows], 0.0,
                               atol=1e-9 * np.abs(Gk).max())
    seg = [s for s in sources_with(root, "x1")]
    assert seg, "the eigenvector of λmax is drawn as segments"
    view.C1.value = fit["C1"] / 3
    view.check.clicks += 1
    assert not st.criterion["satisfied"] and "NOT satisfied" in view.info.object
    view.sbase.value = [ids[0]]                 # one point does not fix the datum: a message
    view.check.clicks += 1
    assert st.criterion is None and "does not fix the datum" in st.criterion_error and view.message.visible


def test_criterion_for_blocks_and_heights_refused_without_positions(block_problem):
    """M84 §2.3 asks for criterion matrices of heights and 3D blocks: the tab compares them (λmax = 1
    after the fit); a levelling network without point positions has no distances and is refused."""
    from baarda.dashboard.views import CriterionView

    for st in (State(problem=block_problem), network_state("krumm/1D/Niemeier_Height_free.gkf")):
        assert measures.criterion_reason(st.results) == ""
        view = CriterionView(state=st)
        pn.panel(view).get_root(Document())
        c = st.criterion_compare("logarithmic")
        assert c is not None and c["lam_max"] == pytest.approx(1.0, rel=1e-6), st.criterion_error
    st = State(Path(__file__).resolve().parents[2] / "data" / "demo-levelling.gkf")
    assert "planimetric positions" in measures.criterion_reason(st.results)
    assert st.criterion_compare("linear") is None and st.criterion_error.startswith("Criterion:")


def test_risk_panel_matches_closed_form():
    from scipy import stats as sps

    from baarda.stats import risk
    from baarda.dashboard.views import RiskView

    st = network_state(FREE_2D)
    view = RiskView(state=st)
    pn.panel(view).get_root(Document())
    assert view.lam.value == pytest.approx(st.reliability.delta0 ** 2, abs=1e-4)
    view.p.value, view.L1.value, view.L2.value, view.lam.value = 0.05, 1.0, 20.0, 9.0
    rc = view.rc
    C = risk.critical_value(0.05, 1.0, 20.0, 9.0)
    assert rc["C"] == pytest.approx(C, rel=1e-12)
    assert rc["C"] == pytest.approx(risk.critical_value_numeric(0.05, 1.0, 20.0, 9.0), abs=1e-6)
    assert rc["alpha"] == pytest.approx(sps.norm.sf(C)) and rc["beta"] == pytest.approx(sps.norm.sf(C - 3.0))
    assert rc["r_C"] == pytest.approx(risk.risk(C, 0.05, 1.0, 20.0, 9.0))
    assert rc["r"].min() >= rc["r_C"] - 1e-12                  # the marked C is the minimum of the curve
    assert f"{C:.4f}" in view.info.object
    view.p.value = 0.0
    assert "0 < p < 1" in view.info.object


def test_radial_variance_model_matches_core_and_refusal_is_a_message(block_problem):
    from baarda.stats import variance
    from baarda.model.bundle import build_block_problem
    from baarda.dashboard.views import AnalysisPanel
    from baarda.simulate import simulate_block

    block, _ = simulate_block(strips=4, images_per_strip=10, design=True, seed=3, control="dense",
                              approx_sigma=0.0, pattern=[5, 3])
    p = build_block_problem(block)
    comps = variance.radial_components(p)
    rng = np.random.default_rng(12)
    e = np.zeros(p.n)
    for c, idx in enumerate(p.cov.members):
        C = 0.002 ** 2 * comps["a²"][c] + 0.005 ** 2 * comps["b²c²"][c] + comps["other"][c]
        e[idx] = np.linalg.cholesky(C) @ rng.normal(size=idx.size)
    st = State(problem=replace(p, l=p.l + e))
    panel = AnalysisPanel(state=st)
    assert list(panel.variance_model.options) == ["families", "radial", "radial-isotropic"]
    panel.variance_model.value = "radial"
    assert st.variance_model == "radial"
    panel.variance_button.clicks += 1
    prob = st.results.problem
    image = np.char.startswith(np.asarray(prob.info.kind).astype(str), "image")
    sig2 = float(np.median(prob.cov.sigma()[image]) ** 2)
    ref = variance.estimate_components(prob, comps, theta0=[sig2 / 2, sig2 / 2, 1.0], options=st.options())
    tab = frames.variance_table(st.variance, st.components)
    assert list(tab["component"]) == list(ref.names) and st.analysis_error == ""
    assert [float(x) for x in tab["θ"]] == pytest.approx(ref.theta, rel=1e-3)
    assert len(panel.variance_table.value) == 3 and panel.variance_table.visible
    st2 = network_state("gama-local.gkf")                 # no camera: the core refuses
    panel2 = AnalysisPanel(state=st2)
    st2.variance_model = "radial"
    assert not st2.run_variance()
    assert "radial variance model needs a block" in st2.analysis_error and panel2.message.visible


# --------------------------------------------------------------------------------------------
# colour scales and large blocks
# --------------------------------------------------------------------------------------------
def test_mdb_and_external_maps_use_log_colour_scales(block_problem):
    """δ̄0 and MDB / σ span orders of magnitude on a block (r ≈ 1e-5 at its edges): their colour
    mappers are logarithmic up to the largest value (no saturation); the r map keeps its
    0.1 / 0.3 levels."""
    from bokeh.models import ColorBar, LinearColorMapper, LogColorMapper

    from baarda.dashboard.views import ExternalMap, MDBMap, RedundancyMap

    st = State(problem=block_problem)
    obs, pts = st.frames()
    for view, values, low in ((MDBMap, obs["mdb_sigma"], st.reliability.delta0), (ExternalMap, pts["max_ext"], None)):
        root = pn.panel(view(state=st)).get_root(Document())
        mappers = list(root.select({"type": LogColorMapper}))
        assert mappers, view.__name__
        finite = values.to_numpy(dtype=float)
        top = float(np.max(finite[np.isfinite(finite)]))
        assert top > 100 * (low or 1.0) or view is ExternalMap
        assert [m.high for m in mappers] == pytest.approx([top] * len(mappers))
        if low is not None:
            assert [m.low for m in mappers] == pytest.approx([low] * len(mappers))
        assert any("log scale" in str(b.title) for b in root.select({"type": ColorBar}))
    root = pn.panel(RedundancyMap(state=st)).get_root(Document())
    (r_map,) = [m for m in root.select({"type": LinearColorMapper}) if m.high == 1]
    assert r_map.low == 0 and len(r_map.palette) >= 10       # 0.1 / 0.3 / 0.6 steps of the levels


def test_teaching_mdb_plot_thins_large_blocks_but_keeps_every_cell():
    import pandas as pd

    from baarda.dashboard.views.teaching import MAX_POINTS, thinned

    rng = np.random.default_rng(4)
    r = rng.uniform(1e-4, 1, 30_000)
    obs = pd.DataFrame({"r": r, "mdb_sigma": 4.13 / np.sqrt(r),
                        "kind": rng.choice(["image-x", "image-y", "control-z"], r.size)})
    small = obs.iloc[:MAX_POINTS]
    assert thinned(small) is small
    few = thinned(obs)
    assert len(few) < len(obs) / 5 and set(few["kind"]) == set(obs["kind"])
    cells = lambda d: {(k, int(a * 400), int(b)) for k, a, b in  # noqa: E731
                       zip(d["kind"], np.clip(d["r"], 0, 1), 400 * (np.log(d["mdb_sigma"]) - np.log(obs["mdb_sigma"]).min())
                           / np.ptp(np.log(obs["mdb_sigma"])))}
    assert cells(few) == cells(obs)


# --------------------------------------------------------------------------------------------
# COLMAP image points observed by several keypoints of one image
# --------------------------------------------------------------------------------------------
def test_duplicate_keypoints_are_image_points_of_their_own(tmp_path):
    from baarda.build import read_problem
    from tests.io.test_colmap import duplicate_model

    txt, _, _, added = duplicate_model(tmp_path)
    p = read_problem(txt)
    st = State(problem=p)
    assert st.error == "" and st.results is not None, st.error
    ids = p.info.ids
    # a keypoint index is not a point id: every image observation names exactly its own point,
    # also when points are named like the keypoints (added here: ids "0" … "64")
    kp_rows = [i for i, d in enumerate(ids) if "keypoint" in d]
    assert kp_rows
    named = SimpleNamespace(points=SimpleNamespace(ids=tuple(p.points.ids) + tuple(
        str(k) for k in range(65) if str(k) not in p.points.ids)), info=p.info)
    pid_index = {pid: k for k, pid in enumerate(named.points.ids)}
    assert all(str(ids[i]["keypoint"]) in pid_index for i in kp_rows)
    for pts, d in zip(observation_points(named), ids):
        if "image" in d:
            assert pts == [pid_index[str(d["point"])]]
    assert st.problem_index()["obs_points"] == observation_points(p)
    for iid, pid, kp in added:
        both = [i for i, d in enumerate(ids) if d.get("image") == str(iid) and d.get("point") == str(pid)]
        assert len(both) == 4
        mine = [i for i in both if ids[i].get("keypoint") == kp]
        assert len(mine) == 2 and geometry.image_point_rows(st.problem_index(), iid, pid, kp) == mine
        assert geometry.point_rows_in_image(st.problem_index(), iid, pid) == both
        assert len(geometry.keypoints_of(st.problem_index(), iid, pid)) == 2
        with pytest.raises(ValueError, match="keypoints"):
            geometry.image_point_rows(st.problem_index(), iid, pid)
        # the hypothesis of one keypoint's image point: q = 2, the core's test of those two rows
        k = st.add_hypothesis({"kind": "image-point", "image": str(iid), "point": str(pid), "keypoint": kp})
        h = st.outcomes[k].test
        ref = reliability_of(st.results).test(selection(st.results.n, mine))
        assert h.q == 2 and h.T == pytest.approx(ref.T, rel=1e-12)
        assert f"keypoint {kp}" in specs.describe(st.problem, st.hypotheses[k], st.problem_index())


# --------------------------------------------------------------------------------------------
# lower bound of a hypothesis the test cannot see (F80 eq. 13)
# --------------------------------------------------------------------------------------------
def dangling_levelling(m: int, sigma: float):
    """A levelling loop of m points and one point X hanging on one height difference (r = 0)."""
    from tests.networks import Cluster, NetObservation, NetPoint, Network, levelling_loop, problem

    net = levelling_loop(m, sigma)
    pts = net.points + (NetPoint("X", z=50.0, adjusted="z"),)
    obs = net.observations + (NetObservation("height-diff", ("H1", "X"), 0.1234567),)
    cl = net.clusters + (Cluster((len(net.observations),), np.array([[sigma ** 2]])),)
    return problem(Network(pts, obs, cl, sigma_act="apriori"))


def test_lower_bound_of_an_untestable_q1_hypothesis_has_no_warning():
    import warnings

    from baarda.stats import hypotheses

    seen_negative = False
    for m, sigma in [(6, 0.0007), (7, 0.003), (8, 0.003), (6, 0.003), (7, 0.001)]:
        adj = adjust(dangling_levelling(m, sigma))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            # the loop's observations: q = 1, ∇0 = MDB (F80 eq. 13 = M84's minimal detectable bias)
            h = hypotheses.test(adj, selection(adj.n, [0]))
            assert h.q == 1
            assert abs(h.lower_bound([1.0])[0]) == pytest.approx(reliability_of(adj).mdb[0], rel=1e-9)
            # the dangling observation (r = 0): W is round-off (of either sign), q = 0
            h = hypotheses.test(adj, selection(adj.n, [adj.n - 1]))
            seen_negative |= float(h.W[0, 0]) < 0
            assert h.q == 0 and np.isinf(h.lower_bound([1.0])).all()
            with pytest.raises(ValueError, match="q = 0"):
                hypotheses.deformation(adj, h)
    assert seen_negative               # the case that gave "invalid value encountered in sqrt"
    st = State(problem=dangling_levelling(6, 0.0007))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        k = st.add_hypothesis({"kind": "observation", "index": st.problem.n - 1})
        assert st.outcomes[k].test.q == 0
        assert not measures.hypothesis_field(st.results, st.outcomes[k], len(st.problem.points.ids)).any()


def test_cancelled_snooping_stops_within_its_step(monkeypatch):
    """Served, a cancel during a readjustment of iterative snooping stops the run at that
    readjustment's next iteration (it used to finish the step first: seconds on a block)."""
    from baarda.stats import snooping

    st = network_state(FREE_2D)
    st.sigma0_mode = "apriori"
    st.background = True
    started, finished = [], []
    real = snooping.adjust

    def adjust(problem, options=None, x0=None, progress=None):
        started.append(problem.n)

        def iteration(it, step):
            if len(started) == 2:             # the first readjustment (a step) is running
                st.cancel()
            if progress is not None:
                progress(it, step)
        out = real(problem, options, x0=x0, progress=iteration)
        finished.append(problem.n)
        return out
    monkeypatch.setattr(snooping, "adjust", adjust)
    fut = st.submit("iterative data snooping", st.run_snooping)
    assert fut.result(timeout=120) is False
    assert st.progress == "cancelled" and st.snoop is None and st.task == ""
    assert len(started) == 2 and len(finished) == 1     # the step's readjustment did not finish


def test_served_exclusion_adjusts_on_a_worker_and_applies_on_the_loop():
    """Served, "Exclude" adjusts on a task thread (with the task indicator) and only makes the
    result current on the session's loop; the result equals a fresh adjustment without it."""
    import threading

    st = network_state("gama-local.gkf")
    adj0 = st.results
    i = int(np.nanargmax(np.abs(adj0.w)))
    loop_threads, tasks, results_on = [], [], []

    def loop_call(fn):                        # a stand-in for the session's event loop
        t = threading.Thread(target=fn, name="event-loop")
        loop_threads.append(t)
        t.start()
    st.jobs.loop_call = loop_call
    st.background = True
    st.param.watch(lambda e: tasks.append(e.new), "task")
    st.param.watch(lambda e: results_on.append(threading.current_thread().name), "results")
    fut = st.exclude(i)
    assert fut is not None and fut.result(timeout=120) is True
    assert tasks[0] == "excluding and adjusting again" and tasks[-1] == ""
    assert results_on == ["event-loop"] and loop_threads
    ref, _ = fresh(st.problem, [i])
    assert st.excluded == {i} and st.results.vPv == pytest.approx(ref.vPv, rel=1e-10)
    # a second exclusion while one runs is refused (one computation per session at a time)
    st.task = "something else"
    assert st.include(i) is None and st.excluded == {i}
    st.task = ""
    assert st.include(i).result(timeout=120) is True and st.excluded == frozenset()


def test_a_selection_patches_only_the_selection_sources(block_problem):
    """A click (selected point / observation) gives the map's two selection sources new data
    (the rings at the points' map positions, the observation's line); the overlay is not
    redrawn: every other data source of the figure keeps its data object."""
    from bokeh.models import GlyphRenderer

    from baarda.dashboard.views import LayoutMap

    st = State(problem=block_problem)
    view = LayoutMap(state=st)
    root = pn.panel(view).get_root(Document())
    rings = [r for r in root.select({"type": GlyphRenderer}) if r.name == "selection-rings"]
    lines = [r for r in root.select({"type": GlyphRenderer}) if r.name == "selection-lines"]
    assert len(rings) == len(lines) == 1
    rings, lines = rings[0].data_source, lines[0].data_source
    assert rings.data["x"] == [] and lines.data["xs"] == []
    others = {id(s): s.data for s in root.select({"type": ColumnDataSource}) if s not in (rings, lines)}
    _, pts = st.frames()
    st.selected_point = 3
    assert rings.data["x"] == [pts["x"].iat[3]] and rings.data["y"] == [pts["y"].iat[3]]
    i = next(i for i, k in enumerate(st.problem_index()["obs_points"]) if len(k) >= 2) if any(
        len(k) >= 2 for k in st.problem_index()["obs_points"]) else 0
    st.selected_obs = i
    k = st.problem_index()["obs_points"][i]
    assert rings.data["x"] == [pts["x"].iat[j] for j in k]
    assert all(s.data is others[id(s)] for s in root.select({"type": ColumnDataSource})
               if id(s) in others)
    # the report's static map still draws the selection (HoloViews layers)
    assert view.static() is not None


def test_served_file_is_analysed_at_start_and_sessions_take_it_from_the_cache(tmp_path, monkeypatch, capsys):
    """``serve`` warms the cache: a session opened afterwards reads and adjusts nothing and
    shows the same adjustment as a fresh one."""
    import baarda.build
    from baarda.dashboard.app import warm

    path = tmp_path / "net.gkf"
    path.write_bytes((require_extdata(GAMA) / "gama-local.gkf").read_bytes())
    assert warm(path).result(timeout=120) is True
    assert "net.gkf read and adjusted in" in capsys.readouterr().out

    def no_read(*a, **k):
        raise AssertionError("read again")
    monkeypatch.setattr(baarda.build, "read_problem", no_read)
    st = State(path)
    assert st.error == "" and st.results is not None
    monkeypatch.undo()
    ref = State(problem=baarda.build.read_problem(path))
    assert st.results.vPv == pytest.approx(ref.results.vPv, rel=1e-12)


def test_excluding_a_whole_direction_set_equals_the_core_exclusion():
    """Leaving out every direction of a set orphans its orientation unknown: the core's
    :func:`baarda.model.problem.subset` holds it, and the dashboard excludes through the core, so the
    last direction goes as well and the result is a fresh core adjustment without the set."""
    st = network_state("gama-local.gkf")
    p = st.problem
    rows = [i for i in range(p.n) if p.info.kind[i] == "direction" and p.info.ids[i]["from"] == "1"]
    assert len(rows) >= 2
    for i in rows:
        assert st.exclude(i), st.error
    assert st.error == "" and sorted(st.excluded) == rows
    kept = np.setdiff1d(np.arange(p.n), rows)
    ref = adjust(replace(subset(p, kept), sigma_act=st.sigma0_mode), Options())
    adj = st.results
    assert adj.n == p.n - len(rows) and adj.dof == ref.dof
    np.testing.assert_allclose(adj.r, ref.r, atol=1e-12)
    np.testing.assert_allclose(adj.w, ref.w, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(adj.x, ref.x, atol=1e-9)


@pytest.mark.parametrize("sigma0_mode", ["apriori", "aposteriori"])
def test_policy_change_rebuilds_only_the_reliability_over_the_same_result(monkeypatch, sigma0_mode):
    """α0, β0 and the B-method change only the Reliability over the same result: no new
    adjustment (``adjust`` must not be called), the same result object, and every decision, MDB,
    δ̄0 and group test equal to a fresh analysis at the new policy."""
    from baarda.stats.policy import TestPolicy
    from baarda.stats.reliability import Reliability

    st = State(problem=tiny_block_problem())
    st.sigma0_mode = sigma0_mode
    adj, sol, rel = st.results, st.solution, st.reliability
    assert isinstance(rel, Reliability) and rel.result is adj

    def no_refit(*args, **kwargs):
        raise AssertionError("a policy change must not adjust again")

    monkeypatch.setattr(measures, "adjust", no_refit)     # the state adjusts through measures
    with param.parameterized.batch_call_watchers(st):
        st.alpha0, st.beta0, st.b_method = 0.02, 0.9, True
    monkeypatch.undo()
    assert st.results is adj and st.solution == sol
    assert st.reliability is not rel and st.reliability.result is adj
    assert st.reliability.policy == TestPolicy(0.02, 0.9, True, sigma0_mode)
    ref = reliability_of(adjust(replace(adj.problem), Options(alpha0=0.02, beta0=0.9, b_method=True)))
    np.testing.assert_allclose(st.reliability.mdb, ref.mdb, rtol=1e-12)
    np.testing.assert_allclose(st.reliability.external, ref.external, rtol=1e-12)
    assert st.reliability.delta0 == ref.delta0 == distributions.delta0(0.02, 0.9, 1)
    stat, crit = (ref.result.tau, distributions.critical_tau(0.02, ref.result.dof)) if sigma0_mode == "aposteriori" \
        else (ref.result.w, distributions.critical_normal(0.02))
    np.testing.assert_array_equal(st.reliability.rejected, np.nan_to_num(np.abs(stat)) > crit)
    obs, _ = st.frames()
    np.testing.assert_array_equal(obs["rejected"].to_numpy(), st.expand(st.reliability.rejected, fill=False))
    np.testing.assert_allclose(obs["mdb_sigma"].to_numpy(), ref.mdb / adj.problem.cov.sigma(), rtol=1e-12)
    g, gr = st.reliability.groups, ref.groups
    assert len(g) == len(gr) > 0
    np.testing.assert_array_equal(g.critical, gr.critical)
    np.testing.assert_array_equal(g.rejected, gr.rejected)
    np.testing.assert_allclose(g.T, gr.T, rtol=1e-9)
    assert (g.alpha[g.dimension == 2] == distributions.alpha_b_method(0.02, 0.9, 2)).all()
