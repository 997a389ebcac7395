"""Tables that fit, readable selected rows, maps that use the width and the keyboard (issue 31,
items 6, 8 and 10) in Chromium on the demo block, at 1280 × 800 and 1920 × 1080:

- no cell or header of the suspects table or the tests table is cut: every one's text fits its
  box (``scrollWidth <= clientWidth``; long hypothesis names and "explained by" / "cannot be
  told apart from" texts wrap instead of being cut);
- on a selected row the red and green decisions keep a contrast of at least 4.5 : 1 against the
  row (they were unreadable on the dark-blue selected row);
- a suspect row is selected by the keyboard (Enter or Space on the focused row, as a click),
  the arrow keys move between rows; the page's first Tab stop is a link that skips to the maps;
  a focused toolbar button has a 2-px solid ring.
"""

from __future__ import annotations

import pytest

from tests.browser.test_app import LOAD_TIMEOUT, click_tab, open_app, real_errors, wait_until

pytestmark = pytest.mark.browser

SIZES = [(1280, 800), (1920, 1080)]

#: The cells and headers of a table (by its css class) whose text does not fit their box.
JS_CUT = """(cls) => {
  const all = (root, sel, out = []) => {
    if (root.shadowRoot) all(root.shadowRoot, sel, out);
    root.querySelectorAll(sel).forEach(e => out.push(e));
    for (const el of root.querySelectorAll('*')) if (el.shadowRoot) all(el.shadowRoot, sel, out);
    return out; };
  const out = [], seen = [];
  for (const host of all(document, '.' + cls)) {
    for (const e of all(host, '.tabulator-cell, .tabulator-col-title')) {
      const r = e.getBoundingClientRect();
      if (!(r.width > 0 && r.height > 0)) continue;
      seen.push(e);
      if (e.scrollWidth > e.clientWidth + 1 || e.scrollHeight > e.clientHeight + 2)
        out.push(`${e.getAttribute('tabulator-field') || 'header'}: "${e.innerText.slice(0, 50)}" `
                 + `(${e.scrollWidth}×${e.scrollHeight} in ${e.clientWidth}×${e.clientHeight})`);
    }
  }
  return seen.length ? out : ['no cell of .' + cls + ' shown'];
}"""

#: [text colour, background colour] of the decision in the first selected suspects row.
JS_SELECTED_DECISION = """() => {
  const all = (root, sel, out = []) => {
    if (root.shadowRoot) all(root.shadowRoot, sel, out);
    root.querySelectorAll(sel).forEach(e => out.push(e));
    for (const el of root.querySelectorAll('*')) if (el.shadowRoot) all(el.shadowRoot, sel, out);
    return out; };
  const host = all(document, '.suspects-table')[0];
  const row = host && all(host, '.tabulator-row.tabulator-selected')[0];
  if (!row) return null;
  const span = row.querySelector(".tabulator-cell[tabulator-field='decision'] span");
  let bg = 'rgba(0, 0, 0, 0)';
  for (let e = span; e && bg.startsWith('rgba(0, 0, 0, 0)'); e = e.parentElement) bg = getComputedStyle(e).backgroundColor;
  return [getComputedStyle(span).color, bg, span.innerText];
}"""


def _rgb(text: str) -> tuple:
    return tuple(float(v) for v in text[text.index("(") + 1:text.index(")")].split(",")[:3])


def contrast(a: str, b: str) -> float:
    """The WCAG contrast ratio of two CSS ``rgb(...)`` colours."""
    def lum(c):
        ch = [v / 255 for v in _rgb(c)]
        ch = [v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4 for v in ch]
        return 0.2126 * ch[0] + 0.7152 * ch[1] + 0.0722 * ch[2]
    la, lb = sorted((lum(a), lum(b)), reverse=True)
    return (la + 0.05) / (lb + 0.05)


def no_cut(page, cls: str, where: str) -> None:
    try:
        page.wait_for_function(f"() => ({JS_CUT})({cls!r}).length === 0", timeout=30_000)
    except Exception:
        problems = page.evaluate(JS_CUT, cls)
        if problems:
            raise AssertionError(f"{where}: {problems[:8]}") from None


