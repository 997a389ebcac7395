"""The iterations of :func:`baarda.adjust.adjust` as an object: :class:`Iteration` holds their
state (x, the design matrix and its reduced copy, the datum plan, the elimination layout, the
trust region, the end game) and its methods are the named steps of the loop — the method and
its constants are described in :mod:`baarda.adjust`'s docstring (Gauss-Newton,
Levenberg-Marquardt with Ceres Solver's trust region, the undamped end game, termination) —
plus :func:`update_radius`, :func:`gain_ratio`, :func:`check_termination` and the factor of a
step with the diagnosis of a singular one (:func:`factor_step`, :func:`diagnose`).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from . import datum as datum_mod
from .errors import DatumDefectError, SingularError
from .model.problem import take, weight_matrix
from .result import Adjustment, HeldColumns
from .solve import heap
from .solve.linalg import SPDFactor
from .solve.linearisation import Linearisation
from .solve.schur import SchurFactor, StepFactor, schur_structure

#: a Gauss-Newton step that multiplies vᵀPv by more than this switches to Levenberg-Marquardt
DIVERGENCE = 1.5
#: Levenberg-Marquardt trust region: Ceres Solver's defaults (``Solver::Options``)
INITIAL_RADIUS = 1e4
MAX_RADIUS = 1e16
MIN_RADIUS = 1e-32
#: a damped step is accepted when its gain ratio exceeds this (Ceres' min_relative_decrease)
MIN_RELATIVE_DECREASE = 1e-3
#: an accepted damped step changing vᵀPv by less than this (relative) starts the undamped end
#: game (Ceres' function_tolerance)
FUNCTION_TOL = 1e-6
#: Ceres' parameter_tolerance: with ``stop="ceres"`` an accepted step with ‖Δx‖ ≤ this · (‖x‖ + this) ends the run
PARAMETER_TOL = 1e-8
#: the stopping rules of ``Options.stop``: the strict optimum (increments below tol conditional
#: standard deviations, after the undamped end game) or Ceres Solver's at its defaults
STOPS = ("optimum", "ceres")
#: gradient tolerance (Ceres' gradient_tolerance, here on the scaled gradient; see gradient_small)
GRADIENT_TOL = 1e-10
#: increments (in conditional standard deviations) below which round-off is reached when they
#: stop shrinking
ROUNDOFF_STEP = 1e-6
#: an S-transformation of an undamped step that raises vᵀPv by more than this factor (a long
#: gauge drift, linearised) is skipped; smaller rises are second order and the next undamped
#: steps remove them
GAUGE_COST = 1.0
#: undamped end games (after the function tolerance) that may fail before the run stops
MAX_END_GAMES = 3
#: A gauge switch keeps the elimination layouts it leaves while all of them together take at
#: most this many bytes (a block switches between the free gauge of its damped steps and the held
#: one of its undamped steps: the held layout is not analysed twice); larger blocks hold one
#: layout at a time.
KEEP_LAYOUTS_BYTES = 64 << 20
#: an undamped end-game step may raise vᵀPv by this much (relative) and still count as round-off
ROUNDOFF_COST = 1e-10

#: termination status → message (> 0 converged, ≤ 0 not; the style of SciPy's least_squares)
STATUS = {
    -1: "not converged: the trust region collapsed (no damped step lowers vᵀPv)",
    0: "not converged: the maximum number of iterations was reached",
    1: "converged: every increment below tol conditional standard deviations (undamped step)",
    2: "converged: the increments reached round-off (undamped steps no longer shrink)",
    3: "converged: the scaled gradient AᵀPv vanished (gradient tolerance)",
    4: ("converged: every increment below tol conditional standard deviations with {n_far} far "
        "point(s) held where Levenberg-Marquardt left them (they drift along their rays towards "
        "infinity: no finite optimum for them)"),
    5: ("converged by Ceres Solver's rule (stop=\"ceres\"): a step changed vᵀPv by less than the function "
        "tolerance 1e-6 (relative) or the parameters by less than 1e-8: near the optimum's cost, "
        "not the strict optimum of tol"),
}


class _Labels:
    """The labels of the free parameters, made only when an error names one (labels may be
    generated lazily, :class:`baarda.model.problem.LazySequence`)."""

    def __init__(self, labels, free):
        self.labels, self.idx = labels, np.asarray(free)

    def __getitem__(self, i):
        if isinstance(i, (np.ndarray, list)):
            return _Labels(self.labels, self.idx[np.asarray(i)])
        return self.labels[int(self.idx[int(i)])]

    def __len__(self):
        return self.idx.size

    def __array__(self, dtype=None, copy=None):
        return np.asarray(take(self.labels, self.idx), dtype=dtype)


def update_radius(mu: float, decrease: float, rho: float, accepted: bool) -> tuple[float, float]:
    """Levenberg-Marquardt trust region μ (damping λ = 1/μ) after a step of gain ratio ρ.

    Ceres Solver's ``LevenbergMarquardtStrategy`` (Nielsen 1999, Madsen et al. 2004 §3.2):
    accepted, μ ← μ / max(1/3, 1 − (2ρ − 1)³) (at most :data:`MAX_RADIUS`) and the decrease
    factor is reset to 2; rejected, μ ← μ / factor and the factor doubles.
    """
    if accepted:
        return min(mu / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), MAX_RADIUS), 2.0
    return mu / decrease, 2.0 * decrease


def gain_ratio(cost: float, cost_new: float, dx: np.ndarray, g: np.ndarray, lam: float,
               diagN: np.ndarray) -> float:
    """ρ = actual / predicted decrease of vᵀPv for the step dx of (N + λ D) dx = g, g = −AᵀPv.

    The linear model predicts vᵀPv − (v + A dx)ᵀP(v + A dx) = 2 dxᵀg − dxᵀN dx = dxᵀ(g + λ D dx).
    """
    predicted = float(dx @ (lam * diagN * dx + g))
    if not np.isfinite(cost_new):
        return -np.inf
    if predicted <= 0.0:
        return 1.0 if cost_new <= cost else -np.inf
    return (cost - cost_new) / predicted


@dataclass(eq=False)
class Trial:
    """A solved step and the point it leads to (:meth:`Iteration.solve`): λ, the increment of
    the unknowns solved for, its largest value in conditional standard deviations, the trial
    point x, f(x), v, vᵀPv there, the gain ratio ρ, and (once moved there, :meth:`Iteration.move`)
    the relative drop of vᵀPv."""

    lam: float
    dx: np.ndarray
    step: float
    x: np.ndarray
    f: np.ndarray
    v: np.ndarray
    cost: float
    rho: float
    rel_drop: float = 0.0


class Iteration:
    """The state of the iterations of :func:`baarda.adjust.adjust` and their steps, each a method
    (module docstring of :mod:`baarda.adjust`): :meth:`begin` (λ, the gauge and the layout of a
    step), :meth:`solve` (factor, gradient test, step, trial point), :meth:`judge` (accept or
    reject: trust region, end game, divergence), :meth:`move` (S-transformation, linearisation
    at the new point), :meth:`converged`, :meth:`release` (what only the iterations needed) and
    :meth:`result` (the datum at the solution, the :class:`baarda.result.Adjustment`).

    Made at x0 (the first linearisation, the datum plan, the elimination layout). ``status`` is
    a key of :data:`STATUS`, non-zero once the run is to stop. A's values are not held while a
    reduced copy Ar is what the steps use (:meth:`full` makes them again at x).
    """

    def __init__(self, problem, options, x0: np.ndarray | None = None):
        self.t0 = time.perf_counter()
        self.problem, self.options = problem, options
        params = problem.params
        self.free = free = params.free
        self.x = (params.x0 if x0 is None else x0).astype(float).copy()
        self.x_ref = self.x.copy()
        heap.map_large(problem.n)
        self.P = weight_matrix(problem.cov)
        self.labels = _Labels(params.labels, free)
        self.lin = Linearisation(problem, free)
        self.f, self.A = self.lin.first(self.x)
        heap.trim(problem.n)           # (the layout's temporaries: freed heap given back)
        self.plan = datum_mod.plan(problem, self.x, self.A, self.P, free)
        self.keep_all = np.setdiff1d(np.arange(free.size), self.plan.eliminate)
        self.keep = self.keep_all      # the unknowns solved for (far points held in the end game)
        self.Ar = self.lin.reduced(self.A, self.keep, consume=True)
        if self.Ar is not self.A:
            self.A = None              # (made again at x when needed: full())
        self.st = schur_structure(problem, self.Ar, self.keep, options.solver)
        self.st_keep = self.keep       # the unknowns st was analysed for
        self.layouts = []              # (keep, layout) kept across gauge switches (KEEP_LAYOUTS_BYTES)
        self.use_schur = self.st is not None   # points eliminated (kept for every later Ar)
        # Levenberg-Marquardt from the start for blocks whose points are eliminated (as Ceres);
        # Gauss-Newton first otherwise, damped only once a step makes the fit much worse
        self.damped = options.method == "levenberg-marquardt" or (options.method == "auto" and self.use_schur)
        self.ever_damped = self.damped
        self.endgame = False           # undamped steps after Levenberg-Marquardt's function tolerance
        self.mu, self.decrease = INITIAL_RADIUS, 2.0
        self.history: list[float] = []
        self.trace = []                # (λ, step, vᵀPv at the trial point, gain ratio) per solved step
        self.last_undamped = None      # size of the last accepted undamped step
        self.failed = 0                # undamped end games that failed
        self.quiet = 0                 # damped steps in a row at the function tolerance
        self.n_far = 0                 # far points held in the end game
        self.status = 0
        self.it = 0
        self.free_gauge = None         # all unknowns: the damped steps of a free block
        self.v = problem.misclosure(self.f)
        self.cost = float(self.v @ (self.P @ self.v))

    # -- the design matrix and the layout ------------------------------------------------------
    def full(self):
        """A at x: while a reduced copy Ar is what the steps use, A's values are not held (the
        next linearisation at x writes the same values again when A is needed: a switch of
        gauge, the datum)."""
        if self.A is None:
            self.A = self.lin.linearise(self.x)[1]
        return self.A

    def reduce(self) -> None:
        """Ar = A[:, keep]; A's values are let go when Ar is a copy (:meth:`full`)."""
        self.Ar = None
        self.Ar = self.lin.reduced(self.full(), self.keep, consume=True)
        if self.Ar is not self.A:
            self.A = None

    def structure(self) -> None:
        """The elimination layout of the current Ar: one kept from an earlier switch
        (:data:`KEEP_LAYOUTS_BYTES`), else analysed. Otherwise one is held at a time: the
        previous one (another gauge's, or without far points) is dropped before this one is
        analysed."""
        self.st, self.st_keep = None, self.keep
        if self.use_schur:
            self.st = next((s for k, s in self.layouts if np.array_equal(k, self.keep) and s.matches(self.Ar)), None)
            if self.st is None:
                heap.trim(self.problem.n)   # (the old layout's freed heap, before the new one is analysed)
                self.st = schur_structure(self.problem, self.Ar, self.keep, "schur")

    def switch(self) -> None:
        """Ar and its layout for a new set of unknowns ``keep``: the old layout goes before the
        new Ar is made (a gauge switch must not hold both layouts and both matrices), unless
        the layouts are small enough to be kept."""
        st = self.st
        if st is not None and not any(s is st for _, s in self.layouts) and \
                sum(s.nbytes() for _, s in self.layouts) + st.nbytes() <= KEEP_LAYOUTS_BYTES:
            self.layouts.append((self.st_keep, st))
        self.st = st = None
        self.reduce()
        self.structure()

    # -- the steps -----------------------------------------------------------------------------
    def begin(self, it: int) -> float:
        """Start iteration ``it``: its damping λ (the first step is undamped whatever the method:
        a singular system there is a defect to diagnose, not something to damp away; so are the
        end game's and Gauss-Newton's), and the gauge and the layout of the step."""
        self.it = it
        lam = 1.0 / self.mu if self.damped and not self.endgame and it != 1 else 0.0
        heap.trim(self.problem.n)      # (the last step's freed heap, before this one's factor)
        self.gauge(lam)
        if self.st is not None and not self.st.matches(self.Ar):
            self.structure()
        return lam

    def gauge(self, lam: float) -> None:
        """A free network's or block's damped steps move all unknowns, the gauge too (the
        damping makes N + λD regular, as in Ceres, which fixes no gauge); its undamped steps hold
        the datum's coordinates and are S-transformed. (Holding coordinates while damped makes
        the way much longer: 72 instead of 19 iterations on BAL Dubrovnik-16; a two-view Bundler
        block did not converge in 50.)"""
        if not self.plan.defect:
            return
        if lam > 0.0 and self.keep is self.keep_all:
            if self.free_gauge is None:
                self.free_gauge = np.arange(self.free.size)
            self.keep = self.free_gauge
            self.switch()
        elif lam == 0.0 and self.free_gauge is not None and self.keep is self.free_gauge:
            self.keep = self.keep_all
            self.switch()

    def solve(self, lam: float) -> Trial | None:
        """Factor N + λ diag(N), test the gradient, solve for the step and evaluate vᵀPv at the
        trial point (the factor is not alive then). None when the system is singular after the
        first step (damped more: :meth:`damp_more`) or the gradient vanished (status 3).
        Raises DatumDefectError when singular at the start or past a huge damping."""
        try:
            factor, diagN = factor_step(self.st, self.Ar, self.P, self.labels[self.keep], self.options.backend,
                                        lam, self.problem, self.plan)
        except DatumDefectError:
            # singular at the start: a real defect. Later (after a long step) or while damped:
            # damp more and retry from the same point; give up past a huge damping.
            if self.it == 1 or lam > 1e12:
                raise
            self.damp_more(lam)
            return None
        g = -(self.Ar.T @ (self.P @ self.v))
        if self.damped and not self.n_far and gradient_small(g, diagN, self.cost):
            self.status = 3
            return None
        dx = factor.solve(g)
        del factor                     # not alive while the trial point is evaluated
        step = float((np.abs(dx) * np.sqrt(diagN)).max(initial=0.0))
        x = self.x.copy()
        x[self.free[self.keep]] += dx
        f = self.lin.values(x)
        v = self.problem.misclosure(f)
        cost = float(v @ (self.P @ v))
        rho = gain_ratio(self.cost, cost, dx, g, lam, diagN)
        self.trace.append((lam, step, cost, rho))
        return Trial(lam, dx, step, x, f, v, cost, rho)

    def damp_more(self, lam: float) -> None:
        """A singular system after the first step: the end game failed, or more damping (a
        smaller trust region), or the trust region from its start; damped from now on."""
        if self.endgame:
            self.end_game_failed()
        elif lam:
            self.mu, self.decrease = self.mu / self.decrease, 2.0 * self.decrease
        else:
            self.mu, self.decrease = INITIAL_RADIUS, 2.0
        self.damped = self.ever_damped = True
        self.history.append(float("inf"))

    def judge(self, t: Trial) -> bool:
        """Whether the trial point is accepted: by the trust region (damped; the radius updated,
        status −1 when it collapses), its rule alone (a damped run's undamped first step), the
        end game (vᵀPv not beyond round-off) or Gauss-Newton's divergence test (a much worse fit
        switches to Levenberg-Marquardt)."""
        if t.lam > 0.0:
            ok = t.rho > MIN_RELATIVE_DECREASE
            if not ok and np.isfinite(t.cost) and abs(t.cost - self.cost) <= ROUNDOFF_COST * self.cost:
                # vᵀPv changes at round-off only: the gain ratio is noise, the damping has done
                # its work (Ceres would stop here); the undamped end game decides
                self.endgame, self.quiet = True, 0
                self.history.append(t.step)
                if self.options.stop == "ceres":
                    self.status = 5
                return False
            self.mu, self.decrease = update_radius(self.mu, self.decrease, t.rho, ok)
            if not ok and self.mu < MIN_RADIUS:
                self.history.append(t.step)
                self.status = -1
                return False
        elif self.it == 1 and self.damped:
            ok = t.rho > MIN_RELATIVE_DECREASE          # the trust region's rule, radius untouched
        elif self.endgame:
            # the undamped end game accepts what does not raise vᵀPv beyond round-off;
            # otherwise the quadratic model is not good yet
            ok = bool(np.isfinite(t.cost) and t.cost <= self.cost * (1.0 + ROUNDOFF_COST))
            if not ok:
                self.end_game_failed()
        else:
            # Gauss-Newton may raise vᵀPv a little on its way (and a free network's gauge motion
            # is not exactly cost-free for a finite step); only a step that makes the fit much
            # worse is taken as the start of divergence: switch to Levenberg-Marquardt
            ok = np.isfinite(t.cost) and not (t.cost > DIVERGENCE * self.cost and t.step > 1e-3)
            if not ok:
                self.damped = self.ever_damped = True
        self.history.append(t.step)
        return bool(ok)

    def end_game_failed(self) -> None:
        """An undamped step of the end game failed (rejected, or a singular system). When far
        points are what drifts (along their rays towards infinity: vᵀPv falls towards an
        infimum, no finite optimum for them), hold them where they are and finish the rest
        undamped; otherwise back to the trust region."""
        problem, free = self.problem, self.free
        self.failed += 1
        self.last_undamped = None
        if self.n_far == 0 and self.failed <= MAX_END_GAMES:
            far = far_columns(problem, self.x, free[self.keep_all])
            if far.any():
                if self.plan.defect:
                    # the datum analysed again here: the S-base leaves the far points out
                    held, self.plan = self.plan.eliminate, None      # (the old plan's G goes first)
                    self.plan = replan(problem, self.x, self.full(), self.P, free, held)
                    new = np.setdiff1d(np.arange(free.size), self.plan.eliminate)
                    if not np.array_equal(new, self.keep_all):
                        self.keep_all = new
                    far = far_columns(problem, self.x, free[self.keep_all])
                self.keep = self.keep_all[~far]
                self.switch()
                self.n_far = int(np.unique(problem.params.point[free[self.keep_all][far]]).size)
                return
        if self.n_far:
            self.keep, self.n_far = self.keep_all, 0
            self.switch()
        self.endgame = False

    def move(self, t: Trial) -> None:
        """Go to the accepted trial point: an undamped step of a network or block with a datum
        defect S-transformed to the S-base (M84 §2) unless that blows vᵀPv up (:data:`GAUGE_COST`),
        then A (and Ar) at the new point, the old matrices freed first."""
        free = self.free
        x_new, f_new, v_new, cost_new = t.x, t.f, t.v, t.cost
        if self.plan.defect and t.lam == 0.0 and self.keep is self.keep_all:
            # (while damped, the minimal constraint's gauge is kept; the S-base is restored by
            # the undamped steps at the end)
            # S-transform the total shift from the input coordinates to the S-base (M84 §2)
            dx = np.zeros(free.size)
            dx[self.keep] = t.dx
            total = self.x[free] + dx - self.x_ref[free]
            x_s = self.x.copy()
            x_s[free] += self.plan.transform(total) - (self.x[free] - self.x_ref[free])
            f_s = self.lin.values(x_s)
            v_s = self.problem.misclosure(f_s)
            cost_s = float(v_s @ (self.P @ v_s))
            # the linearised S-transformation of a long gauge drift can blow vᵀPv up: then the
            # step stays in the minimal constraint's gauge (the statistics do not depend on
            # it; the S-base is applied to the covariances through the plan)
            if cost_s <= max(cost_new, self.cost) * (1.0 + GAUGE_COST):
                x_new, f_new, v_new, cost_new = x_s, f_s, v_s, cost_s
        if not np.isfinite(x_new).all():
            raise SingularError("the adjustment diverged (non-finite parameters)")
        t.rel_drop = (self.cost - cost_new) / self.cost if self.cost > 0 else 0.0
        self.x, self.f, self.v, self.cost = x_new, f_new, v_new, cost_new
        self.A = self.Ar = None        # the old matrices are freed before the new ones are made
        self.A = self.lin.linearise(self.x)[1]    # (f as the trial point's: the same kernel)
        self.reduce()

    def converged(self, t: Trial) -> bool:
        """After a move: an undamped step ends the run when :func:`check_termination` says so
        (status 1, 2; 4 with far points held); a damped one at Levenberg-Marquardt's function
        tolerance (Ceres) starts the undamped end game — far, weakly determined points may still
        drift along their rays — after 2, 4, 8 ... such steps once an end game failed (a curved
        valley: the undamped step overshoots)."""
        if self.options.stop == "ceres" and self.it > 1 and (abs(t.rel_drop) < FUNCTION_TOL or self._small_step(t)):
            self.status = 5            # Ceres' function (or parameter) tolerance: no end game
            return True
        if t.lam == 0.0:
            status = check_termination(t.step, self.last_undamped, self.options.tol)
            self.last_undamped = t.step
            if status:
                self.status = 4 if self.n_far else status
                return True
        elif abs(t.rel_drop) < FUNCTION_TOL or t.step < self.options.tol:
            self.quiet += 1
            if self.quiet >= (2 ** self.failed if self.failed else 1):
                self.endgame, self.quiet = True, 0
        else:
            self.quiet = 0
        return False

    def _small_step(self, t: Trial) -> bool:
        """Ceres' parameter tolerance: ‖Δx‖ ≤ :data:`PARAMETER_TOL` (‖x‖ + :data:`PARAMETER_TOL`)."""
        return float(np.linalg.norm(t.dx)) <= PARAMETER_TOL * (float(np.linalg.norm(self.x[self.free])) + PARAMETER_TOL)

    # -- the end -------------------------------------------------------------------------------
    def release(self) -> None:
        """What only the iterations needed is freed before the datum at the solution is
        analysed: Ar's values (made again from A, the same values at the same x on the pattern
        the layout keeps) where the gauge or the datum changes, another gauge's layout, the
        linearisation's layout and the observation sets' work arrays. A at the solution is made."""
        back = self.keep is not self.keep_all
        if back or self.plan.defect:
            self.Ar = None
        self.full()                    # (A at the solution: the datum and the result need it)
        self.keep, self.free_gauge = self.keep_all, None
        if back:
            self.st = None             # another gauge's (or the far points') layout
        self.lin.release()
        for s in self.problem.sets:
            getattr(s, "release", lambda: None)()
        heap.trim(self.problem.n)      # (the iterations' freed heap, before the datum is analysed)

    def result(self) -> Adjustment:
        """The datum at the solution and the :class:`baarda.result.Adjustment` (after
        :meth:`release`). A block keeps its held coordinates where they still fix the gauge (the
        reduced system, and so the structure, stay as they are)."""
        problem, free, x = self.problem, self.free, self.x
        if self.plan.defect:
            old, self.plan = self.plan.eliminate, None       # (the iterations' plan and its G go first)
            self.plan = (replan(problem, x, self.A, self.P, free, old) if self.use_schur
                         else datum_mod.plan(problem, x, self.A, self.P, free))
            if self.use_schur and not np.array_equal(old, self.plan.eliminate):
                self.keep = np.setdiff1d(np.arange(free.size), self.plan.eliminate)
                self.st = None         # (the old layout goes before the new one is made)
        if self.Ar is None:
            self.Ar = self.lin.reduced(self.A, self.keep)
        if self.use_schur and self.st is None:
            self.structure()
        t_solve = time.perf_counter() - self.t0
        A, Ar, keep, st = self.A, self.Ar, self.keep, self.st
        if Ar is not None and Ar is not A and np.array_equal(np.setdiff1d(np.arange(free.size), self.plan.eliminate), keep):
            A = HeldColumns(A, Ar, keep)   # the result holds Ar and the held columns, not A besides
        self.A = None
        status = self.status
        adj = Adjustment(problem=problem, options=self.options, x=x, f=self.f, A=A, P=self.P, plan=self.plan,
                         converged=status > 0, iterations=self.it, history=tuple(self.history),
                         timings={"solve": t_solve}, solver="schur" if st is not None else "generic",
                         status=status, termination=STATUS[status].format(n_far=self.n_far),
                         damped=self.ever_damped, trace=tuple(self.trace), far_held=self.n_far)
        if st is not None:
            adj.seed(schur_structure=st)
        if "Ar" not in adj.__dict__ and np.array_equal(adj.keep, keep):
            adj.seed(Ar=Ar)            # (its pattern is the structure's: not made a second time)
        heap.trim(problem.n)
        return adj


