"""Finding errors: robust reweighting beside data snooping, iterative data snooping with the
leave-one-out view, variance components (issue 7), and the "inject an error here" teaching tool.

Every number comes from the core through the state (its ``robust`` result, :meth:`State.run_snooping`,
:meth:`State.run_variance`, :meth:`State.inject`), tabulated by :mod:`baarda.dashboard.frames`;
these views only show them and forward button clicks.
"""

from __future__ import annotations

import pandas as pd
import panel as pn
import param

from baarda.stats.variance import groups_by_kind

from .. import auxdata, frames
from ..geometry import object_unit, observation_label
from ..state import VARIANCE_MODELS, State
from ..text import md_text, plain
from baarda.stats.reliability import reliability_of

TABLE = dict(show_index=False, disabled=True, sizing_mode="stretch_width", layout="fit_data_stretch",
             stylesheets=[".tabulator { font-size: 12px; }"])


class _Slot:
    """A place for a table that appears when it has rows. Each new content is a new Tabulator made
    while its place is shown: Tabulator cannot lay out rows given to it while hidden (its virtual DOM
    measures them), and a hidden table given data then shown stayed empty (tabulator issues 542,
    4698; seen in the browser test of snooping's leave-one-out table)."""

    def __init__(self, css: str, height: int):
        self.css, self.height = css, height
        self.value = pd.DataFrame()
        self.panel = pn.Column(sizing_mode="stretch_width", margin=0)

    def show(self, frame: pd.DataFrame, visible: bool) -> None:
        """Show ``frame`` in a new table, or nothing; an unchanged content changes nothing in the
        page (no re-render of the column while the page is built)."""
        same = (self.value.equals(frame) and list(self.value.columns) == list(frame.columns)
                and bool(self.panel.objects) == visible)
        self.value = frame
        if same:
            return
        self.panel.objects = ([pn.widgets.Tabulator(frame, height=self.height, css_classes=[self.css], **TABLE)]
                              if visible else [])

    @property
    def visible(self) -> bool:
        return bool(self.panel.objects)


def _table(css: str, height: int) -> _Slot:
    return _Slot(css, height)


