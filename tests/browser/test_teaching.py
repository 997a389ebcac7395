"""Teaching in Chromium (issue 31, item 3): moving the q slider redraws the power plots on axes of
that q — the H0 density's maximum and k inside the frame — and leaves the page where it was."""

from __future__ import annotations

import pytest
from scipy import stats

from tests.browser.test_app import LOAD_TIMEOUT, click_tab, open_app, real_errors, wait_until

pytestmark = pytest.mark.browser

JS_POWER = """() => { for (const doc of Bokeh.documents) for (const m of doc.all_models)
    if (m.title && m.title.text && m.title.text.startsWith('Power of the'))
      return [m.title.text, m.x_range.start, m.x_range.end, m.y_range.start, m.y_range.end];
  return null; }"""

JS_SCROLL = """() => { let best = [window.scrollY];
  for (const el of document.querySelectorAll('*')) if (el.scrollTop > 0) best.push(el.scrollTop);
  return best; }"""


#: Lines of drawn plot titles that run beyond their canvas (measured with the title's font).
JS_TITLES_CUT = """() => {
  const out = [], ctx = document.createElement('canvas').getContext('2d');
  for (const doc of Bokeh.documents) for (const m of doc.all_models) {
    const t = m.title;
    if (!t || typeof t !== 'object' || !('text_font_size' in t) || !t.text) continue;
    const tv = Bokeh.index.find_one(t);
    if (!tv || !tv.layout || !tv.parent || !tv.parent.el || !tv.parent.el.isConnected) continue;
    const r = tv.parent.el.getBoundingClientRect();
    if (!(r.width > 0 && r.height > 0)) continue;
    ctx.font = `${t.text_font_style} ${t.text_font_size} ${t.text_font}`;
    for (const line of String(t.text).split('\\n')) {
      const end = tv.layout.bbox.left + t.offset + ctx.measureText(line).width;
      if (end > r.width + 1) out.push(`${line} (ends at ${Math.round(end)} of ${Math.round(r.width)} px)`);
    }
  }
  return out; }"""


def test_q_slider_moves_the_axes_not_the_page(page, block_app, screenshots):
    state, errors = open_app(page, block_app)
    click_tab(page, "Teaching")
    page.locator(".teach-power").first.wait_for(timeout=LOAD_TIMEOUT)
    page.wait_for_function(f"({JS_POWER})() !== null", timeout=30_000)
    policy = state.reliability.policy
    power = page.locator(".teach-power").first
    power.scroll_into_view_if_needed()
    handle = page.locator(".noUi-handle").last
    for q in (2, 3, 4, 5, 6):
        before = page.evaluate(JS_SCROLL)
        handle.focus()
        page.keyboard.press("ArrowRight")
        page.wait_for_function(f"(({JS_POWER})() || [''])[0].includes('{q}-dimensional')", timeout=30_000)
        assert wait_until(lambda: (page.evaluate(JS_POWER) or [0, 0, 0, 0, 0])[4] > 0)
        _, x0, x1, y0, y1 = page.evaluate(JS_POWER)
        k = stats.chi2.isf(policy.alpha(q), q)
        mode = stats.chi2.pdf(q - 2 if q > 2 else 1e-9, q)
        assert x0 <= max(q - 2, 0) < k < x1 and y0 == 0 and mode < y1 < 1.5 * mode, (q, x0, x1, y1)
        assert page.evaluate(JS_SCROLL) == before, "the page moved when q changed"
    page.screenshot(path=str(screenshots / "teaching-q6.png"))
    # at q = 6 the tail plot's log axis is widest: no title cut, at the narrowest right panel too
    for width, height in ((1920, 1080), (1280, 800)):
        page.set_viewport_size({"width": width, "height": height})
        assert wait_until(lambda: page.evaluate(JS_TITLES_CUT) == [], 20), (width, page.evaluate(JS_TITLES_CUT))
        page.screenshot(path=str(screenshots / f"teaching-q6-{width}.png"))
    assert real_errors(errors) == []
