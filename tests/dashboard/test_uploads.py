"""The uploads of a session (issue 25): what a closed session's uploads held is freed, and the
upload widget shows a file's name as plain text."""

from __future__ import annotations

import gc
import glob
import tempfile
import weakref
from pathlib import Path

import pytest

pytest.importorskip("panel")

from baarda.dashboard import jobs  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402
from baarda.dashboard.uploads import BoundedDropper, Uploads  # noqa: E402
from baarda.dashboard.views import FilePanel  # noqa: E402

LEVELLING = Path(__file__).resolve().parents[2] / "data" / "demo-levelling.gkf"


def test_closing_sessions_frees_what_their_uploads_held(tmp_path, monkeypatch):
    """Sessions that uploaded a file and ended hold none of its data any more, although Panel
    may keep the session's objects (here: the panels and states stay referenced)."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    data = LEVELLING.read_bytes()
    sessions, refs = [], []
    for k in range(3):
        st = State()
        panel = FilePanel(state=st)
        assert panel.receive(f"upload-{k}.gkf", data), st.error
        assert st.results is not None and st.file_name == f"upload-{k}.gkf"
        st.frames()
        st.add_hypothesis({"kind": "observation", "index": 0})
        refs += [weakref.ref(st.problem), weakref.ref(st.results), weakref.ref(st.snapshot),
                 weakref.ref(st.analysis)]
        sessions.append(panel)
    assert all(r() is not None for r in refs)
    for panel in sessions:
        panel.state.jobs.closed = True
        panel.uploads.close()                 # what the app does when the session ends
    gc.collect()
    alive = [r() for r in refs if r() is not None]
    assert alive == [], f"{len(alive)} objects of closed sessions still held: {[type(a).__name__ for a in alive]}"
    assert all(p.state.results is None and p.state.outcomes == [] for p in sessions)
    assert glob.glob(str(tmp_path / "baarda-upload-*")) == []
    assert jobs.cached(None) is None


def test_the_upload_list_shows_a_name_as_plain_text():
    """A name with a right-to-left override, a zero-width space and an escape arrives: the
    widget's own list hides the browser's name and the panel shows it neutralised."""
    st = State()
    panel = FilePanel(state=st)
    name = "gnp\u202eexe.\u200bjson\x1b[2J"
    panel.upload._process_event(type("E", (), {"event_name": "upload_event", "data": {
        "name": name, "chunk": 1, "total_chunks": 2, "data": b"{}"}})())
    shown = panel.upload.receiving
    assert shown and not any(c in shown for c in "\u202e\u200b\x1b")
    html = str(panel.receiving.object)
    assert "Receiving" in html and not any(c in html for c in "\u202e\u200b\x1b")
    assert BoundedDropper.HIDE_NAMES in panel.upload.stylesheets
    assert isinstance(panel.uploads, Uploads)
