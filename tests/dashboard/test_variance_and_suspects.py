"""Issue 27 in the dashboard: variance components of merged families (``--merge-groups``) and
partly inseparable pairs in the suspects list, both the core's numbers."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("panel")

from baarda.dashboard.state import State  # noqa: E402
from baarda.dashboard.suspects import suspects  # noqa: E402
from baarda.dashboard.views import AnalysisPanel  # noqa: E402
from baarda.stats import hypotheses, separability  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo-block.json"


@pytest.fixture(scope="module")
def demo():
    return State(DEMO)


def test_merged_families_give_the_cli_numbers(demo):
    st = demo
    panel = AnalysisPanel(state=st)
    assert "control" in panel.merge.description and "image observations" in panel.merge.description
    assert st.run_variance() is False and "merge it with another group" in st.analysis_error
    panel.merge.value = "image observations+control"          # what the user types
    assert st.merge_groups == "image observations+control"
    assert st.run_variance() is True and st.analysis_error == ""
    ref = st.analysis.variance_components("families", "image observations+control")   # baarda analyze's
    got = st.variance.as_dict()
    assert [d["group"] for d in got] == ["image observations+control"]
    assert got[0]["factor"] == pytest.approx(ref.as_dict()[0]["factor"], rel=1e-12)
    assert panel.variance_table.panel is not None
    st.merge_groups = "control+nothing"
    assert st.run_variance() is False and "no group 'nothing'" in st.analysis_error


def test_suspects_name_partly_inseparable_pairs_as_baarda_test(demo):
    st = demo
    df = suspects(st)
    adj = st.results
    pid, a, b = "P05003", "302", "303"
    Ha, Hb = hypotheses.h_image_point(adj.problem, a, pid), hypotheses.h_image_point(adj.problem, b, pid)
    (pair,) = separability.partly_inseparable(adj, [("a", Ha), ("b", Hb)])
    row = df[(df["what"] == "image point") & (df["hypothesis"] == f"{pid} in image {a}")].iloc[0]
    text = (f"partly inseparable from image point {pid} in image {b} "
            f"(canonical correlations {pair.largest:.2f} … {pair.smallest:.2f})")
    assert text in row["cannot be told apart from"]
    assert pair.largest >= separability.THRESHOLD > pair.smallest
