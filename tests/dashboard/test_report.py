"""The client report (issue 15, item 5) and the CSV downloads, without a browser.

The verdict is checked against the summary's own numbers on three files whose cases differ
(global test failed with rejections, passed with no rejection, not converged); the report carries
no session state (a selection, an active hypothesis' deformation field) and no toolbar; the CSV
tables round-trip through pandas to the app's tables, and a hostile id is text in a spreadsheet.
The printed page count is tested in Chromium (tests/browser/test_report.py).
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from baarda.adjust import Options, adjust
from baarda.build import read_problem
from baarda.dashboard.report import caption, report_html, verdict
from baarda.dashboard.state import State
from baarda.dashboard.tables import TABLES, csv_bytes, table_csv

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def demo(demo_adjustment):
    return demo_adjustment


def test_verdict_of_the_demo_block_names_its_rejections(demo):
    st = State.from_adjustment(demo)
    s, obs = st.summary(), st.frames()[0]
    level, head, said = verdict(s, obs)
    assert level == "bad" and head == f"Not acceptable as it stands: {s['n_rejected']} rejected observations."
    worst = int(obs["w"].abs().idxmax())
    assert any(f"observation {worst} " in x and f"|w| = {abs(obs.at[worst, 'w']):.3g}" in x for x in said)
    assert any("global test fails" in x for x in said)
    assert any(f"{s['n_uncontrolled']} observations are hardly controlled" in x for x in said)
    ext = obs.loc[obs["r"] >= 0.1, "ext"].max()
    assert any(f"δ̄0 = {ext:.3g}" in x for x in said)


def test_verdict_of_a_consistent_levelling():
    adj = adjust(read_problem(DATA / "demo-levelling.gkf"))
    st = State.from_adjustment(adj)
    s, obs = st.summary(), st.frames()[0]
    level, head, said = verdict(s, obs)
    # the levelling demo: what the summary says decides the level
    if s["n_rejected"] == 0 and s["global_test"]["passed"] and s["n_uncontrolled"] == 0:
        assert level == "ok" and head.startswith("Consistent")
    else:
        assert level in ("bad", "warn")
    assert any(("passes" in x) == bool(s["global_test"]["passed"]) for x in said if "global test" in x)


def test_verdict_of_an_unconverged_adjustment():
    adj = adjust(read_problem(DATA / "demo-block.json"), Options(max_iter=1))
    st = State.from_adjustment(adj)
    level, head, said = verdict(st.summary(), st.frames()[0])
    assert level == "bad" and head.startswith("Not converged") and "after 1 iterations" in said[0]
    html = report_html(adj)
    assert "class='notconv'><b>NOT converged</b>" in html


def test_report_has_no_session_state_and_no_toolbar(demo):
    st = State.from_adjustment(demo)
    st.param.update(selected_obs=int(st.frames()[0]["w"].abs().idxmax()))
    st.add_hypothesis({"kind": "observation", "index": 4})
    html = report_html(demo, state=st)
    assert "selection-rings" not in html and "∇0x of obs" not in html
    assert html.count('"toolbar_location":null') == 4            # every map without its toolbar
    assert "select an observation" not in html
    # the reviewer's hypothesis is listed with its decision, the sections are three pages
    assert "Hypotheses tested by the reviewer" in html
    assert html.count('<section class="page') == 3
    assert not re.search(r"<(script|link)[^>]+(src|href)=\"https?://", html)


def test_caption_drops_app_instructions():
    assert caption("External reliability δ̄0 (select an observation or a hypothesis: its ∇0x)") == \
        "External reliability δ̄0"
    assert caption("Redundancy r_i (red < 0.1 uncontrolled)") == "Redundancy r_i (red < 0.1 uncontrolled)"


def test_csv_tables_round_trip_to_the_app_tables(demo):
    st = State.from_adjustment(demo)
    for name, make in TABLES.items():
        raw = table_csv(st, name).getvalue()
        assert raw.startswith(b"\xef\xbb\xbf")              # BOM: spreadsheets read UTF-8
        back = pd.read_csv(io.BytesIO(raw), encoding="utf-8-sig")
        ref = make(st)
        assert len(back) == len(ref) and list(back.columns) == [str(c) for c in ref.columns]
        assert not any(str(c).startswith("Unnamed") for c in back.columns)     # no index column
        num = [c for c in ref.columns if pd.api.types.is_float_dtype(ref[c])]
        for c in num:
            np.testing.assert_allclose(back[c].to_numpy(dtype=float), ref[c].to_numpy(dtype=float),
                                       rtol=1e-12, equal_nan=True)


def test_csv_text_is_never_a_formula():
    df = pd.DataFrame({"id": ["=HYPERLINK(\"http://x\")", "+1", "-2", "@A1", "P1\x1b[2J"], "w": [1.0, -2.0, 3, 4, 5]})
    back = pd.read_csv(io.BytesIO(csv_bytes(df)), encoding="utf-8-sig")
    assert back["id"].tolist()[:4] == ["'=HYPERLINK(\"http://x\")", "'+1", "'-2", "'@A1"]
    assert "\x1b" not in back["id"].iat[4]
    assert back["w"].tolist() == [1.0, -2.0, 3.0, 4.0, 5.0]      # numbers stay numbers


def test_file_panel_offers_the_report_and_every_table(demo):
    from baarda.dashboard.views.controls import FilePanel

    st = State.from_adjustment(demo)
    panel = FilePanel(state=st, render_report=report_html)
    assert set(panel.tables) == set(TABLES)
    for name, widget in panel.tables.items():
        assert widget.filename == f"baarda-{name}.csv"
        raw = widget.callback().getvalue()
        assert raw == table_csv(st, name).getvalue()
    html = panel.report().getvalue()
    assert html.count('<section class="page') == 3


def test_report_does_not_use_bokehs_current_document(demo):
    """A served session's document left on Bokeh's process-wide ``curdoc()`` stack and destroyed
    by the server (as CI saw after the browser tests: "'Document' object has no attribute
    '_theme'") is not the report's: it renders into documents of its own, with the same result."""
    from bokeh.document import Document
    from bokeh.io.doc import curdoc, patch_curdoc

    expected = report_html(demo)
    session = Document()
    session.remove_on_change = lambda *_: None        # destroy() of a document never served
    with patch_curdoc(session):
        session.destroy(None)
        assert curdoc() is session
        with pytest.raises(AttributeError):
            session.theme = "dark_minimal"              # what hv.render and components did
        got = report_html(demo)
    ids = re.compile(r'[0-9a-f]{8}-[0-9a-f-]{27}|"p\d+"|\bp\d{3,}\b|\d{4}-\d\d-\d\d[ T][\d:]+')
    assert ids.sub("", got) == ids.sub("", expected)
