"""Criterion matrices and the risk of a critical value (Molenaar 1984, §2 and §3.3).

:class:`CriterionView` compares the coordinate covariance of a planimetric network with a chaotic
criterion matrix in an S-base: fitted (C1 so that λmax = 1, C2 so that λmax/λmin is smallest,
M84 §2.3) or typed by the user, and maps the eigenvector of λmax as a displacement pattern — the
direction in which the network is weakest relative to the criterion. :class:`RiskView` shows the
critical value C that minimises the risk r_C = (1 − p) α_C L1 + p (1 − β_C) L2 and r_C over C.

Every number comes from the core through :meth:`State.criterion_compare` and
:func:`baarda.dashboard.measures.risk_curve`; these views only render them.
"""

from __future__ import annotations

import holoviews as hv
import numpy as np
import pandas as pd
import panel as pn
import param

from baarda.errors import BaardaError
from baarda.stats import analyses

from .. import measures
from ..jobs import Cancelled
from ..geometry import display_matrix, display_xy
from ..state import State
from ..text import fit_title, labels, md_text, plain
from .common import NARROW_TITLE, formatters, frame_size

KINDS = ["linear", "logarithmic", "exponential"]
#: Length of the longest pattern arrow as a share of the network's extent.
ARROW_SHARE = 0.12
#: The larger side of the criterion map's frame (pixels): it fits the map column at 1280 px.
MAP_SIZE = 400
#: Networks up to this many points are fitted when the view opens (the covariance is dense).
AUTO_FIT_POINTS = 300


