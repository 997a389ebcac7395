"""The image view on real SfM blocks (issue 31, item 7): the typical residual vectors show beside
their points (hollow markers under the vectors, sized from them; a factor that draws the median
vector at least ``MEDIAN_PX`` pixels), the selected point is ringed, and COLMAP's images are drawn
with y down as their pixels are (BAL and Bundler keep y up)."""

from __future__ import annotations

import holoviews as hv
import numpy as np
import pytest

from baarda.dashboard import geometry
from baarda.dashboard.state import State
from baarda.dashboard.views.image import IMAGE_FRAME, MEDIAN_PX, ImageResidualView
from tests.extdata import EXTDATA, require_extdata
from tests.test_point_at_centre import write_model

hv.extension("bokeh", logo=False)


@pytest.fixture(scope="module")
def colmap(tmp_path_factory):
    st = State()
    assert st.load(write_model(tmp_path_factory.mktemp("colmap") / "sparse", with_point=False)), st.error
    return st


def layers(view):
    overlay = view._render()
    border, pts, vec, ring = overlay.values()
    return overlay, pts, vec, ring


def test_median_vector_visible_markers_under_it(colmap):
    view = ImageResidualView(state=colmap)
    colmap.selected_image = geometry.images(colmap.problem)[0]["id"]
    df = view.data()
    ex = view.exaggeration(df)
    med = np.median(np.hypot(df["vx"], df["vy"]))
    drawn = med * ex * IMAGE_FRAME / view.span(df)
    assert drawn >= MEDIAN_PX - 1e-9 and ex >= colmap.exaggeration
    assert ex == colmap.exaggeration or drawn < 5 * MEDIAN_PX        # the least round factor, not more
    overlay, pts, vec, ring = layers(view)
    assert isinstance(vec, hv.Segments) and overlay.values().index(vec) > overlay.values().index(pts)
    o = hv.Store.lookup_options("bokeh", pts, "style").kwargs
    assert o["fill_alpha"] == 0 and o["size"] <= max(3.0, 0.5 * drawn) + 1e-9
    x1 = vec.data["x1"].to_numpy() - vec.data["x"].to_numpy()
    np.testing.assert_allclose(x1, ex * df["vx"].to_numpy())
    assert f"×{ex:g}" in overlay.opts.get().kwargs["title"].replace("\n", " ")


def test_selected_point_is_ringed(colmap):
    view = ImageResidualView(state=colmap)
    colmap.selected_image = geometry.images(colmap.problem)[0]["id"]
    df = view.data()
    name = df["point"].iat[3]
    k = [str(p) for p in colmap.problem.points.ids].index(name)
    colmap.param.update(selected_obs=None, selected_point=k)
    ring = layers(view)[3]
    assert ring.data["point"].tolist() == [name]
    assert ring.data[["x", "y"]].to_numpy().tolist() == df.loc[df["point"] == name, ["x", "y"]].to_numpy().tolist()
    colmap.param.update(selected_point=None, selected_obs=int(df["obs"].iat[5]) + 1)   # its y observation
    assert layers(view)[3].data["point"].tolist() == [df["point"].iat[5]]
    colmap.param.update(selected_point=None, selected_obs=None)
    assert len(layers(view)[3].data) == 0


def test_colmap_y_down_bal_y_up(colmap):
    view = ImageResidualView(state=colmap)
    colmap.selected_image = geometry.images(colmap.problem)[0]["id"]
    overlay = view._render()
    fig = hv.render(overlay, backend="bokeh")
    assert view.y_down() and fig.y_range.start > fig.y_range.end        # pixel y grows downwards
    assert "(down)" in fig.yaxis[0].axis_label
    bal = State()
    assert bal.load(require_extdata(EXTDATA / "bal" / "Balbianello.out")), bal.error
    v2 = ImageResidualView(state=bal)
    bal.selected_image = geometry.images(bal.problem)[0]["id"]
    fig2 = hv.render(v2._render(), backend="bokeh")
    assert not v2.y_down() and fig2.y_range.start < fig2.y_range.end
