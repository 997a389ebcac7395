"""The dashboard application: ``create_app`` builds it, ``serve`` runs it (``baarda serve``).

    from baarda.dashboard.app import serve
    serve("network.gkf")            # http://127.0.0.1:5006/

Without a file the demo problem is opened: ``data/demo-block.json`` if it exists, otherwise the
first Gama network under ``data/`` (``demo-levelling.gkf`` preferred).
"""

from __future__ import annotations

import asyncio
import os
import secrets
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import holoviews as hv
import panel as pn
import panel.reactive
import panel.theme.base
from panel.io import resources as pn_resources
from panel.io.resources import parse_template
from panel.io.state import set_curdoc
from tornado.ioloop import IOLoop

from baarda.build import read_problem
from baarda.errors import BaardaError
from baarda.threads import limit_native_threads, limit_worker_threads

from . import geometry
from .guard import HostCheck, bound_messages, guard_hosts, is_loopback
from .jobs import TASKS, Cancelled, next_tick
from .report import report_html
from .state import State
from .text import html_text
from .views import (MAP_VIEWS, AnalysisPanel, Controls, CriterionView, FilePanel, HypothesisPanel, ImageResidualView,
                    RiskView, SelectionPanel, SummaryHeader, SuspectsView, TaskPanel, TeachingView, TestsTable,
                    InjectPanel)

DATA = Path(__file__).resolve().parents[1] / "data"
#: The server's websocket message limit, checked by Tornado from each frame's header before its
#: payload is read: uploads come in chunks of 4 MB (``UPLOAD_CHUNK``), the largest message a page
#: sends otherwise (a selection of 10⁶ points) is a few MB.
WEBSOCKET_MAX_MB = 16
#: The most binary data one Bokeh message may carry in all its buffers (Bokeh assembles them all
#: before it looks at the message): :func:`baarda.dashboard.guard.bound_messages`.
MESSAGE_MAX_MB = 32
TAB_NAMES = {"layout": "Layout", "redundancy": "Redundancy", "residuals": "w",
             "external": "External", "mdb": "MDB", "precision": "Precision"}


def default_path(data: Path | None = None) -> Path | None:
    """The demo file to open when none is given (looked for in ``data``, default data/), or None."""
    data = DATA if data is None else data
    block = data / "demo-block.json"
    if block.exists():
        return block
    level = data / "demo-levelling.gkf"
    if level.exists():
        return level
    nets = sorted(data.glob("*.gkf")) if data.is_dir() else []
    return nets[0] if nets else None


class Fast(pn.theme.fast.Fast):
    """Panel's Fast design without its web font (Google Fonts), so the app works offline.

    The class keeps the name ``Fast``: Panel finds a design's bundled files by its class name.
    """

    _resources = {**pn.theme.fast.Fast._resources, "font": {}}


#: The page as Panel's FastListTemplate writes it, and the summary of a file the server has
#: analysed written into it as HTML (``first_summary``, the cards of :func:`summary_html`, every
#: string from the file escaped). With a summary, Bokeh's and Panel's scripts (some megabytes,
#: which twenty pages opened at once parse for seconds) move from the head to the end of the
#: body, after the summary: it shows as soon as the browser has the page, before any of them
#: has run. A script puts it where the live summary will be (marks the time:
#: ``performance.mark("baarda-first-summary")``) and removes it once Bokeh renders the main area.
#: The page is held invisible until the summary is in place (a style the script removes; an
#: animation shows the page after 5 s should the script not run): the browser's first paint is
#: never a page without it (a header painted while the rest of the page was being parsed was).
FIRST_PAGE = """{% extends "fast/list/fast_list_template.html" %}
{% block js_resources %}{% if not first_summary %}{{ super() }}{% endif %}{% endblock %}
{% block inner_body %}
<a id="baarda-skip" class="baarda-skip" href="#main">Skip to the maps and suspects</a>
<style>.baarda-skip{position:absolute;left:8px;top:-60px;z-index:1000;padding:8px 12px;background:#fff;color:#1f4e9c;
border:2px solid #0b5cad;border-radius:4px;font-weight:600}.baarda-skip:focus{top:8px}</style>
{% if first_summary %}
<style id="baarda-hold">body{visibility:hidden;animation:baarda-show 0s 5s forwards}
@keyframes baarda-show{to{visibility:visible}}</style>
{% endif %}
{{ super() }}
{% if first_summary %}
<div id="baarda-first-summary" class="summary first-summary" style="margin:5px 10px">{{ first_summary }}</div>
<script type="text/javascript">
(function () {
  var first = document.getElementById("baarda-first-summary");
  var hold = document.getElementById("baarda-hold");
  var root = document.querySelector("#main [data-root-id]");
  if (!root) { first.remove(); hold.remove(); return; }
  root.parentNode.insertBefore(first, root);
  performance.mark("baarda-first-summary");
  hold.remove();
  new MutationObserver(function (_, obs) {
    if (root.childNodes.length) { first.remove(); obs.disconnect(); }
  }).observe(root, {childList: true});
})();
</script>
{{ bokeh_js }}
{% endif %}
<script type="text/javascript">{{ keyboard_js }}</script>
{% endblock %}
"""

