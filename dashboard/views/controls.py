"""Sidebar widgets: test settings (α0, β0, B-method, σ0), the selection with exclude /
re-include, the image and exaggeration of block views, file upload and report export."""

from __future__ import annotations

import functools
import io

import panel as pn
import param

from .. import geometry
from ..geometry import observation_label
from ..state import ROBUST_METHODS, State
from .. import auxdata
from ..tables import OPTIONAL, TABLES, table_csv
from ..text import html_text, md_text, plain
from ..uploads import MAX_UPLOAD_MB, UPLOAD_CHUNK, UPLOAD_MAX_CONTENT, BoundedDropper, Uploads, upload_name

__all__ = ["Controls", "FilePanel", "SelectionPanel", "TaskPanel", "MAX_UPLOAD_MB", "UPLOAD_CHUNK",
           "UPLOAD_MAX_CONTENT", "BoundedDropper", "upload_name"]

ALPHAS = [1e-5, 1e-4, 2e-4, 5e-4, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1]


def _two_way(widget, state, name):
    """Keep ``widget.value`` and ``state.<name>`` equal in both directions."""
    widget.param.watch(lambda e: setattr(state, name, e.new), "value")
    state.param.watch(lambda e: setattr(widget, "value", e.new), name)


class Controls(pn.viewable.Viewer):
    """α0, β0 (δ0 updates live), the B-method, which σ0 the decisions use and the global test."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.alpha = pn.widgets.DiscreteSlider(label="α0 (1D test size)", options=ALPHAS,
                                               value=min(ALPHAS, key=lambda a: abs(a - s.alpha0)),
                                               css_classes=["alpha-slider"], sizing_mode="stretch_width")
        self.beta = pn.widgets.FloatSlider(label="β0 (power)", start=0.5, end=0.99, step=0.01,
                                           value=s.beta0, sizing_mode="stretch_width")
        self.b_method = pn.widgets.Checkbox(label="B-method (same δ0 for all dimensions)", value=s.b_method)
        self.sigma = pn.widgets.RadioButtonGroup(label="σ0", options={"σ0 a priori (w)": "apriori",
                                                                   "σ̂0 a posteriori (τ)": "aposteriori"},
                                                 value=s.sigma0_mode, sizing_mode="stretch_width")
        self.global_test = pn.widgets.Select(label="Global test (F80 §4.1)",
                                             options={"one-sided at (1 − conf-pr)/2 (F80)": "one-sided",
                                                      "two-sided at conf-pr (gama-local)": "two-sided",
                                                      "one-sided, B-method α_r (F80 §7.2)": "b-method"},
                                             value=s.global_test, css_classes=["global-test-select"],
                                             sizing_mode="stretch_width")
        self.robust = pn.widgets.Select(label="Robust reweighting (M84 §3.1, R84)", options=list(ROBUST_METHODS),
                                        value=s.robust_method, css_classes=["robust-select"],
                                        sizing_mode="stretch_width")
        for w, name in ((self.alpha, "alpha0"), (self.beta, "beta0"), (self.b_method, "b_method"),
                        (self.sigma, "sigma0_mode"), (self.global_test, "global_test"),
                        (self.robust, "robust_method")):
            _two_way(w, s, name)
        self.delta = pn.pane.Markdown(pn.bind(self.delta_text, s.param.reliability),
                                      css_classes=["delta0"], sizing_mode="stretch_width")

    @staticmethod
    def delta_text(rel):
        """The δ0 line under the test controls for a Reliability ``rel`` ("" without one)."""
        if rel is None:
            return ""
        return (f"**δ0 = {rel.delta0:.3f}** (λ0 = {rel.delta0 ** 2:.2f}); critical |w| = "
                f"{rel.critical_w:.3f}, |τ| = {rel.critical_tau:.3f}")

    def __panel__(self):
        return pn.Column("### Tests", self.alpha, self.beta, self.delta, self.b_method, self.sigma,
                         self.global_test, self.robust, sizing_mode="stretch_width")


class SelectionPanel(pn.viewable.Viewer):
    """The selected point / observation, exclude and re-include, the block image and exaggeration."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.info = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["selection-info"])
        self.exclude = pn.widgets.Button(label="Exclude", color="warning", width=80)
        self.include = pn.widgets.Button(label="Re-include", width=90)
        self.test = pn.widgets.Button(label="Test it", width=70)
        self.include_all = pn.widgets.Button(label="Re-include all", width=120)
        self.excluded = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.image = pn.widgets.Select(label="Image (residual view)", options=[], sizing_mode="stretch_width")
        self.exaggeration = pn.widgets.FloatInput(label="Residual vector exaggeration", value=s.exaggeration,
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
        # HTML built here; every string of the file goes through html_text (text, never markup)
        text = "<i>Click a point or line on a map, or a row of the table.</i>"
        if s.selected_obs is not None:
            r = obs.loc[s.selected_obs]
            unit = html_text(r.unit)
            text = (f"<b>Observation {html_text(observation_label(s.problem, s.selected_obs))}</b><br>"
                    f"v = {r.v:.4g} {unit}, w = {r.w:.3f}, τ = {r.tau:.3f}, r = {r.r:.3f}<br>"
                    f"MDB = {r.mdb:.4g} {unit}, δ̄0 = {r.ext:.3g}"
                    + ("<br><b>excluded</b>" if r.excluded else ""))
        elif s.selected_point is not None:
            p = pts.iloc[s.selected_point]
            text = (f"<b>Point {html_text(p.id)}</b> ({html_text(p.status)}), {int(p.n_obs)} observations<br>"
                    f"min r = {p.min_r:.3f}, max |w| = {p.max_w:.3f}, max δ̄0 = {p.max_ext:.3g}")
        self.info.object = text
        self.excluded.object = ("Excluded: " + ", ".join(str(i) for i in sorted(s.excluded))
                                if s.excluded else "")
        images = [str(im.get("id")) for im in geometry.images(s.problem)]
        if list(self.image.options.values() if isinstance(self.image.options, dict) else self.image.options) \
                != images:                     # a thousand options are not sent again on every click
            self.image.options = {plain(i): i for i in images}
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
    """Upload a problem file and export the report.

    The upload widget (:class:`panel.widgets.FileDropper`) refuses a file above
    :data:`MAX_UPLOAD_MB` in the browser, before anything is sent, and sends the others in
    chunks (:data:`UPLOAD_CHUNK`); the server checks the size again, refuses empty and
    whitespace-only files with a message (:class:`BoundedDropper` refuses a larger one while its
    chunks arrive; its content, decompressed, may hold :data:`UPLOAD_MAX_CONTENT`), and writes the file under a name of its own
    (:func:`upload_name`) into a temporary directory that is removed as soon as the file has
    been read (and, for a read still running, when the session ends: :meth:`cleanup`).
    Messages show the upload's own name as text, never the server's path.
    """

    state = param.ClassSelector(class_=State)
    render_report = param.Callable(default=None, doc="report_html(adj, state=...) of baarda.dashboard.report, "
                                   "given by the app (the report renders views: imported above them)")

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.upload = BoundedDropper(MAX_UPLOAD_MB * 1024 * 1024, self._refused,
                                     max_file_size=f"{MAX_UPLOAD_MB}MB", multiple=False, previews=[],
                                     chunk_size=UPLOAD_CHUNK, layout="compact",
                                     sizing_mode="stretch_width", css_classes=["file-input"])
        self.upload.param.watch(self._uploaded, "value")
        self.limit = pn.pane.HTML(f"<small>Gama .gkf, baarda .json, Bundler .out, BAL; at most "
                                  f"{MAX_UPLOAD_MB} MB</small>", sizing_mode="stretch_width")
        self.alert = pn.pane.Alert("", alert_type="danger", visible=False, sizing_mode="stretch_width",
                                   css_classes=["error-alert"])
        s.param.watch(self._show_error, "error")
        self.download = pn.widgets.FileDownload(callback=self._report, filename="baarda-report.html",
                                                label="Download HTML report", color="success",
                                                sizing_mode="stretch_width",
                                                description="The client report: verdict, maps and suspects on "
                                                            "three A4 pages (print it to PDF from the browser)")
        # the full tables, for spreadsheets (baarda.dashboard.tables)
        self.tables = {name: pn.widgets.FileDownload(callback=functools.partial(self._table, name),
                                                     filename=f"baarda-{name}.csv", label=f"{name.capitalize()} table (CSV)",
                                                     color="default", sizing_mode="stretch_width",
                                                     css_classes=[f"csv-{name}"])
                       for name in TABLES}
        self.source = pn.pane.HTML(pn.bind(lambda name: f"File: <code>{html_text(name)}</code>"
                                           if name else "", s.param.file_name),
                                   sizing_mode="stretch_width", css_classes=["file-source"])
        #: the file being received, as plain text (the widget's own list hides the browser's raw name)
        self.receiving = pn.pane.HTML(pn.bind(lambda name: f"<small>Receiving <code>{html_text(name)}</code></small>"
                                              if name else "", self.upload.param.receiving),
                                      sizing_mode="stretch_width", css_classes=["file-receiving"])
        #: the checks, temporary copies and reading of uploads (baarda.dashboard.uploads)
        self.uploads = Uploads(s)
        self._show_error()
        s.param.watch(self._optional_tables, ["results"])
        self._optional_tables()

    def _optional_tables(self, *_) -> None:
        """The check points' download only where the block has check points."""
        for name in OPTIONAL:
            has = self.state.results is not None and auxdata.check_points(self.state)["n"] > 0
            self.tables[name].visible = has

    def _refused(self, name) -> None:
        self.uploads.refused(name)

    def _uploaded(self, event):
        if not event.new:
            return
        name, data = list(event.new.items())[-1]
        self.upload.param.update(value={}, mime_type={})   # the bytes are not kept in the session
        self.receive(name, data)

    def receive(self, name, data) -> bool:
        """Check an uploaded file and read it (:meth:`baarda.dashboard.uploads.Uploads.receive`)."""
        return self.uploads.receive(name, data)

    def cleanup(self, *_) -> None:
        """Remove every temporary upload directory of this panel (session ended)."""
        self.uploads.cleanup()

    def _show_error(self, *_):
        self.alert.object = md_text(self.state.error)
        self.alert.visible = bool(self.state.error)

    def report(self):
        """The HTML report of the current result as a file object (what the download button gives)."""
        return self._report()

    def _report(self):
        if self.render_report is None:
            raise RuntimeError("FilePanel: no report renderer (render_report) given")
        return io.StringIO(self.render_report(self.state.results, state=self.state))

    def _table(self, name):
        if self.state.results is None:
            return io.BytesIO(b"")
        return table_csv(self.state, name)

    def __panel__(self):
        return pn.Column("### File", self.source, self.upload, self.receiving, self.limit, self.alert, self.download,
                         pn.pane.HTML("<small>Full tables for spreadsheets:</small>", margin=(4, 10, 0, 10)),
                         *self.tables.values(), sizing_mode="stretch_width")


class TaskPanel(pn.viewable.Viewer):
    """The background computation of the session: what runs, how far it is, and Cancel."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.bar = pn.indicators.Progress(active=True, value=-1, sizing_mode="stretch_width", height=12,
                                          css_classes=["task-progress"])
        self.text = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["task-text"])
        self.cancel = pn.widgets.Button(label="Cancel", color="danger", width=90, css_classes=["task-cancel"])
        self.cancel.on_click(lambda e: s.cancel())
        self.box = pn.Column(self.bar, self.text, self.cancel, sizing_mode="stretch_width", visible=False,
                             css_classes=["task-panel"])
        s.param.watch(self._show, ["task", "progress"])
        self._show()

    def _show(self, *_):
        s = self.state
        self.box.visible = bool(s.task)
        self.text.object = (f"<b>{html_text(s.task)}</b>" + (f"<br>{html_text(s.progress)}" if s.progress else "")
                            if s.task else "")

    def __panel__(self):
        return self.box
