"""One analysis as the dashboard shows it, with the tables derived from it made once.

A :class:`Snapshot` is immutable: the core's :class:`~baarda.analysis.Analysis` (problem,
adjustment, test policy, exclusions), the problem's index
(:func:`baarda.dashboard.geometry.problem_index`) and the robust result shown beside it. What
the views read of it — the observations and points tables, the summary, the hypotheses'
outcomes, the covariance in an S-base — are cached on it and computed when first read, so a
new snapshot replaces the old one and nothing is invalidated by hand.

What does not depend on the test policy (the tables' v, w, τ, r, σ columns, the hypotheses'
W_s, T, ∇ŝ, the covariance in an S-base) is kept in an :class:`AdjustmentTables` shared by every
snapshot of one adjustment: :meth:`Snapshot.with_policy` (α0, β0, the B-method, the global
test changed) recomputes only the decisions, MDBs and δ̄0 (:func:`baarda.dashboard.frames.with_policy`,
:meth:`baarda.dashboard.outcomes.Outcome.under`).
"""

from __future__ import annotations

import threading
from dataclasses import replace
from functools import cached_property

import numpy as np

from baarda.errors import BaardaError
from baarda.io.results import summary as core_summary
from baarda.stats import precision

from . import frames as tables
from . import geometry, specs
from .outcomes import Outcome


class AdjustmentTables:
    """What the snapshots of one adjustment share (nothing here depends on the test policy):
    the policy-free columns of the tables, the hypotheses' outcomes as first tested, the
    coordinate covariance per S-base."""

    #: outcomes and covariances kept per adjustment (oldest dropped beyond)
    MAX_ITEMS = 64

    def __init__(self, analysis, index: dict):
        self.adjustment = analysis.adjustment
        self._analysis = analysis
        self._index = index
        self._lock = threading.Lock()
        self.outcomes: dict = {}
        self.covariances: dict = {}

    @cached_property
    def base_frames(self):
        """:func:`baarda.dashboard.frames.base_frames` of the adjustment."""
        a = self._analysis
        return tables.base_frames(a.problem, a.adjustment, a.kept, a.excluded, self._index)

    def remember(self, store: dict, key, value):
        with self._lock:
            while len(store) >= self.MAX_ITEMS:
                store.pop(next(iter(store)))
            store[key] = value
        return value


class Snapshot:
    """The analysis the dashboard shows (module docstring)."""

    def __init__(self, analysis, index: dict | None = None, robust=None, shared: AdjustmentTables | None = None):
        self.analysis = analysis
        self.index = index if index is not None else geometry.problem_index(analysis.problem)
        self.robust = robust
        if shared is None or shared.adjustment is not analysis.adjustment:
            shared = AdjustmentTables(analysis, self.index)
        self.shared = shared

    # -- the analysis ---------------------------------------------------------------------------
    @property
    def problem(self):
        return self.analysis.problem

    @property
    def adjustment(self):
        return self.analysis.adjustment

    @property
    def reliability(self):
        return self.analysis.reliability

    @property
    def policy(self):
        return self.analysis.policy

    @property
    def kept(self) -> np.ndarray:
        return np.asarray(self.analysis.kept)

    @property
    def excluded(self) -> frozenset:
        return frozenset(self.analysis.excluded)

    def with_policy(self, policy) -> "Snapshot":
        """The same adjustment under ``policy``: the policy-free tables shared, no robust result
        (it depends on the policy: made again by the caller)."""
        if policy == self.policy:
            return self
        return Snapshot(self.analysis.with_policy(policy), self.index, None, self.shared)

    def with_robust(self, robust) -> "Snapshot":
        """The same analysis shown with the robust result ``robust`` (None: none)."""
        if robust is self.robust:
            return self
        return Snapshot(self.analysis, self.index, robust, self.shared)

    def for_session(self, analysis) -> "Snapshot":
        """A snapshot of ``analysis`` (another session's Analysis over the same adjustment,
        the server's cache) sharing this one's policy-free tables."""
        return Snapshot(analysis, self.index, None, self.shared)

    # -- derived tables -------------------------------------------------------------------------
    @cached_property
    def frames(self):
        """``(observations, points)`` (:func:`baarda.dashboard.frames.frames`)."""
        return tables.with_policy(self.shared.base_frames, self.problem, self.reliability, self.kept,
                                  self.index, self.robust)

    @cached_property
    def summary(self) -> dict:
        """The numbers of the summary header: the core's summary and the tables' counts."""
        s = core_summary(self.adjustment, self.reliability)
        obs, pts = self.frames
        s.update(tables.summary_counts(obs, pts, self.excluded, geometry.images(self.problem)))
        return s

    def outcome(self, spec: dict) -> Outcome:
        """The :class:`~baarda.dashboard.outcomes.Outcome` of hypothesis ``spec`` under this
        snapshot's policy: tested once per adjustment, rescaled to other policies."""
        if not spec.get("active", True):
            return Outcome("inactive", spec.get("label", ""))
        key = specs.key(spec)
        got = self.shared.outcomes.get(key)
        if got is None or got.needs_retest(self.policy):
            got = self.shared.remember(self.shared.outcomes, key, specs.evaluate(
                self.problem, self.adjustment, self.reliability, self.kept, spec, self.index))
        out = got.under(self.policy)
        label = spec.get("label", "")
        return out if out.label == label else _relabel(out, label)

    def covariance(self, sbase: tuple):
        """``(CoordinateCovariance or None, error text)`` in the S-base ``sbase`` (point ids)."""
        got = self.shared.covariances.get(sbase)
        if got is None:
            try:
                got = (precision.covariance(self.adjustment, list(sbase) or None), "")
            except (BaardaError, np.linalg.LinAlgError) as err:
                got = (None, f"S-base {', '.join(sbase)}: {err}")
            self.shared.remember(self.shared.covariances, sbase, got)
        return got


def _relabel(out: Outcome, label: str) -> Outcome:
    test = replace(out.test, label=label) if out.test is not None else None
    msg = out.message
    return replace(out, label=label, test=test, message=msg)
