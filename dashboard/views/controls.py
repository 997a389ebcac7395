"""Sidebar widgets: test settings (α0, β0, B-method, σ0), the selection with exclude /
re-include, the image and exaggeration of block views, file upload and report export."""

from __future__ import annotations

import io
import tempfile
from pathlib import Path

import panel as pn
import param

from ..state import ROBUST_METHODS, State, observation_label

ALPHAS = [1e-5, 1e-4, 2e-4, 5e-4, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1]
MAX_UPLOAD_MB = 50


def _two_way(widget, state, name):
    """Keep ``widget.value`` and ``state.<name>`` equal in both directions."""
    widget.param.watch(lambda e: setattr(state, name, e.new), "value")
    state.param.watch(lambda e: setattr(widget, "value", e.new), name)


class Controls(pn.viewable.Viewer):
    """α0, β0 (δ0 updates live), the B-method and which σ0 the decisions use."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.alpha = pn.widgets.DiscreteSlider(name="α0 (1D test size)", options=ALPHAS,
                                               value=min(ALPHAS, key=lambda a: abs(a - s.alpha0)),
                                               css_classes=["alpha-slider"], sizing_mode="stretch_width")
        self.beta = pn.widgets.FloatSlider(name="β0 (power)", start=0.5, end=0.99, step=0.01,
                                           value=s.beta0, sizing_mode="stretch_width")
        self.b_method = pn.widgets.Checkbox(name="B-method (same δ0 for all dimensions)", value=s.b_method)
        self.sigma = pn.widgets.RadioButtonGroup(name="σ0", options={"σ0 a priori (w)": "apriori",
                                                                   "σ̂0 a posteriori (τ)": "aposteriori"},
                                                 value=s.sigma0_mode, sizing_mode="stretch_width")
        self.robust = pn.widgets.Select(name="Robust reweighting (M84 §3.1, R84)", options=list(ROBUST_METHODS),
                                        value=s.robust_method, css_classes=["robust-select"],
                                        sizing_mode="stretch_width")
        for w, name in ((self.alpha, "alpha0"), (self.beta, "beta0"), (self.b_method, "b_method"),
                        (self.sigma, "sigma0_mode"), (self.robust, "robust_method")):
            _two_way(w, s, name)
        self.delta = pn.pane.Markdown(pn.bind(self._delta_text, s.param.results),
                                      css_classes=["delta0"], sizing_mode="stretch_width")

    @staticmethod
    def _delta_text(adj):
        if adj is None:
            return ""
        return (f"**δ0 = {adj.delta0:.3f}** (λ0 = {adj.delta0 ** 2:.2f}); critical |w| = "
                f"{adj.critical_w:.3f}, |τ| = {adj.critical_tau:.3f}")

    def __panel__(self):
        return pn.Column("### Tests", self.alpha, self.beta, self.delta, self.b_method, self.sigma,
                         self.robust, sizing_mode="stretch_width")


class SelectionPanel(pn.viewable.Viewer):
    """The selected point / observation, exclude and re-include, the block image and exaggeration."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.info = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["selection-info"])
        self.exclude = pn.widgets.Button(name="Exclude", button_type="warning", width=80)
        self.include = pn.widgets.Button(name="Re-include", width=90)
        self.test = pn.widgets.Button(name="Test it", width=70)
        self.include_all = pn.widgets.Button(name="Re-include all", width=120)
        self.excluded = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.image = pn.widgets.Select(name="Image (residual view)", options=[], sizing_mode="stretch_width")
        self.exaggeration = pn.widgets.FloatInput(name="Residual vector exaggeration", value=s.exaggeration,
                                                  start=0.0, sizing_mode="stretch_width")
        _two_way(self.exaggeration, s, "exaggeration")
        self.image.param.watch(lambda e: setattr(s, "selected_image", e.new), "value")
        self.exclude.on_click(self._exclude)
        self.include.on_click(self._include)
        self.include_all.on_click(lambda e: s.include_all())
        self.test.on_click(self._test)
        s.param.watch(self._refresh, ["results", "selected_obs", "selected_point", "excluded", "problem"])
        self._refresh()

    def _refresh(self, *_):
        s = self.state
        if s.results is None:
            return
        obs, pts = s.frames()
        text = "*Click a point or line on a map, or a row of the table.*"
        if s.selected_obs is not None:
            r = obs.loc[s.selected_obs]
            text = (f"**Observation {observation_label(s.problem, s.selected_obs)}**  \n"
                    f"v = {r.v:.4g} {r.unit}, w = {r.w:.3f}, τ = {r.tau:.3f}, r = {r.r:.3f}  \n"
                    f"MDB = {r.mdb:.4g} {r.unit}, δ̄0 = {r.ext:.3g}"
                    + ("  \n**excluded**" if r.excluded else ""))
        elif s.selected_point is not None:
            p = pts.iloc[s.selected_point]
            text = (f"**Point {p.id}** ({p.status}), {int(p.n_obs)} observations  \n"
                    f"min r = {p.min_r:.3f}, max |w| = {p.max_w:.3f}, max δ̄0 = {p.max_ext:.3g}")
        self.info.object = text
        self.excluded.object = ("Excluded: " + ", ".join(str(i) for i in sorted(s.excluded))
                                if s.excluded else "")
        images = [str(im.get("id")) for im in s.images]
        if self.image.options != images:       # a thousand options are not sent again on every click
            self.image.options = images
        self.image.visible = bool(images)
        self.exaggeration.visible = bool(images)
        if images and str(s.selected_image) in images:
            self.image.value = str(s.selected_image)

    def _exclude(self, *_):
        if self.state.selected_obs is not None:
            self.state.exclude(self.state.selected_obs)

    def _include(self, *_):
        if self.state.selected_obs is not None:
            self.state.include(self.state.selected_obs)

    def _test(self, *_):
        s = self.state
        if s.selected_obs is not None:
            s.add_hypothesis({"kind": "observation", "index": int(s.selected_obs)})

    def __panel__(self):
        return pn.Column("### Selection", self.info, pn.Row(self.exclude, self.include, self.test),
                         self.include_all, self.excluded, self.image, self.exaggeration,
                         sizing_mode="stretch_width")


