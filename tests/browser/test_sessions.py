"""Many sessions on one server (issue 12): the views of a session whose page is gone are not
built (Bokeh keeps a closed page's session 15-30 s before it destroys it; a build for it held
the event loop for seconds while other users clicked)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.browser

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo-block.json"


def _wait(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def test_no_map_build_for_a_closed_page(page, serve_app, monkeypatch):
    import panel as pn

    from baarda.dashboard import app
    from baarda.dashboard.state import State

    if not DEMO.exists():
        pytest.skip(f"{DEMO} not found")
    assert State().load(DEMO)                    # in the server's cache: the build follows onload
    made, docs = [], []
    main = app.main_views
    monkeypatch.setattr(app, "main_views", lambda state, **kw: made.append(state) or main(state, **kw))

    def factory():
        docs.append(pn.state.curdoc)
        return app.create_app(DEMO)

    served = serve_app(factory)
    app.pending(+1)                             # a session still loading: the builds wait for it
    try:
        page.goto(served.url)
        page.locator(".alpha-slider").first.wait_for()        # the sidebar, made on onload
        doc = docs[-1]
        ctx = doc.session_context
        page.close()

        def gone():
            return all(s.connection_count == 0 for s in ctx.server_context.sessions if s.id == ctx.id)
        _wait(gone, 30, "the server to see the page closed")
    finally:
        app.pending(-1)
    app.builds_done(timeout=120)                             # the builder has done what it was given
    assert made == []
