"""The client report: a verdict in plain language and the key numbers on two or three A4 pages.

What a consultant hands a client (issue 15, item 5): page 1 the verdict, the summary cards and
the map of the tests (|w|); page 2 the reliability maps (redundancy numbers, external
reliability δ̄0, precision); page 3 the suspects (the largest tests, the rejected groups named by
their points and images, inseparable twins marked) and the user's hypotheses. Printed from
Chromium (``@page`` A4, each section on its own page) or read on screen. The full tables are CSV
downloads of the app (:mod:`baarda.dashboard.tables`) and ``baarda analyze --csv``.

The report is made from a fresh state over the session's result and test policy: nothing of
the session's view (selection rings, a hypothesis' deformation field, an S-base lesson, the
image chosen) reaches it. The maps are Bokeh figures without toolbars, embedded with Bokeh's
*inline* resources (the BokehJS code is inside the file), so the report opens offline.
Every string from the file is escaped (:func:`baarda.dashboard.text.html_text`).

    from baarda.dashboard.report import write_report
    write_report(adj, "report.html")
"""

from __future__ import annotations

import datetime as _dt
import math
import re
from pathlib import Path

import holoviews as hv
import numpy as np
from bokeh.resources import Resources

from baarda.io.output import write_text
from baarda.stats.distributions import STRICT
from baarda.stats.reliability import policy_of

from . import geometry, render
from .frames import R_UNCONTROLLED
from .state import State
from .suspects import suspects
from .text import html_text
from .views.common import frame_size
from .views.maps import ExternalMap, RedundancyMap, ResidualMap
from .views.precision import PrecisionMap
from .views.summary import summary_html

#: Maps of the report: the tests on page 1, the reliability on page 2 (one per concept).
FIRST_MAP = ResidualMap
RELIABILITY_MAPS = (RedundancyMap, ExternalMap, PrecisionMap)
#: Rows of the suspects table (the largest tests first).
TOP_SUSPECTS = 14
#: Redundancy number below which an observation is "hardly controlled" (the summary's r < 0.1).
WEAK_R = R_UNCONTROLLED
#: Printable width of an A4 page with 14 mm margins, CSS px.
PAGE_PX = 680


def _render(view_class, state, width: int, height: int):
    """The map ``view_class`` of ``state`` as a Bokeh figure of ``width`` × ``height`` px, no toolbar."""
    view = view_class(state=state)
    fs = frame_size(view.points(), geometry.images(state.problem))
    # equal scales on both axes (as in the app), the frame fitted into the box left by the axes,
    # the legend and the colour bar
    k = min((width - 150) / fs["frame_width"], (height - 90) / fs["frame_height"])
    obj = view.static().opts(hv.opts.Overlay(responsive=False, frame_width=int(fs["frame_width"] * k),
                                             frame_height=int(fs["frame_height"] * k), min_height=None,
                                             toolbar=None, fontscale=0.85))
    fig = render.figure(obj)
    fig.toolbar_location = None
    fig.sizing_mode = None            # the frame's size sets the figure's (no "fixed" without width)
    fig.title.text = ""               # the caption above it says it (and wraps)
    return caption(view.title()), fig, view.far_count()


def caption(title: str) -> str:
    """A map's title without the app's instructions ("select an observation …")."""
    return re.sub(r"\s*\((select|click)[^)]*\)", "", title).strip()


def _fmt(x, spec: str = ".3g") -> str:
    return "–" if x is None or not math.isfinite(float(x)) else format(float(x), spec)


