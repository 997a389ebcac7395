"""The suspects list (issue 15, item 2) on the demo block, without a browser.

- every planted error of ``data/demo-block.truth.json`` is a row of the list (its observations,
  point or hypothesis), rejected where the core rejects it;
- the numbers are the core's: T = w², ∇ŝ / ∇0s = |w| / δ0 for one observation, against the dense
  oracle's w; a transfer row's T against the core's own test of the same images;
- twins (the two image points of a 2-ray point) name each other, with ρ checked against the
  dense P C_vv P of the oracle;
- a click selects the observation, the point and the image in the state; the tests table shows
  the decision in words.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("panel")

from baarda.dashboard import geometry  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402
from baarda.dashboard.suspects import suspects, transfer_candidates  # noqa: E402
from baarda.dashboard.views.suspects import SuspectsView  # noqa: E402
from baarda.stats.hypotheses import h_point_transfer  # noqa: E402
from baarda.stats.reliability import reliability_of
from tests.oracle import dense  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def demo(demo_path):
    st = State(demo_path)
    truth = json.loads((DATA / "demo-block.truth.json").read_text())
    return st, suspects(st), truth["errors"]


def rows_of(st, df):
    """Per suspect row, the full observation indices it is about."""
    out = []
    for _, r in df.iterrows():
        if r["what"] == "transfer":
            pid, ims = r["hypothesis"].split(" in images ")
            out.append({i for im in ims.split(", ") for i in geometry.point_rows_in_image(st.problem_index(), im, pid)})
        elif r["what"] == "control point":
            out.append({i for i, ids in enumerate(st.problem.info.ids) if str(ids.get("id")) == r["hypothesis"]})
        elif r["what"] == "image point":
            pid, im = r["hypothesis"].split(" in image ")
            out.append(set(geometry.image_point_rows(st.problem_index(), im, pid)))
        else:
            out.append({int(r["obs"])})
    return out


def test_every_planted_error_is_a_suspect(demo):
    st, df, errors = demo
    sets = rows_of(st, df)
    for e in errors:
        planted = set(int(i) for i in e["rows"])
        hits = [k for k, s in enumerate(sets) if s and s <= planted]
        assert hits, f"planted {e['kind']} {e['ids']} not in the suspects"
        assert (df["decision"].iloc[hits] == "rejected").any(), e["kind"]
    # the transfer error itself (point P04004 in images 203, 204, 205) is one of the scanned rows
    tr = df[(df["what"] == "transfer") & (df["hypothesis"] == "P04004 in images 203, 204, 205")]
    assert len(tr) == 1 and tr["decision"].iat[0] == "rejected"
    h = reliability_of(st.results).test(h_point_transfer(st.results.problem, "P04004", ["203", "204", "205"]))
    assert tr["T"].iat[0] == pytest.approx(h.T, rel=1e-9)


def test_sorted_by_abs_w_with_core_numbers(demo):
    st, df, _ = demo
    w = np.asarray(df["|w|"], dtype=float)
    assert np.all(np.diff(w[np.isfinite(w)]) <= 1e-12)
    assert list(df["rank"]) == list(range(1, len(df) + 1))
    oracle = dense(st.results)
    d0 = st.reliability.delta0
    one = df[df["what"] == "observation"]
    assert len(one) > 10
    for _, r in one.iterrows():
        wi = st.results.w[int(r["obs"])]        # no exclusions: full index = reduced index
        # the core's w is the dense oracle's (to the conditioning of the weakest 2-ray points)
        assert abs(wi) == pytest.approx(abs(oracle.w[int(r["obs"])]), rel=1e-3)
        assert r["|w|"] == pytest.approx(abs(wi), rel=1e-12)
        assert r["T"] == pytest.approx(wi ** 2, rel=1e-7)
        assert r["MDB ratio"] == pytest.approx(abs(wi) / d0, rel=1e-9)
        # ∇ŝ = −(Pv)_i / (P C_vv P)_ii (F80 eq. 10, H = e_i) from the oracle, in the file's unit
        i = int(r["obs"])
        M = oracle.P @ oracle.Cvv @ oracle.P
        ref = -(oracle.P @ oracle.v)[i] / M[i, i] * st.problem_index()["factor"][0][i]
        assert float(r["∇ŝ"].split()[0]) == pytest.approx(ref, rel=6e-3)    # shown to 3 digits
        assert (r["decision"] == "rejected") == (abs(wi) > st.reliability.critical)
    assert set(df["decision"]) <= {"rejected", "accepted"}


def test_two_ray_twins_are_marked(demo):
    st, df, _ = demo
    oracle = dense(st.results)
    M = oracle.P @ oracle.Cvv @ oracle.P
    rho = M / np.sqrt(np.outer(np.diag(M), np.diag(M)))
    # P00001 is seen in images 101 and 102 only: its four image coordinates have |ρ| = 1 (to the
    # oracle's conditioning)
    rows = geometry.image_point_rows(st.problem_index(), "101", "P00001") + geometry.image_point_rows(st.problem_index(), "102", "P00001")
    assert np.abs(rho[np.ix_(rows, rows)]).min() > 0.999
    for i in rows:
        r = df[(df["what"] == "observation") & (df["obs"] == i)]
        assert len(r) == 1
        named = r["cannot be told apart from"].iat[0]
        for j in rows:
            if j != i:
                assert f"obs {j} " in named
    ip = df[(df["what"] == "image point") & (df["hypothesis"] == "P00001 in image 101")]
    assert "image point P00001 in image 102" in ip["cannot be told apart from"].iat[0]
    # an observation of a well-controlled point has no twin
    r = df[(df["what"] == "observation") & (df["obs"] == 301)]
    assert r["cannot be told apart from"].iat[0] == ""
    assert np.abs(np.delete(rho[301], 301)).max() < 0.99


def test_transfer_candidates_are_runs_of_one_strip(demo):
    st, _, _ = demo
    runs = transfer_candidates(st, "P04004")
    assert ["203", "204", "205"] in runs
    strip = {str(im["id"]): im.get("strip") for im in geometry.images(st.problem)}
    seen = geometry.images_of_point(st.problem_index(), "P04004")
    for run in runs:
        assert 2 <= len(run) < len(seen) and len({strip[i] for i in run}) == 1


def test_click_selects_observation_point_and_image():
    path = DATA / "demo-block.json"
    if not path.exists():
        pytest.skip("data/demo-block.json not generated")
    st = State(path)
    view = SuspectsView(state=st)
    df = view.frame()
    k = int(df.index[(df["what"] == "image point") & (df["hypothesis"] == "P00001 in image 101")][0])
    view.table.selection = [k]
    assert st.selected_obs == int(df["obs"].iat[k]) and st.selected_image == "101"
    k = int(df.index[df["what"] == "transfer"][0])
    view.table.selection = [k]
    assert st.selected_obs is None and st.selected_point == geometry.point_index(st.problem)[df["hypothesis"].iat[k].split(" in ")[0]]
    assert "rejected" in view.note.object and "suspects" in view.note.object


def test_tests_table_decisions_in_words_and_abs_w_sorted(demo):
    st, _, _ = demo
    from baarda.dashboard.views import table as table_view

    view = table_view.TestsTable(state=st)
    df = view.table.value
    w = st.results.w
    np.testing.assert_allclose(df["abs_w"].to_numpy(), np.abs(w), equal_nan=True)
    np.testing.assert_allclose(df["abs_tau"].to_numpy(), np.abs(st.results.tau), equal_nan=True)
    rejected = np.abs(w) > st.reliability.critical
    assert (df["decision"].to_numpy() == "rejected").sum() == rejected.sum() == 23
    assert set(df["decision"][~rejected]) <= {"accepted", "not testable"}
    assert (df["decision"][~np.isfinite(w)] == "not testable").all()
    assert view.table.sorters == [{"field": "abs_w", "dir": "desc"}]
    st.exclude(301)
    df = view.table.value
    assert df["decision"].iat[301] == "excluded" and df["excluded"].iat[301] == "excluded"
    st.include(301)
