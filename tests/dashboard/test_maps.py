"""Maps that read on real blocks (issue 15, item 1), without a browser.

- the frame is robust: far points are moved to its edge, flagged and listed; the Gama-sized sets
  and the demo keep their full extent;
- on Ladybug (BAL, ``../shared/extdata/bal``) every map's frame holds the real points spread
  over it (the middle 90 % of the points span most of the frame), the far points are listed, the
  axes have no unit and the precision title counts the off-scale ellipses instead of "max 2e12 mm";
- the |w| colour scale reaches the largest |w| with the critical value as a bin edge;
- the image residuals' exaggeration follows the block's own scale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("panel")

import holoviews as hv  # noqa: E402
from bokeh.models import ColorBar  # noqa: E402

from baarda.dashboard import geometry  # noqa: E402
from baarda.dashboard import render  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402
from baarda.dashboard.mapgeometry import FRAME_MIN_POINTS, far_note, framed, robust_box, w_levels  # noqa: E402
from baarda.dashboard.views import MAP_VIEWS, PrecisionMap, ResidualMap  # noqa: E402
from tests.extdata import EXTDATA, require_extdata  # noqa: E402

hv.extension("bokeh", logo=False)

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo-block.json"


def test_robust_box_moves_far_points_to_the_edge():
    rng = np.random.default_rng(3)
    x, y = rng.uniform(0, 10, 500), rng.uniform(0, 5, 500)
    x[:4] = [1e6, -3e5, 5.0, 5.0]
    y[:4] = [0.0, 2.0, 7e7, -np.inf]
    pts = pd.DataFrame({"id": [f"p{i}" for i in range(500)], "x": x, "y": y})
    f = framed(pts)
    assert f["far"].tolist()[:4] == [True] * 4 and f["far"].sum() == 4
    x0, x1, y0, y1 = robust_box(x, y)
    assert -10 < x0 <= 0.1 and 9.9 <= x1 < 20 and -10 < y0 <= 0.1 and 4.9 <= y1 < 15
    assert f["x"].between(x0, x1).all() and f["y"].between(y0, y1).all()
    assert f["x"].iat[0] == x1 and f["x"].iat[1] == x0 and f["y"].iat[2] == y1 and f["y"].iat[3] == y0
    assert f["x_true"].iat[0] == 1e6
    note = far_note(f)
    assert note.startswith("4 far point(s)")
    assert note.index("p3 (") < note.index("p2 (") < note.index("p0 (") < note.index("p1 (")     # farthest first
    # the ordinary points are where they were
    np.testing.assert_array_equal(f["x"].to_numpy()[4:], x[4:])
    # a small set keeps its full extent (a network with one remote point is not clamped)
    small = pts.iloc[:FRAME_MIN_POINTS - 1].assign(y=0.0)
    assert small["x"].iat[0] == 1e6 and not framed(small)["far"].any()


def test_w_levels_reach_the_largest_w_with_the_critical_value_an_edge():
    lv = w_levels(3.29, 13.42)
    assert lv[0] == 0 and lv[2] == 3.29 and lv[-1] >= 13.42 and len(lv) == 8
    assert np.all(np.diff(lv) > 0)
    # 4.5 and 13.4 fall in different bins above the critical value
    assert np.searchsorted(lv, 4.5) < np.searchsorted(lv, 13.4)
    assert w_levels(3.29, 1.0)[-1] == pytest.approx(1.5 * 3.29)


def test_demo_maps_keep_every_point_and_metres():
    if not DEMO.exists():
        pytest.skip("data/demo-block.json not generated")
    st = State(DEMO)
    assert geometry.display_xy(st.problem, st.results.coordinates)[2:] == ("X [m]", "Y [m]")
    view = ResidualMap(state=st)
    assert view.far_count() == 0 and not view.far_note.visible
    fig = render.figure(view.dmap)
    (bar,) = fig.select(type=ColorBar)          # the |w| scale drawn: its ticks are the levels
    fig_levels = list(bar.ticker.ticks)
    assert fig_levels[2] == round(st.reliability.critical, 2)
    assert fig_levels[-1] >= np.nanmax(np.abs(st.results.w))
    # the largest image residual drawn at most 30 % of the image (the 20σ error), a round factor
    assert st.exaggeration in (100.0, 200.0, 500.0, 1000.0)
    v = np.abs(st.results.v[np.char.startswith(np.asarray(st.problem.info.kind, dtype=str), "image")])
    assert st.exaggeration * v.max() * st.problem_index()["factor"][0].max() <= 0.3 * 230


@pytest.fixture(scope="module")
def ladybug():
    path = require_extdata(EXTDATA / "bal" / "problem-49-7776-pre.txt")
    return State(path)


def test_ladybug_maps_spread_the_real_points_and_list_the_far_ones(ladybug):
    st = ladybug
    assert geometry.display_xy(st.problem, st.results.coordinates)[2:] == ("X", "Y")          # BAL: no unit
    _, raw = st.frames()
    for V in MAP_VIEWS:
        view = V(state=st)
        plot = render.figure(view.dmap)
        pts = view.points()
        far = pts["far"].to_numpy()
        assert 0 < far.sum() < 0.05 * len(pts), V.key
        assert view.far_note.visible and f"{far.sum()} far point(s)" in view.far_note.object
        x0, x1 = plot.x_range.start, plot.x_range.end
        y0, y1 = plot.y_range.start, plot.y_range.end
        # the frame is the points' frame, not the drifting points' (was ±1e6)
        assert x1 - x0 < 20 and y1 - y0 < 20, (V.key, x0, x1, y0, y1)
        # the middle 90 % of the real points span a good part of the frame
        inner = raw[~far]
        span = max(np.ptp(np.percentile(inner["x"], [5, 95])), np.ptp(np.percentile(inner["y"], [5, 95])))
        assert span > 0.3 * max(x1 - x0, y1 - y0), V.key
        title = view.title()
        assert "e+" not in title and " mm" not in title, title
        if V.key == "precision":
            assert "off-scale, not drawn" in title
    # image residuals: drawn at the block's scale (was ×0.01, invisible)
    assert st.exaggeration >= 5.0


def test_levelling_schematic_gives_every_benchmark_its_own_place():
    path = Path(__file__).resolve().parents[2] / "data" / "demo-levelling.gkf"
    if not path.exists():
        pytest.skip("data/demo-levelling.gkf not generated")
    from baarda.dashboard.geometry import schematic_layout

    st = State(path)
    x, y = schematic_layout(st.problem)
    xy = np.column_stack([x, y])
    d = np.sqrt(((xy[:, None] - xy[None]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    assert len(xy) == 8 and d.min() > 0.2 * np.ptp(xy)      # was: 8 benchmarks on 4 positions


def test_criterion_map_holds_the_network_and_its_arrows():
    from tests.extdata import GAMA

    from baarda.dashboard.geometry import display_matrix, display_xy
    from baarda.dashboard.views.criterion import ARROW_SHARE, CriterionView

    path = require_extdata(GAMA / "gama-local.gkf")
    st = State(path)
    view = CriterionView(state=st)
    c = st.criterion
    assert c is not None
    opts = view.pattern_map().opts.get().kwargs
    (x0, x1), (y0, y1) = opts["xlim"], opts["ylim"]
    e, n, _, _ = display_xy(st.problem, st.results.coordinates)
    d = (display_matrix(st.problem) @ c["pattern"].T).T
    scale = ARROW_SHARE * max(np.ptp(e), np.ptp(n)) / np.hypot(*d.T).max()
    for x, y in ((e, n), (e + scale * d[:, 0], n + scale * d[:, 1])):
        assert x.min() > x0 and x.max() < x1 and y.min() > y0 and y.max() < y1
    # equal scales on both axes, few enough ticks for 7-digit coordinates
    assert (x1 - x0) / opts["frame_width"] == pytest.approx((y1 - y0) / opts["frame_height"], rel=1e-9)
    assert opts["xticks"] <= 4
    assert view.C1.format and view.C1.value == c["C1"]


def test_sbase_label_names_a_large_datum_briefly(ladybug):
    """Ladybug's free datum is every one of its 7,776 points: the S-base label says so in a few
    words (it listed every id on one line, across the right panel)."""
    label = PrecisionMap(state=ladybug).sbase.label
    n = len(ladybug.problem.points.ids)
    assert f"all {n:,} points" in label and len(label) < 80
    if DEMO.exists():                                   # a controlled block: its control
        assert "its fixed / weighted points" in PrecisionMap(state=State(DEMO)).sbase.label


def test_colour_bar_titles_fit_the_shortest_bar(demo_path):
    """A colour bar's title runs along the bar and was cut where longer (the w map's "largest |w|
    per point (critical 3.29: rejected above)", issue 31, item 10): every map's title fits the
    shortest bar, measured at the mean character width of Bokeh's colour bar title."""
    import holoviews as hv
    from bokeh.models import ColorBar

    from baarda.dashboard.state import State
    from baarda.dashboard.views.maps import COLORBAR_PX, MDBMap, ExternalMap, RedundancyMap, ResidualMap, colorbar_title

    assert colorbar_title("x " * 100).endswith("…") and len(colorbar_title("x " * 100)) * 6.3 <= COLORBAR_PX
    st = State()
    assert st.load(demo_path), st.error
    for V in (RedundancyMap, ResidualMap, ExternalMap, MDBMap):
        fig = hv.render(V(state=st).static(), backend="bokeh")
        titles = [r.title for r in fig.right + fig.left if isinstance(r, ColorBar)]
        assert titles, V
        for t in titles:
            assert "…" not in t and len(t) * 6.3 <= COLORBAR_PX, (V.__name__, t)
        assert min(fig.frame_height, fig.frame_width) >= 260 > COLORBAR_PX


