"""The hypothesis panel: build a hypothesis, toggle it, read T, R, critical value, ∇ŝ, its
lower-bound ellipse, δ0′max and δ̄0max (F80 eq. 10-17, computed by the core's ``Adjustment.test``
and ``external_reliability``)."""

from __future__ import annotations

import holoviews as hv
import numpy as np
import pandas as pd
import panel as pn
import param
from bokeh.models.widgets.tables import CheckboxEditor, HTMLTemplateFormatter

from baarda.observations.collinearity import AP_GROUPS

from .. import geometry, specs
from ..geometry import observation_label
from ..outcomes import Outcome
from ..state import State
from ..text import fit_title, labels, md_text, plain


def text_options(values) -> dict:
    """Select options showing each value as text (control characters escaped); a label two
    values would share gets a numbered suffix."""
    out: dict = {}
    for v in values:
        label, k = plain(v), 2
        while label in out:
            label, k = f"{plain(v)} ({k})", k + 1
        out[label] = v
    return out

#: Decisions in words: rejected red, accepted green, not testable grey.
DECISION = HTMLTemplateFormatter(template=(
    '<span style="color:<%= value.startsWith("rejected") ? "#b2182b" : (value.startsWith("accepted") '
    '? "#116329" : "#555555") %>"><%- value %></span>'))


def with_selection(widget, options) -> None:
    """Set a Select's options and keep a selection: the current value if it is still offered,
    else the first option (a dropdown never opens blank)."""
    widget.options = options
    values = list(options.values()) if isinstance(options, dict) else list(options)
    if values and widget.value not in values:
        widget.value = values[0]


def rank_deficient(h) -> bool:
    """The test (a HypothesisTest) sees fewer dimensions than H has columns (W singular, F80
    eq. 12): part of the error is absorbed by the unknowns and cannot be tested."""
    return h.q < h.H.shape[1]


def not_testable(state, h, partly: bool = False) -> str:
    """Why a rank-deficient hypothesis is not (``partly``: not wholly) testable, naming the points
    whose unknowns absorb the untestable error direction (its effect ∇x = Σ AᵀP H s, the core's
    ``Adjustment.deformation``, F80 §6)."""
    s = state
    null = np.flatnonzero(~np.isfinite(h.ellipse_axes))
    what = (f"q = {h.q} of {h.H.shape[1]}" if h.q else "W = 0")
    head = (f"tests {h.q} of {h.H.shape[1]} dimensions" if partly else "not testable: rank-deficient")
    if not null.size:
        return f"{head} ({what})"
    direction = h.ellipse_dirs[:, null[0]]
    shifts = s.results.point_shifts(s.results.deformation(np.asarray(h.H @ direction).ravel()))
    size = np.linalg.norm(shifts, axis=1)
    top = np.flatnonzero(size > 0.1 * size.max(initial=0.0)) if size.max(initial=0.0) > 0 else []
    ids = [str(s.problem.points.ids[k]) for k in top[np.argsort(-size[top])][:4]] if len(top) else []
    by = (f"the coordinates of {', '.join(ids)}" + (" and others" if len(top) > 4 else "")) if ids else \
        "the other unknowns (orientations, camera parameters)"
    if partly:
        return f"{head}: the other is absorbed by {by}"
    return f"{head} ({what}): the error is absorbed by {by}"


KINDS = {
    "observation": "one observation",
    "group": "test group (2D/3D: vector, image point)",
    "image-point": "image point (x, y)",
    "control": "control point",
    "transfer": "point transfer across images",
    "ap-group": "additional-parameter group (camera)",
}


