"""Maps on a real SfM block in Chromium (issue 15, item 1): on Ladybug (BAL, 49 images, 7,776
points, a few drifting towards infinity) every map's frame holds the real points, the far points
are drawn at the edge and listed under the map, the axes carry no unit, and the image view's
residuals are exaggerated at the block's scale. Screenshots of each map go to ``screenshots/``.
"""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from tests.browser.test_app import click_tab, open_app, real_errors, wait_for_title

pytestmark = pytest.mark.browser

MAPS = {"Layout": "Layout", "Redundancy": "Redundancy", "w": "|w|", "External": "External",
        "MDB": "Minimal detectable", "Precision": "Standard ellipses"}

JS_RANGES = """(prefix) => {
  for (const doc of Bokeh.documents) for (const m of doc.all_models)
    if (m.constructor.__name__ === 'Figure' && m.title && String(m.title.text).startsWith(prefix))
      return [m.x_range.start, m.x_range.end, m.y_range.start, m.y_range.end,
              m.below.map(a => a.axis_label), m.left.map(a => a.axis_label)];
  return null;
}"""


def test_ladybug_maps_read(page, ladybug_app, screenshots):
    page.set_default_timeout(120_000)
    state, errors = open_app(page, ladybug_app)
    _, pts = state.frames()
    for tab, prefix in MAPS.items():
        click_tab(page, tab)
        wait_for_title(page, prefix, timeout=120_000)
        x0, x1, y0, y1, xl, yl = page.evaluate(JS_RANGES, prefix)
        assert x1 - x0 < 20 and y1 - y0 < 20, (tab, x0, x1, y0, y1)     # was about ±1e6
        assert "[m]" not in " ".join(str(a) for a in xl + yl if a)
        expect(page.locator(".far-note").filter(has_text="far point(s) drawn at the frame's edge").first
               ).to_be_visible()
        page.screenshot(path=str(screenshots / f"ladybug-map-{tab.lower()}.png"))
    click_tab(page, "Image v")
    wait_for_title(page, "Image ", timeout=120_000)
    assert state.exaggeration >= 1
    page.screenshot(path=str(screenshots / "ladybug-map-image.png"))
    assert real_errors(errors) == []
