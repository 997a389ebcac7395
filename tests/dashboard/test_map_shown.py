"""A map that is not on screen redraws nothing while the state changes, and catches up once
shown (issue 29 item 1: the views not on screen are updated when shown)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("panel")

import holoviews as hv  # noqa: E402
import panel as pn  # noqa: E402
from bokeh.document import Document  # noqa: E402
from bokeh.models import ColumnDataSource  # noqa: E402

from baarda.dashboard.state import State  # noqa: E402
from baarda.dashboard.views import MDBMap  # noqa: E402

hv.extension("bokeh", logo=False)
LEVELLING = Path(__file__).resolve().parents[2] / "data" / "demo-levelling.gkf"


def mdb_data(root) -> list[np.ndarray]:
    return [np.asarray(m.data["mdb_sigma"], dtype=float).copy()
            for m in root.select({"type": ColumnDataSource}) if "mdb_sigma" in m.data]


def test_a_hidden_map_catches_up_when_shown():
    st = State(LEVELLING)
    view = MDBMap(state=st)
    root = pn.panel(view).get_root(Document())
    before = mdb_data(root)
    assert before
    d_old = st.reliability.delta0
    view.set_shown(False)
    calls = []
    real = view.points
    view.points = lambda: calls.append(1) or real()
    st.alpha0 = 0.01
    assert calls == [] and all(np.array_equal(a, b, equal_nan=True) for a, b in zip(mdb_data(root), before))
    view.set_shown(True)
    ratio = st.reliability.delta0 / d_old
    # redrawn once shown, with the new policy's MDBs
    for b, a in zip(before, mdb_data(root)):
        np.testing.assert_allclose(a, b * ratio, rtol=1e-9)
    st.alpha0 = 0.001                 # shown: follows at once
    for b, a in zip(before, mdb_data(root)):
        np.testing.assert_allclose(a, b, rtol=1e-9)
