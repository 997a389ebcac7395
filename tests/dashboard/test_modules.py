"""The dashboard's modules beside the state (issue 13): geometry, frames, specs, measures, sbase
and jobs are plain functions of the core's objects, and give what the state shows.

Each check compares a module's function with the core or with the state that calls it; the
import check keeps ``state.py`` the only holder of the choices (no module below it imports it).
"""

from __future__ import annotations

import ast
import threading
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("panel")
pytest.importorskip("holoviews")

import pandas as pd  # noqa: E402

from baarda.dashboard import frames, geometry, jobs, mapgeometry, measures, sbase, specs  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402
from baarda.dashboard.outcomes import Outcome  # noqa: E402
from baarda.stats.hypotheses import selection  # noqa: E402
from tests.extdata import GAMA, require_extdata  # noqa: E402

DASHBOARD = Path(__file__).resolve().parents[2] / "dashboard"
#: the modules below the state: they take the core's objects, never the state's module
BELOW_STATE = ("geometry", "mapgeometry", "frames", "specs", "measures", "sbase", "jobs", "suspects", "text")


@pytest.fixture(scope="module")
def st():
    s = State(require_extdata(GAMA) / "krumm/2D/Hoepke_Distance_free.gkf")
    assert s.error == "" and s.results is not None, s.error
    return s


@pytest.mark.parametrize("name", BELOW_STATE)
def test_modules_below_the_state_do_not_import_it(name):
    tree = ast.parse((DASHBOARD / f"{name}.py").read_text(encoding="utf-8"))
    targets = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module]
    assert not any(t == "state" or t.endswith(".state") or t.startswith("views") for t in targets), targets


def test_every_dashboard_module_is_small():
    sizes = {p.name: len(p.read_text(encoding="utf-8").splitlines()) for p in DASHBOARD.glob("*.py")}
    assert sizes["state.py"] < 900 and max(sizes.values()) < 900, sizes


