"""A standalone HTML report of an analysis: summary, tables and the maps, readable offline.

The plots are Bokeh figures rendered from the dashboard's own map views (HoloViews → Bokeh) and
embedded with Bokeh's *inline* resources (the BokehJS code is inside the file, about 1 MB per
library; links that other libraries' Bokeh extensions would add are left out), so the report
opens without a server or network. No Panel stylesheets are involved.

    from baarda.dashboard.report import write_report
    write_report(adj, "report.html")
"""

from __future__ import annotations

import datetime as _dt
import html
from pathlib import Path

import holoviews as hv
import numpy as np

from .text import html_text

MAX_ROWS = 500


def _figures(state) -> list[tuple[str, object]]:
    from .views.maps import MAP_VIEWS

    hv.extension("bokeh", logo=False)
    figs = []
    for V in MAP_VIEWS:
        view = V(state=state)
        obj = view.static().opts(hv.opts.Overlay(responsive=False, frame_width=760, frame_height=560,
                                                           min_height=None))
        fig = hv.render(obj, backend="bokeh")
        figs.append((view.title(), fig))     # view.title() is text; escaped where it is used
    return figs


def _table_html(state) -> str:
    obs, _ = state.frames()
    df = obs.copy()
    note = ""
    if len(df) > MAX_ROWS:
        order = np.argsort(-np.nan_to_num(np.abs(df["w"].to_numpy(dtype=float)), nan=-1.0))
        df = df.iloc[order[:MAX_ROWS]]
        note = f"<p>The {MAX_ROWS} observations with the largest |w| of {len(obs)} (full table: baarda's CSV output).</p>"
    df = df.drop(columns=["mdb_sigma"]).rename(columns={"tau": "τ", "mdb": "MDB", "ext": "δ̄0"})
    return note + df.to_html(float_format=lambda x: f"{x:.4g}", classes="obs", border=0, na_rep="–")


def _hypotheses_html(state) -> str:
    if not state.hypotheses:
        return ""
    from .views.hypotheses import HypothesisPanel

    df = HypothesisPanel.frame(type("P", (), {"state": state})())
    return "<h2>Hypotheses</h2>" + df.to_html(classes="obs", border=0, index=False, na_rep="–")


def _bokeh_js() -> str:
    """BokehJS (core, WebGL, widgets) inline, without the links other libraries' extensions add."""
    from bokeh.resources import Resources

    res = Resources(mode="inline", components=["bokeh", "bokeh-gl", "bokeh-widgets"])
    return "\n".join(f"<script>\n{code}\n</script>" for code in res.js_raw)


def report_html(adj, state=None) -> str:
    """The report of the adjustment ``adj`` as one HTML string (see the module docstring).

    state: the dashboard's :class:`~baarda.dashboard.state.State` if there is one (its
    exclusions and hypotheses are reported too); otherwise one is made from ``adj``.
    """
    from bokeh.embed import components

    from baarda.io.results import text_summary
    from baarda.text import printable_lines

    from .state import State
    from .views.summary import summary_html

    if state is None or state.results is not adj:
        state = State.from_adjustment(adj)
    figs = _figures(state)
    script, divs = components([f for _, f in figs])
    s = state.summary()
    title = html_text(s["title"] or Path(s["source"]).name or "baarda report")
    plots = "".join(f"<h3>{html_text(t)}</h3>{d}" for (t, _), d in zip(figs, divs))
    groups = ""
    rel = state.reliability
    if rel.groups:
        rows = "".join(
            f"<tr><td>{html_text(g['group'])}</td><td>{g['dimension']}</td><td>{g['T']:.4g}</td><td>{g['critical']:.4g}</td>"
            f"<td>{'REJECTED' if g['rejected'] else 'accepted'}</td></tr>" for g in rel.groups[:MAX_ROWS])
        groups = ("<h2>Group tests</h2><table class='obs'><tr><th>group</th><th>q</th><th>T</th>"
                  f"<th>critical</th><th>decision</th></tr>{rows}</table>")
    banner = ("" if adj.converged else
              "<p class='notconv'><b>NOT converged</b> after "
              f"{adj.iterations} iterations: {html_text(getattr(adj, 'termination', '') or 'not converged')}. "
              "The numbers below belong to the last iterate, not to the least-squares solution.</p>")
    excluded = ("<p><b>Excluded observations:</b> " + ", ".join(map(str, sorted(state.excluded))) + "</p>"
                if state.excluded else "")
    css = ("body{font-family:system-ui,sans-serif;margin:20px;max-width:1100px}"
           "table.obs{border-collapse:collapse;font-size:12px}table.obs td,table.obs th{padding:2px 6px;"
           "border-bottom:1px solid #eee;text-align:right}pre{background:#f6f6f6;padding:8px;font-size:12px}"
           ".notconv{background:#b00020;color:#fff;padding:8px 12px;font-size:15px}")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>baarda — {title}</title>
<style>{css}</style>
{_bokeh_js()}
{script}
</head><body>
<h1>baarda — {title}</h1>
{banner}
<p>Source: <code>{html_text(Path(str(s['source'])).name)}</code>; written {_dt.datetime.now().isoformat(timespec='seconds')}.</p>
{summary_html(s)}
{excluded}
<h2>Summary</h2><pre>{html.escape(printable_lines(text_summary(adj, reliability=rel)))}</pre>
<h2>Maps</h2>{plots}
{_hypotheses_html(state)}
{groups}
<h2>Observations</h2>{_table_html(state)}
</body></html>
"""


def write_report(adj, path, state=None) -> Path:
    """Write the standalone HTML report of ``adj`` to ``path`` (UTF-8) and return the path."""
    path = Path(path)
    path.write_text(report_html(adj, state=state), encoding="utf-8")
    return path
