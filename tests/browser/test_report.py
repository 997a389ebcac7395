"""`baarda report` writes a standalone HTML file that opens offline in Chromium with its plots."""

from __future__ import annotations

from pathlib import Path

import pytest

from baarda.cli import main

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.mark.browser
def test_report_opens_offline_with_plots(page, tmp_path, screenshots, capsys):
    out = tmp_path / "demo-report.html"
    assert main(["report", str(DATA / "demo-block.json"), "-o", str(out), "--quiet"]) == 0
    requests, errors = [], []
    page.on("request", lambda r: requests.append(r.url))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.goto(out.as_uri())
    page.wait_for_function("window.Bokeh && Bokeh.documents.length > 0", timeout=60_000)
    n_plots = page.evaluate(
        "Bokeh.documents.reduce((n, d) => n + d.all_models.size && "
        "[...d.all_models].filter(m => m.type === 'Figure' || (m.constructor && m.constructor.__name__ === 'Figure')).length, 0)")
    # the plots are drawn: canvases inside Bokeh's (nested) shadow roots
    page.wait_for_function("""() => {
        const count = (root) => { let n = root.querySelectorAll('canvas').length;
            for (const el of root.querySelectorAll('*')) if (el.shadowRoot) n += count(el.shadowRoot);
            return n; };
        return count(document) >= 3; }""", timeout=60_000)
    page.screenshot(path=str(screenshots / "report-top.png"))
    page.screenshot(path=str(screenshots / "report.png"), full_page=True)
    assert n_plots >= 3
    assert all(u.startswith(("file:", "data:", "blob:", "about:")) for u in requests), requests
    assert errors == []
    assert page.get_by_text("FAILED").count() >= 1        # the demo block fails the global test