#: Keyboard and screen-reader basics for Bokeh's tab bars and checkboxes (issue 15, item 6), in
#: every shadow root of the page: each bar is a ``tablist``, each header a ``tab`` with
#: ``aria-selected``; Enter or Space opens the focused tab, the arrow keys, Home and End move to
#: the previous, next, first and last tab and open it. Only the open tab is in the Tab order (a
#: roving tabindex), so the Tab key goes from one bar to the next, the right panel's included. A
#: checkbox's label toggles it and is its accessible name. Bokeh redraws a bar's headers when its
#: tabs change: the page is looked at again after every click and key, and once a second.
#: A table's rows (suspects, tests table) are rows of which one is in the Tab order: Enter or Space
#: selects the focused row as a click does, the arrow keys, Home and End move between rows (issue
#: 31, item 8). The page's first link skips to the map tabs; a toolbar's focused button has a
#: 2-px ring (Bokeh draws a faint dotted one). The maps' frames grow to the width of their tabs.
KEYBOARD_JS = """
(function () {
  if (window.baardaKeyboard) return;
  window.baardaKeyboard = true;
  let moves = 0;
  function roots(root, out) {
    out.push(root);
    for (const el of root.querySelectorAll('*')) if (el.shadowRoot) roots(el.shadowRoot, out);
    return out;
  }
  function onKey(e) {
    const tab = e.currentTarget, tabs = Array.from(tab.parentNode.querySelectorAll('.bk-tab'));
    const i = tabs.indexOf(tab);
    let j = null;
    if (e.key === 'Enter' || e.key === ' ') { e.preventDefault(); tab.click(); setTimeout(enhance, 0); return; }
    if (e.key === 'ArrowRight' || e.key === 'ArrowDown') j = (i + 1) % tabs.length;
    else if (e.key === 'ArrowLeft' || e.key === 'ArrowUp') j = (i - 1 + tabs.length) % tabs.length;
    else if (e.key === 'Home') j = 0;
    else if (e.key === 'End') j = tabs.length - 1;
    if (j === null) return;
    e.preventDefault();
    const titles = tabs.map(t => t.textContent).join('\u0000');
    const key = ++moves;                  // a later key press ends this one's refocusing
    tabs[j].click();
    // Panel redraws the tab bar when the open tab changes: focus tab j of the bar with the
    // same headers as it is then
    let tries = 0;
    (function refocus() {
      if (key !== moves) return;
      enhance();
      let now = null;
      for (const root of roots(document, []))
        for (const bar of root.querySelectorAll('.bk-headers-wrapper')) {
          const ts = Array.from(bar.querySelectorAll('.bk-tab'));
          if (ts.map(t => t.textContent).join('\u0000') === titles) now = ts[j];
        }
      // (for ten seconds: the redraw comes after the server has built the tab's view; the
      // focus is moved only while it is nowhere, so a user who moved on keeps it)
      let at = document.activeElement;
      while (at && at.shadowRoot && at.shadowRoot.activeElement) at = at.shadowRoot.activeElement;
      if (now && (at === null || at === document.body || at === tabs[j] || !at.isConnected)) now.focus();
      if (++tries < 200) setTimeout(refocus, 50);
    })();
  }
  // a table row (the suspects, the tests table) is selected by Enter or Space as by a click;
  // the arrow keys move between rows, Home and End to the first and last (only one row of a
  // table is in the Tab order: the selected one, else the first)
  function onRow(e) {
    const row = e.currentTarget;
    if (e.target !== row) return;
    const rows = Array.from(row.parentNode.querySelectorAll(':scope > .tabulator-row'));
    const i = rows.indexOf(row);
    let j = null;
    if (e.key === 'Enter' || e.key === ' ') {
      e.preventDefault();
      const cell = row.querySelector('.tabulator-cell');
      (cell || row).click();
      return;
    }
    if (e.key === 'ArrowDown') j = Math.min(i + 1, rows.length - 1);
    else if (e.key === 'ArrowUp') j = Math.max(i - 1, 0);
    else if (e.key === 'Home') j = 0;
    else if (e.key === 'End') j = rows.length - 1;
    if (j === null) return;
    e.preventDefault();
    for (const r of rows) r.tabIndex = -1;
    rows[j].tabIndex = 0;
    rows[j].focus();
    rows[j].scrollIntoView({block: 'nearest'});
  }
  // the skip link: to the open tab of the map tabs (the first bar of the main area)
  function skip(e) {
    e.preventDefault();
    for (const root of roots(document, [])) {
      const tab = root.querySelector('.bk-tab.bk-active');
      if (tab) { tab.tabIndex = 0; tab.focus(); return; }
    }
  }
  //: the focus ring of a toolbar's buttons (Bokeh's is a 1-px dotted line)
  const TOOLBAR_FOCUS = ':host > :not(.bk-divider):focus-visible { outline: 2px solid #0b5cad !important; ' +
                        'outline-offset: -2px !important; }';
  // the maps use the width they have (issue 31, item 6): a map's frame, drawn for 420 px by the
  // server, is scaled (width and height by one factor, so the scales stay equal and the ranges
  // as they are) to fill its tabs, at most 2.2 times and no taller than the window leaves room for
  function fitMaps() {
    if (!window.Bokeh) return;
    let tabs = null;
    for (const root of roots(document, [])) { tabs = root.querySelector('.map-tabs') || tabs; if (tabs) break; }
    const W = tabs ? tabs.getBoundingClientRect().width : 0;
    if (!(W > 0)) return;
    for (const doc of Bokeh.documents) for (const m of doc.all_models) {
      if (m.constructor.__name__ !== 'Figure' || !m.tags || !m.tags.includes('baarda-map')) continue;
      if (!m.frame_width || !m.frame_height) continue;
      if (m.baardaSet !== m.frame_width) m.baardaBase = [m.frame_width, m.frame_height];
      const v = Bokeh.index.find_one(m);
      if (!v || !v.el || !v.el.isConnected) continue;
      const r = v.el.getBoundingClientRect();
      if (!(r.width > 0)) continue;
      const [fw, fh] = m.baardaBase, deco = r.width - m.frame_width;
      const k = Math.max(1, Math.min(2.2, (W - deco - 24) / fw, Math.max(fh, window.innerHeight - 260) / fh));
      const w = Math.round(fw * k), h = Math.round(fh * k);
      if (Math.abs(w - m.frame_width) > 4) {
        m.baardaSet = w;
        m.frame_height = h;
        m.frame_width = w;
      }
    }
  }
  function onLabel(e) {
    const box = e.currentTarget.previousElementSibling;
    if (box && !box.disabled) box.click();
  }
  function enhance() {
    for (const root of roots(document, [])) {
      for (const bar of root.querySelectorAll('.bk-headers-wrapper')) {
        bar.setAttribute('role', 'tablist');
        // the tab bar first in the focus order, then its panel (the WAI-ARIA tabs pattern):
        // Bokeh places the header by its grid area, so its place among the shadow root's
        // children is not seen, but it may append it after the panel it redraws, and the Tab
        // key then left the panel for the page's end without ever reaching the bar
        const header = bar.parentNode;
        if (header && header.parentNode === root) {
          let first = root.firstElementChild;
          while (first && (first.tagName === 'STYLE' || first.tagName === 'LINK')) first = first.nextElementSibling;
          if (first && first !== header) root.insertBefore(header, first);
        }
        for (const tab of bar.querySelectorAll('.bk-tab')) {
          const open = tab.classList.contains('bk-active');
          tab.setAttribute('role', 'tab');
          tab.setAttribute('aria-selected', open ? 'true' : 'false');
          tab.tabIndex = open ? 0 : -1;
          if (!tab.baardaKeys) { tab.baardaKeys = true; tab.addEventListener('keydown', onKey); }
        }
      }
      if (root.host && root.host.classList.contains('bk-Toolbar') && !root.baardaFocus) {
        root.baardaFocus = true;
        const style = document.createElement('style');
        style.textContent = TOOLBAR_FOCUS;
        root.appendChild(style);
      }
      for (const body of root.querySelectorAll('.tabulator-tableholder .tabulator-table')) {
        const rows = Array.from(body.querySelectorAll(':scope > .tabulator-row'));
        if (!rows.length) continue;
        const current = rows.find(r => r.tabIndex === 0 && r.baardaRow) ||
                        rows.find(r => r.classList.contains('tabulator-selected')) || rows[0];
        for (const r of rows) {
          if (!r.baardaRow) {
            r.baardaRow = true;
            r.setAttribute('role', 'row');
            r.addEventListener('keydown', onRow);
          }
          r.setAttribute('aria-selected', r.classList.contains('tabulator-selected') ? 'true' : 'false');
          const focused = root.activeElement === r;
          r.tabIndex = (r === current || focused) ? 0 : -1;
        }
      }
      // a checkbox's label (Bokeh draws it as a div beside the box) toggles it and names it
      for (const box of root.querySelectorAll('input[type=checkbox]')) {
        const label = box.nextElementSibling;
        if (!label || !label.classList.contains('bk-label') || label.baardaLabel) continue;
        label.baardaLabel = true;
        box.setAttribute('aria-label', label.textContent);
        label.style.cursor = 'pointer';
        label.addEventListener('click', onLabel);
      }
    }
  }
  const link = document.getElementById('baarda-skip');
  if (link) link.addEventListener('click', skip);
  document.addEventListener('click', function () { setTimeout(enhance, 0); }, true);
  document.addEventListener('keyup', function () { setTimeout(enhance, 0); }, true);
  setInterval(enhance, 1000);
  setInterval(fitMaps, 500);
  window.addEventListener('resize', fitMaps);
  enhance();
})();
"""

