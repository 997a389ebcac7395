"""The dashboard's modules beside the state (issue 13): geometry, frames, specs, measures, sbase
and jobs are plain functions of the core's objects, and give what the state shows.

Each check compares a module's function with the core or with the state that calls it; the
import check keeps ``state.py`` the only holder of the choices (no module below it imports it).
"""

from __future__ import annotations

import ast
import threading
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("panel")
pytest.importorskip("holoviews")

from baarda.dashboard import frames, geometry, jobs, measures, sbase, specs  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402
from baarda.stats.hypotheses import selection  # noqa: E402
from tests.extdata import GAMA, require_extdata  # noqa: E402

DASHBOARD = Path(__file__).resolve().parent.parent / "dashboard"
#: the modules below the state: they take the core's objects, never the state's module
BELOW_STATE = ("geometry", "frames", "specs", "measures", "sbase", "jobs", "suspects", "text")


@pytest.fixture(scope="module")
def st():
    s = State(require_extdata(GAMA) / "krumm/2D/Hoepke_Distance_free.gkf")
    assert s.error == "" and s.results is not None, s.error
    return s


@pytest.mark.parametrize("name", BELOW_STATE)
def test_modules_below_the_state_do_not_import_it(name):
    tree = ast.parse((DASHBOARD / f"{name}.py").read_text(encoding="utf-8"))
    targets = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module]
    assert not any(t == "state" or t.endswith(".state") or t.startswith("views") for t in targets), targets


def test_every_dashboard_module_is_small():
    sizes = {p.name: len(p.read_text(encoding="utf-8").splitlines()) for p in DASHBOARD.glob("*.py")}
    assert sizes["state.py"] < 900 and max(sizes.values()) < 900, sizes


def test_geometry_index_and_full_reduced_mapping(st):
    p = st.problem
    index = geometry.problem_index(p)
    assert index["obs_points"] == geometry.observation_points(p) == st.obs_points
    assert len(index["labels"]) == p.n
    k = index["inc_pt"][0]
    assert geometry.observations_of_point(index, k) == st.observations_of_point(k)
    kept = np.array([i for i in range(p.n) if i != 3])
    red = geometry.reduced_index(kept, p.n, [0, 3, 4])
    assert red.tolist() == [0, -1, 3]
    full = geometry.expand(np.arange(kept.size, dtype=float), kept, p.n)
    assert np.isnan(full[3]) and full[4] == 3.0


def test_frames_are_the_states_tables(st):
    obs, pts = frames.frames(st.problem, st.results, st.reliability, st.kept, st.excluded,
                             st.problem_index(), st.robust)
    o, q = st.frames()
    assert obs.equals(o) and pts.equals(q)
    np.testing.assert_array_equal(obs["w"].to_numpy(), st.results.w)
    assert frames.segments(pts, st.problem_index()).equals(st.segments())
    assert frames.variance_table(None, None).empty and frames.robust_suspects(None, st.kept, None).empty
    counts = frames.summary_counts(obs, pts, st.excluded, st.images)
    assert counts["n_points"] == len(pts) and counts["n_excluded"] == 0


def test_specs_translate_to_the_cores_tests(st):
    spec = {"kind": "observation", "index": 2, "active": True, "label": "x"}
    H = specs.matrix(st.problem, st.results, st.kept, spec, st.problem_index())
    assert (H != selection(st.results.n, [2])).nnz == 0
    h = specs.evaluate(st.problem, st.results, st.reliability, st.kept, spec, st.problem_index())
    ref = st.reliability.test(selection(st.results.n, [2]), label="x")
    assert h.T == pytest.approx(ref.T, rel=1e-12)
    assert specs.evaluate(st.problem, st.results, st.reliability, st.kept, {**spec, "active": False},
                          st.problem_index()) is None
    assert specs.describe(st.problem, spec, st.problem_index()).startswith("obs 2 ")
    assert specs.point(st.problem, spec, st.problem_index()) == st.hypothesis_point(spec)


def test_measures_and_sbase_are_the_states(st):
    m = len(st.problem.points.ids)
    i = int(np.nanargmax(st.reliability.mdb))
    np.testing.assert_array_equal(measures.observation_field(st.results, st.reliability, st.kept, st.problem.n, m, i),
                                  st.deformation_field(i))
    assert not measures.observation_field(st.results, st.reliability, st.kept, st.problem.n, m, None).any()
    assert not measures.hypothesis_field(st.results, "refused", m).any()
    e = measures.injected_error(st.results, st.reliability, st.kept, st.problem.n, i, 5.0)
    assert np.flatnonzero(e).tolist() == [i]
    rc = measures.risk_curve(0.1, 1.0, 1.0, st.reliability.delta0 ** 2, n=20)
    assert rc["grid"].size == rc["r"].size == 20
    assert sbase.datum_points(st.problem) == st.datum_points()
    assert sbase.sbase_check(st.problem, st.results, [], "", st.options()) == "S-base: the problem's own datum."


def test_jobs_run_in_place_without_a_loop_and_cancel_only_task_threads():
    j = jobs.Jobs()
    assert j.on_loop(lambda: 7) == 7               # no loop_call: here
    j.cancel()
    j.check()                                      # not a task thread: nothing raised
    assert j.cancelled() is False
    j.reset()
    fut = j.start(lambda: (threading.current_thread().name, j.cancelled()))
    name, cancelled = fut.result(timeout=30)
    assert name.startswith("baarda-task") and cancelled is False
    assert jobs.file_key("/no/such/file", None) is None and jobs.cached(None) is None