def verdict(s: dict, obs) -> tuple[str, str, list[str]]:
    """(level, headline, sentences) of the summary ``s`` (:meth:`State.summary`) and the
    observations table ``obs`` (:meth:`State.frames`) in plain language (plain text, not HTML).
    level is ``ok`` (the observations agree with their precision and no test rejects), ``warn``
    (weakly controlled observations, σ0 a priori too pessimistic, or the global test failed high
    with no observation rejected: σ̂0 above σ0, said with its confidence interval) or ``bad``
    (not converged, rejections). A B-method rejection that σ̂0's interval does not confirm is
    said as such, not as a failure (F80 §4.1, §7.2)."""
    g = s["global_test"]
    live = obs[~obs["excluded"]]
    stat = "τ" if s["statistic"] == "tau" else "w"
    col = "tau" if stat == "τ" else "w"
    crit = s["critical_tau"] if stat == "τ" else s["critical_w"]
    said: list[str] = []
    if not s["converged"]:
        return ("bad", "Not converged: these numbers cannot be relied on.",
                [f"The adjustment stopped after {s['iterations']} iterations without converging "
                 f"({s['termination']}). Every number below belongs to the last iterate, not to the "
                 "least-squares solution."])
    rejected = int(s["n_rejected"])
    strict = g.get("verdict") == STRICT          # a B-method rejection σ̂0's interval does not confirm
    high = g["passed"] is False and g.get("side") != "low" and not strict
    low = g.get("side") == "low"
    iv = g.get("sigma0_interval") or {}
    sig = (f"σ̂0 = {_fmt(s['sigma0_aposteriori'], '.3g')}"
           + (f" ({100 * iv['confidence']:.3g} % interval {_fmt(iv['lower'], '.3g')} to {_fmt(iv['upper'], '.3g')})"
              if iv.get("lower") is not None and iv.get("upper") is not None else "")
           + f" against σ0 = {s['sigma0_apriori']:.3g} a priori")
    if g["passed"] is None:
        said.append("There is no redundancy (r = 0): nothing can be tested.")
    elif high:
        said.append(f"The observations scatter more than their stated precision: the global test fails "
                    f"(vᵀPv = {g['statistic']:.4g} for r = {g['dof']}, critical {g['upper']:.4g}); {sig}."
                    + ("" if rejected else " No single observation is rejected, so the excess is spread over "
                       "many: σ0 a priori is too optimistic or there are small systematic errors (all model "
                       "errors accumulate in σ̂0, F80 §4)."))
    elif low:
        said.append(f"The observations are better than their stated precision ({sig}): σ0 a priori is too "
                    "pessimistic; this is not an error in the data.")
    elif strict:
        said.append(f"The observations agree with their stated precision ({sig}, σ0 inside the interval); "
                    f"only the B-method's strict bound (α = {100 * g['alpha']:.3g} %, F80 §7.2) is exceeded.")
    else:
        said.append(f"The observations agree with their stated precision: the global test passes ({sig}).")
    if rejected:
        v = live[col].abs()
        worst = int(v.idxmax()) if v.notna().any() else None
        what = (f" The largest is observation {worst} ({live.at[worst, 'kind']} {live.at[worst, 'ids']}), "
                f"|{stat}| = {v.max():.3g}." if worst is not None else "")
        said.append(f"{rejected} observation{'s' if rejected != 1 else ''} fail{'s' if rejected == 1 else ''} the "
                    f"{stat}-test at α0 = {100 * s['alpha0']:.3g} % (|{stat}| > {crit:.3g}).{what} "
                    "Check them before the result is used (page 3 lists the suspects).")
    elif g["passed"] is not None:
        said.append(f"No observation fails the {stat}-test at α0 = {100 * s['alpha0']:.3g} %.")
    weak = int(s["n_uncontrolled"])
    if weak:
        said.append(f"{weak} observation{'s are' if weak != 1 else ' is'} hardly controlled by the others "
                    "(redundancy number r < 0.1): an error there would go unseen or be taken for an error "
                    "elsewhere (page 2, redundancy map).")
    controlled = live["r"].to_numpy(dtype=float) >= WEAK_R
    ext = live["ext"].to_numpy(dtype=float)[controlled]
    ext = ext[np.isfinite(ext)]
    if ext.size:
        said.append(f"An error the tests cannot find (at β0 = {100 * s['beta0']:.3g} %) in a controlled observation "
                    f"(r ≥ {WEAK_R:g}) shifts the coordinates by up to δ̄0 = {ext.max():.3g} times their standard "
                    "deviation (external reliability).")
    if s["n_excluded"]:
        said.append(f"{s['n_excluded']} observation{'s were' if s['n_excluded'] != 1 else ' was'} excluded "
                    "from the adjustment by the reviewer.")
    said += aux_sentences(s)
    gnss = s.get("gnss") or {}
    aux_rejected = int(gnss.get("rejected", 0)) + int(gnss.get("strips_rejected", 0))
    if rejected:
        return "bad", f"Not acceptable as it stands: {rejected} rejected observation{'s' if rejected != 1 else ''}.", said
    if high:
        return ("warn", f"Less precise than stated: σ̂0 = {_fmt(s['sigma0_aposteriori'], '.3g')} against σ0 = "
                        f"{s['sigma0_apriori']:.3g}; no single observation is rejected.", said)
    if aux_rejected:
        return ("warn", f"GNSS: {aux_rejected} rejected test{'s' if aux_rejected != 1 else ''} of projection "
                        "centres or strips; no single observation is rejected.", said)
    if low or weak:
        return ("warn", "Consistent, with reservations: " + ("σ0 a priori too pessimistic" if low else
                                                            f"{weak} weakly controlled observations") + ".", said)
    return "ok", "Consistent: no test rejects the observations.", said


