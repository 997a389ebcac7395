"""`baarda serve` with no file serves the demo block on 127.0.0.1, prints the URL, and reads and
adjusts the file once at start."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request



def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_demo_on_loopback(tmp_path):
    port = _free_port()
    env = dict(os.environ, DISPLAY="", BROWSER="false")
    proc = subprocess.Popen([sys.executable, "-m", "baarda.cli", "serve", "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, env=env, cwd=tmp_path)
    try:
        first = proc.stdout.readline()
        assert first.strip() == f"baarda dashboard: http://127.0.0.1:{port}/"
        deadline = time.time() + 90
        body = ""
        while time.time() < deadline:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as r:
                    body = r.read().decode("utf-8", "replace")
                    break
            except OSError:
                time.sleep(0.5)
        assert "baarda" in body
        # the served file is read and adjusted once at start (the sessions' cache is warm)
        import threading

        seen = []

        def read():
            for line in proc.stdout:
                seen.append(line)
                if "read and adjusted in" in line:
                    return
        t = threading.Thread(target=read, daemon=True)
        t.start()
        t.join(120)
        assert seen and "demo-block.json read and adjusted in" in seen[-1], seen
        # bound to loopback only: no listener on the machine's other addresses
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(2)
            try:
                other = socket.gethostbyname(socket.gethostname())
            except OSError:
                other = None
            if other and not other.startswith("127."):
                assert s.connect_ex((other, port)) != 0
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=20)


def test_served_stylesheets_never_point_at_the_cdn():
    """Panel patches a stylesheet towards cdn.holoviz.org when the model's document lacks the
    template's ``dist_url`` (unreachable offline: a failed request in the page, seen under load);
    served, baarda's patch gives this server's dist path instead, and leaves others alone."""
    from bokeh.models import ImportedStyleSheet
    from panel.io import resources as pn_resources

    from baarda.dashboard.app import _patch_stylesheet_locally

    sheet = ImportedStyleSheet(url=f"{pn_resources.LOCAL_DIST}css/loading.css")
    _patch_stylesheet_locally(sheet, pn_resources.CDN_DIST)
    assert not sheet.url.startswith("http") and sheet.url.split("?")[0].endswith("css/loading.css")
    unpatched = ImportedStyleSheet(url=f"{pn_resources.LOCAL_DIST}css/loading.css")
    pn_resources.patch_stylesheet(unpatched, pn_resources.CDN_DIST)
    assert unpatched.url.startswith(pn_resources.CDN_DIST)          # what Panel itself does
    other = ImportedStyleSheet(url="https://example.org/a.css")
    _patch_stylesheet_locally(other, pn_resources.CDN_DIST)
    assert other.url == "https://example.org/a.css"


def test_a_failing_page_callback_does_not_stay_bokehs_current_document(caplog):
    """Bokeh runs a next-tick callback inside ``patch_curdoc``, which pops the document only if
    the callback returns: one that raised left its session's document as ``curdoc()`` of every
    thread, and once the session ended every later report failed on it (CI). The dashboard's
    callbacks (:func:`baarda.dashboard.jobs.next_tick`) log their error instead."""
    from bokeh.document import Document
    from bokeh.document.callbacks import invoke_with_curdoc
    from bokeh.io.doc import curdoc

    from baarda.dashboard.jobs import next_tick

    doc = Document()

    def boom():
        raise RuntimeError("the page's callback failed")
    next_tick(doc, boom)
    (cb,) = doc.session_callbacks
    with caplog.at_level("ERROR", logger="baarda.dashboard"):
        invoke_with_curdoc(doc, cb.callback)
    assert curdoc() is not doc
    assert "the page's callback failed" in caplog.text
