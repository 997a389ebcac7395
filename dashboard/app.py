"""The dashboard application: ``create_app`` builds it, ``serve`` runs it (``baarda serve``).

    from baarda.dashboard.app import serve
    serve("network.gkf")            # http://127.0.0.1:5006/

Without a file the demo problem is opened: ``data/demo-block.json`` if it exists, otherwise the
first Gama network under ``data/`` (``demo-levelling.gkf`` preferred).
"""

from __future__ import annotations

from pathlib import Path

import holoviews as hv
import panel as pn

from .state import State
from .views import (MAP_VIEWS, AnalysisPanel, Controls, CriterionView, FilePanel, HypothesisPanel, ImageResidualView,
                    RiskView, SelectionPanel, SummaryHeader, TeachingView, TestsTable, InjectPanel)

DATA = Path(__file__).resolve().parents[1] / "data"
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


def _extensions():
    pn.extension("tabulator", notifications=False, sizing_mode="stretch_width")
    hv.extension("bokeh", logo=False)


def create_app(path=None, problem=None):
    """The dashboard for ``path`` (or an already read ``problem``) as a Panel template."""
    _extensions()
    if problem is not None:
        state = State(problem=problem, path=path)
    else:
        path = path or default_path()
        state = State(path) if path else State()
        if path is None:
            state.error = ("No file given and no demo file under data/ (demo-block.json or a .gkf); "
                           "upload a file.")
    template = pn.template.FastListTemplate(title="baarda", accent="#1f4e9c", header_background="#1f4e9c",
                                            sidebar_width=290, main_layout=None, theme_toggle=False,
                                            design=Fast, font="system-ui, sans-serif")
    files = FilePanel(state=state)
    template.sidebar.append(files)
    content = pn.Column(_main(state) if state.results is not None else pn.pane.Markdown("Upload a file (sidebar)."),
                        sizing_mode="stretch_width")
    template.main.append(content)

    def rebuild(*_):
        # a new problem gets new views (map extents, frame sizes and widgets depend on it)
        content.objects = [_main(state)]

    state.param.watch(rebuild, "problem")
    template.sidebar.extend([Controls(state=state), SelectionPanel(state=state)])
    template.state = state
    return template


def _main(state):
    """Summary on top; the maps in tabs on the left, table / hypotheses / teaching on the right."""
    maps = []
    for V in MAP_VIEWS:
        view = V(state=state)
        maps.append((TAB_NAMES[V.key], view))
        if V.key == "residuals" and state.images:
            maps.append(("Image v", ImageResidualView(state=state)))
    maps.append(("Criterion", CriterionView(state=state)))
    map_tabs = pn.Tabs(*maps, dynamic=True, sizing_mode="stretch_width", min_height=660,
                       css_classes=["map-tabs"])
    right = pn.Tabs(("Tests table", TestsTable(state=state)), ("Hypotheses", HypothesisPanel(state=state)),
                    ("Find errors", AnalysisPanel(state=state)),
                    ("Teaching", pn.Column(InjectPanel(state=state), TeachingView(state=state),
                                           RiskView(state=state), scroll=True, height=640,
                                           sizing_mode="stretch_width")),
                    dynamic=True, sizing_mode="fixed", width=590, height=660, css_classes=["right-tabs"])
    main = pn.Column(SummaryHeader(state=state),
                     pn.Row(map_tabs, right, sizing_mode="stretch_width"),
                     sizing_mode="stretch_width")
    main.loading = state.busy
    state.param.watch(lambda e: setattr(main, "loading", e.new), "busy")
    return main


def serve(path=None, port: int = 5006, address: str = "127.0.0.1", show: bool = False, **kwargs):
    """Serve the dashboard on ``address:port`` (loopback by default) and print its URL.

    show: open a browser (only if asked; there may be no display). Blocks until stopped.
    """
    url = f"http://{address}:{port}/"
    print(f"baarda dashboard: {url}", flush=True)
    return pn.serve({"/": lambda: create_app(path)}, port=port, address=address, show=show,
                    websocket_origin=[f"{address}:{port}", f"localhost:{port}"] if address in
                    ("127.0.0.1", "localhost") else [f"{address}:{port}"],
                    title="baarda", **kwargs)