class AnalysisPanel(pn.viewable.Viewer):
    """Robust suspects (R84 classes) with the least-squares data snooping beside (M84 §3.2);
    iterative data snooping and σ̂0 with each top suspect left out; variance components."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.message = pn.pane.Alert("", alert_type="warning", visible=False, sizing_mode="stretch_width",
                                     css_classes=["analysis-alert"])
        self.robust_info = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["robust-info"])
        self.robust_table = _table("robust-table", 200)
        self.snoop_button = pn.widgets.Button(label="Run iterative data snooping", color="primary",
                                              width=220, css_classes=["snoop-run"])
        self.accept = pn.widgets.Button(label="Accept: exclude the removed", color="warning", width=210,
                                        disabled=True, css_classes=["snoop-accept"])
        self.snoop_info = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["snoop-info"])
        self.snoop_table = _table("snoop-table", 130)
        self.loo_table = _table("loo-table", 130)
        self.variance_button = pn.widgets.Button(label="Estimate variance components", width=230,
                                                 css_classes=["variance-run"])
        self.variance_model = pn.widgets.RadioButtonGroup(options=list(VARIANCE_MODELS), value=s.variance_model,
                                                          color="primary", variant="outline", width=300,
                                                          css_classes=["variance-model"])
        self.variance_model.link(s, value="variance_model")
        # families given one factor together (baarda analyze --merge-groups)
        self.merge = pn.widgets.TextInput(label="Merge families (A+B, C+D)", value=s.merge_groups, width=300,
                                          css_classes=["variance-merge"])
        self.merge.link(s, value="merge_groups", bidirectional=True)
        s.param.watch(self._families, ["problem"])
        self._families()
        self.variance_table = _table("variance-table", 110)
        # check points (issue 28): adjusted − known and the RMSE row
        self.check_info = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["check-info"])
        self.check_table = _table("check-table", 160)
        s.param.watch(self._checks, ["results"])
        self._checks()
        self.snoop_button.on_click(lambda e: s.submit("iterative data snooping", s.run_snooping))
        self.accept.on_click(lambda e: s.accept_snooping())
        self.variance_button.on_click(lambda e: s.submit("variance components", s.run_variance))
        s.param.watch(self._robust, ["robust", "robust_method", "results"])
        s.param.watch(self._snoop, ["snoop", "snoop_loo", "results"])
        s.param.watch(self._variance, ["variance", "components", "results"])
        s.param.watch(self._message, ["analysis_error"])
        self._robust()
        self._snoop()
        self._variance()

    def _checks(self, *_):
        s = self.state
        df = auxdata.check_table(s) if s.results is not None else pd.DataFrame(columns=auxdata.CHECK_COLUMNS)
        n = max(len(df) - 1, 0)
        self.check_table.show(df, n > 0)
        unit = object_unit(s.problem) if s.problem is not None else ""
        self.check_info.object = (f"#### Check points ({n}, not in the adjustment)\nAdjusted − known "
                                  f"coordinates{f' [{unit}]' if unit else ''} and σ of the adjusted ones; "
                                  "last row the RMSE per axis." if n else "")

    def _message(self, *_):
        self.message.object = md_text(self.state.analysis_error)
        self.message.visible = bool(self.state.analysis_error)

    def _robust(self, *_):
        s = self.state
        rr = s.robust
        self.robust_table.show(frames.robust_suspects(rr, s.kept, s.frames()[0] if rr is not None else None),
                               rr is not None and bool(rr.suspects))
        if s.robust_method == "none":
            self.robust_info.object = "*Robust reweighting is off (choose a method in the sidebar).*"
            return
        if rr is None:
            self.robust_info.object = f"*{md_text(s.robust_method)}: no result.*"
            return
        obs, _ = s.frames()
        rejected = obs.index[obs["rejected"] & ~obs["excluded"]].tolist()
        final = ""
        if rr.final is not None:
            g = reliability_of(rr.final).global_test
            final = (f" Least squares without them: σ̂0 = {rr.final.sigma0_post:.4g}, global test "
                     f"{'passed' if g.get('passed') else 'FAILED'}.")
        self.robust_info.object = (
            f"**{rr.method}**: {rr.iterations} iterations ({'converged' if rr.converged else 'NOT converged'}), "
            f"{len(rr.suspects)} suspects (orange on the maps).{final}  \n"
            f"Data snooping of the least-squares fit beside: {len(rejected)} rejected"
            + (f" ({', '.join(map(str, rejected[:8]))}{'…' if len(rejected) > 8 else ''})" if rejected else "")
            + ".")

    def _snoop(self, *_):
        s = self.state
        res = s.snoop
        self.snoop_table.show(frames.snoop_log(res, s.kept, s.frames()[0] if res is not None else None,
                                               *s.problem_index()["factor"]), res is not None and bool(res.steps))
        self.loo_table.show(frames.loo_table(s.snoop_loo, s.kept, s.frames()[0]), bool(s.snoop_loo))
        self.accept.disabled = res is None or not res.steps
        if res is None:
            self.snoop_info.object = ""
            return
        stat = "τ" if res.use_tau else "w"
        self.snoop_info.object = (f"{len(res.steps)} observations removed (test with {stat}); final σ̂0 = "
                                  f"{res.adjustment.sigma0_post:.4g}. Below: σ̂0 with each of the largest "
                                  f"|w| left out in turn (the likeliest error lowers it most).")

    def _families(self, *_):
        """The families of the problem, as the merge field's placeholder."""
        p = self.state.problem
        names = list(groups_by_kind(p)) if p is not None else []
        self.merge.placeholder = plain("+".join(names[:2])) if len(names) >= 2 else "(one family)"
        self.merge.description = plain("Families: " + ", ".join(names)) if names else None

    def _variance(self, *_):
        self.variance_table.show(frames.variance_table(self.state.variance, self.state.components),
                                 self.state.variance is not None or self.state.components is not None)

    def __panel__(self):
        return pn.Column(
            self.message, self.check_info, self.check_table.panel,
            "#### Robust reweighting and data snooping (M84 §3.2)", self.robust_info, self.robust_table.panel,
            "#### Iterative data snooping", pn.Row(self.snoop_button, self.accept), self.snoop_info,
            self.snoop_table.panel, self.loo_table.panel,
            "#### Variance components (F80 eq. 9): per observation family, or the radial model "
            "σ² = a² + b²c²/cos⁴α of a block (F80 §2.1)", pn.Row(self.variance_model, self.variance_button), self.merge,
            self.variance_table.panel, sizing_mode="stretch_width", scroll=True, height=640)