def grid_points(n: int = 10) -> pd.DataFrame:
    """n × n points on the unit square's grid, ids g0, g1, ..."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    return pd.DataFrame({"id": [f"g{i}" for i in range(n * n)], "x": x.ravel(), "y": y.ravel()})


def test_mapgeometry_frame_puts_far_points_at_the_edge_and_lists_them():
    pts = grid_points()
    far = pd.DataFrame({"id": ["east", "south"], "x": [1e6, 0.5], "y": [0.5, -5e3]})
    f = mapgeometry.framed(pd.concat([pts, far], ignore_index=True))
    x0, x1, y0, y1 = mapgeometry.robust_box(f["x_true"], f["y_true"])
    # the grid sets the frame: the unit square inside it, widened by at most 0.75 of its side
    assert -0.75 <= x0 <= 0 and 1 <= x1 <= 1.75 and -0.75 <= y0 <= 0 and 1 <= y1 <= 1.75
    assert f["far"].tolist() == [False] * 100 + [True, True]
    assert (f["x"].iat[100], f["y"].iat[100]) == (x1, 0.5) and (f["x"].iat[101], f["y"].iat[101]) == (0.5, y0)
    assert f["x_true"].iat[100] == 1e6 and f["y_true"].iat[101] == -5e3
    note = mapgeometry.far_note(f)
    assert note.startswith("2 far point(s)") and note.index("east (1e+06, 0.5)") < note.index("south (0.5, -5000)")
    assert mapgeometry.far_note(mapgeometry.framed(pts)) == ""
    # a long list is cut: the farthest `limit` named, the rest counted
    many = pd.DataFrame({"id": [f"f{i}" for i in range(5)], "x": 1e3 * (2.0 + np.arange(5)), "y": 0.5})
    note = mapgeometry.far_note(mapgeometry.framed(pd.concat([pts, many], ignore_index=True)), limit=2)
    assert note.startswith("5 far point(s)") and "f4 (" in note and "f3 (" in note and "f2 (" not in note
    assert note.endswith("and 3 more.")
    # the observation lines end at the frame
    seg = pd.DataFrame({"x0": [0.2], "y0": [0.2], "x1": [1e6], "y1": [-7.0]})
    assert mapgeometry.clamped_segments(seg, f)[["x0", "y0", "x1", "y1"]].iloc[0].tolist() == [0.2, 0.2, x1, y0]


def test_mapgeometry_w_levels_reach_the_largest_w():
    for crit, top in [(3.29, 13.42), (2.0, 250.0), (3.29, 3.3)]:
        lv = mapgeometry.w_levels(crit, top)
        assert len(lv) == 8 and lv[:3] == [0.0, round(crit / 2, 2), round(crit, 2)]
        assert np.all(np.diff(lv) > 0) and lv[-1] >= max(top, 1.5 * crit)
    assert mapgeometry.w_levels(2.0, np.inf)[-1] == 3.0         # no finite |w|: up to 1.5 × critical
    seg = pd.DataFrame({"abs_w": [1.0, np.nan, 7.5]})
    assert mapgeometry.largest_abs_w(seg, pd.DataFrame({"max_w": [2.0, np.nan]})) == 7.5
    assert mapgeometry.largest_abs_w(seg.iloc[:0], pd.DataFrame({"max_w": [2.0, np.nan]})) == 2.0


def test_mapgeometry_standard_ellipses_and_field_at_round_scales():
    pts = mapgeometry.framed(grid_points())
    sigma = np.full(100, 0.001)
    sigma[7] = 1.0                                   # one point 1000 × worse: off-scale, not drawn
    cov2 = sigma[:, None, None] ** 2 * np.eye(2)
    paths, scale, big, off = mapgeometry.ellipse_paths(cov2, np.eye(2), pts)
    # the ordinary circles' radius, 1 mm, is at most 5 % of the 1 m frame: 0.05 / 0.001 = 50
    assert scale == 50.0 and big == pytest.approx(0.001) and off == 1
    xy = paths[0][np.isfinite(paths[0][:, 0])]
    centres = pts[["x", "y"]].to_numpy()
    d = np.min(np.hypot(xy[:, None, 0] - centres[None, :, 0], xy[:, None, 1] - centres[None, :, 1]), axis=1)
    np.testing.assert_allclose(d, 0.05, rtol=1e-9)  # every drawn point on a circle of 1 mm × 50
    assert np.isnan(paths[0][:, 0]).sum() == 98      # 99 circles drawn, one glyph
    assert mapgeometry.ellipse_paths(cov2, np.eye(2), pts, scale=3.0)[1] == 3.0
    # the deformation field: its longest vector at most 12 % of the frame, a round factor
    shifts = np.zeros((100, 3))
    shifts[5] = [0.003, 0.004, 0.0]                  # 5 mm
    d, size, scale = mapgeometry.deformation_field(shifts, np.array([[0.0, 1.0], [1.0, 0.0]]), 2, pts)
    assert scale == 20.0 and size[5] == pytest.approx(0.005) and d[5].tolist() == [0.004, 0.003]
    vec = mapgeometry.field_vectors(pts, d, size, scale)
    assert len(vec) == 1 and vec["x1"].iat[0] == pytest.approx(pts["x"].iat[5] + 0.08)
    assert vec["shift_mm"].iat[0] == pytest.approx(5.0)
    shifts[5] = [0.0, 0.0, -0.002]                   # a levelling network: the height drawn northward
    d, size, _ = mapgeometry.deformation_field(shifts, np.eye(2), 1, pts)
    assert d[5].tolist() == [0.0, -0.002] and size[5] == 0.002


def test_mapgeometry_image_residuals():
    value = np.array([10.0, 20.0, 30.0, 40.0])
    v = np.array([0.1, -0.2, 0.0, 0.5])
    w = np.array([1.0, -4.0, 0.5, 0.2])
    df = mapgeometry.image_residuals([("a", 0, 1), ("b", 2, 3)], value, v, w, 10.0)
    assert df["x1"].tolist() == [11.0, 30.0] and df["y1"].tolist() == [18.0, 45.0]
    assert df["abs_w"].tolist() == [4.0, 0.5] and df["obs"].tolist() == [0, 2]
    assert mapgeometry.image_residuals([], value, v, w, 10.0).empty
    (border,) = mapgeometry.image_border(df, (100, 50))
    assert border[2].tolist() == [100.0, 50.0]
    (border,) = mapgeometry.image_border(df.assign(x=[-30.0, 5.0]), (100, 50))     # centred image coordinates
    assert border[0].tolist() == [-50.0, -25.0]
    assert mapgeometry.image_border(df, None) == []


def test_geometry_index_and_full_reduced_mapping(st):
    p = st.problem
    index = geometry.problem_index(p)
    assert index["obs_points"] == geometry.observation_points(p) == st.problem_index()["obs_points"]
    assert len(index["labels"]) == p.n
    k = index["inc_pt"][0]
    assert geometry.observations_of_point(index, k) == geometry.observations_of_point(st.problem_index(), k)
    kept = np.array([i for i in range(p.n) if i != 3])
    red = geometry.reduced_index(kept, p.n, [0, 3, 4])
    assert red.tolist() == [0, -1, 3]
    full = geometry.expand(np.arange(kept.size, dtype=float), kept, p.n)
    assert np.isnan(full[3]) and full[4] == 3.0


def test_frames_are_the_states_tables(st):
    obs, pts = frames.frames(st.problem, st.results, st.reliability, st.kept, st.excluded,
                             st.problem_index(), st.robust)
    o, q = st.frames()
    assert obs.equals(o) and pts.equals(q)
    np.testing.assert_array_equal(obs["w"].to_numpy(), st.results.w)
    seg = frames.segments(pts, st.problem_index())
    assert seg["obs"].tolist() == st.problem_index()["line_obs"].tolist() and len(seg) > 0
    assert frames.variance_table(None, None).empty and frames.robust_suspects(None, st.kept, None).empty
    counts = frames.summary_counts(obs, pts, st.excluded, geometry.images(st.problem))
    assert counts["n_points"] == len(pts) and counts["n_excluded"] == 0


def test_specs_translate_to_the_cores_tests(st):
    spec = {"kind": "observation", "index": 2, "active": True, "label": "x"}
    H = specs.matrix(st.problem, st.results, st.kept, spec, st.problem_index())
    assert (H != selection(st.results.n, [2])).nnz == 0
    h = specs.evaluate(st.problem, st.results, st.reliability, st.kept, spec, st.problem_index())
    ref = st.reliability.test(selection(st.results.n, [2]), label="x")
    assert h.status == "test" and h.T == pytest.approx(ref.T, rel=1e-12) and h.test.T == h.T
    assert specs.evaluate(st.problem, st.results, st.reliability, st.kept, {**spec, "active": False},
                          st.problem_index()).status == "inactive"
    assert specs.describe(st.problem, spec, st.problem_index()).startswith("obs 2 ")
    assert specs.point(st.problem, spec, st.problem_index()) == st.problem_index()["obs_points"][2][-1]


def test_measures_and_sbase_are_the_states(st):
    m = len(st.problem.points.ids)
    i = int(np.nanargmax(st.reliability.mdb))
    old = st.selected_obs
    st.selected_obs = i
    try:
        np.testing.assert_array_equal(measures.observation_field(st.results, st.reliability, st.kept, st.problem.n, m, i),
                                      st.external_field()[1])
    finally:
        st.selected_obs = old
    assert not measures.observation_field(st.results, st.reliability, st.kept, st.problem.n, m, None).any()
    assert not measures.hypothesis_field(st.results, Outcome("refused", message="x"), m).any()
    e = measures.injected_error(st.results, st.reliability, st.kept, st.problem.n, i, 5.0)
    assert np.flatnonzero(e).tolist() == [i]
    rc = measures.risk_curve(0.1, 1.0, 1.0, st.reliability.delta0 ** 2, n=20)
    assert rc["grid"].size == rc["r"].size == 20
    assert set(sbase.datum_points(st.problem)) <= set(st.problem.points.ids)
    assert sbase.sbase_check(st.problem, st.results, [], "", st.options()) == "S-base: the problem's own datum."


def test_jobs_run_in_place_without_a_loop_and_cancel_only_task_threads():
    j = jobs.Jobs()
    assert j.on_loop(lambda: 7) == 7               # no loop_call: here
    j.cancel()
    j.check()                                      # not a task thread: nothing raised
    assert j.cancelled() is False
    j.reset()
    fut = j.start(lambda: (threading.current_thread().name, j.cancelled()))
    name, cancelled = fut.result(timeout=30)
    assert name.startswith("baarda-task") and cancelled is False
    assert jobs.file_key("/no/such/file", None) is None and jobs.cached(None) is None


def test_jobs_shared_computes_once_for_waiting_callers_and_retries_after_an_error():
    class Owner:                     # any object that can be weakly referenced
        pass

    owner, calls, gate, started = Owner(), [], threading.Event(), threading.Event()

    def compute():
        calls.append(threading.current_thread().name)
        started.set()
        gate.wait(30)
        return object()

    out = []
    threads = [threading.Thread(target=lambda: out.append(jobs.shared(owner, ("x", 1), compute)))
               for _ in range(6)]
    for t in threads:
        t.start()
    assert started.wait(30)
    gate.set()
    for t in threads:
        t.join(30)
    assert len(calls) == 1 and len(out) == 6 and all(v is out[0] for v in out)
    assert jobs.shared(owner, ("x", 2), compute) is not out[0] and len(calls) == 2   # another key

    def fail():
        raise ValueError("no")
    with pytest.raises(ValueError):
        jobs.shared(owner, ("y",), fail)
    assert jobs.shared(owner, ("y",), lambda: 5) == 5          # nothing kept from the failure
    for k in range(jobs.SHARED_MAX + 3):                        # bounded per owner
        jobs.shared(owner, ("z", k), lambda: k)
    assert len(jobs._SHARED[owner]) == jobs.SHARED_MAX


def test_sessions_on_one_cached_file_share_its_suspects_per_test_policy(tmp_path):
    """Sessions opened on a cached file compute its suspects once (issue 12: twenty sessions at
    once); a session with another α0 gets its own list, equal to one computed afresh."""
    from baarda.dashboard.suspects import _ranked, suspects

    path = Path(__file__).resolve().parents[2] / "data" / "demo-block.json"
    if not path.exists():
        pytest.skip("data/demo-block.json not generated")
    jobs.clear_cache()
    try:
        a, b = State(), State()
        assert a.load(path) and b.load_cached(path)
        assert b.results is a.results
        first = suspects(a)
        assert suspects(b) is first
        pd.testing.assert_frame_equal(first, _ranked(b))
        b.alpha0 = 0.01
        other = suspects(b)
        assert other is not first
        pd.testing.assert_frame_equal(other, _ranked(b))
        assert (other["decision"] == "rejected").sum() >= (first["decision"] == "rejected").sum()
    finally:
        jobs.clear_cache()



def test_a_block_without_strips_says_nothing_of_strips():
    """SfM blocks (Bundler, BAL, COLMAP) have no strips: the summary says "5 images", never
    "in 1 strips" (issue 31, item 10); a block with strips counts them in the right number."""
    from tests.extdata import EXTDATA, require_extdata

    from baarda.dashboard.state import State
    from baarda.dashboard.views.summary import block_text, summary_html

    st = State()
    assert st.load(require_extdata(EXTDATA / "bal" / "Balbianello.out")), st.error
    counts = frames.summary_counts(*st.frames(), st.excluded, geometry.images(st.problem))
    assert counts["n_images"] == 5 and counts["n_strips"] == 0
    html = summary_html(st.summary())
    assert "5 images<br>" in html and "strip" not in html
    assert block_text(6, 1) == "6 images in 1 strip" and block_text(24, 3) == "24 images in 3 strips"
    assert block_text(1, 0) == "1 image"
    images = [{"strip": "A"}, {"strip": "A"}, {"strip": "B"}, {"strip": ""}]
    assert frames.summary_counts(*st.frames(), st.excluded, images)["n_strips"] == 2


def test_ellipses_of_a_dense_block_at_half_the_point_spacing():
    """Thousands of points (Ladybug: 7,776): the 90th-percentile ellipse is half the mean point
    spacing, not 5 % of the frame (a solid mass of overlapping ellipses), issue 31, item 10."""
    rng = np.random.default_rng(4)
    n = 4000
    pts = mapgeometry.framed(pd.DataFrame({"id": [f"p{i}" for i in range(n)], "x": rng.uniform(0, 100, n),
                                           "y": rng.uniform(0, 100, n), "status": "adjusted"}))
    cov2 = (0.01 ** 2) * np.eye(2)[None].repeat(n, axis=0)
    paths, scale, big, off = mapgeometry.ellipse_paths(cov2, np.eye(2), pts)
    spacing = mapgeometry.mean_spacing(pts)
    assert spacing == pytest.approx(100 / np.sqrt(n), rel=0.02)
    assert 0.01 * scale <= 0.5 * spacing < 0.01 * scale * 2.5      # the round factor just below
    assert 0.01 * scale < 0.05 * 100 / 5
    # few points keep the 5 %-of-the-frame rule
    assert mapgeometry.mean_spacing(pts.iloc[:1]) == np.inf


def test_only_the_largest_ellipses_drawn_when_asked():
    pts = mapgeometry.framed(grid_points())
    sigma = np.linspace(0.001, 0.002, 100)
    cov2 = sigma[:, None, None] ** 2 * np.eye(2)
    full = mapgeometry.ellipse_paths(cov2, np.eye(2), pts)
    paths, scale, big, off = mapgeometry.ellipse_paths(cov2, np.eye(2), pts, most=10)
    assert scale == full[1] and big == full[2] and off == full[3] == 0
    assert np.isnan(paths[0][:, 0]).sum() == 9                     # ten ellipses, one glyph
    xy = paths[0][np.isfinite(paths[0][:, 0])]
    centres = pts[["x", "y"]].to_numpy()
    nearest = np.argmin(np.hypot(xy[:, None, 0] - centres[None, :, 0], xy[:, None, 1] - centres[None, :, 1]), axis=1)
    assert set(nearest.tolist()) == set(range(90, 100))             # the ten largest σ