#: A focus ring on every control reached by the keyboard (tabs, buttons, inputs, table cells),
#: added to every component's stylesheets (Panel's ``raw_css``: inside their shadow roots).
FOCUS_CSS = (":focus-visible { outline: 2px solid #0b5cad !important; outline-offset: 2px; }"
             " .bk-tab:focus-visible { outline-offset: -2px; }")


class FastListTemplate(pn.template.FastListTemplate):
    """Panel's FastListTemplate whose page carries the summary before any JavaScript runs
    (:data:`FIRST_PAGE`). The class keeps Panel's name: Panel finds a template's bundled
    files by its class name."""

    def __init__(self, first_summary: str = "", **params):
        super().__init__(**params)
        self.template = self.nb_template = parse_template(FIRST_PAGE)
        self.first_summary = first_summary

    def server_doc(self, doc=None, title=None, location=True):
        doc = super().server_doc(doc, title, location)
        doc.template_variables["first_summary"] = self.first_summary
        doc.template_variables["keyboard_js"] = KEYBOARD_JS
        return doc


def _server_dist_path(cdn="auto") -> str:
    """Panel's dist path as the server has it, never the CDN (see :func:`_local_stylesheets`)."""
    return pn_resources.get_dist_path(cdn=False)


def _patch_stylesheet_locally(stylesheet, dist_url):
    """Panel's ``patch_stylesheet`` with this server's dist path where Panel would use the CDN."""
    if dist_url == pn_resources.CDN_DIST:
        dist_url = _server_dist_path()
    return _PANEL_PATCH_STYLESHEET(stylesheet, dist_url)


