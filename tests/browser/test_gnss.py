"""A block with GNSS centres, IMU attitudes and check points, served and read in Chromium
(issue 28, item 6): served as ``baarda serve FILE --gnss CSV --imu CSV`` serves it
(``create_app(path, inputs=...)``), the page shows the GNSS and check-point summary cards, the
maps carry the GNSS residual vectors at the 18 centres (legend entry, image and residuals in the
plot data) and the precision map the centres' standard ellipses, the suspects list names the planted 1 m centre error in its first ten rows, and the
"Find errors" tab shows the check-point table with its RMSE row. Screenshots at 1280 and 1920
pixels wide go to ``screenshots/``.
"""

from __future__ import annotations

import re

import pytest
from playwright.sync_api import expect

from tests.browser.test_app import (LOAD_TIMEOUT, click_tab, open_app, real_errors, wait_for_column,
                                    wait_for_title)
from tests.browser.test_suspects import suspect_row

pytestmark = pytest.mark.browser

JS_LEGEND = """() => {
  const out = [];
  for (const doc of Bokeh.documents) for (const m of doc.all_models)
    if (m.constructor.__name__ === 'LegendItem') {
      const l = m.label; out.push(String(l && l.value !== undefined ? l.value : l));
    }
  return out;
}"""


@pytest.fixture(scope="module")
def gnss_app(serve_app, tmp_path_factory):
    from baarda.dashboard.app import create_app
    from baarda.io.gnss import GnssOptions, ImuOptions
    from baarda.simulate import gnss_path, simulate_to_files
    from tests.dashboard.test_auxdata import RECIPE

    d = tmp_path_factory.mktemp("gnss-served")
    path = d / "b.json"
    simulate_to_files(RECIPE, path, d / "b.truth.json")
    inputs = {"gnss": GnssOptions(gnss_path(path)), "imu": ImuOptions(gnss_path(path, ".imu.csv"))}
    return serve_app(lambda: create_app(path, inputs=inputs))


def test_gnss_block_served(page, gnss_app, screenshots):
    page.set_default_timeout(LOAD_TIMEOUT)
    state, errors = open_app(page, gnss_app)
    summary = page.locator(".summary")
    expect(summary.get_by_text("GNSS centres").first).to_be_visible()
    expect(summary.get_by_text("Check points").first).to_be_visible()
    # the layout map: one residual vector per centre, with its image, legend entry "GNSS residuals ×k"
    images = wait_for_column(page, "vx", "(cols) => cols.some(c => c.length === 18)")
    assert any(len(c) == 18 for c in images)
    legend = page.evaluate(JS_LEGEND)
    assert any(re.fullmatch(r"GNSS residuals ×[0-9.e+]+", x) for x in legend), legend
    assert any(x.startswith("check points, adjusted − known ×") for x in legend), legend
    # the suspects list: the 1 m error of centre 203 in the first ten, its 3-D test rejected
    if not page.locator(".suspects-table").first.is_visible():
        click_tab(page, "Suspects")
    page.locator(".suspects-table .tabulator-row").first.wait_for(timeout=LOAD_TIMEOUT)
    row = suspect_row(page, "image 203 (strip 2)").locator("xpath=..")
    assert int(row.locator(".tabulator-cell[tabulator-field='rank']").inner_text()) <= 10
    assert "rejected" in row.locator(".tabulator-cell[tabulator-field='decision']").inner_text()
    for width in (1280, 1920):
        page.set_viewport_size({"width": width, "height": 1000})
        page.screenshot(path=str(screenshots / f"gnss-layout-{width}.png"))
    # the residual map with its legend (GNSS and check points)
    click_tab(page, "w")
    wait_for_title(page, "|w|", timeout=LOAD_TIMEOUT)
    for width in (1280, 1920):
        page.set_viewport_size({"width": width, "height": 1000})
        page.screenshot(path=str(screenshots / f"gnss-residuals-{width}.png"))
    # the precision map: the projection centres' ellipses (pose covariance) with their legend entry
    click_tab(page, "Precision")
    wait_for_title(page, "Standard ellipses", timeout=LOAD_TIMEOUT)
    wait_for_column(page, "sX0_mm", "(cols) => cols.some(c => c.length === 18)")
    assert "projection centres, σ X0, Y0 (own datum)" in page.evaluate(JS_LEGEND)
    for width in (1280, 1920):
        page.set_viewport_size({"width": width, "height": 1000})
        page.screenshot(path=str(screenshots / f"gnss-precision-{width}.png"))
    # the check points' table: three rows and the RMSE row
    click_tab(page, "Find errors")
    table = page.locator(".check-table").first
    table.wait_for(timeout=LOAD_TIMEOUT)
    expect(page.locator(".check-info").get_by_text("Check points (3, not in the adjustment)")).to_be_visible()
    cells = table.locator(".tabulator-cell[tabulator-field='id']")
    expect(cells).to_have_count(4)
    assert cells.nth(3).inner_text() == "RMSE"
    for width in (1280, 1920):
        page.set_viewport_size({"width": width, "height": 1000})
        table.scroll_into_view_if_needed()
        page.screenshot(path=str(screenshots / f"gnss-checks-{width}.png"))
    assert state.summary()["gnss"]["centres"] == 18
    assert real_errors(errors) == []


def test_gnss_report_prints_on_three_a4_pages(page, tmp_path, screenshots, capsys):
    """``baarda report FILE --gnss CSV --imu CSV``: the verdict's GNSS and check-point sentences
    and cards keep the report on three A4 pages (as tests/browser/test_report.py asks of data/)."""
    from baarda.cli import main
    from baarda.simulate import gnss_path, simulate_to_files
    from tests.browser.test_report import _pdf_pages
    from tests.dashboard.test_auxdata import RECIPE

    path = tmp_path / "b.json"
    simulate_to_files(RECIPE, path, tmp_path / "b.truth.json")
    out = tmp_path / "report.html"
    assert main(["report", str(path), "--gnss", str(gnss_path(path)), "--imu", str(gnss_path(path, ".imu.csv")),
                 "-o", str(out), "--quiet"]) == 0
    page.goto(out.as_uri())
    expect(page.locator(".verdict").get_by_text("GNSS: the 3-D test of 1 of 18 projection centres")).to_be_visible()
    expect(page.locator(".verdict").get_by_text("Check points (3, not in the adjustment)")).to_be_visible()
    page.emulate_media(media="print")
    pdf = page.pdf(format="A4", print_background=True)
    assert 1 <= _pdf_pages(pdf) <= 3, _pdf_pages(pdf)
    page.screenshot(path=str(screenshots / "gnss-report.png"), full_page=True)