def click_decision(page, decision: str) -> bool:
    """Click the first suspects row of ``decision``; True once it is selected (the table may
    redraw its rows meanwhile: then False, and the caller tries again)."""
    try:
        # the accepted are ranked last: at the list's end; the rejected at its top
        page.locator(".suspects-table .tabulator-tableholder").first.evaluate(
            f"(el) => {{ el.scrollTop = {'el.scrollHeight' if decision == 'accepted' else 0}; }}")
        cell = page.locator(".suspects-table .tabulator-cell[tabulator-field='decision']").filter(
            has_text=decision).first
        cell.scroll_into_view_if_needed(timeout=5_000)
        cell.click(timeout=5_000)
    except Exception:  # noqa: BLE001 - detached or not yet rendered: tried again
        return False
    return wait_until(lambda: (page.evaluate(JS_SELECTED_DECISION) or ["", "", ""])[2].endswith(decision), 5)


def test_tables_fit_and_selected_rows_are_readable(page, block_app, screenshots):
    state, errors = open_app(page, block_app)
    page.locator(".suspects-table .tabulator-row").first.wait_for(timeout=LOAD_TIMEOUT)
    for width, height in SIZES:
        page.set_viewport_size({"width": width, "height": height})
        click_tab(page, "Suspects")
        page.locator(".suspects-table .tabulator-row:visible").first.wait_for(timeout=LOAD_TIMEOUT)
        no_cut(page, "suspects-table", f"suspects at {width}")
        # a rejected and an accepted row selected in turn: the decision readable on the row
        for decision in ("rejected", "accepted"):
            assert wait_until(lambda: click_decision(page, decision), 60), f"no {decision} row selected at {width}"
            color, bg, _ = page.evaluate(JS_SELECTED_DECISION)
            assert contrast(color, bg) >= 4.5, (decision, color, bg, width)
        page.screenshot(path=str(screenshots / f"fit-suspects-{width}.png"))
        click_tab(page, "Tests table")
        page.locator(".tests-table .tabulator-row:visible").first.wait_for(timeout=LOAD_TIMEOUT)
        no_cut(page, "tests-table", f"tests table at {width}")
        page.screenshot(path=str(screenshots / f"fit-tests-{width}.png"))
    assert real_errors(errors) == []


JS_MAP_WIDTH = """() => {   // [figure width, map tabs width] of the shown Layout map
  const all = (root, sel, out = []) => {
    if (root.shadowRoot) all(root.shadowRoot, sel, out);
    root.querySelectorAll(sel).forEach(e => out.push(e));
    for (const el of root.querySelectorAll('*')) if (el.shadowRoot) all(el.shadowRoot, sel, out);
    return out; };
  const tabs = all(document, '.map-tabs')[0];
  for (const d of Bokeh.documents) for (const m of d.all_models) {
    if (m.constructor.__name__ !== 'Figure' || !m.title || !String(m.title.text).startsWith('Layout')) continue;
    const v = Bokeh.index.find_one(m);
    if (!v || !v.el || !v.el.isConnected) continue;
    const r = v.el.getBoundingClientRect();
    if (r.width > 0) return [r.width, tabs.getBoundingClientRect().width, m.frame_width, m.frame_height];
  }
  return null;
}"""


def test_maps_use_the_width(page, block_app, screenshots):
    """At 1920 the maps were 420 px wide beside 900 px of room: the map fills its tabs (at least
    85 % of their width, 40 % of the window), and its frame keeps its aspect (equal scales)."""
    state, errors = open_app(page, block_app)
    click_tab(page, "Layout")
    for width, height in SIZES:
        page.set_viewport_size({"width": width, "height": height})
        assert wait_until(lambda: (lambda r: r is not None and r[0] >= 0.85 * r[1] and r[0] >= 0.4 * width)(
            page.evaluate(JS_MAP_WIDTH)), 30), (width, page.evaluate(JS_MAP_WIDTH))
        fig, tabs, fw, fh = page.evaluate(JS_MAP_WIDTH)
        assert fig <= tabs + 1
        page.screenshot(path=str(screenshots / f"fit-map-{width}.png"))
    assert real_errors(errors) == []


JS_FOCUSED = """() => {
  let a = document.activeElement;
  while (a && a.shadowRoot && a.shadowRoot.activeElement) a = a.shadowRoot.activeElement;
  if (!a) return null;
  const s = getComputedStyle(a);
  return {cls: String(a.className), role: a.getAttribute('role'), text: (a.innerText || '').trim().slice(0, 80),
          outline: [s.outlineStyle, s.outlineWidth], id: a.id};
}"""