_PANEL_PATCH_STYLESHEET = pn_resources.patch_stylesheet


def _local_stylesheets() -> None:
    """Every served component links Panel's ``loading.css`` from this server, never from the CDN.

    Panel picks the link through the process-wide resource mode, which it switches for a moment
    while it writes resources (``set_resource_mode``); a component made on another thread in
    that moment linked ``cdn.holoviz.org`` — unreachable offline, a failed request in the page
    (seen in the browser tests under load). The server serves the same file under /static."""
    panel.reactive.get_dist_path = _server_dist_path
    # A model updated outside a document that has Panel's ``dist_url`` (not yet attached, or
    # attached to a document without the template's variables) has its stylesheets patched
    # towards the CDN by Panel: ``loading.css?v=…`` from cdn.holoviz.org (seen again under load)
    panel.reactive.patch_stylesheet = _patch_stylesheet_locally
    panel.theme.base.patch_stylesheet = _patch_stylesheet_locally


#: Draw the maps with WebGL (``baarda serve --webgl``). Off by default: where the browser renders
#: without a GPU (a virtual machine, a remote desktop, a blocklisted driver, headless Chromium)
#: WebGL runs in software, and one repaint of a map of a real block (Ladybug's 63,686 image
#: points) took 15-45 s there against under a second on the 2D canvas; every change of the
#: page's layout (opening a tab of the right panel) repaints the maps. On a GPU, WebGL pans and
#: zooms blocks of 10⁵ and more image points more smoothly.
WEBGL = False


