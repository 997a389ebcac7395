"""`baarda report` writes a standalone HTML file that opens offline in Chromium with its plots."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from playwright.sync_api import expect

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


def _pdf_pages(pdf: bytes) -> int:
    """Pages of a PDF written by Chromium (its page objects are plain dictionaries)."""
    return len(re.findall(rb"/Type\s*/Page\b(?!s)", pdf))


@pytest.mark.browser
@pytest.mark.parametrize("name", ["demo-block.json", "demo-levelling.gkf"])
def test_client_report_prints_on_three_a4_pages(page, tmp_path, screenshots, name, capsys):
    """Issue 15, item 5: Chromium's print to PDF gives at most three A4 pages, each a section
    (verdict and the tests' map; reliability maps; suspects), no toolbar and no selection."""
    out = tmp_path / "report.html"
    assert main(["report", str(DATA / name), "-o", str(out), "--quiet"]) in (0, 4)
    page.goto(out.as_uri())
    page.wait_for_function("""() => {
        const count = (root) => { let n = root.querySelectorAll('canvas').length;
            for (const el of root.querySelectorAll('*')) if (el.shadowRoot) n += count(el.shadowRoot);
            return n; };
        return count(document) >= 4; }""", timeout=60_000)
    expect(page.locator(".verdict .head")).to_be_visible()
    # no Bokeh toolbar anywhere (they live in the plots' shadow roots)
    toolbars = page.evaluate("""() => { const count = (root) => { let n = root.querySelectorAll('.bk-toolbar').length;
            for (const el of root.querySelectorAll('*')) if (el.shadowRoot) n += count(el.shadowRoot);
            return n; }; return count(document); }""")
    assert toolbars == 0
    page.emulate_media(media="print")
    pdf = page.pdf(format="A4", print_background=True)
    assert 1 <= _pdf_pages(pdf) <= 3, _pdf_pages(pdf)
    (screenshots / f"client-report-{name}.pdf").write_bytes(pdf)
    page.screenshot(path=str(screenshots / f"client-report-{name}.png"), full_page=True)


@pytest.mark.browser
def test_a_long_id_does_not_push_the_tables_off_the_page(page, tmp_path, capsys):
    """Issue 25, item 7: a 300-character point id wraps inside its cell; the suspects and the
    rejected-groups tables keep their q, T and critical columns on the page."""
    import json

    doc = json.loads((DATA / "demo-block.json").read_text())
    long_id = "P" + "x" * 299
    text = json.dumps(doc).replace('"P05003"', json.dumps(long_id))
    src = tmp_path / "long-id.json"
    src.write_text(text)
    out = tmp_path / "long-id.html"
    assert main(["report", str(src), "-o", str(out), "--quiet"]) in (0, 4)
    page.set_viewport_size({"width": 900, "height": 1200})
    page.goto(out.as_uri())
    expect(page.locator("table.t").first).to_be_visible()
    assert page.get_by_text("Rejected group tests").count() == 1
    widths = page.evaluate("""() => [...document.querySelectorAll('table.t')].map(t => {
        const page = t.closest('section').getBoundingClientRect();
        return [t.getBoundingClientRect().right, page.right]; })""")
    assert widths and all(right <= limit + 1 for right, limit in widths), widths