class CriterionView(pn.viewable.Viewer):
    """Fit or type a criterion (C1, C2) and see λmax, λmin and the worst displacement pattern."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.reason = measures.criterion_reason(s.results)
        self.kind = pn.widgets.Select(label="structure", options=KINDS, value="logarithmic", width=150,
                                      css_classes=["criterion-kind"])
        self.sbase = pn.widgets.MultiChoice(label="S-base", options=labels(s.problem.points.ids),
                                            value=s.criterion_base(), css_classes=["criterion-sbase"])
        self.fit = pn.widgets.Button(label="Fit C1, C2", color="primary", width=120,
                                     css_classes=["criterion-fit"])
        # four significant digits in the fields (C1 of a fit is some 1e-7: its digits were cut)
        self.C1 = pn.widgets.FloatInput(label="C1 [m²/m]", value=1e-6, width=150, format="0.000e+0",
                                        css_classes=["criterion-c1"])
        self.C2 = pn.widgets.FloatInput(label="C2 [m]", value=1.0, width=150, format="0.000e+0",
                                        css_classes=["criterion-c2"])
        self.check = pn.widgets.Button(label="Compare with C1, C2", width=170, css_classes=["criterion-check"])
        self.info = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["criterion-info"])
        self.message = pn.pane.Alert("", alert_type="warning", visible=False, sizing_mode="stretch_width",
                                     css_classes=["criterion-alert"])
        self.plot = pn.pane.HoloViews(self.pattern_map(), sizing_mode="stretch_width", css_classes=["criterion-map"],
                                      linked_axes=False)
        self.kind.param.watch(self._units, "value")
        self._units()
        self.fit.on_click(lambda e: self.run_fit())
        self.check.on_click(lambda e: self.run_check())
        s.param.watch(self._show, ["criterion", "criterion_error"])
        if not self.reason and len(s.problem.points.ids) <= AUTO_FIT_POINTS:
            self.run_fit()

    def _units(self, *_):
        """C1 and C2 labelled in the units of the chosen structure (C2 in m^-½ for the exponential)."""
        u = analyses.criterion_units(self.kind.value)
        self.C1.label = f"C1 [{u['C1']}]"
        self.C2.label = f"C2 [{u['C2']}]" if u["C2"] else "C2 (not used)"
        self.C2.disabled = not u["C2"]

    def run_fit(self):
        self._compare(None, 1.0)

    def run_check(self):
        self._compare(float(self.C1.value), float(self.C2.value))

    def _compare(self, C1, C2):
        """The fit (C1 None) or the comparison: in place in scripts and tests
        (:meth:`State.criterion_compare`); served, on a task thread of the session
        (:meth:`baarda.dashboard.jobs.Jobs.start`, the dense covariance in the S-base and its
        eigenvalues take seconds), its result shown on the event loop, which never waits for it
        (the page of a session opening the tab is built meanwhile)."""
        s = self.state
        if not (s.background and s.jobs.loop_call is not None):
            c = s.criterion_compare(self.kind.value, C1=C1, C2=C2, sbase=self.sbase.value)
            if c is not None and C1 is None:
                self.C1.value, self.C2.value = c["C1"], c["C2"]
            return
        adj, kind = s.results, self.kind.value
        base = list(self.sbase.value) or s.criterion_base()
        m = len(s.problem.points.ids)

        def run():
            try:
                out, err = measures.criterion(adj, m, base, kind, C1, C2), ""
            except (BaardaError, ValueError, np.linalg.LinAlgError) as e:   # as State.criterion_compare
                out, err = None, f"Criterion: {e}"
            except Exception as e:  # noqa: BLE001 - a message in the tab, never a silent nothing
                out, err = None, f"Criterion: {type(e).__name__}: {e}"

            def show():
                if s.results is not adj:             # another file or adjustment since: not its result
                    return
                s.param.update(criterion=out, criterion_error=err)
                if out is not None and C1 is None:
                    self.C1.value, self.C2.value = out["C1"], out["C2"]
            try:
                s.on_loop(show)
            except Cancelled:                        # the session ended meanwhile
                pass
        s.jobs.start(run)

    def _show(self, *_):
        s = self.state
        self.message.object = md_text(s.criterion_error)
        self.message.visible = bool(s.criterion_error)
        c = s.criterion
        if c is None:
            self.info.object = ""
        else:
            verdict = ("λmax = 1 by construction of the fit" if c["fitted"] else
                       "**satisfied** (λmax < 1)" if c["satisfied"] else "**NOT satisfied** (λmax ≥ 1)")
            self.info.object = (
                f"{'Fitted' if c['fitted'] else 'Given'} {c['kind']} criterion in S-base "
                f"{md_text(', '.join(c['sbase']))}: C1 = {c['C1']:.4g} {c['units']['C1']}"
                + (f", C2 = {c['C2']:.4g} {c['units']['C2']}" if c["units"]["C2"] else "")
                + (" (C2 at the end of its range: d² hardly varies with distance here)" if c["C2_at_bound"] else "")
                + "  \n"
                f"λmax = {c['lam_max']:.4g}, λmin = {c['lam_min']:.4g}, λmax/λmin = {c['ratio']:.3g}: {verdict}  \n"
                "The map: the S-base points as squares, the eigenvector of λmax as arrows (the direction "
                "in which the network is weakest relative to the criterion).")
        self.plot.object = self.pattern_map()

    def pattern_map(self):
        """The map of the worst displacement pattern of the last criterion comparison."""
        s = self.state
        e, n, xl, yl = display_xy(s.problem, s.results.coordinates)
        pts = hv.Points((e, n, [plain(i) for i in s.problem.points.ids]), [xl, yl], ["id"]).opts(
            color="#1f4e9c", size=6, tools=["hover"])
        c = s.criterion
        title = "Eigenvector of λmax (M84 §2.3)"
        if c is None:
            return pts.opts(title=title, xticks=4, yticks=5, fontscale=0.9,
                            **frame_size(pd.DataFrame({"x": e, "y": n}), size=MAP_SIZE), **formatters())
        d = (display_matrix(s.problem) @ c["pattern"].T).T
        extent = max(float(np.ptp(e)), float(np.ptp(n)), 1e-9)
        scale = ARROW_SHARE * extent / max(float(np.hypot(*d.T).max()), 1e-300)
        arrows = hv.Segments((e, n, e + scale * d[:, 0], n + scale * d[:, 1]), [xl, yl, "x1", "y1"]).opts(
            color="#e6007e", line_width=2)
        tips = hv.Points((e + scale * d[:, 0], n + scale * d[:, 1]), [xl, yl]).opts(
            color="#e6007e", size=4, marker="triangle")
        base = np.isin(list(s.problem.points.ids), c["sbase"])
        sb = hv.Points((e[base], n[base]), [xl, yl], label="S-base").opts(
            color="black", marker="square", size=10, fill_alpha=0)
        # the frame holds the points and the arrows' tips, with equal scales (nothing cropped)
        frame = frame_size(pd.DataFrame({"x": np.r_[e, e + scale * d[:, 0]], "y": np.r_[n, n + scale * d[:, 1]]}),
                           size=MAP_SIZE)
        return (pts * sb * arrows * tips).opts(
            title=fit_title(f"Eigenvector of λmax = {c['lam_max']:.3g} (M84 §2.3); arrows ≤ {ARROW_SHARE:.0%} of "
                            "the extent", frame["frame_width"], 12.7),
            show_legend=False, xlabel=xl, ylabel=yl, fontscale=0.9, fontsize={"title": "9.5pt"},
            xticks=4, yticks=5, **frame, **formatters())

    def __panel__(self):
        if self.reason:
            return pn.pane.Markdown(f"*{self.reason}*", css_classes=["criterion-reason"],
                                    sizing_mode="stretch_width")
        return pn.Column("#### Criterion matrix (M84 §2)",
                         pn.FlexBox(self.kind, self.sbase, pn.Column(pn.Spacer(height=20), self.fit),
                                    sizing_mode="stretch_width"),
                         pn.FlexBox(self.C1, self.C2, pn.Column(pn.Spacer(height=20), self.check),
                                    sizing_mode="stretch_width"),
                         self.message, self.info, self.plot, sizing_mode="stretch_width")


class RiskView(pn.viewable.Viewer):
    """Risk-minimising critical value C of a one-sided test and r_C over C (M84 §3.3)."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        kw = dict(width=110)
        self.p = pn.widgets.FloatInput(label="p (erroneous)", value=0.01, step=0.005, start=1e-6, end=0.999,
                                       css_classes=["risk-p"], **kw)
        self.L1 = pn.widgets.FloatInput(label="L1 (reject good)", value=1.0, step=0.5, css_classes=["risk-l1"], **kw)
        self.L2 = pn.widgets.FloatInput(label="L2 (miss bad)", value=10.0, step=1.0, css_classes=["risk-l2"], **kw)
        self.lam = pn.widgets.FloatInput(label="λtol", value=round(float(s.reliability.delta0 ** 2), 4), step=1.0,
                                         css_classes=["risk-lam"], **kw)
        self.info = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["risk-info"])
        self.plot = pn.pane.HoloViews(hv.Curve([]), sizing_mode="stretch_width", css_classes=["risk-plot"],
                                      linked_axes=False)
        for w in (self.p, self.L1, self.L2, self.lam):
            w.param.watch(self._update, "value")
        self._update()

    def _update(self, *_):
        try:
            rc = measures.risk_curve(float(self.p.value), float(self.L1.value), float(self.L2.value),
                                     float(self.lam.value))
        except (TypeError, ValueError) as err:
            self.info.object = f"**Risk:** {err}"     # the core's message about p, L1, L2, λtol
            return
        self.rc = rc
        self.info.object = (f"C = **{rc['C']:.4f}** (closed form), α_C = {rc['alpha']:.3g}, "
                            f"β_C = {rc['beta']:.3f}, r_C = {rc['r_C']:.4g} (λtol = {rc['lam_tol']:.3g})")
        self.plot.object = (
            hv.Curve((rc["grid"], rc["r"]), "C", "r_C").opts(color="#1f4e9c", line_width=2)
            * hv.VLine(rc["C"]).opts(color="#e6007e", line_dash="dashed")
            * hv.Points([(rc["C"], rc["r_C"])], ["C", "r_C"]).opts(color="#e6007e", size=8)
        ).opts(title=fit_title("Risk r_C = (1−p) α_C L1 + p (1−β_C) L2 (M84 §3.3)", NARROW_TITLE, 14.4),
               responsive=True, height=260,
               fontscale=0.9)

    def __panel__(self):
        return pn.Column("#### Risk of a critical value (M84 §3.3)", pn.Row(self.p, self.L1, self.L2, self.lam),
                         self.info, self.plot, sizing_mode="stretch_width")
