"""The summary header: global test, σ̂0, counts of observations, rejections, weak ones; for a
block the images and strips."""

from __future__ import annotations

from pathlib import Path

import panel as pn
import param

from ..state import State
from ..text import html_text


def summary_html(s: dict) -> str:
    """HTML cards of the numbers of :meth:`State.summary` (also used by the report)."""
    g = s["global_test"]
    if g["passed"] is None:
        gt, cls = "n/a (r = 0)", "na"
    else:
        gt = "passed" if g["passed"] else "FAILED"
        cls = "ok" if g["passed"] else "bad"
        if g.get("side") == "low":        # not an error in the data (F80 §4.1)
            gt, cls = gt + ": σ0 a priori too pessimistic", "na"
    # the relation the statistic has to its bound(s), as it is (a failed test reads "> bound")
    if g.get("test") in ("one-sided", "b-method") and g["upper"] is not None:
        rel = "≤" if g["statistic"] <= g["upper"] else ">"
        bm = "B-method " if g["test"] == "b-method" else ""
        how = f" {rel} {g['upper']:.4g}<br>one-sided, {bm}α = {100 * g['alpha']:.3g} %"
    elif g["lower"] is not None:
        rel = "∈" if g["lower"] <= g["statistic"] <= g["upper"] else "∉"
        how = f" {rel} [{g['lower']:.4g}, {g['upper']:.4g}]<br>two-sided at conf-pr {g['conf_pr']:.3g}"
    else:
        how = ""
    post = s["sigma0_aposteriori"]
    iv = g.get("sigma0_interval")
    interval = (f"<br>{100 * iv['confidence']:.3g} % interval [{iv['lower']:.4g}, {iv['upper']:.4g}]"
                if iv and iv.get("lower") is not None and iv.get("upper") is not None else "")
    cards = [
        ("Global test", f"<b class='{cls}'>{gt}</b><br>vᵀPv = {g['statistic']:.4g}{how}"),
        ("σ0", f"a priori {s['sigma0_apriori']:.4g}<br>σ̂0 = " + ("–" if post is None else f"{post:.4g}")
         + interval + f" (uses {s['sigma0_used']})"),
        ("Model", f"n = {s['n_observations']}, u = {s['n_unknowns']}, r = {s['dof']}<br>{html_text(s['datum'])}"),
        ("Tests", f"α0 = {s['alpha0']:g}, β0 = {s['beta0']:g}, δ0 = {s['delta0']:.3f}<br>"
         f"<b class='{'bad' if s['n_rejected'] else 'ok'}'>{s['n_rejected']} rejected</b>"),
        ("Reliability", f"{s['n_uncontrolled']} with r &lt; 0.1, {s['n_weak']} with r &lt; 0.3<br>"
         f"{s['n_excluded']} excluded"),
    ]
    if s.get("n_images"):
        cards.append(("Block", f"{block_text(s['n_images'], s['n_strips'])}<br>{s['n_points']} points"))
    else:
        cards.append(("Network", f"{s['n_points']} points"))
    gnss = s.get("gnss")
    if gnss:                 # GNSS projection centres (issue 28): the 3-D tests and strip tests
        bad = gnss["rejected"] or gnss["strips_rejected"]
        strips = (f"<br>strip tests: {gnss['strips_rejected']} of {gnss['strips']} rejected"
                  if gnss["strips"] else "")
        cards.append(("GNSS centres", f"{gnss['centres']} centres<br><b class='{'bad' if bad else 'ok'}'>"
                                      f"{gnss['rejected']} rejected</b> (3-D test){strips}"))
    cp = s.get("check_points")
    if cp:
        unit = f" {html_text(cp['unit'])}" if cp.get("unit") else ""
        rms = ", ".join(f"{a} {x:.3g}" for a, x in zip("XYZ", cp["rms"]))
        cards.append(("Check points", f"{cp['n']} (not adjusted)<br>RMSE {rms}{unit}"))
    defects = s.get("local_defects") or []
    if defects:              # set aside by the core's analysis (baarda.analysis), named as the CLI names them
        shown = "<br>".join(html_text(f"{d['entity']} {d['id']} ({', '.join(d['components'])}): {d['action']}")
                            for d in defects[:6])
        more = f"<br>… {len(defects) - 6} more" if len(defects) > 6 else ""
        cards.append(("Local defects", f"<b class='na'>{len(defects)} set aside</b><br>{shown}{more}"))
    body = "".join(f"<div class='card'><div class='h'>{h}</div><div>{b}</div></div>" for h, b in cards)
    style = ("<style>.cards{display:flex;flex-wrap:wrap;gap:8px}.card{border:1px solid #ddd;border-radius:6px;"
             "padding:6px 10px;min-width:150px;font-size:13px;background:#fafafa}.card .h{font-size:11px;"
             "color:#666;text-transform:uppercase}.ok{color:#1a7f37}.bad{color:#c62828}.na{color:#888}</style>")
    return style + f"<div class='cards'>{body}</div>"


def block_text(n_images: int, n_strips: int) -> str:
    """"24 images in 3 strips", "6 images in 1 strip", "23 images" (a block without strips:
    SfM, BAL and COLMAP images belong to none)."""
    images = f"{n_images} image{'' if n_images == 1 else 's'}"
    if not n_strips:
        return images
    return f"{images} in {n_strips} strip{'' if n_strips == 1 else 's'}"


class SummaryHeader(pn.viewable.Viewer):
    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        self.pane = pn.pane.HTML(pn.bind(self._html, self.state.param.results, self.state.param.task),
                                 sizing_mode="stretch_width", css_classes=["summary"])
        s = self.state
        self.progress = pn.pane.HTML(pn.bind(self.progress_html, s.param.results, s.param.task, s.param.progress),
                                     sizing_mode="stretch_width", css_classes=["load-progress"])

    @staticmethod
    def html(state: State) -> str:
        """The header of ``state``'s results: title and :func:`summary_html` cards (every string
        from the file escaped). Also written into the first page (``app.FIRST_PAGE``)."""
        s = state.summary()
        title = html_text(s["title"] or Path(s["source"]).name)
        return f"<div style='font-size:15px;margin-bottom:4px'><b>{title}</b></div>" + summary_html(s)

    @staticmethod
    def progress_html(adj, task="", progress=""):
        """While a file is read and adjusted (no result yet): how far it is, in words."""
        return f"<small>{html_text(progress)}</small>" if adj is None and task and progress else ""

    def _html(self, adj, task=""):
        if adj is None:
            return f"<i>{html_text(task)}…</i>" if task else "<i>No problem loaded.</i>"
        return self.html(self.state)

    def __panel__(self):
        return pn.Column(self.pane, self.progress, sizing_mode="stretch_width")