def check_termination(step: float, previous: float | None, tol: float) -> int:
    """Status after an accepted undamped step whose largest increment is ``step`` conditional
    standard deviations (|Δx_i| √N_ii): 1 below ``tol``, 2 at round-off (below
    :data:`ROUNDOFF_STEP` and no longer shrinking by half), else 0 (go on)."""
    if step < tol:
        return 1
    if previous is not None and step < ROUNDOFF_STEP and step > 0.5 * previous:
        return 2
    return 0


def replan(problem, x, A, P, free, eliminate):
    """The datum plan at ``x`` (:func:`baarda.datum.plan`), holding the coordinates
    ``eliminate`` (the previous plan's) when they still fix the gauge (so the reduced system
    keeps its structure); else the new plan with its own choice."""
    new = datum_mod.plan(problem, x, A, P, free)
    if np.array_equal(new.eliminate, eliminate):
        return new
    g = new.G[eliminate]
    g = g / np.maximum(np.linalg.norm(g, axis=0), 1e-300)
    if g.shape[0] == new.defect and np.linalg.svd(g, compute_uv=False).min() > 1e-6:
        return dataclasses.replace(new, eliminate=eliminate)
    return new


def far_columns(problem, x, cols) -> np.ndarray:
    """Mask over parameter indices ``cols``: coordinates of far points (:func:`baarda.datum.far_points`)."""
    far = datum_mod.far_points(problem, x)
    pt = problem.params.point[cols]
    return (pt >= 0) & (problem.params.kind[cols] == "k") & far[np.maximum(pt, 0)]


