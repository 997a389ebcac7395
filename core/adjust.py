"""Least-squares adjustment: Gauss-Newton and Levenberg-Marquardt on the sparse normal equations
(F80 eq. 1-3, 8).

Model E(l) = f(x), D(l) = σ0² Q = C, P = C⁻¹. At each iteration the observation equations are
linearised at x, A = ∂f/∂x over the estimated parameters, and

    N Δx = −Aᵀ P (f(x) − l),   N = AᵀPA,

is solved with a sparse Cholesky factor (:mod:`baarda.solve.linalg`) or, for bundle blocks with many
point unknowns that only nuisance parameters couple, through the reduced camera system
(:mod:`baarda.solve.schur`: the points are eliminated blockwise, the Schur complement S is factored and
the points back-substituted; ``Options.solver``, chosen automatically by default). A datum defect is removed by
holding d parameters at their values (a minimum constraint, :mod:`baarda.datum`) and then
S-transforming the increment so that the S-base points keep the minimum sum of squared shifts
from their input coordinates (Gama's free-network convention).

Iteration (the style of SciPy's ``least_squares``: a loop of named steps — the methods of
:class:`baarda.iteration.Iteration`, with :func:`gain_ratio`, :func:`update_radius`,
:func:`check_termination` — that ends with a status of :data:`STATUS`).
The first step is undamped (a singular system there is a defect to diagnose). Then:

- networks (``Options.method="auto"`` without point elimination): Gauss-Newton; a step that
  raises vᵀPv by more than ``DIVERGENCE`` switches to Levenberg-Marquardt;
- bundle blocks (points eliminated, :mod:`baarda.solve.schur`): Levenberg-Marquardt from the second
  step, with Ceres Solver's trust-region strategy (Agarwal, Mierle et al., Ceres Solver,
  ``LevenbergMarquardtStrategy``; Nielsen 1999; Madsen, Nielsen & Tingleff 2004, §3.2):
  (N + λ D) Δx = −AᵀP v with D = diag(N), λ = 1/μ, μ0 = 10⁴; the gain ratio
  ρ = (vᵀPv − v'ᵀPv') / Δxᵀ(g + λDΔx) accepts a step when ρ > 10⁻³; accepted,
  μ ← μ / max(1/3, 1 − (2ρ − 1)³); rejected, μ ← μ / f and f ← 2f (f reset to 2 on success).
  A free block's damped steps solve for every unknown, the gauge included (the damping makes the
  system regular, as in Ceres, which fixes no gauge); its undamped steps hold the datum's d
  coordinates.

End game: an accepted damped step that changes vᵀPv by less than ``FUNCTION_TOL`` (Ceres'
function tolerance) does not end the run: undamped Gauss-Newton steps follow (accepted while
vᵀPv does not grow beyond round-off), each S-transformed (unless the linearised transformation
of a long gauge drift would more than double vᵀPv: ``GAUGE_COST``), until the increment criterion below
holds — the optimum in the parameters, not only in the cost. When an undamped step fails and far
points (:func:`baarda.datum.far_points`) are what drifts — points running off along their rays,
whose cost keeps falling towards an infimum with no finite optimum — they are held where the
trust region left them and the rest is finished undamped (status 4); otherwise the trust region
takes over again, and waits 2^k damped steps at the function tolerance before the k-th next
try (a curved valley, where the undamped step overshoots).

Convergence criterion (undamped steps only): every increment is below ``tol`` times the
conditional standard deviation of its parameter, |Δx_i| < tol / √N_ii (unit-free, so metres,
radians and pixels can share it), with tol = 1e-9 by default (status 1); or the increments have
reached round-off (below 1e-6 and no longer shrinking by half per iteration, status 2); or, once
damped, the scaled gradient max |AᵀPv|_i / √N_ii is below 1e-10 √(vᵀPv) (status 3). At most
``max_iter`` iterations (status 0: not converged; ``baarda analyze`` exits with status 4). A loose tolerance biases tests
of strongly correlated parameters (additional parameters): their T grows with the leftover
increments.

Residuals are v = f(x̂) − l (adjusted minus observed). With P = C⁻¹ the quadratic form vᵀPv is
Ω/σ0² of F80, the statistic of the global test.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import OptionError
from .iteration import (DIVERGENCE, FUNCTION_TOL, GAUGE_COST, GRADIENT_TOL, INITIAL_RADIUS, KEEP_LAYOUTS_BYTES,
                        MAX_END_GAMES, MAX_RADIUS, MIN_RADIUS, MIN_RELATIVE_DECREASE, PARAMETER_TOL, ROUNDOFF_COST,
                        ROUNDOFF_STEP, STATUS, STOPS, Iteration, check_termination, diagnose, gain_ratio, update_radius)
from .solve.linearisation import Linearisation

__all__ = ["DIVERGENCE", "FUNCTION_TOL", "GAUGE_COST", "GRADIENT_TOL", "INITIAL_RADIUS", "KEEP_LAYOUTS_BYTES",
           "MAX_END_GAMES", "MAX_RADIUS", "METHODS", "MIN_RADIUS", "MIN_RELATIVE_DECREASE", "PARAMETER_TOL",
           "ROUNDOFF_COST", "ROUNDOFF_STEP", "STATUS", "STOPS", "Iteration", "Linearisation", "Options", "adjust", "check_termination",
           "diagnose", "gain_ratio", "update_radius"]

METHODS = ("auto", "gauss-newton", "levenberg-marquardt")


@dataclass(frozen=True)
class Options:
    """Options of the adjustment and of the tests.

    alpha0: size α0 of the one-dimensional tests (data snooping). beta0: power β0 (the names of
    :class:`baarda.stats.policy.TestPolicy`; the CLI's ``--alpha``, ``--beta``).
    b_method: derive α of multi-dimensional tests from α0 and β0 (Baarda's B-method).
    tol, max_iter: convergence and the iteration limit (module docstring; ``baarda analyze
    --max-iter``). method: ``"auto"`` (Levenberg-Marquardt after the first step where points are
    eliminated, Gauss-Newton first otherwise), ``"gauss-newton"`` (damped only after a diverging
    step) or ``"levenberg-marquardt"``.
    solver: ``"auto"`` (eliminate points through the reduced camera system when that pays,
    :meth:`baarda.solve.schur.Structure.worthwhile`), ``"schur"`` (whenever the structure allows it) or
    ``"generic"`` (one sparse Cholesky of N). backend: the pair loops of the Schur path,
    ``"numba"`` or ``"numpy"`` (None: numba when installed). Every choice gives the same
    numbers to round-off.
    sigma0, global_test, conf_pr: the test policy's σ0 of the decisions (``"apriori"``: w,
    ``"aposteriori"``: τ), its global test (``"one-sided"``, ``"two-sided"``, ``"b-method"``) and
    the confidence level of that test and of σ̂0's interval (None: the file's conf-pr, else 0.95;
    :class:`baarda.stats.policy.TestPolicy`). stop: ``"optimum"`` (default: the increment
    criterion after the undamped end game, the optimum the reliability is computed at) or
    ``"ceres"`` (Ceres Solver's rule at its defaults: the first accepted step after the first
    that changes vᵀPv by less than ``FUNCTION_TOL`` relative, or x by less than
    ``PARAMETER_TOL``, ends the run, status 5 — the cost to about 1e-6, in Ceres's time; a free
    block's coordinates then stay in the gauge the damped steps left them in).
    """

    alpha0: float = 0.001
    beta0: float = 0.80
    b_method: bool = False
    tol: float = 1e-9
    max_iter: int = 200
    solver: str = "auto"
    backend: str | None = None
    method: str = "auto"
    sigma0: str = "apriori"
    global_test: str = "one-sided"
    conf_pr: float | None = None
    stop: str = "optimum"


def adjust(problem, options: Options | None = None, x0: np.ndarray | None = None, progress=None):
    """Adjust ``problem`` (Gauss-Newton, Levenberg-Marquardt where needed; module docstring)
    and return an :class:`baarda.result.Adjustment`.

    The result carries ``status`` (a key of :data:`STATUS`: > 0 converged, ≤ 0 not) and
    ``termination`` (its message). progress: optional callable(iteration, max_increment_ratio).
    Raises DatumDefectError (defect not resolved by the datum, or parameters the observations do
    not determine) — never returns a result from a singular system.
    """
    options = options or Options()
    if options.method not in METHODS:
        raise OptionError("method", options.method, METHODS,
                          f"unknown method {options.method!r} (known: {', '.join(METHODS)})")
    if options.stop not in STOPS:
        raise OptionError("stop", options.stop, STOPS, f"unknown stop {options.stop!r} (known: {', '.join(STOPS)})")
    if int(options.max_iter) < 1:
        raise OptionError("max_iter", options.max_iter, (), f"max_iter must be at least 1 (got {options.max_iter})")
    run = Iteration(problem, options, x0)      # linearised at x0; the datum plan, the layout
    for it in range(1, options.max_iter + 1):
        lam = run.begin(it)                    # λ, the gauge and the layout of this step
        trial = run.solve(lam)                 # factor, gradient test, step, trial point
        if trial is not None and run.judge(trial):
            run.move(trial)                    # to the trial point: S-transformation, A there
            if progress is not None:
                progress(it, trial.step)
            if run.converged(trial):
                break
        elif run.status:                       # the gradient vanished, the trust region collapsed
            break
    run.release()                              # what only the iterations needed
    return run.result()                        # the datum at the solution, the Adjustment