class HypothesisPanel(pn.viewable.Viewer):
    """Widgets to define hypotheses, their results table and the lower-bound ellipse plot."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.kind = pn.widgets.Select(label="Hypothesis", options={}, width=260, css_classes=["hyp-kind"])
        self.obs_input = pn.widgets.IntInput(label="Observation index", value=0, start=0, width=150,
                                             css_classes=["hyp-obs"])
        self.group = pn.widgets.Select(label="Group", options=[], width=260)
        self.point = pn.widgets.Select(label="Point", options=[], width=150, css_classes=["hyp-point"])
        self.image = pn.widgets.Select(label="Image", options=[], width=150, css_classes=["hyp-image"])
        self.images = pn.widgets.MultiChoice(label="Images (the transferred point's)", options=[], width=260)
        self.camera = pn.widgets.Select(label="Camera", options=[], width=150, css_classes=["hyp-camera"])
        self.ap_group = pn.widgets.Select(label="AP group", options=[], width=150, css_classes=["hyp-ap"])
        self.add = pn.widgets.Button(label="Test", color="primary", width=90,
                                     css_classes=["hyp-add"])
        self.remove = pn.widgets.Button(label="Remove selected", width=130)
        self.message = pn.pane.Alert("", alert_type="warning", visible=False)
        self.results = pn.widgets.Tabulator(
            pd.DataFrame(), disabled=False, selectable=1, show_index=False, sizing_mode="stretch_width",
            height=220, editors={}, css_classes=["hyp-table"], layout="fit_data_stretch")
        self.add.on_click(self._add)
        self.remove.on_click(self._remove)
        self.kind.param.watch(self._kind_changed, "value")
        self.point.param.watch(self._point_changed, "value")
        self.camera.param.watch(lambda e: with_selection(self.ap_group, self._ap_options()), "value")
        self.results.on_edit(self._edited)
        self.results.param.watch(self._selected, "selection")
        s.param.watch(self._refresh_options, ["problem"])
        s.param.watch(self._refresh_table, ["outcomes", "hypotheses"])
        s.param.watch(self._sync_selection, ["selected_hypothesis"])
        s.param.watch(self._follow_selection, ["selected_obs", "selected_point"])
        self.plot = hv.DynamicMap(self._ellipse_plot, streams=[hv.streams.Params(
            s, ["outcomes", "selected_hypothesis"])])
        self._refresh_options()
        self._refresh_table()

    # -- options --------------------------------------------------------------------------------
    def _available(self) -> dict:
        p = self.state.problem
        kinds = set(p.info.kind)
        out = {KINDS["observation"]: "observation"}
        if (np.asarray(p.info.group) >= 0).any():
            out[KINDS["group"]] = "group"
        if any(k.startswith("image-") for k in kinds):
            out[KINDS["image-point"]] = "image-point"
            out[KINDS["transfer"]] = "transfer"
        if any("id" in ids for ids in p.info.ids):
            out[KINDS["control"]] = "control"
        if self._cameras():
            out[KINDS["ap-group"]] = "ap-group"
        return out

    def _cameras(self) -> list[str]:
        block = geometry.block(self.state.problem)
        return [str(c["id"]) for c in block.get("cameras", [])] if isinstance(block, dict) else []

    def _group_firsts(self) -> dict:
        """First observation (full index) of every test group, in the order of the groups."""
        g = np.asarray(self.state.problem.info.group)
        groups, first = np.unique(g, return_index=True)
        keep = groups >= 0
        order = np.argsort(first[keep], kind="stable")
        return {int(k): int(i) for k, i in zip(groups[keep][order], first[keep][order])}

    def _ap_options(self) -> dict:
        """AP groups: the estimated ones (``problem.notes.ap_groups``) first, then the others."""
        est = self.state.problem.notes.ap_groups
        out = {}
        for g in AP_GROUPS:
            if f"{self.camera.value}:{g}" in est:
                out[f"{g} (estimated: significance)"] = g
        for g in AP_GROUPS:
            if f"{self.camera.value}:{g}" not in est:
                out[f"{g} (not in the model: H = ∂f/∂s)"] = g
        return out

    def _refresh_options(self, *_):
        p = self.state.problem
        with_selection(self.kind, self._available())
        self.obs_input.end = p.n - 1
        groups = {}
        for g, i in self._group_firsts().items():     # one pass (a block has thousands of groups)
            groups[plain(f"{g}: group {g} ({observation_label(p, i).split(' ', 2)[-1]})")] = g
        with_selection(self.group, groups)
        with_selection(self.camera, text_options(self._cameras()))
        with_selection(self.ap_group, self._ap_options())
        self._kind_changed()

    def _kind_changed(self, *_):
        p = self.state.problem
        kind = self.kind.value
        if kind in ("image-point", "transfer"):
            pts = sorted({str(ids["point"]) for ids in p.info.ids if "point" in ids},
                         key=lambda x: (len(x), x))
        elif kind == "control":
            pts = sorted({str(ids["id"]) for ids in p.info.ids if "id" in ids}, key=lambda x: (len(x), x))
        else:
            pts = []
        with_selection(self.point, text_options(pts))
        self._point_changed()
        self.obs_input.visible = kind == "observation"
        self.group.visible = kind == "group"
        self.point.visible = kind in ("image-point", "transfer", "control")
        self.image.visible = kind == "image-point"
        self.images.visible = kind == "transfer"
        self.camera.visible = self.ap_group.visible = kind == "ap-group"

    def _point_changed(self, *_):
        p = self.state.problem
        ims = sorted({str(ids["image"]) for ids in p.info.ids
                      if str(ids.get("point")) == str(self.point.value) and "image" in ids})
        # an image with several keypoints on the point (COLMAP): one entry per keypoint,
        # its value (image, keypoint)
        opts: dict = {}
        for im in ims:
            kps = geometry.keypoints_of(self.state.problem_index(), im, self.point.value) if self.point.value is not None else [None]
            if len(kps) > 1:
                for kp in kps:
                    label = f"{plain(im)} (keypoint {kp})"
                    opts[label if label not in opts else f"{label} ({len(opts)})"] = (im, kp)
            else:
                label, k = plain(im), 2
                while label in opts:
                    label, k = f"{plain(im)} ({k})", k + 1
                opts[label] = im
        with_selection(self.image, opts)
        self.images.options = labels(ims)
        self.images.value = ims[:2] if len(ims) >= 2 else ims

    def _follow_selection(self, *_):
        s = self.state
        if s.selected_obs is not None:
            self.obs_input.value = int(s.selected_obs)
        if s.selected_point is not None:
            pid = s.problem.points.ids[s.selected_point]
            if pid in (self.point.options.values() if isinstance(self.point.options, dict)
                        else self.point.options):
                self.point.value = pid

    def spec(self) -> dict:
        kind = self.kind.value
        if kind == "observation":
            return {"kind": kind, "index": int(self.obs_input.value)}
        if kind == "group":
            return {"kind": kind, "group": int(self.group.value)}
        if kind == "image-point":
            if isinstance(self.image.value, tuple):
                im, kp = self.image.value
                return {"kind": kind, "image": im, "point": self.point.value, "keypoint": kp}
            return {"kind": kind, "image": self.image.value, "point": self.point.value}
        if kind == "control":
            return {"kind": kind, "point": self.point.value}
        if kind == "ap-group":
            return {"kind": kind, "camera": self.camera.value, "group": self.ap_group.value}
        return {"kind": kind, "point": self.point.value, "images": list(self.images.value)}

    # -- actions --------------------------------------------------------------------------------
    def add_current(self) -> None:
        """Add the hypothesis the widgets describe (what the "Add" button does)."""
        self._add()

    def _add(self, *_):
        try:
            spec = self.spec()
            if spec["kind"] == "transfer" and len(spec["images"]) < 1:
                raise ValueError("choose the images of the transferred point")
            if any(v is None for v in spec.values()):
                raise ValueError("choose the ids of the hypothesis")
            self.state.add_hypothesis(spec)
            self.message.visible = False
        except (ValueError, KeyError, TypeError) as err:
            self.message.object = md_text(f"Cannot build this hypothesis: {err}")
            self.message.visible = True

    def _remove(self, *_):
        k = self.state.selected_hypothesis
        if k is not None and k < len(self.state.hypotheses):
            self.state.remove_hypothesis(k)

    def edited(self, event) -> None:
        """A cell of the hypotheses table edited (``event``: column, row, value): the "active" box
        toggles the hypothesis (what the table's edit does)."""
        self._edited(event)

    def _edited(self, event):
        if event.column == "active":
            value = event.value
            if isinstance(value, str):          # never bool("false") == True
                value = value.strip().lower() in ("true", "1", "yes")
            self.state.toggle_hypothesis(int(event.row), bool(value))

    def _selected(self, event):
        if event.new:
            self.state.param.update(selected_hypothesis=int(event.new[0]), field_source="hypothesis")

    # -- display --------------------------------------------------------------------------------
    def frame(self) -> pd.DataFrame:
        """One row per hypothesis with the core's test results (∇ŝ in the file's σ units)."""
        s = self.state
        factor, units = s.problem_index()["factor"]
        rows = []
        missing = [Outcome()] * (len(s.hypotheses) - len(s.outcomes))
        for spec, o in zip(s.hypotheses, s.outcomes + missing):
            row = {"active": bool(spec.get("active", True)), "hypothesis": plain(spec.get("label", "")),
                   "q": None, "T": None, "critical T": None, "R": None, "decision": "",
                   "∇ŝ": "", "σ∇ŝ": "", "δ0'max": None, "δ̄0max": None}
            h = o.test
            if o.status == "refused":
                row["decision"] = plain(o.message)
            elif o.status == "ap-test":
                h = o.ap
                row.update({"q": h.q, "T": round(h.T, 3), "critical T": round(h.critical, 3),
                            "decision": "SIGNIFICANT" if h.significant else "not significant",
                            "∇ŝ": ", ".join(f"{x:.3g}" for x in h.estimate) + " (ŝ)",
                            "σ∇ŝ": ", ".join(f"{x:.3g}" for x in h.sigma),
                            "δ0'max": round(h.delta0_prime_max, 2) if np.isfinite(h.delta0_prime_max) else None,
                            "δ̄0max": round(h.reliability_max, 2) if np.isfinite(h.reliability_max) else None})
            elif o.status == "test" and o.rank_deficient and h.q == 0:
                row["q"] = 0
                row["decision"] = plain(not_testable(s, h))
            elif o.status == "test":
                first = specs.rows(s.problem, spec, s.problem_index())[0]
                f = factor[int(first[0])] if len(first) else 1.0
                u = units[int(first[0])] if len(first) else ""
                row.update({"q": h.q, "T": round(h.T, 3), "critical T": round(h.critical_T, 3),
                            "R": None if not np.isfinite(h.R) else round(h.R, 3),
                            "decision": ("rejected" if h.rejected_T else "accepted")
                            + (f" ({plain(not_testable(s, h, partly=True))})" if rank_deficient(h) else ""),
                            "∇ŝ": ", ".join(f"{x * f:.3g}" for x in h.nabla) + f" {u}",
                            "σ∇ŝ": ", ".join(f"{x * f:.3g}" for x in h.nabla_sigma) + f" {u}",
                            "δ0'max": round(h.delta0_prime_max, 2) if np.isfinite(h.delta0_prime_max) else None})
                if np.isfinite(o.external_max):
                    row["δ̄0max"] = round(o.external_max, 2)
            rows.append(row)
        return pd.DataFrame(rows, columns=["active", "hypothesis", "q", "T", "critical T", "R", "decision",
                                           "∇ŝ", "σ∇ŝ", "δ0'max", "δ̄0max"])

    def _refresh_table(self, *_):
        df = self.frame()
        self.results.editors = {**{c: None for c in df.columns if c != "active"}, "active": CheckboxEditor()}
        self.results.formatters = {"active": {"type": "tickCross"}, "decision": DECISION}
        self.results.value = df
        self._sync_selection()

    def _sync_selection(self, *_):
        """The selected hypothesis (a new one once added) is the highlighted row."""
        k = self.state.selected_hypothesis
        n = len(self.results.value)
        sel = [k] if k is not None and k < n else []
        if list(self.results.selection) != sel:
            self.results.selection = sel

    def ellipse_plot(self):
        """The selected hypothesis' lower-bound ellipse (or why it is not testable) as the
        HoloViews element the panel shows."""
        return self._ellipse_plot()

    def _ellipse_plot(self, **_):
        s = self.state
        k = s.selected_hypothesis
        o = s.outcomes[k] if k is not None and k < len(s.outcomes) else Outcome()
        h = o.test
        ell, est, title = [], pd.DataFrame({"s1": [], "s2": []}), "Select a hypothesis"
        if o.status == "ap-test":
            title = (f"AP group, q = {o.ap.q}: T = {o.ap.T:.2f}, semi-axes "
                     + ", ".join(f"{x:.3g}" for x in o.ap.ellipsoid_axes))
        elif o.status == "test" and o.rank_deficient and h.q == 0:
            title = "Not testable: rank-deficient (see the table)"
        elif o.status == "test":
            spec = s.hypotheses[k]
            factor, units = s.problem_index()["factor"]
            first = specs.rows(s.problem, spec, s.problem_index())[0]
            f = factor[int(first[0])] if len(first) else 1.0
            u = units[int(first[0])] if len(first) else ""
            finite = np.flatnonzero(np.isfinite(h.ellipse_axes))
            if h.q == 1 and h.H.shape[1] == 2 and finite.size == 1:
                d = h.ellipse_dirs[:, finite[0]] * float(h.ellipse_axes[finite[0]]) * f
                ell = [np.array([-d, d])]
                est = pd.DataFrame({"s1": [h.nabla[0] * f], "s2": [h.nabla[1] * f]})
                title = (f"q = 1 of 2 (one direction absorbed): |∇0s| = "
                         f"{float(h.ellipse_axes[finite[0]]) * f:.3g} {u}")
            elif h.q == 2 and np.isfinite(h.ellipse_axes).all():
                ell = [h.ellipse() * f]  # 73 points
                est = pd.DataFrame({"s1": [h.nabla[0] * f], "s2": [h.nabla[1] * f]})
                title = f"∇0s (β0) and ∇ŝ [{u}], T = {h.T:.2f}"
            elif h.q == 1 and h.H.shape[1] == 1:
                a = float(h.ellipse_axes[0]) * f
                ell = [np.array([[-a, 0.0], [a, 0.0]])]
                est = pd.DataFrame({"s1": [h.nabla[0] * f], "s2": [0.0]})
                title = f"q = 1: |∇0s| = {a:.3g} {u}, ∇ŝ = {h.nabla[0] * f:.3g}"
            else:
                title = f"q = {h.q}: semi-axes " + ", ".join(f"{x * f:.3g}" for x in h.ellipse_axes) + f" {u}"
        # the critical region's boundary ∇ŝᵀ W ∇ŝ = k (rejected outside; F80 eq. 12), drawn over
        # the lower bound ∇0sᵀ W ∇0s = δ0² (F80 eq. 13): the same ellipse scaled by √k / δ0
        crit = ([e * np.sqrt(h.critical_T) / h.delta0 for e in ell]
                if ell and h is not None and h.delta0 > 0 else [])
        pts = ell + crit + ([est[["s1", "s2"]].to_numpy(dtype=float)] if len(est) else [])
        extent = float(np.nanmax(np.abs(np.concatenate(pts)))) * 1.15 if ell else 1.0
        return (hv.Path(ell, ["s1", "s2"], label="∇0s: lower bound (β0)").opts(
                    color="#e6007e", line_width=2, framewise=True)
                * hv.Path(crit, ["s1", "s2"], label="critical: rejected outside").opts(
                    color="#333333", line_width=2, line_dash="dashed", framewise=True)
                * hv.Points(est, ["s1", "s2"], label="∇ŝ").opts(color="black", size=10, marker="x", framewise=True)
                * hv.VLine(0).opts(color="#bbbbbb") * hv.HLine(0).opts(color="#bbbbbb")).opts(
            title=fit_title(title, 240, 13), xlabel="∇s₁", ylabel="∇s₂", xlim=(-extent, extent), ylim=(-extent, extent),
            frame_width=240, frame_height=240, framewise=True, xticks=5, yticks=5, show_legend=False,
            fontscale=0.9)

    def __panel__(self):
        form = pn.FlexBox(self.kind, self.obs_input, self.group, self.point, self.image, self.images,
                          self.camera, self.ap_group,
                          pn.Column(pn.Spacer(height=18), pn.Row(self.add, self.remove)),
                          sizing_mode="stretch_width")
        return pn.Column(
            "### Hypotheses (F80 eq. 10-15)", form, self.message, self.results,
            pn.pane.HoloViews(self.plot, css_classes=["hyp-ellipse"],
                                                   linked_axes=False),
            pn.pane.Markdown("Magenta: the lower bound ∇0s, the smallest error found with power β0 (F80 "
                             "eq. 13); dashed: the critical ellipse ∇ŝᵀW∇ŝ = k — an estimate ∇ŝ (×) outside "
                             "it is rejected (F80 eq. 12).", css_classes=["hyp-caption"],
                             sizing_mode="stretch_width"),
            sizing_mode="stretch_width")
