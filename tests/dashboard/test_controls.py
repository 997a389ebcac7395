"""Real controls (issue 15, item 4), without a browser: the hypothesis panel's dropdowns have a
selection, the "active" column is a checkbox (typing "false" deactivates), a new hypothesis is the
highlighted row, and rank-deficient hypotheses say so and name the points that absorb the error.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("panel")

import holoviews as hv  # noqa: E402
from bokeh.models.widgets.tables import CheckboxEditor  # noqa: E402

from baarda.dashboard import geometry  # noqa: E402
from baarda.dashboard import render  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402
from baarda.dashboard.views.hypotheses import HypothesisPanel  # noqa: E402
from tests.extdata import GAMA, require_extdata  # noqa: E402

hv.extension("bokeh", logo=False)

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo-block.json"


@pytest.fixture(scope="module")
def demo(demo_path):
    return demo_path


def test_dropdowns_open_with_a_selection(demo):
    st = State(demo)
    panel = HypothesisPanel(state=st)
    assert panel.kind.value == "observation"
    for kind in ("image-point", "transfer", "control", "group", "ap-group"):
        panel.kind.value = kind
        shown = {"image-point": [panel.point, panel.image], "transfer": [panel.point],
                 "control": [panel.point], "group": [panel.group], "ap-group": [panel.camera, panel.ap_group]}
        for w in shown[kind]:
            values = list(w.options.values()) if isinstance(w.options, dict) else list(w.options)
            assert values and w.value in values, (kind, w.name)


def test_active_is_a_checkbox_and_false_deactivates(demo):
    st = State(demo)
    panel = HypothesisPanel(state=st)
    st.add_hypothesis({"kind": "observation", "index": 301})
    st.add_hypothesis({"kind": "observation", "index": 317})
    assert isinstance(panel.results.editors["active"], CheckboxEditor)
    # the new hypothesis is the highlighted row, not the previous one
    assert panel.results.selection == [1] and st.selected_hypothesis == 1
    panel.edited(SimpleNamespace(column="active", row=0, value="false"))
    assert st.hypotheses[0]["active"] is False and st.outcomes[0].status == "inactive"
    panel.edited(SimpleNamespace(column="active", row=0, value=True))
    assert st.hypotheses[0]["active"] is True
    df = panel.frame()
    assert df["decision"].tolist() == ["rejected", "rejected"]


def test_partly_testable_image_point_names_the_absorbing_point(demo):
    st = State(demo)
    panel = HypothesisPanel(state=st)
    # P00001 is seen in two images: one of its two image-point dimensions is absorbed by it
    st.add_hypothesis({"kind": "image-point", "image": "101", "point": "P00001"})
    h = st.outcomes[0].test
    assert h.q == 1 and h.H.shape[1] == 2
    row = panel.frame().iloc[0]
    assert row["decision"].startswith("rejected") and "tests 1 of 2 dimensions" in row["decision"]
    assert "absorbed by the coordinates of P00001" in row["decision"]
    el = panel.ellipse_plot()
    assert "q = 1 of 2" in el.opts.get().kwargs["title"]
    assert "inf" not in el.opts.get().kwargs["title"]


def test_untestable_hypothesis_says_why():
    path = require_extdata(GAMA / "fixed-azimuth.gkf")
    st = State(path)
    assert st.results.uncontrolled[0]
    panel = HypothesisPanel(state=st)
    st.add_hypothesis({"kind": "observation", "index": 0})
    h = st.outcomes[0].test
    assert h.q == 0
    row = panel.frame().iloc[0]
    assert row["decision"].startswith("not testable: rank-deficient (W = 0)")
    assert "absorbed by" in row["decision"]
    assert row["∇ŝ"] == "" and row["T"] is None or np.isnan(row["T"])
    assert panel.ellipse_plot().opts.get().kwargs["title"].startswith("Not testable")


def test_critical_ellipse_is_drawn_over_the_lower_bound(demo):
    st = State(demo)
    panel = HypothesisPanel(state=st)
    st.add_hypothesis({"kind": "image-point", "image": "302", "point": "P05003"})
    h = st.outcomes[0].test
    assert h.q == 2
    el = panel.ellipse_plot()
    lower, crit = el.get(0), el.get(1)
    assert lower.label.startswith("∇0s") and crit.label.startswith("critical")
    f = st.problem_index()["factor"][0][geometry.image_point_rows(st.problem_index(), "302", "P05003")[0]]
    for path, level in ((lower, h.delta0 ** 2), (crit, h.critical_T)):
        xy = path.split()[0].array([0, 1]) / f
        # on the ellipse sᵀ W s = level (F80 eq. 12-13), W the core's
        np.testing.assert_allclose(np.einsum("ni,ij,nj->n", xy, h.W, xy), level, rtol=1e-9)
    # the estimate lies outside the critical ellipse: the hypothesis is rejected
    assert h.rejected_T and h.nabla @ h.W @ h.nabla > h.critical_T


def test_sbase_lesson_on_a_controlled_block(demo):
    from dataclasses import replace

    from baarda.adjust import adjust
    from baarda.dashboard import sbase as lesson
    from baarda.datum import Datum
    from baarda.dashboard.views.precision import PrecisionMap
    from baarda.model.problem import without

    st = State(demo)
    view = PrecisionMap(state=st)
    assert view.free.visible and "no datum defect" in view.note.object
    own = view.point_cov2()
    st.sbase = ["P00001", "P06008", "P00008"]
    np.testing.assert_array_equal(view.point_cov2(), own)      # controlled: the S-base changes nothing
    view.free.value = True
    assert "free block" in view.title() and "Free-block view" in view.note_html()
    free = view.point_cov2()
    assert not np.allclose(free, own)
    # the free block is adjusted once per adjustment, kept in the state's public cache
    assert st.free_block_cache["results"] is st.results
    assert lesson.free_block(st) is st.free_block_cache["free"]
    # the S-transformed free block equals the free block adjusted with that S-base as its datum (to
    # the nonlinear refit's other linearisation point)
    reduced, _ = without(st.results.problem, lesson.control_rows(st.results.problem))
    ref = adjust(replace(reduced, datum=Datum("free", ("P00001", "P06008", "P00008"))), st.options())
    refcov = ref.point_cov[:, :2, :2]
    np.testing.assert_allclose(free, refcov, rtol=2e-2, atol=2e-3 * np.abs(refcov).max())
    assert np.abs(free - own).max() > 0.1 * np.abs(refcov).max()
    # another S-base, other ellipses; r and w of the free block do not change
    other = lesson.free_point_cov2(st, ["P00004", "P06004", "P03001"])
    assert not np.allclose(other, free)
    render.figure(view.dmap)
    render.figure(view.compare.object)            # the comparison pane, after the last change