def aux_sentences(s: dict) -> list[str]:
    """The verdict's sentences on the GNSS projection centres (their 3-D tests, F80 eq. 10-12, and
    the strips' shift tests, F80 §2.2) and on the check points (RMSE of adjusted − known per axis),
    from the summary ``s`` (:meth:`State.summary`'s ``gnss`` and ``check_points``); plain text."""
    said = []
    g = s.get("gnss")
    if g:
        n, bad = int(g["centres"]), int(g["rejected"])
        text = f"GNSS: the 3-D test of {bad} of {n} projection centres rejects (q = 3)"
        if g.get("strips"):
            text += f"; a shift common to a strip's centres (cycle slip) is rejected in {g['strips_rejected']} of {g['strips']} strips"
        said.append(text + (" (page 3 names them)." if bad or g.get("strips_rejected") else "."))
    cp = s.get("check_points")
    if cp:
        unit = f" {cp['unit']}" if cp.get("unit") else " (model units)"
        rms = ", ".join(f"{a} {_fmt(x)}" for a, x in zip("XYZ", cp["rms"]))
        said.append(f"Check points ({cp['n']}, not in the adjustment): RMSE of adjusted − known {rms}{unit}.")
    return said


def _suspects_html(state: State) -> str:
    try:
        df = suspects(state)
    except Exception as err:              # noqa: BLE001 — the report says what it could not do
        return f"<p>The suspects list could not be made: {html_text(err)}</p>"
    if df.empty:
        return "<p>No suspects.</p>"
    df = df.head(TOP_SUSPECTS)
    head = "".join(f"<th>{h}</th>" for h in ("#", "what", "hypothesis", "|w|", "decision", "T / k",
                                            "estimated error", "cannot be told apart from"))
    rows = []
    for _, r in df.iterrows():
        dec = str(r["decision"])
        cls = "bad" if dec.startswith("rejected") else "ok"
        rows.append(f"<tr><td>{int(r['rank'])}</td><td>{html_text(r['what'])}</td><td>{html_text(r['hypothesis'])}</td>"
                    f"<td class='n'>{_fmt(r['|w|'])}</td><td class='{cls}'>{html_text(dec)}</td>"
                    f"<td class='n'>{_fmt(r['T'])} / {_fmt(r['k'])}</td><td>{html_text(r['∇ŝ'])}</td>"
                    f"<td>{html_text(r['cannot be told apart from'])}</td></tr>")
    return f"<table class='t'><tr>{head}</tr>{''.join(rows)}</table>"


def _groups_html(state: State) -> str:
    """The rejected group tests (largest T / k first), named by their observations' ids."""
    rel = state.reliability
    groups = [g for g in rel.groups if g["rejected"]] if rel.groups else []
    if not groups:
        return ""
    obs, _ = state.frames()
    groups.sort(key=lambda g: -g["T"] / g["critical"])
    rows = []
    for g in groups[:10]:
        members = np.asarray(g["members"], dtype=np.int64)
        names = sorted({str(obs.at[int(m), "ids"]) for m in members if int(m) in obs.index})
        rows.append(f"<tr><td>{html_text(', '.join(names[:3]) + (' …' if len(names) > 3 else ''))}</td>"
                    f"<td class='n'>{g['dimension']}</td><td class='n'>{g['T']:.4g}</td>"
                    f"<td class='n'>{g['critical']:.4g}</td></tr>")
    more = f" (the 10 largest of {len(groups)})" if len(groups) > 10 else ""
    return (f"<h3>Rejected group tests{more}</h3><table class='t'><tr><th>observations of</th><th>q</th>"
            f"<th>T</th><th>critical</th></tr>{''.join(rows)}</table>")