class InjectPanel(pn.viewable.Viewer):
    """Add an error of a chosen size to the selected observation of a *copy* of the problem,
    adjust it and show what the tests see; "keep" makes it part of the loaded data."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        self.target = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["inject-target"])
        self.size = pn.widgets.FloatInput(label="Error size", value=1.0, step=0.5, width=120,
                                          css_classes=["inject-size"])
        self.unit = pn.widgets.RadioButtonGroup(options={"× σ": "sigma", "× MDB": "mdb"}, value="mdb", width=160,
                                                color="primary", variant="outline",
                                                css_classes=["inject-unit"])
        self.run = pn.widgets.Button(label="Inject and adjust", color="primary", width=150,
                                     css_classes=["inject-run"])
        self.keep = pn.widgets.Button(label="Keep it in the data", color="danger", width=150,
                                      disabled=True, css_classes=["inject-keep"])
        self.result = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["inject-result"])
        self.message = pn.pane.Alert("", alert_type="warning", visible=False, sizing_mode="stretch_width")
        self.run.on_click(self._run)
        self.keep.on_click(lambda e: s.keep_injection())
        s.param.watch(self._target, ["selected_obs", "results"])
        s.param.watch(self._show, ["injection", "analysis_error"])
        self._target()
        self._show()

    def _target(self, *_):
        s = self.state
        if s.selected_obs is None:
            self.target.object = "*Select an observation (map or tests table).*"
            self.run.disabled = True
            return
        obs, _ = s.frames()
        r = obs.loc[s.selected_obs]
        self.run.disabled = bool(r.excluded)
        self.target.object = (f"**{md_text(observation_label(s.problem, s.selected_obs))}**: σ-scaled MDB = "
                              f"{r.mdb_sigma:.2f} σ ({r.mdb:.4g} {md_text(r.unit)}), r = {r.r:.3f}")

    def _run(self, *_):
        s = self.state
        if s.selected_obs is not None:
            s.inject(int(s.selected_obs), float(self.size.value), self.unit.value)

    def _show(self, *_):
        s = self.state
        inj = s.injection
        self.message.object = md_text(s.analysis_error)
        self.message.visible = bool(s.analysis_error) and s.analysis_error.startswith("Cannot inject")
        self.keep.disabled = inj is None
        if inj is None:
            self.result.object = ""
            return
        st = inj["statistic"]
        unit = "σ" if inj["unit"] == "sigma" else "MDB"
        group = ("" if inj["group_T"] is None else
                 f"  \nT of its group = {inj['group_T']:.2f} (critical {inj['group_critical']:.2f})")
        dw = inj["w_after"] - inj["w_before"]
        d0 = s.reliability.delta0
        where = ("the same observation" if inj["largest_index"] == inj["index"]
                 else f"obs {md_text(inj['largest_label'])}")
        self.result.object = (
            f"Error of {inj['size']:g} {unit} = {inj['error']:.4g} {md_text(inj['error_unit'])} "
            f"in obs {inj['index']} (a copy of the data):  \n"
            f"{st} of that observation: {inj['w_before']:.3f} → **{inj['w_after']:.3f}** "
            f"(critical {inj['critical']:.3f}): **{'rejected' if inj['rejected'] else 'not rejected'}**  \n"
            f"Δ{st} = {dw:+.3f} = {dw / d0:+.2f} δ0 (δ0 = {d0:.3f}): an error of one MDB moves {st} by δ0 "
            f"(F80 §5); whether it is then rejected depends on where the noise had put {st} before — "
            f"the test finds it with probability β0 = {s.beta0:.2f}  \n"
            f"largest |{st}| = {inj['largest']:.3f} at {where}{group}  \n"
            f"σ̂0 = {inj['sigma0_post']:.4g}, global test "
            f"{'passed' if inj['global_passed'] else 'failed' if inj['global_passed'] is False else 'n/a'}")

    def __panel__(self):
        return pn.Column("#### Inject an error here (teaching)", self.target,
                         pn.Row(self.size, pn.Column(pn.Spacer(height=20), self.unit)),
                         pn.Row(self.run, self.keep), self.message, self.result,
                         sizing_mode="stretch_width")