def gradient_small(g: np.ndarray, diagN: np.ndarray, cost: float) -> bool:
    """Gradient tolerance: max |g_i| / √N_ii ≤ :data:`GRADIENT_TOL` · √(vᵀPv) (the scaled
    gradient of Ceres' test, unit-free; at the fixed point it is round-off)."""
    d = np.sqrt(np.maximum(diagN, 1e-300))
    return float(np.abs(g / d).max(initial=0.0)) <= GRADIENT_TOL * np.sqrt(max(cost, 1e-300))


def factor_step(st, Ar, P, labels, backend, lam, problem, plan):
    """The factor of N + λ diag(N) and the undamped diag(N)."""
    if st is not None:
        factor = _schur_or_diagnose(st, Ar, P, labels, backend, lam)
        return factor, factor.diagonal
    N = (Ar.T @ P @ Ar).tocsr()
    diagN = N.diagonal()
    if lam:
        N = (N + sp.diags(lam * diagN)).tocsr()
    return _factor_or_diagnose(N, Ar, P, labels, problem, plan), diagN


def _schur_or_diagnose(st, Ar, P, labels, backend, damping=0.0):
    """The step's factor: :class:`baarda.solve.schur.StepFactor` where it applies (one compiled pass),
    else :class:`baarda.solve.schur.SchurFactor` (always for ``backend="numpy"``, the reference)."""
    try:
        if backend != "numpy" and StepFactor.applicable(st, P):
            return StepFactor(st, Ar, P, damping=damping)
        return SchurFactor(st, Ar, P, backend=backend, damping=damping)
    except SingularError as err:
        raise _defect_error(err, (Ar.T @ P @ Ar).tocsr(), labels) from None


