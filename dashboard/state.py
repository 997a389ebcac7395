"""The dashboard's one state object: the user's choices, and the results of the core they give.

:class:`State` holds the choices (the problem, α0, β0, the B-method, σ0, exclusions, hypotheses,
selections, S-base, robust method, variance model) and the core's results for them; it calls the
core (:func:`baarda.adjust.adjust`, :class:`~baarda.stats.reliability.Reliability`, …) when a
choice changes, and caches what several views read: the problem's index (:meth:`State.problem_index`),
the tables (:meth:`State.frames`) and the covariance in the chosen S-base. The views only read it and
write choices back. Everything else lives in its own module, which the state and the views call
with the state's fields (e.g. ``geometry.images(state.problem)``,
``frames.segments(state.frames()[1], state.problem_index())``):

- :mod:`baarda.dashboard.geometry` — display geometry, units, a block's images and the problem's index;
- :mod:`baarda.dashboard.frames` — the tables built from the results;
- :mod:`baarda.dashboard.specs` — hypothesis specifications and their tests;
- :mod:`baarda.dashboard.measures` — the adjustment without the excluded observations, deformation
  fields, criterion, risk, injected errors, snooping, variance components;
- :mod:`baarda.dashboard.sbase` — precision in an S-base;
- :mod:`baarda.dashboard.jobs` — background computations and the server's file cache.

Observation indices are always those of the *full* problem as read (``problem``); the
adjustment ``results`` is computed on the problem without the excluded observations
(:func:`baarda.model.problem.without`), and ``kept[k]`` maps its index k back.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import param

from baarda.adjust import Options
from baarda.analysis import Analysis, analyze
from baarda.build import read_problem
from baarda.errors import BaardaError
from baarda.io.source import checking
from baarda.stats import robust
from baarda.stats.policy import TestPolicy

from . import auxdata, geometry, measures, specs
from . import sbase as sbase_lesson
from .outcomes import Outcome
from .snapshot import Snapshot
from .jobs import Cancelled, Jobs, cached, file_key, file_lock, on_worker_thread, store
from .text import plain

#: Robust methods of the controls ("none": plain least squares).
ROBUST_METHODS = ("none", *robust.METHODS)
#: The reader's companion files :meth:`State.load` takes (options of :func:`baarda.analysis.analyze`).
INPUTS = ("control", "gnss", "imu")
#: variance models: per family, the radial model of F80 §2.1, its isotropic variant
VARIANCE_MODELS = ("families", "radial", "radial-isotropic")


class State(param.Parameterized):
    """Everything the dashboard shows (see the module docstring)."""

    source = param.String(default="", doc="Path of the problem file.")
    file_name = param.String(default="", doc="The file's name as shown (an upload's own name).")
    problem = param.Parameter(default=None, doc="The problem as read, its local defects set aside "
                              "(baarda.model.problem.Problem; the Analysis's ``problem``).")
    alpha0 = param.Number(default=0.001, bounds=(1e-6, 0.5), doc="Size α0 of the 1D tests.")
    beta0 = param.Number(default=0.80, bounds=(0.5, 0.999), doc="Power β0.")
    b_method = param.Boolean(default=False, doc="Baarda's B-method for multi-dimensional tests.")
    sigma0_mode = param.Selector(default="apriori", objects=["apriori", "aposteriori"],
                                 doc="σ0 used for covariances and the decision (w or τ).")
    global_test = param.Selector(default="one-sided", objects=["one-sided", "two-sided", "b-method"],
                                 doc="The global test (TestPolicy): F80 §4.1's one-sided test at (1 − conf-pr)/2, "
                                     "gama-local's two-sided interval at conf-pr, or one-sided at the B-method's "
                                     "α_r (F80 §7.2).")
    excluded = param.Parameter(default=frozenset(), doc="Excluded observations (full indices).")
    hypotheses = param.List(default=[], doc="Hypothesis specifications (module docstring).")
    outcomes = param.List(default=[], doc="Per hypothesis its Outcome (baarda.dashboard.outcomes): "
                          "inactive, refused (with the core's message), a test or an AP group's test.")
    selected_point = param.Integer(default=None, allow_None=True, doc="Selected point index.")
    selected_obs = param.Integer(default=None, allow_None=True, doc="Selected observation (full index).")
    selected_hypothesis = param.Integer(default=None, allow_None=True)
    selected_image = param.Parameter(default=None, doc="Image shown in the image-space view (blocks).")
    exaggeration = param.Number(default=1.0, bounds=(0.0, None),
                                doc="Exaggeration of image residual vectors.")
    snapshot = param.Parameter(default=None, doc="The Snapshot shown (baarda.dashboard.snapshot): "
                               "``analysis`` and the tables derived from it, made once.")
    exact = param.Boolean(default=True, doc="False while the result shown is the downdate of an "
                          "exclusion and its exact re-adjustment runs (measures.downdated).")
    analysis = param.Parameter(default=None, doc="The core's Analysis (baarda.analysis) of ``problem`` "
                               "without the excluded observations under the state's test policy: "
                               "``results``, ``reliability`` and ``kept`` are its adjustment, reliability "
                               "and kept indices.")
    results = param.Parameter(default=None, doc="The core's Adjustment of the reduced problem.")
    reliability = param.Parameter(default=None, doc="The core's Reliability of ``results`` under the "
                                  "state's test policy (α0, β0, B-method, σ0): rebuilt over the same "
                                  "``results`` when only the policy changes.")
    solution = param.Integer(default=0, doc="Counts the adjustments: changes when the problem is solved "
                             "again (exclusion, σ0, a new problem), not when only α0, β0 or the B-method "
                             "change (then only ``reliability`` does, and ``results`` is triggered so "
                             "that the views redraw).")
    kept = param.Array(default=np.zeros(0, dtype=np.int64), doc="Full index of each reduced observation.")
    error = param.String(default="", doc="A message for the user (bad file, failed exclusion).")
    busy = param.Boolean(default=False, doc="True while a computation runs.")
    task = param.String(default="", doc="The background computation running now ('' = none).")
    replacing = param.Event(doc="Another problem is about to become current (the app drops the views "
                            "of the old one before they would redraw with the new results).")
    progress = param.String(default="", doc="What the background computation has done so far.")
    background = param.Boolean(default=False, doc="Run long computations on a worker thread "
                               "(set by the served app; scripts and tests compute in place).")
    timings = param.Dict(default={}, doc="Seconds of the last recomputations.")
    sbase = param.List(default=[], doc="S-base (point ids) of the precision view; [] = the problem's datum.")
    sbase_error = param.String(default="", doc="Why the chosen S-base cannot be used.")
    field_source = param.Selector(default="observation", objects=["observation", "hypothesis"],
                                  doc="Whose deformation field the external-reliability map shows.")
    robust_method = param.Selector(default="none", objects=list(ROBUST_METHODS),
                                   doc="Robust reweighting of the analysis panel.")
    robust = param.Parameter(default=None, doc="The core's RobustResult, or None.")
    snoop = param.Parameter(default=None, doc="The core's SnoopResult of the current problem, or None.")
    snoop_loo = param.List(default=[], doc="σ̂0 with each top suspect left out (snooping.leave_one_out).")
    variance = param.Parameter(default=None, doc="The core's VarianceComponents, or None.")
    injection = param.Dict(default=None, allow_None=True, doc="What the tests see of an injected error.")
    analysis_error = param.String(default="", doc="A message of the last analysis the core refused.")
    variance_model = param.Selector(default="families", objects=list(VARIANCE_MODELS),
                                    doc="Variance components per family, or the radial model of a block "
                                        "(b on the radial component, F80 §2.1; or isotropic).")
    components = param.Parameter(default=None, doc="The core's ComponentEstimate (radial model), or None.")
    merge_groups = param.String(default="", doc="Families estimated with one variance factor together, "
                                "\"A+B[,C+D]\" (``baarda analyze --merge-groups``; "
                                "baarda.stats.variance.merge_groups); '' = one factor per family.")
    criterion = param.Dict(default=None, allow_None=True, doc="The last criterion comparison (criterion_*).")
    criterion_error = param.String(default="", doc="Why the criterion comparison was refused.")

    def __init__(self, path=None, problem=None, progress_to: "State | None" = None, **params):
        """progress_to: the state whose ``progress`` the adjustment's iterations are written
        to (a session's, for a state made on its worker thread to read a file); default self."""
        super().__init__(**params)
        self._progress_to = progress_to
        self._index, self._index_for = None, None
        #: the analysis of the current problem without exclusions (the exclusions' downdates start there)
        self._full = None
        #: (exclusions, snapshot) before the last downdate (:meth:`downdate`; restored if its refinement fails)
        self._before = (frozenset(), None)
        #: the session's background computations (:class:`~baarda.dashboard.jobs.Jobs`): the
        #: served app sets its ``loop_call`` and ``closed``
        self.jobs = Jobs()
        #: the free-block view's adjustment (:func:`~baarda.dashboard.sbase.free_block`), kept
        #: while the adjustment is current: ``{"results": the Adjustment it was made from,
        #: "free": the free block's Adjustment}``, or ``{}``; replaced whole, never updated in place
        self.free_block_cache: dict = {}
        if problem is not None:
            self.set_problem(problem, source=str(path or problem.source))
        elif path is not None:
            self.load(path)

    @classmethod
    def from_adjustment(cls, adj, policy=None) -> "State":
        """A state showing an existing adjustment (no exclusions, no new solve); ``policy`` (a
        :class:`TestPolicy`, e.g. the command line's) sets σ0 of the decisions and the global
        test, else the file's σ0 and the one-sided test."""
        mode = adj.problem.sigma_act if adj.problem.sigma_act in ("apriori", "aposteriori") else "apriori"
        pol = TestPolicy(alpha0=adj.options.alpha0, beta0=adj.options.beta0, b_method=adj.options.b_method,
                         sigma0=policy.sigma0 if policy is not None else mode,
                         global_test=policy.global_test if policy is not None else "one-sided")
        return cls.from_analysis(Analysis(adj.problem, adj, pol, name=str(adj.problem.source)))

    @classmethod
    def from_analysis(cls, analysis: Analysis) -> "State":
        """A state showing the core's ``analysis`` as it is: its problem, exclusions, test policy
        and adjustment (nothing solved again)."""
        st = cls()
        pol = analysis.policy
        with param.parameterized.discard_events(st):
            st.param.update(problem=analysis.problem, source=str(analysis.problem.source or analysis.name),
                            sigma0_mode=pol.sigma0, global_test=pol.global_test, alpha0=pol.alpha0,
                            beta0=pol.beta0, b_method=pol.b_method, excluded=frozenset(analysis.excluded))
            st._set_snapshot(Snapshot(analysis))
            images = geometry.images(st.problem)
            st.selected_image = images[0]["id"] if images else None
        return st

    def _set_snapshot(self, snap: Snapshot) -> None:
        """Make ``snap`` current: its analysis' adjustment, reliability and kept indices."""
        analysis = snap.analysis
        if not analysis.excluded and (self._full is None or self._full.problem is not analysis.problem
                                      or self._full.adjustment is not analysis.adjustment):
            self._full = analysis
        self.kept = np.asarray(analysis.kept)
        self.snapshot = snap
        self.analysis = analysis
        self.reliability = analysis.reliability
        if self.results is not analysis.adjustment:     # the same (a new policy): triggered by the caller
            self.results = analysis.adjustment

    # -- background computations ----------------------------------------------------------------
    def submit(self, label: str, fn, *args):
        """Run ``fn(*args)`` on a worker thread (:data:`~baarda.dashboard.jobs.TASKS`) with
        ``task = label``; with ``background`` off (scripts, tests) run it here. One computation
        per session at a time: returns None (and does nothing) while another runs, else the
        Future (or the result)."""
        if not self.background:
            return fn(*args)
        if self.task:
            return None

        def run():
            try:
                with checking(self._stop_if_closed):       # a closed page's file is read no further
                    return fn(*args)
            except Cancelled:
                self.progress = "cancelled"
                return False
            finally:
                self.task = ""
        self.jobs.reset()
        self.param.update(task=label, progress="")
        return self.jobs.start(run)

    def on_loop(self, fn):
        """``fn()`` on the session's event loop when called from a worker thread of a served
        session, here otherwise (:meth:`baarda.dashboard.jobs.Jobs.on_loop`)."""
        return self.jobs.on_loop(fn)

    def _stop_if_closed(self) -> None:
        """Raise :class:`Cancelled` once the session has ended (its page closed)."""
        if self.jobs.closed:
            raise Cancelled()

    def cancel(self) -> None:
        """Ask the running background computation to stop: snooping stops within its current
        step (at the readjustment's next iteration); the other computations finish on their thread but their result is dropped."""
        if self.task:
            self.jobs.cancel()
            self.progress = "cancelling…"

    def _check_cancel(self) -> None:
        """Raise :class:`Cancelled` in a background computation whose session cancelled it."""
        self.jobs.check()

    # -- loading --------------------------------------------------------------------------------
    def load(self, path, name: str | None = None, inputs: dict | None = None) -> bool:
        """Read and adjust a file; on failure keep the current problem and set ``error``.

        name: the file's name to show (an upload's own name); messages never show ``path``
        when a name is given. inputs: the reader's companion files of ``path``, the options
        ``control``, ``gnss`` and ``imu`` of :func:`baarda.analysis.analyze` (a control CSV with
        roles, GNSS projection centres and IMU attitudes as a path or
        :class:`baarda.io.gnss.GnssOptions` / :class:`~baarda.io.gnss.ImuOptions`; ``baarda
        serve FILE --gnss CSV ...``), read as ``analyze`` reads them. A file read before by this
        server (same path, modification time, size, companion files and test options) is taken
        from the cache without reading or adjusting it again.
        """
        inputs = {k: v for k, v in (inputs or {}).items() if v is not None}
        unknown = set(inputs) - set(INPUTS)
        if unknown:
            raise ValueError(f"State.load: unknown inputs {sorted(unknown)} (known: {', '.join(INPUTS)})")
        shown = plain(name if name is not None else Path(str(path)).name)

        def message(err) -> str:
            text = str(err)
            for p in {str(path), str(Path(str(path)).resolve()), str(Path(str(path)).parent)}:
                if p and p not in (".", "/"):
                    text = text.replace(p, shown)
            return plain(text)

        key = file_key(path, self.options(), inputs) if name is None else None
        lock = file_lock(key) if key is not None else None
        # the lock is held while the file is read and adjusted (other sessions opening the same
        # file wait for it), not while this session shows it
        with (lock or contextlib.nullcontext()):
            hit = cached(key)
            if hit is None:
                try:
                    with self._busy():
                        self.progress = f"reading {shown}"
                        problem = read_problem(path, **inputs)
                except BaardaError as err:
                    self.error = f"Cannot read {shown}: {message(err)}"
                    return False
                except Exception as err:  # noqa: BLE001 - the app must show a message, never a traceback
                    self.error = f"Cannot read {shown}: {type(err).__name__}: {message(err)}"
                    return False
                self._check_cancel()
                if name is not None:
                    problem = replace(problem, source=str(name))
                self.progress = f"adjusting {shown}"
                with self._busy():
                    fresh = State(problem=problem, path=name if name is not None else path, progress_to=self,
                                  alpha0=self.alpha0, beta0=self.beta0, b_method=self.b_method)
                if fresh.results is None:
                    self.error = message(fresh.error)
                    return False
                fresh.frames()
                hit = fresh.snapshot
                if key is not None:
                    store(key, hit)
        self._check_cancel()
        ok = self.on_loop(lambda: self._set_loaded(hit, source=str(name if name is not None else path)))
        if ok:
            self.file_name = shown
        return ok

    def load_cached(self, path, inputs: dict | None = None) -> bool:
        """Make ``path`` (with its companion files ``inputs``, :meth:`load`) current if the
        server's cache holds it already (read and adjusted by another session or at the
        server's start), at once and without waiting; else False."""
        inputs = {k: v for k, v in (inputs or {}).items() if v is not None}
        hit = cached(file_key(path, self.options(), inputs))
        if hit is None:
            return False
        self._set_loaded(hit, source=str(path))
        self.file_name = plain(Path(str(path)).name)
        return True

    def _set_loaded(self, hit, source: str) -> bool:
        """Make a cached snapshot current without adjusting again."""
        analysis = hit.analysis
        problem = analysis.problem
        if self.problem is not None:
            self.param.trigger("replacing")
        with param.parameterized.discard_events(self):
            self.problem = problem
            self.sigma0_mode = (problem.sigma_act if problem.sigma_act in ("apriori", "aposteriori")
                                else "apriori")     # as the cached adjustment was made
            self.excluded = frozenset()
            self.sbase, self.sbase_error, self.hypotheses, self.outcomes = [], "", [], []
            self.selected_point = self.selected_obs = self.selected_hypothesis = None
            images = geometry.images(self.problem)
            self.selected_image = images[0]["id"] if images else None
            self.snoop, self.snoop_loo, self.variance, self.injection = None, [], None, None
            self.components, self.criterion, self.criterion_error, self.analysis_error = None, None, "", ""
            self.robust = None
        self._index, self._index_for = hit.index, problem
        with param.parameterized.batch_call_watchers(self):
            # a session's own Analysis over the shared adjustment: its reliability and the
            # computations cached on it are this session's, as they were before the cache
            self._set_snapshot(hit.for_session(Analysis(
                analysis.problem, analysis.adjustment, self.policy(), analysis.solver, name=analysis.name,
                excluded=analysis.excluded, kept=analysis.kept)))
            self.exact = True
            self.solution += 1
            self._run_robust()
        self.param.update(source=source, file_name=plain(Path(source).name))
        self.exaggeration = self._auto_exaggeration()
        self.error = ""
        self.param.trigger("problem")
        return True

    def set_problem(self, problem, source: str = "", error_name: str | None = None,
                    error_path: str | None = None) -> bool:
        """Make ``problem`` current (clears exclusions, hypotheses and selections) and adjust it.

        error_path: a server path (an upload's temporary file) that a failure message shows as
        ``error_name`` instead."""
        old = (self.problem, self.snapshot, self.analysis, self.results, self.kept, self.excluded,
               self.hypotheses, self.outcomes)
        mode = problem.sigma_act if problem.sigma_act in ("apriori", "aposteriori") else "apriori"
        with param.parameterized.discard_events(self):
            self.problem = problem
            self.excluded = frozenset()
            self.sbase = []
            self.sbase_error = ""
            self.hypotheses = []
            self.outcomes = []
            self.selected_point = None
            self.selected_obs = None
            self.selected_hypothesis = None
            self.sigma0_mode = mode
            images = geometry.images(self.problem)
            self.selected_image = images[0]["id"] if images else None
        if not self._readjust() or (self.jobs.cancel_event.is_set() and self.task):
            with param.parameterized.discard_events(self):
                (self.problem, self.snapshot, self.analysis, self.results, self.kept, self.excluded,
                 self.hypotheses, self.outcomes) = old
            if error_path and error_name:
                self.error = self.error.replace(error_path, error_name)
            self._check_cancel()
            return False
        self.source = source or problem.source
        self.file_name = plain(Path(str(self.source)).name)
        self.exaggeration = self._auto_exaggeration()
        self.error = ""
        self.param.trigger("problem")
        return True

    def release(self) -> None:
        """Drop everything the session's state holds of its data (the session ended): the
        problem, its analyses and every result made from them; the choices stay. Panel and Bokeh
        may keep a closed session's objects a while; its data are freed at once."""
        with param.parameterized.discard_events(self):
            self.param.update(problem=None, snapshot=None, analysis=None, results=None, reliability=None,
                              kept=np.zeros(0, dtype=np.int64), outcomes=[], hypotheses=[], robust=None,
                              snoop=None, snoop_loo=[], variance=None, components=None, injection=None,
                              criterion=None, excluded=frozenset())
        self._full, self._before = None, (frozenset(), None)
        self._index, self._index_for = None, None
        self.free_block_cache = {}

    @contextlib.contextmanager
    def _busy(self):
        """``busy`` (the main area's loading overlay) around a computation in place; a
        background computation shows its progress instead (``task``, ``progress``)."""
        if self.task:
            yield
            return
        self.busy = True
        try:
            yield
        finally:
            self.busy = False

    # -- recomputation --------------------------------------------------------------------------
    def options(self) -> Options:
        return Options(alpha0=float(self.alpha0), beta0=float(self.beta0), b_method=bool(self.b_method))

    def policy(self) -> TestPolicy:
        """The test policy of the controls: α0, β0, the B-method and the σ0 of the decisions."""
        return TestPolicy(alpha0=float(self.alpha0), beta0=float(self.beta0), b_method=bool(self.b_method),
                          sigma0=self.sigma0_mode, global_test=self.global_test)

    def _iteration(self, it: int, step: float) -> None:
        """The adjustment's progress, shown while a background computation runs (``progress``)."""
        sink = self._progress_to or self
        sink._stop_if_closed()              # a closed page's adjustment stops at its next iteration
        if sink.task:
            sink.progress = f"adjusting: iteration {it}, largest step {step:.2g} σ"

    def _readjust(self) -> bool:
        """Adjust the problem without the excluded observations; False (and ``error``) on failure.

        On a worker thread (a background computation) the adjustment runs there and only its
        result is made current on the session's event loop (:meth:`on_loop`)."""
        t0 = time.perf_counter()
        problem, excluded, mode, policy = self.problem, self.excluded, self.sigma0_mode, self.policy()
        base = self.analysis if self.analysis is not None and self.analysis.problem is problem else None
        try:
            with self._busy():
                if base is None:          # a new problem: the core's analysis, local defects set aside
                    base = analyze(problem, policy=policy, progress=self._iteration)
                    analysis = base.with_policy(policy).without(excluded, sigma_act=mode, progress=self._iteration)
                elif not excluded and self._full is not None and self._full.problem is problem and \
                        self._full.adjustment.problem.sigma_act == mode:
                    analysis = self._full.with_policy(policy)      # every observation back: as first adjusted
                else:                     # started from the current solution
                    analysis = measures.readjusted(base.with_policy(policy), excluded,
                                                   progress=self._iteration) \
                        if base.adjustment.problem.sigma_act == mode else \
                        base.with_policy(policy).without(excluded, sigma_act=mode, progress=self._iteration)
        except Cancelled:
            raise
        except BaardaError as err:
            msg = f"Adjustment failed: {err}"
            self.on_loop(lambda: setattr(self, "error", msg))
            return False
        except Exception as err:  # noqa: BLE001
            msg = f"Adjustment failed: {type(err).__name__}: {err}"
            self.on_loop(lambda: setattr(self, "error", msg))
            return False
        if self.jobs.cancelled():
            return False                      # cancelled: the result is dropped

        def apply() -> bool:
            if self.problem is not problem or self.excluded != excluded:
                return False                  # changed meanwhile: this result is stale
            self._show(analysis, exact=True)
            self.timings = {**self.timings, "adjust": time.perf_counter() - t0}
            return True
        return bool(self.on_loop(apply))

    def _show(self, analysis: Analysis, exact: bool) -> None:
        """Make a new analysis of the problem current (a new solution: the results of the
        analysis panel dropped, the hypotheses tested again)."""
        with param.parameterized.batch_call_watchers(self):
            if analysis.problem is not self.problem:      # local defects set aside
                with param.parameterized.discard_events(self):
                    self.problem = analysis.problem
            self._set_snapshot(Snapshot(analysis, self.problem_index()))
            self.exact = exact
            self.solution += 1
            self.snoop, self.snoop_loo, self.variance, self.injection = None, [], None, None
            self.components, self.criterion, self.criterion_error = None, None, ""
            self.analysis_error = ""
            self._run_hypotheses()
            self._run_robust()

    @param.depends("alpha0", "beta0", "b_method", "global_test", watch=True)
    def _options_changed(self):
        if self.results is None:
            return
        t0 = time.perf_counter()
        with param.parameterized.batch_call_watchers(self):
            # same adjustment: nothing solved, the policy-free tables and tests shared
            self._set_snapshot(self.snapshot.with_policy(self.policy()))
            self.param.trigger("results")
            self._run_hypotheses()
            self._run_robust()
        self.timings = {**self.timings, "policy": time.perf_counter() - t0}

    @param.depends("sigma0_mode", watch=True)
    def _sigma_changed(self):
        if self.problem is not None:
            self._readjust()

    # -- exclusion ------------------------------------------------------------------------------
    def exclude(self, index: int) -> bool:
        """Exclude observation ``index`` (full index) and adjust again; False if that fails."""
        return self._set_excluded(self.excluded | {int(index)})

    def include(self, index: int) -> bool:
        """Re-include observation ``index``."""
        return self._set_excluded(self.excluded - {int(index)})

    def include_all(self) -> bool:
        return self._set_excluded(frozenset())

    def _set_excluded(self, new):
        """Exclude ``new`` (full indices) and adjust again. Served, on a worker thread with the
        task indicator (:meth:`submit`; returns its Future, None while another task runs);
        otherwise here (True, or False if the adjustment fails and the old state stays)."""
        new = frozenset(int(i) for i in new)
        if new == self.excluded:
            return True
        if self.background and not on_worker_thread():
            if not self.task and self.downdate(new):           # answered at once
                return self.submit("adjusting again exactly", self.refine, new)
            return self.submit("excluding and adjusting again", self._set_excluded, new)
        if self.downdate(new):
            return self.refine(new)
        old = self.excluded
        with param.parameterized.discard_events(self):
            self.excluded = new
        ok = False
        try:
            ok = self._readjust()
        finally:
            if not ok:
                with param.parameterized.discard_events(self):
                    self.excluded = old
        if ok:
            self.on_loop(lambda: self.param.trigger("excluded"))
        return ok

    def downdate(self, new) -> bool:
        """Show the analysis without the observations ``new`` (full indices) at once, from an
        exact downdate of the current factor (:func:`baarda.dashboard.measures.downdated`,
        ``exact`` False until :meth:`refine` replaces it); False (nothing changed) where it does
        not apply: fewer exclusions, more than :data:`~baarda.dashboard.measures.DOWNDATE_MAX`
        new ones, or σ0 a posteriori."""
        t0 = time.perf_counter()
        new = frozenset(int(i) for i in new)
        base = self.analysis
        if base is None or base.problem is not self.problem or self.sigma0_mode != "apriori":
            return False
        if not base.excluded <= new and self._full is not None and self._full.problem is self.problem:
            base = self._full.with_policy(self.policy())   # re-included: downdated from every observation
        try:
            quick = measures.downdated(base, new)
        except Exception:  # noqa: BLE001 - e.g. singular after the update: the re-adjustment says why
            quick = None
        if quick is None:
            return False
        self._before = (self.excluded, self.snapshot)
        with param.parameterized.discard_events(self):
            self.excluded = new
        self._show(quick, exact=False)
        self.param.trigger("excluded")
        self.timings = {**self.timings, "downdate": time.perf_counter() - t0}
        return True

    def refine(self, excluded) -> bool:
        """Replace a downdated analysis (:meth:`downdate`) by the exact re-adjustment without
        ``excluded``, iterated from the downdate's solution; False if the exclusions changed
        meanwhile or it fails (then the exclusion is undone and ``error`` says why)."""
        quick = self.analysis
        if self.exact or quick is None or quick.excluded != frozenset(excluded):
            return False
        t0 = time.perf_counter()
        try:
            with self._busy():
                analysis = measures.readjusted(quick, progress=self._iteration)
        except Cancelled:
            raise
        except (BaardaError, np.linalg.LinAlgError) as err:
            msg = plain(f"Adjustment failed: {err}")
            old, snap = self._before

            def undo():                        # the exclusion is undone: the analysis before it
                if self.analysis is quick:
                    with param.parameterized.discard_events(self):
                        self.excluded = old
                    self._show(snap.analysis, exact=True)
                    self.param.trigger("excluded")
                self.error = msg
            self.on_loop(undo)
            return False
        if self.jobs.cancelled():
            return False

        def apply() -> bool:
            if self.analysis is not quick:
                return False                   # changed meanwhile
            self._show(analysis, exact=True)
            self.timings = {**self.timings, "adjust": time.perf_counter() - t0}
            return True
        return bool(self.on_loop(apply))

    def reduced_index(self, full) -> np.ndarray:
        """Reduced indices of full observation indices (−1 where excluded)."""
        return geometry.reduced_index(self.kept, self.problem.n, full)

    def expand(self, values, fill=np.nan) -> np.ndarray:
        """A per-observation array of the reduced problem spread to the full problem."""
        return geometry.expand(values, self.kept, self.problem.n, fill)

    # -- hypotheses -----------------------------------------------------------------------------
    def add_hypothesis(self, spec: dict) -> int:
        """Add (and activate) a hypothesis; returns its position."""
        spec = {"active": True, **spec}
        spec["label"] = spec.get("label") or specs.describe(self.problem, spec, self.problem_index())
        self.hypotheses = self.hypotheses + [spec]
        self.selected_hypothesis = len(self.hypotheses) - 1
        return len(self.hypotheses) - 1

    def toggle_hypothesis(self, k: int, active: bool | None = None) -> None:
        hyps = [dict(h) for h in self.hypotheses]
        hyps[k]["active"] = (not hyps[k]["active"]) if active is None else bool(active)
        self.hypotheses = hyps

    def remove_hypothesis(self, k: int) -> None:
        hyps = list(self.hypotheses)
        del hyps[k]
        if self.selected_hypothesis is not None and self.selected_hypothesis >= len(hyps):
            self.selected_hypothesis = len(hyps) - 1 if hyps else None
        self.hypotheses = hyps

    @param.depends("hypotheses", watch=True)
    def _hypotheses_changed(self):
        self._run_hypotheses()

    def _run_hypotheses(self):
        """The outcome of every hypothesis under the current snapshot (tested once per
        adjustment, :meth:`baarda.dashboard.snapshot.Snapshot.outcome`)."""
        t0 = time.perf_counter()
        snap = self.snapshot
        out = [snap.outcome(spec) if snap is not None else Outcome("inactive", spec.get("label", ""))
               for spec in self.hypotheses]
        self.outcomes = out
        self.timings = {**self.timings, "hypotheses": time.perf_counter() - t0}

    # -- derived data for the views -------------------------------------------------------------
    def problem_index(self) -> dict:
        """:func:`~baarda.dashboard.geometry.problem_index` of the current problem, built once
        per problem (the problem is immutable)."""
        snap = self.snapshot
        if snap is not None and snap.problem is self.problem:
            return snap.index
        if self._index is None or self._index_for is not self.problem:
            self._index, self._index_for = geometry.problem_index(self.problem), self.problem
        return self._index

    def frames(self) -> tuple[pd.DataFrame, pd.DataFrame]:
        """``(observations, points)`` tables of the current results (:func:`baarda.dashboard.frames.frames`),
        made once per snapshot (:attr:`baarda.dashboard.snapshot.Snapshot.frames`)."""
        return self.snapshot.frames

    def external_field(self) -> tuple[str, np.ndarray]:
        """The deformation field the external-reliability map shows: ``(label, shifts)`` of the
        last selected observation or hypothesis ("" and zeros if there is none)."""
        m = len(self.problem.points.ids)
        k = self.selected_hypothesis
        if self.field_source == "hypothesis" and k is not None and k < len(self.hypotheses):
            h = self.outcomes[k] if k < len(self.outcomes) else None
            shifts = measures.hypothesis_field(self.results, h, m)
            if np.abs(shifts).max(initial=0.0) > 0:
                return f"hypothesis {self.hypotheses[k].get('label', k)}", shifts
        if self.selected_obs is not None:
            return f"obs {self.selected_obs}", measures.observation_field(
                self.results, self.reliability, self.kept, self.problem.n, m, self.selected_obs)
        return "", np.zeros((m, 3))

    @param.depends("selected_hypothesis", watch=True)
    def _hypothesis_selected(self):
        if self.selected_hypothesis is not None:
            self.field_source = "hypothesis"

    @param.depends("selected_obs", watch=True)
    def _observation_selected(self):
        if self.selected_obs is not None:
            self.field_source = "observation"

    # -- precision in an S-base -----------------------------------------------------------------
    def coordinate_covariance(self):
        """The core's :class:`~baarda.stats.precision.CoordinateCovariance` in the chosen S-base
        (``sbase``; [] = the problem's datum), or None if the core refuses that base
        (``sbase_error`` says why)."""
        cc, err = self.snapshot.covariance(tuple(self.sbase))
        if self.sbase_error != err:
            self.sbase_error = err
        return cc

    def point_cov2(self) -> np.ndarray:
        """Planimetric 2 × 2 covariance per point (m × 2 × 2, m², the adjustment's σ0) in the
        chosen S-base; the adjustment's own per-point blocks when no S-base is chosen (or the
        chosen one is refused)."""
        cc = self.coordinate_covariance() if self.sbase else None
        if cc is None:
            return self.results.point_cov[:, :2, :2]
        return sbase_lesson.planimetric(cc, len(self.problem.points.ids))

    def sbase_check(self) -> str:
        """The note beside the S-base control (:func:`baarda.dashboard.sbase.sbase_check`)."""
        return sbase_lesson.sbase_check(self.problem, self.results, self.sbase, self.sbase_error, self.options())

    # -- robust estimation, data snooping, variance components ----------------------------------
    def _run_robust(self):
        """Robust reweighting of the current problem with ``robust_method`` (None for "none")."""
        if self.results is None or self.robust_method == "none":
            self.robust = None
            return
        t0 = time.perf_counter()
        adj, method = self.results, self.robust_method
        try:
            with self._busy():
                rr = robust.estimate(adj.problem, method, self.options())
        except (BaardaError, np.linalg.LinAlgError) as err:
            self.robust = None
            self.analysis_error = plain(f"Robust estimation ({method}) failed: {err}")
            return
        self._check_cancel()
        if self.results is not adj or self.robust_method != method:    # stale
            return
        self.on_loop(lambda: setattr(self, "robust", rr))
        self.timings = {**self.timings, "robust": time.perf_counter() - t0}

    @param.depends("robust_method", watch=True)
    def _robust_changed(self):
        if self.background and self.results is not None and self.robust_method != "none":
            self.submit(f"robust reweighting ({self.robust_method})", self._run_robust)
        else:
            self._run_robust()

    @param.depends("robust", watch=True)
    def _robust_done(self):
        if self.snapshot is not None:
            self.snapshot = self.snapshot.with_robust(self.robust)

    def run_snooping(self) -> bool:
        """Iterative data snooping (:func:`baarda.stats.snooping.iterate`) of the current problem with
        w (σ0 a priori) or τ (a posteriori), and σ̂0 with each of the :data:`~baarda.dashboard.measures.LOO_SUSPECTS` largest
        |w| left out in turn (:func:`baarda.stats.snooping.leave_one_out`)."""
        adj = self.results

        def step(k, st):
            self.progress = f"step {k}: removed obs {int(self.kept[st.removed])} (|w| = {st.statistic:.2f})"

        try:
            with self._busy():
                res, loo = measures.snoop(adj, self.options(), self.sigma0_mode == "aposteriori",
                                          progress=step, check=self._check_cancel)
        except (BaardaError, np.linalg.LinAlgError) as err:
            self.analysis_error = plain(f"Data snooping failed: {err}")
            return False
        if self.results is not adj:     # the problem changed meanwhile: the result is stale
            return False
        self.on_loop(lambda: self.param.update(snoop=res, snoop_loo=loo, analysis_error=""))
        return True

    def accept_snooping(self) -> bool:
        """Exclude the observations the snooping removed (a full rerun)."""
        if self.snoop is None or not self.snoop.steps:
            return False
        removed = {int(self.kept[i]) for i in self.snoop.removed}
        return self._set_excluded(self.excluded | removed)

    def run_variance(self) -> bool:
        """Variance components per observation family (:func:`baarda.stats.variance.estimate`), or
        with ``variance_model`` "radial" (or "radial-isotropic") the radial model σ² = a² + b²c²/cos⁴α of a block
        (:func:`baarda.stats.variance.radial_components`, :func:`~baarda.stats.variance.estimate_components`,
        F80 §2.1) started at θ0 = (σ²/2, σ²/2, 1), σ² the median a priori image variance; the
        core's :meth:`baarda.analysis.Analysis.variance_components`, families merged as
        ``merge_groups`` says (``baarda analyze --merge-groups``)."""
        analysis, model, merge = self.analysis, self.variance_model, self.merge_groups.strip() or None
        try:
            with self._busy():
                problem = self.results.problem
                got = analysis.variance_components(model, merge if model == "families" else None)
                vc, est = (got, None) if model == "families" else (None, got)
                self._check_cancel()
        except (BaardaError, np.linalg.LinAlgError) as err:
            self.param.update(variance=None, components=None,
                              analysis_error=plain(f"Variance components: {err}"))
            return False
        if self.results.problem is not problem:
            return False
        self.on_loop(lambda: self.param.update(variance=vc, components=est, analysis_error=""))
        return True

    # -- criterion matrices and risk (M84 §2, §3.3) ---------------------------------------------
    def criterion_base(self) -> list[str]:
        """The S-base of the comparison: the precision view's (``sbase``), else the first two points."""
        return list(self.sbase) or list(self.problem.points.ids[:2])

    def criterion_compare(self, kind: str = "logarithmic", C1: float | None = None, C2: float = 1.0,
                          sbase=None) -> dict | None:
        """Compare the coordinate covariance with a chaotic criterion matrix (M84 §2).

        Without ``C1`` the criterion is fitted (:func:`baarda.stats.precision.fit_criterion`, M84 §2.3:
        C1 so that λmax = 1, C2 so that λmax/λmin is smallest); with ``C1`` (m²/m) and ``C2`` (m)
        the user's criterion is compared (:func:`~baarda.stats.precision.compare`). Keeps λmax, λmin,
        "satisfied" (λmax < 1) and the eigenvector of λmax as a displacement pattern per point
        (m × 2, x, y, largest component 1) in ``criterion``; None and ``criterion_error`` if the
        core refuses.
        """
        base = list(sbase) if sbase else self.criterion_base()
        try:
            out = measures.criterion(self.results, len(self.problem.points.ids), base, kind, C1, C2)
        except (BaardaError, ValueError, np.linalg.LinAlgError) as err:
            self.param.update(criterion=None, criterion_error=f"Criterion: {err}")
            return None
        self.param.update(criterion=out, criterion_error="")
        return out

    # -- teaching: inject an error --------------------------------------------------------------
    def inject(self, index: int, size: float, unit: str = "sigma") -> dict | None:
        """Adjust a copy of the problem with an error added to observation ``index`` and keep
        what the tests see in ``injection``; the loaded data stay as they are."""
        adj, rel = self.results, self.reliability
        try:
            e = measures.injected_error(adj, rel, self.kept, self.problem.n, index, size, unit)
            with self._busy():
                new = measures.adjust_with_error(adj, e, self.options())
        except (ValueError, BaardaError, np.linalg.LinAlgError) as err:
            self.param.update(injection=None, analysis_error=f"Cannot inject: {err}")
            return None
        out = measures.injection(self.problem, adj, rel, self.kept, new, e, index, size, unit, self.problem_index()["factor"])
        self.param.update(injection=out, analysis_error="")
        return out

    def keep_injection(self) -> bool:
        """Make the last injected error part of the loaded data (the user asked to keep it)."""
        inj = self.injection
        if inj is None:
            return False
        with param.parameterized.discard_events(self):
            self.problem = measures.with_error(self.problem, self.kept, inj["error_vector"])
        return self._readjust()

    def _auto_exaggeration(self) -> float:
        """:func:`~baarda.dashboard.geometry.auto_exaggeration` of the current results (1 without images)."""
        if self.results is None or not geometry.images(self.problem):
            return 1.0
        v = self.expand(self.results.v) * self.problem_index()["factor"][0]
        return geometry.auto_exaggeration(self.problem, self.problem_index(), v)

    # -- summary --------------------------------------------------------------------------------
    def summary(self) -> dict:
        """The numbers of the summary header, taken from the core's results; with GNSS centres
        ``gnss`` (centres, rejected 3-D tests, strips tested and rejected) and with check points
        ``check_points`` (n, RMSE per axis, the object unit; :mod:`baarda.dashboard.auxdata`)."""
        s = dict(self.snapshot.summary)
        g = auxdata.gnss_centres(self)
        if len(g):
            strips = auxdata.strip_rows(self)
            s["gnss"] = {"centres": len(g), "rejected": int(g["rejected"].astype(bool).sum()),
                         "strips": len(strips), "strips_rejected": sum(bool(t["rejected"]) for t in strips)}
        cp = auxdata.check_points(self)
        if cp["n"]:
            s["check_points"] = {"n": int(cp["n"]), "rms": [float(x) for x in cp["rms"]],
                                 "unit": geometry.object_unit(self.problem)}
        return s