def extensions():
    if _served():
        _local_stylesheets()
    pn.extension("tabulator", "filedropper", notifications=False, sizing_mode="stretch_width")
    if FOCUS_CSS not in pn.config.raw_css:
        pn.config.raw_css = [*pn.config.raw_css, FOCUS_CSS]
    # HoloViews' backend is the process's (a sixth of a session's setup when set each time)
    if hv.Store.current_backend != "bokeh" or "bokeh" not in hv.Store.renderers:
        hv.extension("bokeh", logo=False)
    hv.renderer("bokeh").webgl = WEBGL       # (the plots' renderers copy it from this one)


#: Views of different sessions are built one at a time: a session being built holds the
#: interpreter for a second or two, and the event loop (pages of new sessions, clicks in
#: others) competes with one builder instead of twenty.
_BUILD_LOCK = threading.Lock()
#: The thread that builds the views of served sessions (one at a time, after the summaries):
#: the task threads that read files are never held up by it.
_BUILDER = ThreadPoolExecutor(max_workers=1, thread_name_prefix="baarda-build")
#: Sessions whose summary is not there yet: the maps of other sessions wait for them (at most
#: :data:`SUMMARY_FIRST` seconds), so that twenty users opening the page at once all see their
#: summary first, and the heavy maps and tables come after.
_PENDING = [0]
_PENDING_CV = threading.Condition()
SUMMARY_FIRST = 15.0


def builds_done(timeout: float = 120.0) -> None:
    """Wait until the view builder has done every build it was given (tests; a server shutting
    down). TimeoutError if it has not within ``timeout`` seconds."""
    _BUILDER.submit(lambda: None).result(timeout=timeout)


def pending(delta: int) -> None:
    """Count sessions still reading and adjusting their file (+1 / −1): map builds wait while any is (:func:`_summaries_first`)."""
    with _PENDING_CV:
        _PENDING[0] += delta
        _PENDING_CV.notify_all()


def _summaries_first(timeout: float = SUMMARY_FIRST) -> None:
    with _PENDING_CV:
        _PENDING_CV.wait_for(lambda: _PENDING[0] <= 0, timeout)


def _timing(session: str, event: str) -> None:
    """With ``BAARDA_TIMING=1`` in the server's environment, a line ``baarda-timing WALL SESSION
    EVENT`` on stderr (request, onload, summary, build-start, maps): where a session's seconds
    go (``bench/bench_load.py`` reads them)."""
    if os.environ.get("BAARDA_TIMING"):
        print(f"baarda-timing {time.time():.3f} {session} {event}", file=sys.stderr, flush=True)


#: The event-loop watch has been started (once per process, :func:`_watch_loop`).
_WATCHING = []
STALL = 0.1       # seconds: a longer delay of the event loop is logged (BAARDA_TIMING)


def _watch_loop() -> None:
    """With ``BAARDA_TIMING=1``, a task on the server's event loop that sleeps 50 ms at a time
    and logs ``baarda-timing WALL - stall:SECONDS`` whenever it woke more than :data:`STALL`
    late: how long the loop could not answer anyone (``bench/bench_load.py`` reports them)."""
    if not os.environ.get("BAARDA_TIMING") or _WATCHING:
        return
    _WATCHING.append(True)

    async def watch():
        while True:
            t = time.perf_counter()
            await asyncio.sleep(0.05)
            late = time.perf_counter() - t - 0.05
            if late > STALL:
                _timing("-", f"stall:{late:.2f}")
    IOLoop.current().add_callback(watch)


def _served() -> bool:
    doc = pn.state.curdoc
    return doc is not None and doc.session_context is not None


