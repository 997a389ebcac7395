"""While a file is read and adjusted, the session says how far it is (issue 15, item 6): the
adjustment's iterations reach the session's ``progress`` (its task panel and the line under the
summary), and nothing is written there when no computation runs."""

from __future__ import annotations

from pathlib import Path

from baarda.build import read_problem
from baarda.dashboard.state import State
from baarda.dashboard.views.summary import SummaryHeader

DATA = Path(__file__).resolve().parents[2] / "data"


def test_iterations_reach_the_sessions_progress():
    session = State()
    seen = []
    session.param.watch(lambda e: seen.append(e.new), "progress")
    session.task = "reading demo-block.json"
    fresh = State(problem=read_problem(DATA / "demo-block.json"), progress_to=session)
    assert fresh.results is not None
    its = [p for p in seen if p.startswith("adjusting: iteration")]
    assert len(its) == fresh.results.iterations, seen
    assert its[0].startswith("adjusting: iteration 1,")
    # shown under the summary while there is no result, as text
    assert SummaryHeader.progress_html(None, session.task, its[-1]) == f"<small>{its[-1]}</small>"
    assert SummaryHeader.progress_html(fresh.results, session.task, its[-1]) == ""
    assert SummaryHeader.progress_html(None, "x", "<b>") == "<small>&lt;b&gt;</small>"


def test_no_progress_without_a_task():
    st = State(problem=read_problem(DATA / "demo-block.json"))
    assert st.results is not None and st.progress == ""