JS_FOCUS_ROW = """(n) => {   // focus the n-th rendered row of the suspects table; its hypothesis
  const all = (root, sel, out = []) => {
    if (root.shadowRoot) all(root.shadowRoot, sel, out);
    root.querySelectorAll(sel).forEach(e => out.push(e));
    for (const el of root.querySelectorAll('*')) if (el.shadowRoot) all(el.shadowRoot, sel, out);
    return out; };
  const host = all(document, '.suspects-table')[0];
  const row = all(host, '.tabulator-row')[n];
  row.focus();
  return row.querySelector(".tabulator-cell[tabulator-field='hypothesis']").innerText;
}"""

JS_FOCUS_TOOL = """() => {   // focus the first toolbar button of the shown Layout map
  const all = (root, sel, out = []) => {
    if (root.shadowRoot) all(root.shadowRoot, sel, out);
    root.querySelectorAll(sel).forEach(e => out.push(e));
    for (const el of root.querySelectorAll('*')) if (el.shadowRoot) all(el.shadowRoot, sel, out);
    return out; };
  for (const bar of all(document, '.bk-Toolbar')) {
    if (!(bar.getBoundingClientRect().width > 0)) continue;
    const button = Array.from(bar.shadowRoot.children).find(e => e.tabIndex >= 0 && !e.classList.contains('bk-divider')
                                                               && e.tagName !== 'STYLE' && e.tagName !== 'LINK');
    if (button) { button.focus(); return true; }
  }
  return false;
}"""


def test_keyboard_skip_link_rows_and_toolbar_ring(page, block_app, screenshots):
    state, errors = open_app(page, block_app)
    page.locator(".suspects-table .tabulator-row").first.wait_for(timeout=LOAD_TIMEOUT)
    # the first Tab stop skips to the map tabs
    page.evaluate("() => { document.activeElement && document.activeElement.blur(); window.scrollTo(0, 0); }")
    page.keyboard.press("Tab")
    assert page.evaluate(JS_FOCUSED)["id"] == "baarda-skip"
    page.keyboard.press("Enter")
    assert wait_until(lambda: (page.evaluate(JS_FOCUSED) or {}).get("role") == "tab")
    assert page.evaluate(JS_FOCUSED)["text"] == "Layout"
    # a suspect row: focused, Enter selects it as a click does; ArrowDown and Space the next
    page.wait_for_function(f"() => {{ try {{ return ({JS_FOCUS_ROW})(0) !== ''; }} catch (e) {{ return false; }} }}")
    first = page.evaluate(JS_FOCUS_ROW, 0)
    assert "tabulator-row" in page.evaluate(JS_FOCUSED)["cls"]
    page.keyboard.press("Enter")
    from baarda.dashboard.suspects import suspects

    frame = suspects(state)                           # (the list the view shows, computed again)
    row = frame[frame["hypothesis"] == first].iloc[0]
    assert wait_until(lambda: state.selected_obs == int(row["obs"]) or state.selected_point == row["point"], 20), \
        (first, state.selected_obs, state.selected_point)
    page.keyboard.press("ArrowDown")
    second = frame["hypothesis"].iloc[1]
    assert page.evaluate(JS_FOCUSED)["text"].find(second) >= 0
    page.keyboard.press(" ")
    row2 = frame.iloc[1]
    assert wait_until(lambda: state.selected_obs == int(row2["obs"]) if row2["what"] not in ("control point", "transfer")
                      else state.selected_point == int(row2["point"]), 20), (second, state.selected_obs)
    page.screenshot(path=str(screenshots / "fit-keyboard-row.png"))
    # a focused toolbar button has a 2-px solid ring
    page.keyboard.press("Tab")                        # (keyboard modality: :focus-visible applies)
    assert wait_until(lambda: page.evaluate(JS_FOCUS_TOOL))
    assert wait_until(lambda: page.evaluate(JS_FOCUSED)["outline"] == ["solid", "2px"]), page.evaluate(JS_FOCUSED)
    page.screenshot(path=str(screenshots / "fit-keyboard-toolbar.png"))
    assert real_errors(errors) == []