class FilePanel(pn.viewable.Viewer):
    """Upload a problem file (size limit, errors shown as a message) and export the report."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.upload = pn.widgets.FileInput(accept=".gkf,.xml,.json", multiple=False,
                                           sizing_mode="stretch_width", css_classes=["file-input"])
        self.upload.param.watch(self._uploaded, "value")
        self.alert = pn.pane.Alert("", alert_type="danger", visible=False, sizing_mode="stretch_width",
                                   css_classes=["error-alert"])
        s.param.watch(self._show_error, "error")
        self.download = pn.widgets.FileDownload(callback=self._report, filename="baarda-report.html",
                                                label="Download HTML report", button_type="success",
                                                sizing_mode="stretch_width")
        self.source = pn.pane.Markdown(pn.bind(lambda src: f"File: `{Path(src).name}`" if src else "",
                                               s.param.source), sizing_mode="stretch_width")
        self._show_error()

    def _uploaded(self, event):
        data = event.new
        name = Path(self.upload.filename or "upload").name
        if data is None:
            return
        if len(data) > MAX_UPLOAD_MB * 1024 * 1024:
            self.state.error = f"{name} is larger than {MAX_UPLOAD_MB} MB; run `baarda` on it instead."
            return
        tmp = Path(tempfile.mkdtemp(prefix="baarda-upload-")) / name
        tmp.write_bytes(data)
        self.state.load(tmp)

    def _show_error(self, *_):
        self.alert.object = self.state.error
        self.alert.visible = bool(self.state.error)

    def _report(self):
        from ..report import report_html

        return io.StringIO(report_html(self.state.results, state=self.state))

    def __panel__(self):
        return pn.Column("### File", self.source, self.upload, self.alert, self.download,
                         sizing_mode="stretch_width")
