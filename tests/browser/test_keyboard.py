"""Keyboard and screen-reader basics (issue 15, item 6) in Chromium, on the demo block: the tab
bars are tablists of tabs with ``aria-selected``; Enter and Space open the focused tab, the arrow
keys, Home and End move through a bar (the focus follows); a focused control shows a focus ring;
a checkbox's label toggles it and names it; the Tab key alone reaches every tab bar, each before
the panel it opens (Bokeh appends a redrawn bar after its panel, and the Tab key then went from the
suspects table to the end of the page, never reaching the right panel's bar).
"""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from tests.browser.test_app import LOAD_TIMEOUT, open_app, real_errors, wait_until

pytestmark = pytest.mark.browser

#: The focused element, through the shadow roots: [role, text, outline style].
JS_FOCUSED = """() => {
  let a = document.activeElement;
  while (a && a.shadowRoot && a.shadowRoot.activeElement) a = a.shadowRoot.activeElement;
  if (!a) return null;
  return [a.getAttribute('role'), (a.innerText || '').trim(), getComputedStyle(a).outlineStyle];
}"""


def focused_tab(page, name):
    """Wait until the focused element is the tab ``name``; return [role, text, outline]."""
    page.wait_for_function(f"() => {{ const f = ({JS_FOCUSED})(); return f && f[0] === 'tab' && f[1] === {name!r}; }}",
                           timeout=30_000)
    return page.evaluate(JS_FOCUSED)


def test_tabs_by_keyboard(page, block_app, screenshots):
    state, errors = open_app(page, block_app)
    page.locator(".suspects-table .tabulator-row").first.wait_for(timeout=LOAD_TIMEOUT)
    tabs = page.get_by_role("tab")
    expect(tabs.first).to_be_visible()
    assert wait_until(lambda: page.get_by_role("tablist").count() >= 2)
    layout = page.get_by_role("tab", name="Layout", exact=True)
    expect(layout).to_have_attribute("aria-selected", "true")
    layout.focus()
    page.keyboard.press("ArrowRight")
    expect(page.get_by_role("tab", name="Redundancy", exact=True)).to_have_attribute("aria-selected", "true")
    role, _, outline = focused_tab(page, "Redundancy")
    assert outline != "none"                                   # the focus ring
    page.keyboard.press("End")
    expect(page.get_by_role("tab", name="Criterion", exact=True)).to_have_attribute("aria-selected", "true")
    focused_tab(page, "Criterion")
    page.keyboard.press("Home")
    expect(layout).to_have_attribute("aria-selected", "true")
    focused_tab(page, "Layout")
    page.keyboard.press("ArrowLeft")                           # wraps round to the last tab
    expect(page.get_by_role("tab", name="Criterion", exact=True)).to_have_attribute("aria-selected", "true")
    suspects = page.get_by_role("tab", name="Suspects", exact=True)
    suspects.focus()
    page.keyboard.press("ArrowRight")
    expect(page.get_by_role("tab", name="Tests table", exact=True)).to_have_attribute("aria-selected", "true")
    hyp = page.get_by_role("tab", name="Hypotheses", exact=True)
    hyp.focus()
    page.keyboard.press("Enter")
    expect(hyp).to_have_attribute("aria-selected", "true")
    teaching = page.get_by_role("tab", name="Teaching", exact=True)
    teaching.focus()
    page.keyboard.press(" ")
    expect(teaching).to_have_attribute("aria-selected", "true")
    page.screenshot(path=str(screenshots / "keyboard-tabs.png"))
    assert real_errors(errors) == []


def test_checkbox_label_toggles_it(page, block_app):
    state, errors = open_app(page, block_app)
    box = page.get_by_role("checkbox", name="B-method (same δ0 for all dimensions)")
    expect(box).to_be_visible(timeout=30_000)
    before = bool(state.b_method)
    assert box.is_checked() == before
    page.get_by_text("B-method (same δ0 for all dimensions)", exact=True).click()
    expect(box).to_be_checked(checked=not before)
    assert wait_until(lambda: state.b_method == (not before))
    page.get_by_text("B-method (same δ0 for all dimensions)", exact=True).click()
    expect(box).to_be_checked(checked=before)
    assert wait_until(lambda: state.b_method == before)
    assert real_errors(errors) == []


#: The focused element's chain of shadow hosts and itself, as [class or role, text] pairs.
JS_FOCUS_PATH = """() => {
  let a = document.activeElement; const path = [];
  while (a) {
    path.push([a.getAttribute('role') || String(a.className || ''), (a.innerText || '').trim()]);
    a = a.shadowRoot && a.shadowRoot.activeElement;
  }
  return path;
}"""


def test_tab_key_reaches_every_bar_before_its_panel(page, block_app):
    """From the map's open tab, the Tab key alone goes through the map to the right panel's open
    tab, then into that tab's panel (its "more columns" box, then the suspects table, within a few
    presses); Shift+Tab from the panel's first control comes back to the tab."""
    state, errors = open_app(page, block_app)
    page.locator(".suspects-table .tabulator-row").first.wait_for(timeout=LOAD_TIMEOUT)
    page.get_by_role("tab", name="Layout", exact=True).focus()
    seen = []
    for _ in range(60):                                         # the map's tools come first
        page.keyboard.press("Tab")
        path = page.evaluate(JS_FOCUS_PATH)
        seen.append(path[-1])
        if path[-1] == ["tab", "Suspects"]:
            break
    assert seen[-1] == ["tab", "Suspects"], f"Tab never reached the right panel's bar: {seen}"
    assert any("right-tabs" in cls for cls, _ in page.evaluate(JS_FOCUS_PATH))
    page.keyboard.press("Tab")                                  # into the open tab's panel
    inside = page.evaluate(JS_FOCUS_PATH)
    assert any("right-tabs" in cls for cls, _ in inside) and inside[-1][0] != "tab", inside
    page.keyboard.press("Shift+Tab")
    assert page.evaluate(JS_FOCUS_PATH)[-1] == ["tab", "Suspects"]
    page.keyboard.press("Tab")                                  # the panel's controls ("more columns"), then its table
    for _ in range(5):
        inside = page.evaluate(JS_FOCUS_PATH)
        if any("DataTabulator" in cls for cls, _ in inside):
            break
        page.keyboard.press("Tab")
    assert any("DataTabulator" in cls for cls, _ in inside) and any("right-tabs" in cls for cls, _ in inside), inside
    assert real_errors(errors) == []
