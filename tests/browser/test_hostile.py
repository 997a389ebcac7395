"""Hostile ids in the served dashboard (issue 12): point, image and camera ids, strip names and
the title carry an ``<iframe srcdoc>`` with a script, ``<b>``, ``<style>``, a newline and an
ANSI escape sequence. No dialog opens on load, click, hover, upload or report, and the text
shows literally (control characters as escapes, :func:`baarda.text.printable`).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from playwright.sync_api import expect

from baarda.cli import main
from baarda.dashboard import geometry
from baarda.text import printable

pytestmark = pytest.mark.browser

IFRAME = '<iframe srcdoc="<script>parent.alert(document.domain)</script>">'
HOSTILE = [IFRAME, "<b>bold</b>", "<style>*{display:none}</style>", "new\nline", "esc\x1b[2J\x1b]0;pwned\x07"]
LEVELLING_IDS = [IFRAME, "<b>bold</b>", "<style>*{display:none}</style>", "new&#10;line"]


def hostile_block(tmp_path: Path) -> Path:
    """A small simulated block (native format) whose ids, strips and title are hostile."""
    src = tmp_path / "sim.json"
    assert main(["simulate", str(src), "--strips", "2", "--images", "4", "--seed", "3", "--quiet"]) == 0
    d = json.loads(src.read_text())
    pts = {p["id"]: p["id"] for p in d["points"]}
    for old, new in zip(list(pts)[:len(HOSTILE)], HOSTILE):
        pts[old] = f"{new} {old}"
    ims = {im["id"]: im["id"] for im in d["images"]}
    for old, new in zip(list(ims)[:len(HOSTILE)], HOSTILE):
        ims[old] = f"{new} {old}"
    cams = {c["id"]: f"{IFRAME} cam{k}" for k, c in enumerate(d["cameras"])}
    strips = {}
    for p in d["points"]:
        p["id"] = pts[p["id"]]
    for c in d["cameras"]:
        c["id"] = cams[c["id"]]
    for im in d["images"]:
        im["id"] = ims[im["id"]]
        im["camera"] = cams[im["camera"]]
        im["strip"] = strips.setdefault(im["strip"], HOSTILE[(len(strips) + 1) % len(HOSTILE)] + " strip")
    for o in d["observations"]:
        o["image"], o["point"] = ims[o["image"]], pts[o["point"]]
    d["title"] = f"{IFRAME} title <b>b</b>\nsecond \x1b[31mred"
    out = tmp_path / "hostile.json"
    out.write_text(json.dumps(d), encoding="utf-8")
    return out


def hostile_levelling() -> bytes:
    """The demo levelling network with its first point ids replaced (XML-escaped)."""
    text = (Path(__file__).resolve().parents[2] / "data" / "demo-levelling.gkf").read_text(encoding="utf-8")
    for old, new in zip("ABCD", LEVELLING_IDS):
        esc = new.replace("&", "&amp;").replace("&amp;#10;", "&#10;").replace("<", "&lt;").replace('"', "&quot;")
        text = re.sub(rf'(id|from|to)="{old}"', rf'\1="{esc}"', text)
    return text.encode("utf-8")


@pytest.fixture(scope="module")
def hostile_app(serve_app, tmp_path_factory):
    from baarda.dashboard.app import create_app

    path = hostile_block(tmp_path_factory.mktemp("hostile"))
    served = serve_app(lambda: create_app(path))
    served.path = path
    return served


def test_first_page_carries_the_summary_as_text(page, hostile_app):
    """A file the server has analysed: its summary is in the HTML of the page as the server
    sends it, before the scripts (shown before any JavaScript runs), every string from the file
    escaped; once Bokeh renders, the live summary replaces it."""
    import urllib.request

    from baarda.dashboard.state import State
    from baarda.dashboard.text import html_text

    assert State().load(hostile_app.path)          # the server's cache holds the file now
    with urllib.request.urlopen(hostile_app.url, timeout=120) as r:
        html = r.read().decode("utf-8")
    # before Bokeh's scripts: nothing waits for them to be parsed
    assert html.index('id="baarda-first-summary"') < html.index("bokeh.min.js")
    first = html[html.index('id="baarda-first-summary"'):]
    first = first[:first.index("<script")]
    title = f"{IFRAME} title <b>b</b>\nsecond \x1b[31mred"
    assert html_text(title) in first and "Global test" in first
    assert "<iframe" not in first and "<b>b</b>" not in first and "\x1b" not in first
    dialogs = []
    page.on("dialog", lambda d: (dialogs.append(d.message), d.dismiss()))
    page.goto(hostile_app.url)
    live = page.locator(".summary:not(.first-summary)")
    expect(live).to_contain_text(printable(title), timeout=90_000)
    expect(page.locator("#baarda-first-summary")).to_have_count(0)
    assert page.locator(".summary").get_by_text("Global test").count() == 1
    assert dialogs == []


def test_hostile_ids_are_text_everywhere(page, hostile_app, tmp_path, screenshots):
    from tests.browser.test_app import JS_FIGURE_PIXELS, real_errors

    dialogs, errors = [], []
    page.on("dialog", lambda d: (dialogs.append(d.message), d.dismiss()))
    page.on("pageerror", lambda e: errors.append(str(e)))
    n = len(hostile_app.templates)
    page.goto(hostile_app.url)
    summary = page.locator(".summary")
    expect(summary).to_contain_text("Global test", timeout=90_000)
    state = hostile_app.templates[n].state
    # the title: markup as text, the newline and the escape sequence visible as escapes
    expect(summary).to_contain_text(printable(f"{IFRAME} title <b>b</b>\nsecond \x1b[31mred"))
    expect(page.locator(".map-tabs").first).to_be_visible(timeout=90_000)
    page.wait_for_function("(p) => { for (const d of Bokeh.documents) for (const m of d.all_models)"
                           " if (m.constructor.__name__ === 'Title' && String(m.text).startsWith(p)) return true;"
                           " return false; }", arg="Layout", timeout=60_000)

    # click a hostile point on the layout map: the selection panel shows its id as text
    _, pts = state.frames()
    k = state.problem.points.ids.index(next(i for i in state.problem.points.ids if i.startswith(IFRAME)))
    xy = page.evaluate(JS_FIGURE_PIXELS, ["Layout", [float(pts["x"].iat[k])], [float(pts["y"].iat[k])]])
    assert xy, "layout figure not found"
    page.mouse.move(*xy[0])                              # hover: the tooltip
    page.mouse.click(*xy[0])
    info = page.locator(".selection-info")
    expect(info).to_contain_text(f"Point {printable(state.problem.points.ids[k])}", timeout=30_000)
    assert info.locator("iframe, b:has-text('bold')").count() == 0
    for pid in state.problem.points.ids[: len(HOSTILE)]:
        state.param.update(selected_obs=None, selected_point=state.problem.points.ids.index(pid))
        expect(info).to_contain_text(f"Point {printable(pid)}", timeout=30_000)
    page.screenshot(path=str(screenshots / "hostile-selection.png"))

    # the tests table, the image list, the hypotheses with hostile labels
    # (the Suspects view is the first tab on the right now: open the tests table)
    page.get_by_text("Tests table", exact=True).first.click()
    expect(page.locator(".tests-table")).to_contain_text(printable(HOSTILE[4]), timeout=30_000)
    image = next(im["id"] for im in geometry.images(state.problem) if im["id"].startswith(IFRAME))
    point = next(str(ids["point"]) for ids in state.problem.info.ids if ids.get("image") == image)
    state.add_hypothesis({"kind": "image-point", "image": image, "point": point})
    page.get_by_text("Hypotheses", exact=True).first.click()
    expect(page.locator(".hyp-table")).to_contain_text(printable(point), timeout=30_000)
    page.locator(".hyp-kind select").first.select_option(label="point transfer across images")
    page.screenshot(path=str(screenshots / "hostile-hypotheses.png"))

    # the S-base list (Choices.js renders its labels as HTML): opened, the ids show as text
    page.get_by_text("Precision", exact=True).first.click()
    box = page.locator(".sbase-choice input.choices__input--cloned").first
    box.click()
    dropdown = page.locator(".sbase-choice .choices__list--dropdown.is-active").first
    expect(dropdown).to_contain_text(IFRAME, timeout=30_000)
    assert dropdown.locator("iframe, b:has-text('bold')").count() == 0
    page.keyboard.press("Escape")
    page.get_by_text("Image v", exact=True).first.click()
    page.screenshot(path=str(screenshots / "hostile-precision.png"))

    # uploads: a file that fails to read and a levelling network, both with hostile names
    file_input = page.locator(".file-input input[type=file]").first
    file_input.set_input_files(files=[{"name": f"{HOSTILE[1]}{HOSTILE[2]}.gkf", "mimeType": "application/xml",
                                        "buffer": b"<gama-local><network>" + IFRAME.encode()}])
    alert = page.locator(".error-alert")
    expect(alert).to_contain_text(f"Cannot read {HOSTILE[1]}{HOSTILE[2]}.gkf", timeout=60_000)
    assert "/tmp" not in alert.inner_text() and "baarda-upload" not in alert.inner_text()
    assert alert.locator("iframe, b:has-text('bold')").count() == 0
    page.screenshot(path=str(screenshots / "hostile-upload-error.png"))
    # a name with a right-to-left override: the widget's list shows no raw control character,
    # the panel names the file neutralised (issue 25)
    file_input.set_input_files(files=[{"name": "gnp\u202eexe.gkf", "mimeType": "application/xml",
                                        "buffer": b"<gama-local>broken"}])
    expect(alert).to_contain_text("Cannot read gnp", timeout=60_000)
    expect(page.locator(".file-receiving")).to_contain_text("gnp", timeout=30_000)
    assert "\u202e" not in page.locator(".file-input").first.inner_text()
    assert "\u202e" not in page.locator(".file-receiving").first.inner_text()
    page.screenshot(path=str(screenshots / "hostile-upload-rlo.png"))

    # the report of the block, opened in the browser
    with page.expect_download(timeout=120_000) as dl:
        page.get_by_role("button", name="Download HTML report").click()
    report = tmp_path / "report.html"
    dl.value.save_as(report)
    rpage = page.context.new_page()
    rpage.on("dialog", lambda d: (dialogs.append(d.message), d.dismiss()))
    rpage.goto(report.as_uri())
    expect(rpage.locator("h1")).to_contain_text(IFRAME, timeout=60_000)
    assert rpage.locator("iframe, b:has-text('bold')").count() == 0
    rpage.screenshot(path=str(screenshots / "hostile-report.png"))
    rpage.close()

    file_input.set_input_files(files=[{"name": f"{IFRAME}.gkf", "mimeType": "application/xml",
                                        "buffer": hostile_levelling()}])
    expect(page.locator(".file-source")).to_contain_text(f"{IFRAME}.gkf", timeout=90_000)
    expect(summary).to_contain_text("Global test", timeout=60_000)
    assert state.problem.points.ids[0] == IFRAME
    state.param.update(selected_obs=None, selected_point=0)
    expect(info).to_contain_text(f"Point {IFRAME}", timeout=30_000)
    page.screenshot(path=str(screenshots / "hostile-levelling.png"))

    assert dialogs == []
    assert real_errors(errors) == []