def _hypotheses_html(session: State | None) -> str:
    if session is None or not session.hypotheses:
        return ""
    rows = []
    for spec, o in zip(session.hypotheses, session.outcomes):
        if not o.tested:
            continue
        label = o.label or ", ".join(f"{k}={v}" for k, v in spec.items() if k != "active")
        rejected = o.rejected
        rows.append(f"<tr><td>{html_text(label)}</td><td>{o.q}</td><td>{_fmt(o.T, '.4g')}</td>"
                    f"<td>{_fmt(o.critical, '.4g')}</td><td class='{'bad' if rejected else 'ok'}'>"
                    f"{'rejected' if rejected else 'accepted'}</td></tr>")
    if not rows:
        return ""
    return ("<h3>Hypotheses tested by the reviewer</h3><table class='t'><tr><th>hypothesis</th><th>q</th>"
            f"<th>T</th><th>critical</th><th>decision</th></tr>{''.join(rows)}</table>")


CSS = f"""
@page {{ size: A4; margin: 14mm; }}
* {{ box-sizing: border-box; }}
body {{ font-family: system-ui, 'DejaVu Sans', sans-serif; margin: 0 auto; padding: 12px; max-width: {PAGE_PX + 24}px;
       color: #222; font-size: 12px; }}
h1 {{ font-size: 19px; margin: 0 0 2px; overflow-wrap: anywhere; }}
h2 {{ font-size: 15px; margin: 10px 0 4px; }}
h3 {{ font-size: 13px; margin: 8px 0 3px; }}
.meta {{ color: #555; margin: 0 0 8px; overflow-wrap: anywhere; }}
.page {{ break-after: page; page-break-after: always; }}
.page.last {{ break-after: auto; page-break-after: auto; }}
.verdict {{ border-left: 6px solid; padding: 6px 10px; margin: 6px 0 8px; background: #f7f7f7; }}
.verdict.ok {{ border-color: #1a7f37; }} .verdict.warn {{ border-color: #b26a00; }} .verdict.bad {{ border-color: #b2182b; }}
.verdict .head {{ font-size: 15px; font-weight: 600; }}
.verdict p {{ margin: 4px 0; }}
.cards .card {{ min-width: 140px; font-size: 11px; }}
.notconv {{ background: #b00020; color: #fff; padding: 6px 10px; font-size: 13px; }}
figure {{ margin: 6px 0; break-inside: avoid; }}
figcaption {{ font-weight: 600; font-size: 12px; margin-bottom: 2px; overflow-wrap: anywhere; }}
.far {{ color: #555; font-size: 11px; }}
table.t {{ border-collapse: collapse; width: 100%; font-size: 10.5px; }}
table.t th {{ text-align: left; border-bottom: 1.5px solid #999; padding: 2px 4px; }}
table.t td {{ border-bottom: 1px solid #e4e4e4; padding: 2px 4px; overflow-wrap: anywhere; }}
table.t td.n {{ white-space: nowrap; }}
td.bad, .bad {{ color: #b2182b; }} td.ok, .ok {{ color: #1a7f37; }}
.foot {{ color: #666; font-size: 10.5px; margin-top: 8px; }}
"""