def create_app(path=None, problem=None, background: bool | None = None, inputs: dict | None = None):
    """The dashboard for ``path`` (or an already read ``problem``) as a Panel template.

    inputs: the companion files of ``path`` (control with roles, GNSS centres, IMU attitudes;
    :meth:`baarda.dashboard.state.State.load`), never applied to an uploaded file.

    Served (``background`` defaults to True in a server session), the page comes up at once
    with the sidebar and the summary area; the file is read and adjusted on a worker thread
    once the page has loaded (a file read before comes from the server's cache), the summary
    appears as soon as the adjustment is there, and the maps and tables are built after it.
    """
    extensions()
    background = _served() if background is None else bool(background)
    sid = pn.state.curdoc.session_context.id if background and _served() else "-"
    if sid != "-":
        _watch_loop()
    doc = pn.state.curdoc if background and _served() else None
    _timing(sid, "request")
    if problem is not None:
        state = State(problem=problem, path=path)
    else:
        path = path or default_path()
        state = State()
        if path is None:
            state.error = ("No file given and no demo file under data/ (demo-block.json or a .gkf); "
                           "upload a file.")
        elif not background:
            state.load(path, inputs=inputs)
        else:
            # a file the server has analysed (at its start, or for another session): its
            # summary is in the page as it is sent; only the maps come after
            state.load_cached(path, inputs=inputs)
    state.background = background
    first = SummaryHeader.html(state) if background and state.results is not None else ""
    template = FastListTemplate(first_summary=first, title="baarda", accent="#1f4e9c", header_background="#1f4e9c",
                                            sidebar_width=290, main_layout=None, theme_toggle=False,
                                            design=Fast, font="system-ui, sans-serif")
    files = FilePanel(state=state, render_report=report_html)
    # served, the sidebar's views are made with the page's first update (onload): the page the
    # server sends first is the header and the summary only (a tenth of a second of the event
    # loop per session, was three quarters)
    sidebar = pn.Column(sizing_mode="stretch_width", css_classes=["sidebar-views"])
    template.sidebar.append(sidebar)
    waiting = pn.pane.HTML("<i>Drawing the maps…</i>" if state.results is not None else
                           "<i>Reading and adjusting the file…</i>" if (path and not state.error)
                           else "<i>Upload a file (sidebar).</i>", css_classes=["main-waiting"])
    content = pn.Column(waiting, sizing_mode="stretch_width", min_width=MAP_MIN_WIDTH)

    waits = {"summary": False}

    def summary_shown(*_):
        if waits["summary"]:
            waits["summary"] = False
            _timing(sid, "summary")
            pending(-1)

    def build():
        # not served in the background (scripts, tests): the whole view at once, here
        try:
            main = _attach(state, *main_views(state))
        except Exception as err:  # noqa: BLE001 - a message in the page, never a silent blank
            main = _build_error(err)
        content.objects = [main]

    def live() -> bool:
        return not state.jobs.closed and _connected(doc)

    def piece(fn):
        # one piece of the build on the event loop (HoloViews is not thread-safe); False once
        # the session's page is gone (it is not built further)
        def run():
            if not live():
                return False
            with _BUILD_LOCK:
                fn()
            return True
        return state.on_loop(run)

    def build_later():
        # on the builder thread, one session after another, after the summaries of waiting
        # sessions: each view is made in an event-loop callback of its own, and all are attached
        # in one more (at once: the browser lays the page out once), so that the events of other
        # sessions run in between; a session whose page is gone (closed, or the session
        # destroyed) is not built, nor built further
        _summaries_first()

        def make(fn):
            box = {}
            if not piece(lambda: box.setdefault("view", fn())):
                raise _Gone()
            return box["view"]

        def attach():
            content.objects = [_attach(state, *parts)]
            _timing(sid, "maps")

        try:
            if not piece(lambda: None):          # the page is gone already: nothing is made
                raise _Gone()
            _timing(sid, "build-start")
            parts = main_views(state, make=make)
            if not piece(attach):
                raise _Gone()
        except _Gone:
            _timing(sid, "build-skipped")
        except Cancelled:        # the session ended while a piece waited for the loop
            pass
        except Exception as err:  # noqa: BLE001 - a message in the page, never a silent blank
            message = _build_error(err)
            try:
                state.on_loop(lambda: setattr(content, "objects", [message]))
            except Exception:  # noqa: BLE001 - the session ended meanwhile
                pass

    def rebuild(*_):
        # a new problem gets new views (map extents, frame sizes and widgets depend on it)
        summary_shown()
        if background and state.jobs.loop_call is not None:
            _BUILDER.submit(build_later)
        else:
            build()

    if state.results is not None and not background:
        rebuild()
    state.param.watch(rebuild, "problem")
    state.param.watch(lambda e: setattr(content, "objects", [pn.pane.HTML("<i>Adjusting the new file…</i>")]),
                      "replacing")
    template.main.append(pn.Column(SummaryHeader(state=state), content, sizing_mode="stretch_width",
                                   min_width=MAP_MIN_WIDTH))

    def fill_sidebar():
        sidebar.objects = [files, TaskPanel(state=state), Controls(state=state), SelectionPanel(state=state)]

    if background:
        pn.state.onload(fill_sidebar)
    else:
        fill_sidebar()
    if background:
        if path is not None and state.results is None and not state.error:
            shown = Path(str(path)).name
            waits["summary"] = True
            pending(+1)
            state.param.watch(summary_shown, ["results", "error"])
            def onload():
                _timing(sid, "onload")
                state.submit(f"reading {shown}", lambda: state.load(path, inputs=inputs))
            pn.state.onload(onload)

        if doc is not None:
            def loop_call(fn, doc=doc):
                def run():
                    with set_curdoc(doc):
                        fn()
                next_tick(doc, run)
            state.jobs.loop_call = loop_call
        if state.results is not None:
            # taken from the cache: the summary is in the page; the maps are built once the
            # page is up, one session at a time, after the summaries of sessions still loading
            _timing(sid, "summary")
            pn.state.onload(lambda: _BUILDER.submit(build_later))

        def destroyed(_context):
            state.jobs.closed = True
            summary_shown()
            state.cancel()
            files.uploads.close()          # temporary files removed, the session's data dropped
        pn.state.on_session_destroyed(destroyed)
    template.state = state
    template.files = files
    return template