def _factor_or_diagnose(N, Ar, P, labels, problem, plan):
    try:
        return SPDFactor(N, labels=labels)
    except SingularError as err:
        raise _defect_error(err, N, labels) from None


def _defect_error(err, N, labels) -> DatumDefectError:
    """The error of a singular normal matrix, naming the unknowns in its null space."""
    undetermined = diagnose(N, labels)
    if not undetermined:
        undetermined = [err.unknown if err.unknown is not None else str(err)]
    return DatumDefectError(
        len(undetermined) if len(undetermined) < 8 else 1, undetermined,
        "the observations do not determine " + ", ".join(undetermined[:20])
        + (" ..." if len(undetermined) > 20 else "")
        + " (a local datum defect: too few observations to these unknowns)", local=True)


def diagnose(N, labels, max_dense: int = 6000) -> list[str]:
    """Names of the unknowns that take part in the null space of N (dense eigen-analysis).

    Only for systems of up to ``max_dense`` unknowns; larger ones are named by the pivot at
    which the factorisation broke down.
    """
    m = N.shape[0]
    if m > max_dense:
        return []
    Nd = N.toarray()
    d = np.sqrt(np.maximum(Nd.diagonal(), 1e-300))
    Ns = Nd / d[:, None] / d[None, :]
    lam, V = np.linalg.eigh(Ns)
    null = lam < 1e-10 * max(lam.max(), 1.0)
    if not null.any():
        return []
    weight = np.sqrt((V[:, null] ** 2).sum(axis=1))
    idx = np.flatnonzero(weight > 0.05)
    return [str(labels[i]) for i in idx[np.argsort(-weight[idx])]]