def report_html(adj, state: State | None = None) -> str:
    """The client report of ``adj`` as one HTML string (see the module docstring).

    state: the session's :class:`~baarda.dashboard.state.State`, if any: its test policy, its
    exclusions and its hypotheses are reported; nothing of its view is.
    """
    session = state if state is not None and state.results is adj else None
    clean = State.from_adjustment(adj, policy=session.policy() if session is not None else policy_of(adj))
    if session is not None:
        clean.param.update(alpha0=session.alpha0, beta0=session.beta0, b_method=session.b_method)
    hv.extension("bokeh", logo=False)
    s = clean.summary()
    if session is not None:
        s["n_excluded"] = len(session.excluded)
    level, head, said = verdict(s, clean.frames()[0])
    title = html_text(s["title"] or Path(str(s["source"])).name or "baarda report")
    first = _render(FIRST_MAP, clean, PAGE_PX, 430)
    rel = [_render(V, clean, PAGE_PX, 300) for V in RELIABILITY_MAPS]
    script, divs = render.components([f for _, f, _ in (first, *rel)])

    def figure(entry, div):
        name, _, far = entry
        note = (f"<div class='far'>{far} point{'s' if far != 1 else ''} far outside the block drawn at the "
                "frame's edge (▽).</div>" if far else "")
        return f"<figure><figcaption>{html_text(name)}</figcaption>{div}{note}</figure>"

    banner = ("" if adj.converged else
              "<p class='notconv'><b>NOT converged</b> after "
              f"{adj.iterations} iterations: {html_text(getattr(adj, 'termination', '') or 'not converged')}. "
              "The numbers below belong to the last iterate, not to the least-squares solution.</p>")
    excluded = ""
    if session is not None and session.excluded:
        ids = sorted(session.excluded)
        excluded = ("<p><b>Excluded observations:</b> " + html_text(", ".join(map(str, ids[:40])))
                    + (f" … ({len(ids)} in all)" if len(ids) > 40 else "") + "</p>")
    when = _dt.datetime.now().isoformat(timespec="minutes")
    said_html = "".join(f"<p>{html_text(x)}</p>" for x in said)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>baarda — {title}</title>
<style>{CSS}</style>
{_bokeh_js()}
{script}
</head><body>
<section class="page">
<h1>{title}</h1>
<p class="meta">Quality report of <code>{html_text(Path(str(s['source'])).name)}</code> · baarda · {when}</p>
{banner}
<div class="verdict {level}"><div class="head">{html_text(head)}</div>{said_html}</div>
{summary_html(s)}
{excluded}
{figure(first, divs[0])}
</section>
<section class="page">
<h2>Reliability</h2>
<p>Redundancy numbers r (0: an error there is not seen, 1: fully controlled by the other observations),
external reliability δ̄0 (how far an error the tests cannot find moves the coordinates, in their
standard deviations; the largest over the points is the δ̄0 of page 1) and the precision of the points
(standard ellipses, or the standard deviation σ of heights in mm: a scale of its own, not δ̄0).</p>
{''.join(figure(e, d) for e, d in zip(rel, divs[1:]))}
</section>
<section class="page last">
<h2>Suspects</h2>
<p>The largest tests of single observations, of image points, control points, GNSS centres and strips,
and point transfers (smallest p-value first); tests the data cannot tell apart name each other.</p>
{_suspects_html(clean)}
{_groups_html(clean)}
{_hypotheses_html(session)}
<p class="foot">Tests at α0 = {100 * s['alpha0']:.3g} %, β0 = {100 * s['beta0']:.3g} %, δ0 = {s['delta0']:.3f}
{'(B-method)' if s['b_method'] else ''}. Full tables: the dashboard's CSV downloads or
<code>baarda analyze FILE --csv DIR</code>. Formulas: Baarda (1968), Förstner (1980), Molenaar (1984).</p>
</section>
</body></html>
"""


def _bokeh_js() -> str:
    """BokehJS (core, WebGL, widgets) inline, without the links other libraries' extensions add."""
    res = Resources(mode="inline", components=["bokeh", "bokeh-gl", "bokeh-widgets"])
    return "\n".join(f"<script>\n{code}\n</script>" for code in res.js_raw)


def write_report(adj, path, state: State | None = None) -> Path:
    """Write the client report of ``adj`` to ``path`` (UTF-8) and return the path."""
    path = Path(path)
    write_text(path, report_html(adj, state=state))
    return path


def write_analysis_report(analysis, path) -> Path:
    """Write the client report of the core's ``analysis`` (:class:`baarda.analysis.Analysis`:
    its adjustment, test policy and exclusions) to ``path``."""
    return write_report(analysis.adjustment, path, state=State.from_analysis(analysis))