#: The narrowest the map tabs get before the tables go below them: a map's frame (420 px), its
#: axes, colour bar and legend.
MAP_MIN_WIDTH = 640
#: Tab headers that do not fit one line wrap to a second (Bokeh cuts them off otherwise).
WRAP_TAB_HEADERS = ".bk-headers-wrapper { flex-wrap: wrap; overflow: visible; } .bk-tab { white-space: nowrap; }"
#: The narrowest the tables get beside the maps (both grow with the screen; below the maps,
#: where the main area holds less than both, the tables take the whole row).
RIGHT_MIN_WIDTH = 420


def main_views(state, make=None):
    """The maps in tabs (left) and the tests table / hypotheses / teaching in tabs (right), made
    but not yet rendered (the summary is above them, built once per session).

    ``make(fn)`` makes each view (``fn()``, by default here): a served session's builder passes
    one that runs it on the event loop, one view per callback, so that the events of other
    sessions run between the views (a tenth of a second each, not the whole build at once).
    """
    make = make or (lambda fn: fn())
    maps = []
    for V in MAP_VIEWS:
        maps.append((TAB_NAMES[V.key], make(lambda V=V: V(state=state))))
        if V.key == "residuals" and geometry.images(state.problem):
            maps.append(("Image v", make(lambda: ImageResidualView(state=state))))
    maps.append(("Criterion", make(lambda: CriterionView(state=state))))
    suspects, table, hypotheses, analysis = (make(lambda V=V: V(state=state)) for V in (
        SuspectsView, TestsTable, HypothesisPanel, AnalysisPanel))
    teaching = make(lambda: pn.Column(InjectPanel(state=state), TeachingView(state=state), RiskView(state=state),
                                      scroll=True, height=640, sizing_mode="stretch_width"))

    def tabs():
        map_tabs = pn.Tabs(*maps, dynamic=True, sizing_mode="stretch_width", min_height=660,
                           min_width=MAP_MIN_WIDTH, styles={"flex": f"1 1 {MAP_MIN_WIDTH}px"},
                           stylesheets=[WRAP_TAB_HEADERS], css_classes=["map-tabs"])

        def shown(*_):
            # only the map on screen follows the state; the others catch up when shown
            for k, (_, view) in enumerate(maps):
                if hasattr(view, "set_shown"):
                    view.set_shown(k == map_tabs.active)
        map_tabs.param.watch(shown, "active")
        shown()
        right = pn.Tabs(("Suspects", suspects), ("Tests table", table), ("Hypotheses", hypotheses),
                        ("Find errors", analysis), ("Teaching", teaching),
                        dynamic=True, sizing_mode="stretch_width", min_width=RIGHT_MIN_WIDTH, height=660,
                        styles={"flex": f"1 1 {RIGHT_MIN_WIDTH}px"}, stylesheets=[WRAP_TAB_HEADERS],
                        css_classes=["right-tabs"])
        return map_tabs, right
    return make(tabs)


def _attach(state, map_tabs, right):
    """The maps and the tables side by side, shown as loading while the state is busy."""
    # side by side where the main area holds both (1920 px screens), else the tables below the
    # maps: nothing overlaps, nothing is cut (1024-1600 px: laptops and projectors)
    row = pn.FlexBox(map_tabs, right, flex_direction="row", flex_wrap="wrap", align_content="flex-start",
                     sizing_mode="stretch_width", css_classes=["main-row"], styles={"row-gap": "12px"})
    row.loading = state.busy
    state.param.watch(lambda e: setattr(row, "loading", e.new), "busy")
    return row


