"""The dashboard's views of one core :class:`~baarda.analysis.Analysis`, inline in a notebook.

    import baarda, panel as pn
    pn.extension("tabulator")
    a = baarda.analyze("data/demo-block.json")
    a.view()                 # the maps: layout, redundancy, w, external reliability, MDB
    a.view("suspects")       # the ranked suspects; "tests": the tests table; "app": everything

The views are the served app's own (:mod:`baarda.dashboard.views`) over a
:class:`~baarda.dashboard.state.State` made from the analysis (nothing adjusted again); a click on
a map selects in that state as in the app.
"""

from __future__ import annotations

import holoviews as hv
import panel as pn

from .app import TAB_NAMES, extensions, main_views
from .state import State
from .views import MAP_VIEWS, SummaryHeader, SuspectsView, TestsTable

#: What :func:`view` shows.
WHATS = ("maps", "suspects", "tests", "summary", "app")


def view(analysis, what: str = "maps"):
    """A Panel object showing ``analysis`` (see the module docstring); ``what`` one of
    :data:`WHATS`."""
    if what not in WHATS:
        raise ValueError(f"view: what must be one of {', '.join(WHATS)} (got {what!r})")
    extensions()
    if not hasattr(hv.opts, "Path"):     # a notebook's own pn.extension() loads HoloViews' backend half-way
        hv.extension("bokeh", logo=False)
    state = State.from_analysis(analysis)
    head = pn.pane.HTML(SummaryHeader.html(state), sizing_mode="stretch_width")
    if what == "summary":
        return head
    if what == "suspects":
        return pn.Column(head, SuspectsView(state=state), sizing_mode="stretch_width")
    if what == "tests":
        return pn.Column(head, TestsTable(state=state), sizing_mode="stretch_width")
    if what == "maps":
        tabs = pn.Tabs(*((TAB_NAMES[V.key], V(state=state)) for V in MAP_VIEWS), dynamic=True, sizing_mode="stretch_width")
        return pn.Column(head, tabs, sizing_mode="stretch_width")
    map_tabs, right = main_views(state)
    return pn.Column(head, pn.Row(map_tabs, right, sizing_mode="stretch_width"), sizing_mode="stretch_width")
