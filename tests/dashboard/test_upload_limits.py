"""The served app's own limits on what a page sends and on what an upload holds (issue 25 item 8),
checked on the server's side: :class:`baarda.dashboard.views.controls.BoundedDropper` refuses
upload chunks past the limit as they arrive (a page script can change the widget's limit, or send
chunks itself); a compressed upload is read within :data:`UPLOAD_MAX_CONTENT`; a closed page's
reading and adjustment stop. The transport's limits (frame size, buffers per message) are tested
against a running server in ``test_serve_guard.py``."""

from __future__ import annotations

import bz2
from pathlib import Path
from types import SimpleNamespace

import pytest

from baarda.dashboard.views.controls import MAX_UPLOAD_MB, UPLOAD_CHUNK, BoundedDropper, FilePanel

MB = 1024 * 1024


def _event(name, chunk, total, data, kind="text/plain"):
    return SimpleNamespace(event_name="upload_event",
                           data={"name": name, "chunk": chunk, "total_chunks": total, "data": data, "type": kind})


def test_chunks_past_the_limit_refused_as_they_arrive():
    refused = []
    w = BoundedDropper(10 * MB, refused.append, chunk_size=UPLOAD_CHUNK)
    piece = b"1" * (4 * MB)
    w._process_event(_event("a.txt", 1, 100, piece))          # a page that announces 100 chunks
    assert refused == ["a.txt"] and w.held_bytes() == 0 and not w._file_buffer
    refused.clear()
    w._process_event(_event("b.txt", 1, 3, piece))
    w._process_event(_event("b.txt", 2, 3, piece))
    assert w.held_bytes() == 8 * MB and not refused
    w._process_event(_event("c.txt", 1, 2, piece))            # a second file at once: over 10 MB in all
    assert refused == ["c.txt"] and w.held_bytes() == 0 and not w._file_buffer
    w._process_event(_event("c.txt", 2, 2, piece))            # the rest of a refused upload is ignored
    assert w.held_bytes() == 0 and not w._file_buffer and not w.value


def test_chunk_sizes_lied_about_and_chunks_out_of_order_refused():
    refused = []
    w = BoundedDropper(10 * MB, refused.append, chunk_size=UPLOAD_CHUNK)
    w._process_event(_event("a.txt", 1, 2, b"1" * (11 * MB)))  # one chunk larger than the limit
    assert refused == ["a.txt"] and w.held_bytes() == 0
    w._process_event(_event("b.txt", 1, 3, b"1"))
    w._process_event(_event("b.txt", 3, 3, b"1"))             # chunk 2 skipped
    assert refused[-1] == "b.txt" and not w._file_buffer
    for bad in ({"name": "x", "chunk": "1", "total_chunks": 1, "data": b""}, {"name": 5}, {},
                {"name": "y", "chunk": 1, "total_chunks": 1, "data": 123}):
        w._process_event(SimpleNamespace(event_name="upload_event", data=bad))
    assert not w.value and w.held_bytes() == 0


def test_upload_within_the_limit_arrives_whole():
    w = BoundedDropper(10 * MB, None, chunk_size=UPLOAD_CHUNK)
    w._process_event(_event("ok.bin", 1, 2, b"a" * (4 * MB), "application/octet-stream"))
    w._process_event(_event("ok.bin", 2, 2, b"b" * 10, "application/octet-stream"))
    assert w.value["ok.bin"] == b"a" * (4 * MB) + b"b" * 10 and w.held_bytes() == 0


def test_the_panel_says_an_upload_was_too_large():
    from baarda.dashboard.state import State

    panel = FilePanel(state=State())
    panel.upload._process_event(_event("big.txt", 1, 1000, b"1" * 10))
    assert panel.state.error == f"big.txt is larger than {MAX_UPLOAD_MB} MB; run `baarda` on it instead."


def test_compressed_upload_read_within_the_upload_ceiling(tmp_path):
    """A 30 KB .bz2 upload holding 600 MB is refused once its content passes UPLOAD_MAX_CONTENT,
    while it is read."""
    from baarda.dashboard.state import State
    from baarda.dashboard.views.controls import UPLOAD_MAX_CONTENT

    one = bz2.compress(b"a" * 45_000_000)
    data = bz2.compress(b'{"format": "baarda-block", "title": "') + one * 14
    assert len(data) < 64 * 1024
    st = State()
    panel = FilePanel(state=st)
    assert panel.receive("bomb.json.bz2", data) is False
    assert st.error.startswith("Cannot read bomb.json.bz2: ")
    assert f"more than {UPLOAD_MAX_CONTENT >> 20} MiB of decompressed content" in st.error


def test_a_closed_pages_reading_and_adjustment_stop(tmp_path):
    """Once the session has ended (``jobs.closed``), the reading of its file stops at the next
    piece read and its adjustment at the next iteration (:class:`Cancelled`)."""
    from baarda.build import read_problem
    from baarda.dashboard.jobs import Cancelled
    from baarda.dashboard.state import State
    from baarda.io.source import checking

    from tests.dashboard.test_state import tiny_block_problem

    st = State()
    gkf = Path(__file__).resolve().parents[2] / "data" / "demo-levelling.gkf"
    with checking(st._stop_if_closed):
        read_problem(gkf)                                   # open page: read
        st.jobs.closed = True
        with pytest.raises(Cancelled):
            read_problem(gkf)
    fresh_sink = State()
    fresh_sink.jobs.closed = True
    with pytest.raises(Cancelled):
        State(problem=tiny_block_problem(), progress_to=fresh_sink)
