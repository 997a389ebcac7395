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
