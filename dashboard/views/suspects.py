"""The suspects view: the reviewer's ranked list of hypotheses (:mod:`baarda.dashboard.suspects`).

One table of 1D tests, group tests and point-transfer scans ranked on one scale — the p-value of
each test under the policy, the suspects that the stronger ones do not explain first (issue 31,
item 1) — sortable by any column (a click on a header); the decision in words
(rejected in red, accepted in green); hypotheses the data cannot tell apart named in their own
column. A click on a row selects what it is about in the state — the observation (maps, tests
table), its point and its image (image view) — so the other views show it at once.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import panel as pn
import param
from bokeh.models.widgets.tables import HTMLTemplateFormatter, NumberFormatter, ScientificFormatter

from baarda.errors import BaardaError

from ..jobs import TASKS
from ..state import State
from ..suspects import COLUMNS, suspects
from ..text import html_text

#: The decision in words and colours people read correctly: rejected red, accepted green (dark
#: enough for 4.5 : 1 on a selected row, issue 31, item 10).
DECISION = HTMLTemplateFormatter(template=(
    '<span style="font-weight:600;color:<%= value == "rejected" ? "#b2182b" : "#116329" %>">'
    '<%= value == "rejected" ? "✗ rejected" : "✓ accepted" %></span>'))
#: Twins: the "cannot be told apart" note in the warning colour.
TWINS = HTMLTemplateFormatter(template='<span style="color:#a15c00"><%- value %></span>')
SHOWN = [c for c in COLUMNS if c not in ("obs", "point", "image", "cannot be told apart from")]
SHOWN.insert(SHOWN.index("explained by") + 1, "cannot be told apart from")
#: The test's numbers, shown by the "more columns" box: by default the table holds what a
#: reviewer reads first — the suspect, its p-value, the decision, what explains it and its twins —
#: and fits its panel at 1600-1920 px (the columns after "decision" needed sideways scrolling,
#: issue 31, item 6).
MORE = ["|w|", "|τ|", "T", "k", "q", "MDB ratio", "∇ŝ"]
#: Cells and headers wrap their text instead of cutting it (issue 31, item 6); a selected row is
#: light blue with a dark edge, so that the red and green decisions stay readable on it.
TABLE_CSS = (".tabulator { font-size: 12px; } .tabulator-col-title { font-size: 12px; white-space: normal !important; }"
             " .tabulator-row .tabulator-cell { white-space: normal !important; overflow-wrap: anywhere; text-overflow: clip !important; }"
             " .tabulator-row.tabulator-selected, .tabulator-row.tabulator-selected:hover"
             " { background-color: #dbe7f8 !important; box-shadow: inset 4px 0 0 #1f4e9c; }"
             " .tabulator-row.tabulator-selected .tabulator-cell { color: #111111; }"
             " .tabulator-row:focus-visible { outline: 2px solid #0b5cad; outline-offset: -2px; }")


class SuspectsView(pn.viewable.Viewer):
    """The ranked suspects of the state's adjustment; a row click selects it in the state."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        self._frame = pd.DataFrame(columns=COLUMNS)
        self._for = None
        self.note = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["suspects-note"])
        self.table = pn.widgets.Tabulator(
            pd.DataFrame(columns=SHOWN), disabled=True, selectable=1, show_index=False, sortable=True,
            sizing_mode="stretch_width", height=560, layout="fit_data_stretch", pagination="local",
            page_size=100, css_classes=["suspects-table"], stylesheets=[TABLE_CSS],
            header_filters={"what": {"type": "input", "func": "like", "placeholder": "what"},
                            "hypothesis": {"type": "input", "func": "like", "placeholder": "name"},
                            "decision": {"type": "list", "values": ["rejected", "accepted"],
                                         "clearable": True}},
            formatters={"decision": DECISION, "cannot be told apart from": TWINS,
                        "|w|": NumberFormatter(format="0.00"), "|τ|": NumberFormatter(format="0.00"),
                        "T": NumberFormatter(format="0.0"), "k": NumberFormatter(format="0.0"),
                        "MDB ratio": NumberFormatter(format="0.00"),
                        "p": ScientificFormatter(precision=2, power_limit_low=-2)},
            titles={"rank": "#", "k": "critical k", "∇ŝ": "∇ŝ (estimate)", "MDB ratio": "∇ŝ / ∇0s", "p": "p-value"},
            text_align={c: "right" for c in ("|w|", "|τ|", "T", "k", "q", "MDB ratio", "p")},
            widths={"rank": 44, "what": 84, "hypothesis": 150, "p": 76, "decision": 90, "explained by": 130,
                    "∇ŝ": 130, "cannot be told apart from": 160}, frozen_columns=["rank"], hidden_columns=MORE)
        self.more = pn.widgets.Checkbox(label="more columns (|w|, |τ|, T, critical k, q, ∇ŝ / ∇0s, ∇ŝ)", value=False,
                                        css_classes=["suspects-more"])
        self.more.param.watch(lambda e: setattr(self.table, "hidden_columns", [] if e.new else MORE), "value")
        self.table.param.watch(self._clicked, "selection")
        self.state.param.watch(self._refresh, ["results", "reliability"])
        self._refresh()

    def _current(self) -> bool:
        s = self.state
        return self._for is not None and self._for[0] is s.results and self._for[1] is s.reliability

    def frame(self) -> pd.DataFrame:
        """The suspects of the current results (computed once per results and policy)."""
        s = self.state
        if not self._current():
            key = (s.results, s.reliability)
            self._frame, self._for = suspects(s), key
        return self._frame

    def _note(self, df: pd.DataFrame) -> str:
        s = self.state
        if s.results is None:
            return ""
        rel = s.reliability
        n_obs = int(np.count_nonzero(rel.rejected))
        g = rel.groups
        n_grp = int(np.count_nonzero(g.rejected)) if len(g) else 0
        shown_obs = int(((df["what"] == "observation") & (df["decision"] == "rejected")).sum())
        shown_grp = int(((df["what"] != "observation") & (df["what"] != "transfer")
                         & (df["decision"] == "rejected")).sum())
        twins = int((df["cannot be told apart from"] != "").sum())
        more = []
        if n_obs > shown_obs:
            more.append(f"{n_obs - shown_obs} more rejected observations in the tests table")
        if n_grp > shown_grp:
            more.append(f"{n_grp - shown_grp} more rejected groups")
        own = int(((df["explained by"] == "") & (df["decision"] == "rejected")).sum())
        text = (f"<b>{len(df)} suspects</b> ranked by the p-value of their test under the policy "
                f"(|{rel.policy.statistic_name}| for one observation, T ~ χ²(q) for a group, a point transfer, "
                "a control point, a GNSS centre or strip)"
                + (f", the {own} rejected that the stronger ones above do not explain first (tested given "
                   "them; \"or …\": an alternative the data hardly tell apart from it)" if own else "")
                + "; click a column header to sort by it. "
                f"{n_obs} observation(s) and {n_grp} group(s) rejected in all"
                + (f" ({'; '.join(more)})" if more else "") + ". "
                + (f"<span style='color:#a15c00'>{twins} cannot be told apart from others</span> "
                   "(their tests are perfectly correlated: the data cannot say which one is wrong). "
                   if twins else "")
                + "∇ŝ / ∇0s (more columns): the estimated error over the smallest one the test finds with power β0. "
                  "Click a row: it is selected on the maps, in the image view and in the tests table.")
        return text

    def _refresh(self, *_):
        """Show the suspects of the current results. Served, they are computed on a worker thread
        (some hundred solves on a 1,000-image block: seconds the event loop must not wait) and
        shown on the session's loop when done."""
        s = self.state
        if s.results is None:
            return
        if not s.background or self._current():
            self._show(self.frame(), self._for)
            return
        self.note.object = "<i>Testing the suspects…</i>"
        key = (s.results, s.reliability)

        def first(df):
            # a slow list is shown ranked by p-value while its tiering runs
            if s.results is key[0] and s.reliability is key[1] and not s.jobs.closed:
                def apply():
                    self._show(df, key)
                    self.note.object = ("<i>Ranked by p-value; testing which of them the stronger ones "
                                        "explain…</i> " + self._note(df))
                s.on_loop(apply)

        def compute():
            try:
                df = suspects(s, early=first)
            except (BaardaError, np.linalg.LinAlgError, ValueError) as err:
                message = f"<b>The suspects could not be tested:</b> {html_text(err)}"
                s.on_loop(lambda: setattr(self.note, "object", message))
                return
            if s.results is key[0] and s.reliability is key[1] and not s.jobs.closed:
                def apply():
                    self._frame, self._for = df, key
                    self._show(df, key)
                s.on_loop(apply)
        TASKS.submit(compute)

    def _show(self, df: pd.DataFrame, key) -> None:
        """Show ``df``, the suspects of ``key`` = (results, reliability)."""
        self._shown = (df, key)
        self.table.value = df[SHOWN]
        self.table.selection = []
        self.note.object = self._note(df)

    def _clicked(self, event):
        if not event.new:
            return
        df, key = getattr(self, "_shown", (None, None))
        s = self.state
        if df is None or key is None or key[0] is not s.results or key[1] is not s.reliability:
            return
        row = df.iloc[int(self.table.value.index[event.new[0]])]
        self.select(row)

    def select(self, row) -> None:
        """Select what a suspect is about: its observation (a point hypothesis: its point) and
        its image."""
        s = self.state
        upd = {}
        if row["image"] is not None and not (isinstance(row["image"], float) and np.isnan(row["image"])):
            upd["selected_image"] = str(row["image"])
        if row["what"] in ("control point", "transfer") and row["point"] is not None and np.isfinite(row["point"]):
            upd.update(selected_obs=None, selected_point=int(row["point"]))
        else:
            upd.update(selected_point=None, selected_obs=int(row["obs"]))
        s.param.update(**upd)

    def __panel__(self):
        return pn.Column(pn.pane.HTML(f"<h3 style='margin:4px 0'>{html_text('Suspects')}</h3>"), self.note,
                         self.more, self.table, sizing_mode="stretch_width")
