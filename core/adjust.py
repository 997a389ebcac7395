"""Least-squares adjustment: Gauss-Newton on the sparse normal equations (F80 eq. 1-3, 8).

Model E(l) = f(x), D(l) = σ0² Q = C, P = C⁻¹. At each iteration the observation equations are
linearised at x, A = ∂f/∂x over the estimated parameters, and

    N Δx = −Aᵀ P (f(x) − l),   N = AᵀPA,

is solved with a sparse Cholesky factor (:mod:`baarda.linalg`) or, for bundle blocks with many
point unknowns that only nuisance parameters couple, through the reduced camera system
(:mod:`baarda.schur`: the points are eliminated blockwise, the Schur complement S is factored and
the points back-substituted; ``Options.solver``, chosen automatically by default). A datum defect is removed by
holding d parameters at their values (a minimum constraint, :mod:`baarda.datum`) and then
S-transforming the increment so that the S-base points keep the minimum sum of squared shifts
from their input coordinates (Gama's free-network convention).

A Gauss-Newton step that raises vᵀPv by more than ``DIVERGENCE`` (or meets a singular system after
the first iteration) switches the solver to Levenberg-Marquardt for the rest of the run: damping
N + λ diag(N), a step accepted only when vᵀPv decreases, λ updated after Nielsen (1999) from the
gain ratio. The damping falls to 0 near the solution, so the last iterations are plain
Gauss-Newton and the result is the least-squares fixed point. Networks whose Gauss-Newton
converges never see the damping.

Convergence criterion (checked once λ < 1e-6): every increment is below ``tol`` times the conditional standard deviation
of its parameter, |Δx_i| < tol / √N_ii (unit-free, so metres, radians and pixels can share it),
with tol = 1e-9 by default; or the increments have reached round-off (below 1e-6 and no longer
shrinking by half per iteration); at most ``max_iter`` iterations. A loose tolerance biases tests
of strongly correlated parameters (additional parameters): their T grows with the leftover
increments.

Residuals are v = f(x̂) − l (adjusted minus observed). With P = C⁻¹ the quadratic form vᵀPv is
Ω/σ0² of F80, the statistic of the global test.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from . import datum as datum_mod
from .errors import DatumDefectError, SingularError
from . import schur
from .linalg import SPDFactor

SOLVERS = ("auto", "schur", "generic")


#: a Gauss-Newton step that multiplies vᵀPv by more than this switches to Levenberg-Marquardt
DIVERGENCE = 1.5
#: in Levenberg-Marquardt mode, two accepted steps lowering vᵀPv by less than this (relative)
#: end the iteration (converged in the cost, as Ceres' function tolerance)
FUNCTION_TOL = 1e-6


@dataclass(frozen=True)
class Options:
    """Options of the adjustment and of the tests.

    alpha: size α0 of the one-dimensional tests (data snooping). beta: power β0.
    b_method: derive α of multi-dimensional tests from α0 and β0 (Baarda's B-method).
    tol, max_iter: Gauss-Newton convergence (see the module docstring).
    solver: ``"auto"`` (eliminate points through the reduced camera system when that pays,
    :meth:`baarda.schur.Structure.worthwhile`), ``"schur"`` (whenever the structure allows it) or
    ``"generic"`` (one sparse Cholesky of N). backend: the pair loops of the Schur path,
    ``"numba"`` or ``"numpy"`` (None: numba when installed). Every choice gives the same
    numbers to round-off.
    """

    alpha: float = 0.001
    beta: float = 0.80
    b_method: bool = False
    tol: float = 1e-9
    max_iter: int = 50
    solver: str = "auto"
    backend: str | None = None


def keep_columns(A: sp.csr_matrix, keep: np.ndarray) -> sp.csr_matrix:
    """A[:, keep] for sorted ``keep`` by one pass over the entries (scipy's column indexing
    costs a gather per entry and a re-sort; here the order is kept and so is canonical form)."""
    A = sp.csr_matrix(A)
    if keep.size == A.shape[1]:
        return A
    colmap = np.full(A.shape[1], -1, dtype=np.int64)
    colmap[keep] = np.arange(keep.size)
    new = colmap[A.indices]
    m = new >= 0
    cm = np.concatenate([[0], np.cumsum(m)])
    out = sp.csr_matrix((A.data[m], new[m].astype(A.indices.dtype), cm[A.indptr].astype(A.indptr.dtype)),
                        shape=(A.shape[0], keep.size))
    out.has_sorted_indices = A.has_sorted_indices
    return out


def _regularised(A, P, free, plan):
    mask = np.ones(free.size, dtype=bool)
    mask[plan.eliminate] = False
    keep = np.flatnonzero(mask)
    return keep, keep_columns(A, keep)


def weight_matrix(cov) -> sp.csr_matrix:
    """P = C⁻¹ block by block: :meth:`baarda.problem.Covariance.weight`, vectorised per cluster
    size (the same batched inverses, so the same numbers)."""
    from .result import size_groups, size_weights

    n = cov.cluster.size
    rows, cols, vals = [], [], []
    for (m, _, members, C), W in zip(size_groups(cov), size_weights(cov)):
        rows.append(np.repeat(members, m, axis=1).ravel())
        cols.append(np.tile(members, (1, m)).ravel())
        vals.append(W.ravel())
    if not rows:
        return sp.csr_matrix((n, n))
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def schur_structure(problem, Ar, keep, solver: str = "auto"):
    """The point-elimination layout of :mod:`baarda.schur` for the reduced design matrix ``Ar``,
    or None when the generic solver is to be used (``solver``: see :class:`Options`)."""
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r} (known: {', '.join(SOLVERS)})")
    if solver == "generic":
        return None
    params = problem.params
    fr = params.free[keep]
    kind = params.kind[fr]
    if solver == "auto" and int((kind == "k").sum()) < schur.MIN_ELIMINATED:
        return None
    st = schur.analyse(Ar, problem.cov, kind, params.point[fr], np.asarray(params.labels)[fr])
    if st is None or (solver == "auto" and not st.worthwhile()):
        return None
    return st


def adjust(problem, options: Options | None = None, x0: np.ndarray | None = None,
           progress=None):
    """Adjust ``problem`` by Gauss-Newton and return an :class:`baarda.result.Adjustment`.

    progress: optional callable(iteration, max_increment_ratio) for progress display.
    Raises DatumDefectError (defect not resolved by the datum, or parameters the observations do
    not determine) — never returns a result from a singular system.
    """
    from .result import Adjustment

    options = options or Options()
    t0 = time.perf_counter()
    params = problem.params
    free = params.free
    x = (params.x0 if x0 is None else x0).astype(float).copy()
    x_ref = x.copy()
    P = weight_matrix(problem.cov)
    labels = np.asarray(params.labels)[free]
    f, J = problem.evaluate(x)
    A = J[:, free].tocsr()
    plan = datum_mod.plan(problem, x, A, P, free)
    converged = False
    history = []
    it = 0
    keep, Ar = _regularised(A, P, free, plan)
    st = schur_structure(problem, Ar, keep, options.solver)
    lam = 0.0                      # Levenberg-Marquardt damping, 0 = Gauss-Newton
    lm_mode = False                # becomes True once a Gauss-Newton step has failed
    small_drops = 0
    nu = 2.0
    v = problem.misclosure(f)
    cost = float(v @ (P @ v))
    it = 0
    for it in range(1, options.max_iter + 1):
        keep, Ar = _regularised(A, P, free, plan)
        if st is not None and not st.matches(Ar):
            st = schur_structure(problem, Ar, keep, "schur")
        try:
            if st is not None:
                factor = _schur_or_diagnose(st, Ar, P, labels[keep], options.backend, lam)
                diagN = factor.diagonal
            else:
                N = (Ar.T @ P @ Ar).tocsr()
                diagN = N.diagonal()
                if lam:
                    N = (N + sp.diags(lam * diagN)).tocsr()
                factor = _factor_or_diagnose(N, Ar, P, labels[keep], problem, plan)
        except DatumDefectError:
            # singular at the start: a real defect. Later (after a long step) or while damped:
            # damp more and retry from the same point; give up past a huge damping.
            if it == 1 or lam > 1e12:
                raise
            lm_mode = True
            lam, nu = max(nu * lam, 1e-3), 2.0 * nu
            history.append(float("inf"))
            continue
        lam_used = lam
        g = -(Ar.T @ (P @ v))
        step_keep = factor.solve(g)
        dx_raw = np.zeros(free.size)
        dx_raw[keep] = step_keep
        ratio = np.abs(step_keep) * np.sqrt(diagN)
        step = float(ratio.max(initial=0.0))
        trial = x.copy()
        trial[free] += dx_raw
        f_new, J_new = problem.evaluate(trial)
        v_new = problem.misclosure(f_new)
        cost_new = float(v_new @ (P @ v_new))
        if lm_mode:
            # Levenberg-Marquardt (Nielsen's update): accept when vᵀPv decreases
            predicted = float(step_keep @ (lam * diagN * step_keep + g))
            rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
            ok = np.isfinite(cost_new) and (rho > 0 or step < 1e-3)
            if ok:
                lam = lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3) if rho > 0 else lam
                nu = 2.0
                if lam < 1e-9:
                    lam = 0.0
            else:
                if lam > 1e12:
                    break
                lam, nu = max(nu * lam, 1e-6), 2.0 * nu
        else:
            # Gauss-Newton may raise vᵀPv a little on its way (and a free network's gauge motion
            # is not exactly cost-free for a finite step); only a step that makes the fit much
            # worse is taken as the start of divergence: switch to Levenberg-Marquardt
            ok = np.isfinite(cost_new) and not (cost_new > DIVERGENCE * cost and step > 1e-3)
            if not ok:
                lm_mode, lam = True, 1e-3
        history.append(step)
        if not ok:
            continue
        dx = dx_raw
        if plan.defect and lam_used == 0.0:
            # (while damped, the minimal constraint's gauge is kept; the S-base is restored by
            # the undamped steps at the end)
            # S-transform the total shift from the input coordinates to the S-base (M84 §2)
            total = x[free] + dx - x_ref[free]
            dx = plan.transform(total) - (x[free] - x_ref[free])
            x_new = x.copy()
            x_new[free] += dx
            f_new, J_new = problem.evaluate(x_new)
            v_new = problem.misclosure(f_new)
            cost_new = float(v_new @ (P @ v_new))
        else:
            x_new = trial
        if not np.isfinite(x_new).all():
            raise SingularError("the adjustment diverged (non-finite parameters)")
        rel_drop = (cost - cost_new) / cost if cost > 0 else 0.0
        x, f, J, v, cost = x_new, f_new, J_new, v_new, cost_new
        A = J[:, free].tocsr()
        if progress is not None:
            progress(it, history[-1])
        if lam_used < 1e-6 and (step < options.tol or (len(history) > 1 and step < 1e-6
                                                    and step > 0.5 * history[-2])):
            converged = True
            break
        if lm_mode and 0.0 <= rel_drop < FUNCTION_TOL:
            small_drops += 1
            if small_drops >= 2:
                # Levenberg-Marquardt's end game (Ceres' function tolerance): vᵀPv no longer
                # changes although far, weakly determined points still drift along their rays
                converged = True
                break
        else:
            small_drops = 0
    if plan.defect:
        old = plan.eliminate
        plan = datum_mod.plan(problem, x, A, P, free)
        if st is not None and not np.array_equal(old, plan.eliminate):
            keep, Ar = _regularised(A, P, free, plan)
            st = schur_structure(problem, Ar, keep, "schur")
    t_solve = time.perf_counter() - t0
    adj = Adjustment(problem=problem, options=options, x=x, f=f, A=A, P=P, plan=plan,
                     converged=converged, iterations=it, history=tuple(history),
                     timings={"solve": t_solve}, solver="schur" if st is not None else "generic")
    if st is not None:
        adj.__dict__["schur_structure"] = st
    adj.__dict__["damped"] = lm_mode          # Levenberg-Marquardt took over from Gauss-Newton
    return adj


def _schur_or_diagnose(st, Ar, P, labels, backend, damping=0.0):
    try:
        return schur.SchurFactor(st, Ar, P, backend=backend, damping=damping)
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
        undetermined = [str(err).split(": ", 1)[-1].split(" is not")[0]]
    return DatumDefectError(
        len(undetermined) if len(undetermined) < 8 else 1, undetermined,
        "the observations do not determine " + ", ".join(undetermined[:20])
        + (" ..." if len(undetermined) > 20 else "")
        + " (a local datum defect: too few observations to these unknowns)")


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
