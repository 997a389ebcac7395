"""Served, the dashboard's long computations stay off the event loop and on one thread each
(issue 29, item 3): the Criterion tab's fit runs on a session's task thread while its page is
built, and the task threads' compiled kernels and the BLAS are limited (BAARDA_BLAS_THREADS)."""

from __future__ import annotations

import threading
import time

import pytest

pytest.importorskip("panel")

import holoviews as hv  # noqa: E402

from baarda.dashboard import jobs, measures  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402
from baarda.dashboard.views import CriterionView  # noqa: E402
from baarda.solve.compiled import numba  # noqa: E402
from tests.extdata import GAMA, require_extdata  # noqa: E402

hv.extension("bokeh", logo=False)
FREE_2D = "krumm/2D/Hoepke_Distance_free.gkf"


def _wait(cond, timeout=60.0):
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


def test_criterion_fit_runs_on_a_task_thread_when_served(monkeypatch):
    """The view opens at once (the fit not on the building thread); the fit's result reaches the
    state through the session's loop, with the numbers of the in-place fit."""
    st = State(require_extdata(GAMA) / FREE_2D)
    assert st.error == "", st.error
    reference = CriterionView(state=st)           # not served: the fit in place, as before
    expected = st.criterion
    assert expected is not None and expected["fitted"]
    st.criterion = None

    where, on_loop = [], []
    real = measures.criterion

    def spy(*args, **kw):
        where.append(threading.current_thread().name)
        return real(*args, **kw)
    monkeypatch.setattr(measures, "criterion", spy)

    def loop_call(fn):                             # the event loop: a thread of its own
        on_loop.append(threading.current_thread().name)
        threading.Thread(target=fn, name="loop").start()
    st.background, st.jobs.loop_call = True, loop_call
    view = CriterionView(state=st)
    _wait(lambda: st.criterion is not None)
    assert where and all(name.startswith("baarda-task") for name in where)
    assert on_loop and all(name.startswith("baarda-task") for name in on_loop)
    for key in ("C1", "C2", "lam_max", "lam_min"):
        assert st.criterion[key] == expected[key]
    _wait(lambda: view.C1.value == expected["C1"])
    assert reference.C1.value == expected["C1"]


@pytest.mark.skipif(numba is None, reason="numba not installed")
def test_task_threads_run_their_kernels_on_one_thread(monkeypatch):
    assert jobs.TASKS.submit(numba.get_num_threads).result(timeout=60) == 1
