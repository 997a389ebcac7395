"""The tests table: every observation with the core's v, w, τ, r, MDB, δ̄0 and the decision.

Selecting one row selects that observation in the state (and so on the maps); a point selected
on a map selects all rows of its observations here. The table is sortable (by |w| descending at
first: |w| and |τ| have their own columns, as sorting the signed w would put large negative
values last), has header filters and can be limited to the rows of the current selection. The
decision is in words, rejected in red and accepted in green (issue 15).
"""

from __future__ import annotations

import numpy as np
import panel as pn
from bokeh.models.widgets.tables import HTMLTemplateFormatter, NumberFormatter
import param

from .. import geometry
from ..state import State
from ..tables import tables_xlsx
from .suspects import TABLE_CSS

COLUMNS = {"kind": "kind [unit]", "ids": "ids", "v": "v", "w": "w", "abs_w": "|w|", "tau": "τ", "abs_tau": "|τ|",
           "decision": "decision", "r": "r", "mdb": "MDB", "ext": "δ̄0", "excluded": "excluded",
           "robust_w": "robust weight"}
WIDTHS = {"index": 48, "kind": 105, "ids": 112, "decision": 84, "excluded": 88}
#: The decision in words: rejected red, accepted green (the colours people read correctly).
DECISION = HTMLTemplateFormatter(template=(
    '<span style="font-weight:600;color:<%= value == "rejected" ? "#b2182b" : '
    '(value == "accepted" ? "#116329" : "#777777") %>"><%- value %></span>'))


class TestsTable(pn.viewable.Viewer):
    """A :class:`panel.widgets.Tabulator` of the observation table of the state."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        self._syncing = False
        self.only_selection = pn.widgets.Checkbox(label="only rows of the selected point / observation",
                                                  value=False)
        # every table of the app in one workbook, one sheet each (issue 31, item 9)
        self.xlsx = pn.widgets.FileDownload(callback=lambda: tables_xlsx(self.state), filename="baarda-tables.xlsx",
                                            label="All tables (Excel .xlsx)", color="default",
                                            css_classes=["xlsx-download"], width=220,
                                            description="Observations, points and suspects, one sheet each")
        self.table = pn.widgets.Tabulator(
            self._frame(), layout="fit_data_stretch", sizing_mode="stretch_width", height=560,
            selectable=True, show_index=True, disabled=True,
            hidden_columns=[] if self.state.robust is not None else ["robust_w"],
            pagination="local", page_size=200,
            header_filters={"kind": {"type": "input", "func": "like", "placeholder": "kind"},
                            "ids": {"type": "input", "func": "like", "placeholder": "ids"},
                            "decision": {"type": "list", "values": ["rejected", "accepted", "excluded",
                                                                   "not testable"], "clearable": True},
                            "excluded": {"type": "list", "values": ["excluded", ""], "clearable": True}},
            formatters={"decision": DECISION,
                        "v": NumberFormatter(format="0.[000]"), "w": NumberFormatter(format="0.000"),
                        "abs_w": NumberFormatter(format="0.000"), "abs_tau": NumberFormatter(format="0.000"),
                        "tau": NumberFormatter(format="0.000"), "r": NumberFormatter(format="0.000"),
                        "mdb": NumberFormatter(format="0.[000]"), "ext": NumberFormatter(format="0.00"),
                        "robust_w": NumberFormatter(format="0.000", nan_format="")},
            titles={"index": "#", **COLUMNS}, css_classes=["tests-table"], stylesheets=[TABLE_CSS], widths=WIDTHS,
            text_align={"v": "right", "w": "right", "tau": "right", "r": "right", "mdb": "right", "ext": "right",
                        "robust_w": "right", "abs_w": "right", "abs_tau": "right"},
            sorters=[{"field": "abs_w", "dir": "desc"}])
        self.only_selection.param.watch(self._refresh, "value")
        self.table.param.watch(self._on_selection, "selection")
        self.state.param.watch(self._refresh, ["results", "robust"])
        self.state.param.watch(self._select_from_state, ["selected_point", "selected_obs"])

    def _frame(self):
        obs, _ = self.state.frames()
        df = obs[["kind", "ids", "v", "w", "tau", "r", "mdb", "ext", "robust_w"]].copy()
        df["kind"] = obs["kind"] + " [" + obs["unit"] + "]"
        df["abs_w"] = np.abs(obs["w"].to_numpy(dtype=float))
        df["abs_tau"] = np.abs(obs["tau"].to_numpy(dtype=float))
        excluded = obs["excluded"].to_numpy(dtype=bool)
        df["decision"] = np.where(excluded, "excluded", np.where(
            obs["rejected"].to_numpy(dtype=bool), "rejected",
            np.where(np.isfinite(obs["w"].to_numpy(dtype=float)), "accepted", "not testable")))
        df["excluded"] = np.where(excluded, "excluded", "")
        df = df[list(COLUMNS)]
        rows = self._state_rows()
        if self.only_selection.value and rows is not None:
            df = df.loc[df.index.isin(rows)]
        for c in ("v", "w", "abs_w", "tau", "abs_tau", "r", "mdb", "ext", "robust_w"):
            df[c] = df[c].astype(float)
        return df

    def _state_rows(self):
        s = self.state
        if s.selected_point is not None:
            return geometry.observations_of_point(s.problem_index(), s.selected_point)
        if s.selected_obs is not None:
            return [s.selected_obs]
        return None

    def _refresh(self, *_):
        self._syncing = True
        try:
            self.table.hidden_columns = [] if self.state.robust is not None else ["robust_w"]
            self.table.value = self._frame()
            self._apply_selection()
        finally:
            self._syncing = False

    def _select_from_state(self, *_):
        if self.only_selection.value:
            self._refresh()
            return
        self._apply_selection()

    def _apply_selection(self):
        rows = self._state_rows()
        sel = [] if rows is None else [int(i) for i in rows]
        positions = list(np.flatnonzero(np.isin(self.table.value.index.to_numpy(), sel)))
        if positions != list(self.table.selection):
            old, self._syncing = self._syncing, True
            try:
                self.table.selection = [int(p) for p in positions]
            finally:
                self._syncing = old

    def _on_selection(self, event):
        if self._syncing:
            return
        added = sorted(set(event.new) - set(event.old or []))
        if added:
            index = int(self.table.value.index[added[-1]])
            self.state.param.update(selected_point=None, selected_obs=index)
            self._select_from_state()
        elif not event.new:
            self.state.param.update(selected_point=None, selected_obs=None)

    def __panel__(self):
        return pn.Column(pn.Row(self.only_selection, pn.layout.HSpacer(), self.xlsx, sizing_mode="stretch_width"),
                         self.table, sizing_mode="stretch_width")