class _Gone(Exception):
    """A session's page went away while its views were being made (they are not made further)."""


def _build_error(err) -> pn.pane.HTML:
    return pn.pane.HTML(f"<b>The views could not be built:</b> {html_text(type(err).__name__)}: "
                        f"{html_text(err)}", css_classes=["main-error"])


def _connected(doc) -> bool:
    """Whether the page of a served session is still open: its session is not destroyed and
    has a connection. (Bokeh destroys the session of a closed page only some 15-30 s later,
    ``unused_session_lifetime``; until then its document lives on without a viewer.) True
    outside a server."""
    ctx = None if doc is None else doc.session_context
    if ctx is None:
        return True
    if ctx.destroyed:
        return False
    for session in ctx.server_context.sessions:
        if session.id == ctx.id:
            return session.connection_count > 0
    return False


def warm(path, inputs: dict | None = None):
    """Read and adjust the served file once at start, on a task thread, into the server's cache
    (:func:`baarda.dashboard.state.State.load`): the sessions that open the page take it from
    there instead of waiting for the first one to adjust it. Prints ``baarda dashboard: FILE
    read and adjusted in S s`` (or why not) when done. Returns the Future."""

    def run():
        t0 = time.perf_counter()
        st = State()
        ok = st.load(path, inputs=inputs)
        name = Path(str(path)).name
        print(f"baarda dashboard: {name} read and adjusted in {time.perf_counter() - t0:.1f} s" if ok
              else f"baarda dashboard: {st.error}", flush=True)
        return ok
    return TASKS.submit(run)


def serve(path=None, port: int = 5006, address: str = "127.0.0.1", show: bool = False, webgl: bool = False,
          allow_hosts=(), token: str | None = None, allow_remote: bool = False, inputs: dict | None = None,
          **kwargs):
    """Serve the dashboard on ``address:port`` (loopback by default) and print its URL.

    show: open a browser (only if asked; there may be no display). webgl: draw the maps with
    WebGL (:data:`WEBGL`). Every request whose Host header names a host the server does not
    serve is refused (:mod:`baarda.dashboard.guard`; ``allow_hosts``: more names to serve).
    A non-loopback ``address`` serves the network: it needs ``token`` (a password to sign in
    with, any user name) or ``allow_remote`` (no authentication, said in a printed line);
    otherwise BaardaError. inputs: the companion files of ``path`` (``baarda serve FILE
    --control CSV --gnss CSV --imu CSV``; :meth:`baarda.dashboard.state.State.load`). Blocks
    until stopped.
    """
    global WEBGL
    WEBGL = bool(webgl)
    limit_native_threads()               # BLAS: the whole process; numba: this (the event loop's) thread
    limit_worker_threads()
    remote = not is_loopback(address)
    if inputs:
        # a bad companion file: the reader's one line (file, line, field) before the server starts
        read_problem(path, **inputs)
    if token is not None and not token.strip():
        raise BaardaError("--token must not be empty")
    if remote and token is None and not allow_remote:
        raise BaardaError(f"--address {address} serves the dashboard to the network: give --token TOKEN "
                          "(a password to sign in with) or --allow-remote (no authentication)")
    host = f"[{address}]" if ":" in address else address
    url = f"http://{host}:{port}/"
    print(f"baarda dashboard: {url}", flush=True)
    if remote and token is None:
        print(f"baarda dashboard: served to the network on {host}:{port} without authentication "
              "(--allow-remote): anyone who can reach it can read the file and upload files", flush=True)
    elif token is not None:
        print("baarda dashboard: sign in with any user name and the token as password", flush=True)
    if (path or default_path()) is not None:
        warm(path or default_path(), inputs)
    kwargs.setdefault("websocket_max_message_size", WEBSOCKET_MAX_MB * 1024 * 1024)
    if token is not None:
        kwargs.setdefault("basic_auth", token)
        kwargs.setdefault("cookie_secret", secrets.token_hex(32))
    origins = [f"{host}:{port}", f"localhost:{port}", f"127.0.0.1:{port}"] + [f"{n}:{port}" for n in allow_hosts]
    server = pn.serve({"/": lambda: create_app(path, inputs=inputs)}, port=port, address=address, show=show,
                      websocket_origin=list(dict.fromkeys(origins)), title="baarda", start=False, **kwargs)
    guard_hosts(server, HostCheck(allow_hosts, remote=remote))
    bound_messages(MESSAGE_MAX_MB * 1024 * 1024)
    server.start()
    try:
        server.io_loop.start()
    except RuntimeError:
        pass
    return server