def point_marker_sizes(st) -> dict:
    """Per map, the sizes of the markers drawn at the block's points (a scatter glyph whose
    source holds one row per point; rings and selections are other glyphs)."""
    from bokeh.models import GlyphRenderer, Scatter

    n = len(st.problem.points.ids)
    out = {}
    for V in MAP_VIEWS:
        plot = render.figure(V(state=st).dmap)
        sizes = {r.glyph.size for r in plot.select(GlyphRenderer) if isinstance(r.glyph, Scatter)
                 and isinstance(r.glyph.size, (int, float)) and len(r.data_source.data.get("id", [])) == n}
        if sizes:
            out[V.__name__] = sizes
    return out


def test_point_markers_are_dots_on_big_blocks(ladybug):
    """Issue 31, item 10: Ladybug's 7,776 point markers at 4-6 px were one solid mass on the
    precision map; above DENSE_POINTS points they are 2-px dots, a small block keeps its markers."""
    from baarda.dashboard.views.maps import DENSE_POINTS, point_size

    assert point_size(pd.DataFrame(index=range(500))) == 12
    assert point_size(pd.DataFrame(index=range(DENSE_POINTS))) == 6
    assert point_size(pd.DataFrame(index=range(DENSE_POINTS + 1))) == 2
    big = point_marker_sizes(ladybug)
    assert len(ladybug.problem.points.ids) > DENSE_POINTS and "PrecisionMap" in big, big
    assert all(max(s) <= 2 for s in big.values()), big
    small = point_marker_sizes(State(DEMO))
    assert "PrecisionMap" in small and all(min(s) >= 9 for s in small.values()), small
