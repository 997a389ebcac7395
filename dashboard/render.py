"""HoloViews objects rendered to Bokeh figures and HTML outside a served page (the report).

``hv.render`` attaches a figure to Bokeh's ``curdoc()``, and ``bokeh.embed.components`` takes
its theme from it. ``curdoc()`` reads a process-wide stack of documents: while a server thread
runs a session's code, or after a session's code left its document on the stack and the server
destroyed it, ``curdoc()`` in every other thread is that session's document. A report written
then (by a session's worker thread, or by any code in a process that also serves) would land in
another user's page, or fail on the destroyed document ("'Document' object has no attribute
'_theme'"). These functions give each figure a document of its own and name the theme.
"""
from __future__ import annotations

import holoviews as hv
from bokeh.document import Document
from bokeh.embed import components as _components


def _theme():
    return hv.renderer("bokeh").theme


def figure(obj):
    """The Bokeh model of the HoloViews object ``obj``, in a new Bokeh document of its own
    with HoloViews' theme, drawn on the 2D canvas."""
    # HoloViews attaches a plot to a given document in its server mode only; otherwise it
    # takes curdoc()'s
    # (on the 2D canvas: a report opens, and prints, where the reader's browser has no GPU)
    renderer = hv.renderer("bokeh").instance(mode="server", webgl=False)
    return renderer.get_plot(obj, doc=Document(theme=_theme())).state


def components(models):
    """``bokeh.embed.components`` of ``models`` as the roots of a new document of their own,
    with HoloViews' theme (Bokeh would otherwise make that document from ``curdoc()``)."""
    doc = Document(theme=_theme())
    for model in models:
        doc.add_root(model)
    return _components(models, theme=doc.theme)
