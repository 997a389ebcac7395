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

Iteration (the style of SciPy's ``least_squares``: a loop of named steps — :func:`gain_ratio`,
:func:`update_radius`, :func:`check_termination` — that ends with a status of :data:`STATUS`).
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

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from . import datum as datum_mod
from .errors import DatumDefectError, OptionError, SingularError
from .model.problem import take, weight_matrix
from .result import Adjustment, HeldColumns
from .solve import heap, schur
from .solve.linalg import SPDFactor, compact, keep_columns
from .solve.schur import schur_structure

METHODS = ("auto", "gauss-newton", "levenberg-marquardt")

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
#: gradient tolerance (Ceres' gradient_tolerance, here on the scaled gradient; see _gradient_small)
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
#: entries per chunk of :meth:`Linearisation._layout`'s temporaries
LAYOUT_CHUNK = 1 << 20

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
}


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
    :class:`baarda.stats.policy.TestPolicy`).
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


class Linearisation:
    """f(x) and the design matrix A = ∂f/∂x over the free parameters, on a pattern found once.

    The observation sets return their Jacobian entries as (row, column, value) triples in a
    fixed order; the CSR pattern of A (and of the reduced Ar, without the datum's held columns)
    and the place of every triple in it are computed at the first evaluation, so each later
    one is a single weighted bincount (duplicates summed as scipy's COO conversion does).
    A set that returns another pattern makes the layout be found again. :attr:`direct` tells
    whether the last :meth:`linearise` wrote the values straight into A's data.
    """

    def __init__(self, problem, free: np.ndarray):
        self.problem = problem
        self.u = free.size
        self.col = np.full(problem.params.size, -1, dtype=np.int64)
        self.col[free] = np.arange(free.size)
        self._key = self._take = self._first = self._dest = self._fixed = None

    @property
    def direct(self) -> bool:
        """True once :meth:`linearise` writes the set's Jacobian values straight into A's data
        (``evaluate_into``, on the layout found before): no array of the raw entries is made and
        their gathering order is dropped. False while A is gathered from the raw entries
        (:meth:`design`)."""
        return self._dest is not None and self._take is None

    def values(self, x: np.ndarray) -> np.ndarray:
        """f(x) alone (a trial point's: its Jacobian is made once the step is accepted)."""
        f = np.empty(self.problem.n)
        for s in self.problem.sets:
            f[s.rows] = s.values(x) if hasattr(s, "values") else s.evaluate(x)[0]
        return f

    def linearise(self, x: np.ndarray):
        """f(x) and A at x (:meth:`evaluate`, :meth:`design`). Once the layout is known, a set
        that writes its values in place (``evaluate_into``) writes them straight into A's data:
        no array of the raw entries besides it."""
        sets = self.problem.sets
        s = sets[0] if len(sets) == 1 else None
        if s is not None and (self._fixed is s or (
                hasattr(s, "evaluate_into") and self._key is not None and self._first is None
                and (self._take is not None or self._dest is not None) and self._same([(*s.pattern(), None)]))):
            self._direct(s)
            data = np.empty(self._indices.size + 1)
            f = np.empty(self.problem.n)
            f[s.rows] = s.evaluate_into(x, self._dest, data)
            return f, self._matrix(data[:-1])
        f, parts = self.evaluate(x)
        return f, self.design(parts)

    def first(self, x: np.ndarray):
        """f(x) and A at the first evaluation: the layout is found from the set's pattern alone,
        before any Jacobian value is made, and a set that writes its values in place
        (``evaluate_into``) writes them straight into A's data — no array of the raw entries
        beside the layout's temporaries. The same f and A as :meth:`evaluate` and :meth:`design`
        (the same kernel); otherwise those two."""
        sets = self.problem.sets
        s = sets[0] if len(sets) == 1 else None
        if s is not None and hasattr(s, "evaluate_into") and hasattr(s, "pattern"):
            self._layout([(*s.pattern(), None)])
            if self._first is None:
                return self.linearise(x)
        f, parts = self.evaluate(x)
        return f, self.design(parts)

    def _direct(self, s) -> None:
        """Make the place in A's data of every entry of the set ``s`` (the inverse of the gather
        order, which it replaces). A set whose pattern is fixed (``pattern_fixed``: a function of
        its own index arrays) is not compared with its entries again: their rows and columns are
        dropped here, by the set too (``release_entries``)."""
        if self._dest is None:
            nnz = self._indices.size
            dest = np.full(self._key[0][0].size, nnz, dtype=self._take.dtype)   # left out: a spare slot
            dest[self._take] = np.arange(nnz, dtype=self._take.dtype)
            self._dest, self._take = dest, None
        if getattr(s, "pattern_fixed", False) and self._fixed is not s:
            self._fixed, self._key = s, None
            getattr(s, "release_entries", lambda: None)()

    def evaluate(self, x: np.ndarray):
        """f(x) (n,) and the raw entries of the Jacobian (pass them to :meth:`design`)."""
        problem = self.problem
        f = np.empty(problem.n)
        parts = []
        for s in problem.sets:
            fs, jr, jc, jv = s.evaluate(x)
            f[s.rows] = fs
            parts.append((jr, jc, jv))
        return f, parts

    def _layout(self, parts):
        """The CSR pattern of A and the gathering order of the raw entries (their stable sort by
        (row, column), duplicates summed). Built in chunks of :data:`LAYOUT_CHUNK` entries: the
        int64 keys row·u + column are the only full-size int64 array besides the sort's order
        (no rows, columns or sorted keys of every entry beside them, ~0.4 KB per image point)."""
        problem = self.problem
        U = max(self.u, 1)
        n = problem.n
        sizes = [np.asarray(jr).size for jr, _, _ in parts]
        E = int(sum(sizes))
        itype = np.int32 if E < 2 ** 31 - 1 else np.int64
        m = np.empty(E, dtype=bool)         # entries of free columns
        o = 0
        for (_, jc, _), k in zip(parts, sizes):
            for s in range(0, k, LAYOUT_CHUNK):
                e = min(s + LAYOUT_CHUNK, k)
                m[o + s:o + e] = self.col[jc[s:e]] >= 0
            o += k
        nm = int(np.count_nonzero(m))
        key = np.empty(nm, dtype=np.int64)
        pos = 0
        rows = cols = mk = None
        for s_, (jr, jc, _), k in zip(problem.sets, parts, sizes):
            srows = np.asarray(s_.rows)
            for s in range(0, k, LAYOUT_CHUNK):
                e = min(s + LAYOUT_CHUNK, k)
                rows = srows[jr[s:e]].astype(np.int64)
                cols = self.col[jc[s:e]]
                mk = cols >= 0
                c = int(np.count_nonzero(mk))
                key[pos:pos + c] = rows[mk] * U + cols[mk]
                pos += c
        del rows, cols, mk
        order = np.argsort(key, kind="stable").astype(itype)
        # entries of the free columns in CSR order (the same stable order as before)
        self._take = order if nm == E else np.flatnonzero(m).astype(itype)[order]
        del m
        # duplicates (one parameter feeding two intrinsics) summed by reduceat over their runs;
        # the unique keys give A's row pointer and column indices, chunk by chunk
        small = self.u < 2 ** 31 - 1
        indices = np.empty(nm, dtype=np.int32 if small else np.int64)
        counts = np.zeros(n, dtype=np.int64)
        firsts, nu = [], 0
        ks = new = uk = None
        for s in range(0, nm, LAYOUT_CHUNK):
            e = min(s + LAYOUT_CHUNK, nm)
            ks = key[order[s:e]]
            new = np.empty(e - s, dtype=bool)
            new[0] = s == 0 or ks[0] != key[order[s - 1]]
            np.not_equal(ks[1:], ks[:-1], out=new[1:])
            if new.all():
                firsts.append((s, e))
                uk = ks
            else:
                firsts.append(np.flatnonzero(new) + s)
                uk = ks[new]
            indices[nu:nu + uk.size] = uk % U
            counts += np.bincount(uk // U, minlength=n)
            nu += uk.size
        del key, order, ks, new, uk
        self._key = tuple((jr, jc) for jr, jc, _ in parts)
        if nu == nm:
            self._first = None
        else:
            self._first = np.concatenate([np.arange(*f, dtype=np.int64) if isinstance(f, tuple) else f
                                          for f in firsts])
            indices = indices[:nu].copy()
        del firsts
        small = nu < 2 ** 31 - 1 and self.u < 2 ** 31 - 1       # int32 indices where they fit
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(counts, out=indptr[1:])
        self._indptr = indptr.astype(np.int32 if small else np.int64)
        self._indices = indices.astype(np.int32 if small else np.int64, copy=False)
        self._reduced = self._dest = self._fixed = None

    def release(self) -> None:
        """Forget the layout of A (kept for the next :meth:`design`); :meth:`reduced` still works."""
        self._key = self._take = self._first = self._dest = self._fixed = None

    def _same(self, parts) -> bool:
        if self._key is None or len(self._key) != len(parts):
            return False
        return all((jr is kr or np.array_equal(jr, kr)) and (jc is kc or np.array_equal(jc, kc))
                   for (jr, jc, _), (kr, kc) in zip(parts, self._key))

    def design(self, parts) -> sp.csr_matrix:
        """A (n × u_free, canonical CSR) from the entries of :meth:`evaluate`."""
        if self._take is None or not self._same(parts):
            self._layout(parts)
        jv = parts[0][2] if len(parts) == 1 else np.concatenate([jv for _, _, jv in parts])
        data = jv[self._take]
        if self._first is not None:
            data = np.add.reduceat(data, self._first)
        sets = self.problem.sets
        if (len(sets) == 1 and self._first is None and getattr(sets[0], "pattern_fixed", False)
                and hasattr(sets[0], "evaluate_into")):
            del jv, parts
            self._direct(sets[0])      # the next linearise writes into A: the entries' pattern goes now
        return self._matrix(data)

    def _matrix(self, data: np.ndarray) -> sp.csr_matrix:
        """A on the layout's pattern with the values ``data`` (no copy)."""
        A = sp.csr_matrix((data, self._indices, self._indptr), shape=(self.problem.n, self.u), copy=False)
        A.has_canonical_format = True
        self._A_indices = A.indices
        return A

    def reduced(self, A: sp.csr_matrix, keep: np.ndarray, consume: bool = False) -> sp.csr_matrix:
        """A[:, keep] (:func:`keep_columns`), its pattern kept for the next A of this layout.
        consume: A is dropped afterwards; Ar's values are moved within A's data array (no second
        array of values while both exist)."""
        if A.indices is not getattr(self, "_A_indices", None):
            return keep_columns(A, keep, consume)
        if keep.size == self.u:
            self._reduced = None       # (the held gauge's pattern is made again when needed)
            return A                   # every column (the free gauge's steps): A itself, no copy
        if self._reduced is None or not np.array_equal(self._reduced[0], keep):
            self._reduced = None
            kept = np.zeros(self.u, dtype=bool)
            kept[keep] = True
            m = kept[A.indices]
            Ar = keep_columns(A, keep, consume)
            self._reduced = (keep.copy(), m, Ar.indices, Ar.indptr)
            Ar.has_canonical_format = True
            return Ar                  # (its values are A.data[m] already: not gathered twice)
        _, m, indices, indptr = self._reduced
        data = compact(A.data, m) if consume else A.data[m]
        Ar = sp.csr_matrix((data, indices, indptr), shape=(A.shape[0], keep.size), copy=False)
        Ar.has_canonical_format = True
        return Ar


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


def adjust(problem, options: Options | None = None, x0: np.ndarray | None = None,
           progress=None):
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
    if int(options.max_iter) < 1:
        raise OptionError("max_iter", options.max_iter, (), f"max_iter must be at least 1 (got {options.max_iter})")
    t0 = time.perf_counter()
    params = problem.params
    free = params.free
    x = (params.x0 if x0 is None else x0).astype(float).copy()
    x_ref = x.copy()
    heap.map_large(problem.n)
    P = weight_matrix(problem.cov)
    labels = _Labels(params.labels, free)
    lin = Linearisation(problem, free)
    f, A = lin.first(x)
    heap.trim(problem.n)           # (the layout's temporaries: freed heap given back)
    plan = datum_mod.plan(problem, x, A, P, free)
    keep_all = np.setdiff1d(np.arange(free.size), plan.eliminate)
    keep = keep_all                # the unknowns solved for (far points held in the end game)
    Ar = lin.reduced(A, keep, consume=True)
    if Ar is not A:
        A = None                   # (made again at x when needed: full() below)
    st = schur_structure(problem, Ar, keep, options.solver)
    st_keep = keep                 # the unknowns st was analysed for
    layouts = []                   # (keep, layout) kept across gauge switches (KEEP_LAYOUTS_BYTES)
    use_schur = st is not None     # points eliminated (the decision is kept for every later Ar)
    # Levenberg-Marquardt from the start for blocks whose points are eliminated (as Ceres);
    # Gauss-Newton first otherwise, damped only once a step makes the fit much worse
    damped = options.method == "levenberg-marquardt" or (options.method == "auto" and st is not None)
    endgame = False                # undamped steps after Levenberg-Marquardt's function tolerance
    mu, decrease = INITIAL_RADIUS, 2.0
    ever_damped = damped
    history: list[float] = []
    trace = []                     # (λ, step, vᵀPv at the trial point, gain ratio) per solved step
    last_undamped = None           # size of the last accepted undamped step
    failed = 0                     # undamped end games that failed
    quiet = 0                      # damped steps in a row at the function tolerance
    n_far = 0                      # far points held in the end game
    status = 0
    v = problem.misclosure(f)
    cost = float(v @ (P @ v))

    def full():
        """A at x: while a reduced copy Ar is what the steps use, A's values are not held (the
        next linearisation at x writes the same values again when A is needed: a switch of
        gauge, the datum)."""
        nonlocal A
        if A is None:
            A = lin.linearise(x)[1]
        return A

    def reduce():
        """Ar = A[:, keep]; A's values are let go when Ar is a copy (:func:`full`)."""
        nonlocal A, Ar
        Ar = None
        Ar = lin.reduced(full(), keep, consume=True)
        if Ar is not A:
            A = None

    def structure():
        """The elimination layout of the current Ar: one kept from an earlier switch
        (:data:`KEEP_LAYOUTS_BYTES`), else analysed. Otherwise one is held at a time: the
        previous one (another gauge's, or without far points) is dropped before this one is
        analysed."""
        nonlocal st, st_keep
        st, st_keep = None, keep
        if use_schur:
            st = next((s for k, s in layouts if np.array_equal(k, keep) and s.matches(Ar)), None)
            if st is None:
                heap.trim(problem.n)   # (the old layout's freed heap, before the new one is analysed)
                st = schur_structure(problem, Ar, keep, "schur")

    def switch():
        """Ar and its layout for a new set of unknowns ``keep``: the old layout goes before the
        new Ar is made (a gauge switch must not hold both layouts and both matrices), unless
        the layouts are small enough to be kept."""
        nonlocal st
        if st is not None and not any(s is st for _, s in layouts) and \
                sum(_nbytes(s) for _, s in layouts) + _nbytes(st) <= KEEP_LAYOUTS_BYTES:
            layouts.append((st_keep, st))
        st = None
        reduce()
        structure()

    def end_game_failed():
        """An undamped step of the end game failed (rejected, or a singular system). When far
        points are what drifts (along their rays towards infinity: vᵀPv falls towards an
        infimum, no finite optimum for them), hold them where they are and finish the rest
        undamped; otherwise back to the trust region."""
        nonlocal keep, keep_all, plan, endgame, failed, n_far, last_undamped
        failed += 1
        last_undamped = None
        if n_far == 0 and failed <= MAX_END_GAMES:
            far = _far_columns(problem, x, free[keep_all])
            if far.any():
                if plan.defect:
                    # the datum analysed again here: the S-base leaves the far points out
                    held, plan = plan.eliminate, None      # (the old plan's G goes first)
                    plan = _replan(problem, x, full(), P, free, held)
                    new = np.setdiff1d(np.arange(free.size), plan.eliminate)
                    if not np.array_equal(new, keep_all):
                        keep_all = new
                    far = _far_columns(problem, x, free[keep_all])
                keep = keep_all[~far]
                switch()
                n_far = int(np.unique(params.point[free[keep_all][far]]).size)
                return
        if n_far:
            keep, n_far = keep_all, 0
            switch()
        endgame = False

    it = 0
    free_gauge = None              # all unknowns: the damped steps of a free block
    for it in range(1, options.max_iter + 1):
        # the first step is undamped whatever the method: a singular system there is a defect
        # to diagnose (DatumDefectError), not something to damp away
        first = it == 1
        lam = 1.0 / mu if damped and not endgame and not first else 0.0
        heap.trim(problem.n)       # (the last step's freed heap, before this one's factor)
        if plan.defect:
            # a free network's or block's damped steps move all unknowns, the gauge too (the
            # damping makes N + λD regular, as in Ceres, which fixes no gauge); its undamped
            # steps hold the datum's coordinates and are S-transformed. (Holding coordinates
            # while damped makes the way much longer: 72 instead of 19 iterations on BAL
            # Dubrovnik-16; a two-view Bundler block did not converge in 50.)
            if lam > 0.0 and keep is keep_all:
                if free_gauge is None:
                    free_gauge = np.arange(free.size)
                keep = free_gauge
                switch()
            elif lam == 0.0 and free_gauge is not None and keep is free_gauge:
                keep = keep_all
                switch()
        if st is not None and not st.matches(Ar):
            structure()
        try:
            factor, diagN = _factor(st, Ar, P, labels[keep], options.backend, lam, problem, plan)
        except DatumDefectError:
            # singular at the start: a real defect. Later (after a long step) or while damped:
            # damp more and retry from the same point; give up past a huge damping.
            if it == 1 or lam > 1e12:
                raise
            if endgame:
                end_game_failed()
            elif lam:
                mu, decrease = mu / decrease, 2.0 * decrease
            else:
                mu, decrease = INITIAL_RADIUS, 2.0
            damped = ever_damped = True
            history.append(float("inf"))
            continue
        g = -(Ar.T @ (P @ v))
        if damped and not n_far and _gradient_small(g, diagN, cost):
            status = 3
            del factor             # not alive while the datum at the solution is analysed
            break
        step_keep = factor.solve(g)
        del factor                 # not alive while the trial point is evaluated
        step = float((np.abs(step_keep) * np.sqrt(diagN)).max(initial=0.0))
        trial = x.copy()
        trial[free[keep]] += step_keep
        f_new = lin.values(trial)
        v_new = problem.misclosure(f_new)
        cost_new = float(v_new @ (P @ v_new))
        rho = gain_ratio(cost, cost_new, step_keep, g, lam, diagN)
        trace.append((lam, step, cost_new, rho))
        if lam > 0.0:
            ok = rho > MIN_RELATIVE_DECREASE
            if not ok and np.isfinite(cost_new) and abs(cost_new - cost) <= ROUNDOFF_COST * cost:
                # vᵀPv changes at round-off only: the gain ratio is noise, the damping has done
                # its work (Ceres would stop here); the undamped end game decides
                endgame, quiet = True, 0
                history.append(step)
                continue
            mu, decrease = update_radius(mu, decrease, rho, ok)
            if not ok and mu < MIN_RADIUS:
                history.append(step)
                status = -1
                break
        elif first and damped:
            ok = rho > MIN_RELATIVE_DECREASE          # the trust region's rule, radius untouched
        elif endgame:
            # the undamped end game accepts what does not raise vᵀPv beyond round-off;
            # otherwise the quadratic model is not good yet
            ok = bool(np.isfinite(cost_new) and cost_new <= cost * (1.0 + ROUNDOFF_COST))
            if not ok:
                end_game_failed()
        else:
            # Gauss-Newton may raise vᵀPv a little on its way (and a free network's gauge motion
            # is not exactly cost-free for a finite step); only a step that makes the fit much
            # worse is taken as the start of divergence: switch to Levenberg-Marquardt
            ok = np.isfinite(cost_new) and not (cost_new > DIVERGENCE * cost and step > 1e-3)
            if not ok:
                damped = ever_damped = True
        history.append(step)
        if not ok:
            continue
        dx = np.zeros(free.size)
        dx[keep] = step_keep
        x_new = trial
        if plan.defect and lam == 0.0 and keep is keep_all:
            # (while damped, the minimal constraint's gauge is kept; the S-base is restored by
            # the undamped steps at the end)
            # S-transform the total shift from the input coordinates to the S-base (M84 §2)
            total = x[free] + dx - x_ref[free]
            x_s = x.copy()
            x_s[free] += plan.transform(total) - (x[free] - x_ref[free])
            f_s = lin.values(x_s)
            v_s = problem.misclosure(f_s)
            cost_s = float(v_s @ (P @ v_s))
            # the linearised S-transformation of a long gauge drift can blow vᵀPv up: then the
            # step stays in the minimal constraint's gauge (the statistics do not depend on
            # it; the S-base is applied to the covariances through the plan)
            if cost_s <= max(cost_new, cost) * (1.0 + GAUGE_COST):
                x_new, f_new, v_new, cost_new = x_s, f_s, v_s, cost_s
        if not np.isfinite(x_new).all():
            raise SingularError("the adjustment diverged (non-finite parameters)")
        rel_drop = (cost - cost_new) / cost if cost > 0 else 0.0
        x, f, v, cost = x_new, f_new, v_new, cost_new
        A = Ar = None              # the old matrices are freed before the new ones are made
        A = lin.linearise(x)[1]    # (f as the trial point's: the same kernel)
        reduce()
        if progress is not None:
            progress(it, step)
        if lam == 0.0:
            status = check_termination(step, last_undamped, options.tol)
            last_undamped = step
            if status:
                status = 4 if n_far else status
                break
        elif abs(rel_drop) < FUNCTION_TOL or step < options.tol:
            # Levenberg-Marquardt's function tolerance (Ceres): vᵀPv no longer changes; far,
            # weakly determined points may still drift along their rays, so finish with
            # undamped steps until the increments themselves are negligible. After a failed
            # end game (a curved valley: the undamped step overshoots), wait 2, 4, 8 ... damped
            # steps at the function tolerance before the next try
            quiet += 1
            if quiet >= (2 ** failed if failed else 1):
                endgame, quiet = True, 0
        else:
            quiet = 0
    # what only the iterations needed is freed before the datum at the solution is analysed
    back = keep is not keep_all
    if back or plan.defect:
        # Ar's values go before A is made (and while the datum is analysed on A): made again
        # from A below, the same values at the same x on the pattern the layout keeps
        Ar = None
    full()                         # (A at the solution: the datum and the result need it)
    keep, free_gauge = keep_all, None
    if back:
        st = None                  # another gauge's (or the far points') layout
    lin.release()
    for s in problem.sets:
        getattr(s, "release", lambda: None)()
    heap.trim(problem.n)           # (the iterations' freed heap, before the datum is analysed)
    if plan.defect:
        old, plan = plan.eliminate, None       # (the iterations' plan and its G go first)
        # the datum at the solution; a block keeps its held coordinates where they still fix
        # the gauge (the reduced system, and so the structure, stay as they are)
        plan = _replan(problem, x, A, P, free, old) if use_schur else datum_mod.plan(problem, x, A, P, free)
        if use_schur and not np.array_equal(old, plan.eliminate):
            keep = np.setdiff1d(np.arange(free.size), plan.eliminate)
            st = None              # (the old layout goes before the new one is made)
    if Ar is None:
        Ar = lin.reduced(A, keep)
    if use_schur and st is None:
        structure()
    t_solve = time.perf_counter() - t0
    if Ar is not None and Ar is not A and np.array_equal(np.setdiff1d(np.arange(free.size), plan.eliminate), keep):
        A = HeldColumns(A, Ar, keep)   # the result holds Ar and the held columns, not A besides
    adj = Adjustment(problem=problem, options=options, x=x, f=f, A=A, P=P, plan=plan,
                     converged=status > 0, iterations=it, history=tuple(history),
                     timings={"solve": t_solve}, solver="schur" if st is not None else "generic",
                     status=status, termination=STATUS[status].format(n_far=n_far), damped=ever_damped,
                     trace=tuple(trace), far_held=n_far)
    if st is not None:
        adj.seed(schur_structure=st)
    if "Ar" not in adj.__dict__ and np.array_equal(adj.keep, keep):
        adj.seed(Ar=Ar)            # (its pattern is the structure's: not made a second time)
    heap.trim(problem.n)
    return adj


def _nbytes(st) -> int:
    """Bytes of the arrays an elimination layout holds (its cached ones too)."""
    vals = [w for v in vars(st).values() for w in (v if isinstance(v, tuple) else (v,))]
    return sum(v.nbytes for v in vals if isinstance(v, np.ndarray))


def check_termination(step: float, previous: float | None, tol: float) -> int:
    """Status after an accepted undamped step whose largest increment is ``step`` conditional
    standard deviations (|Δx_i| √N_ii): 1 below ``tol``, 2 at round-off (below
    :data:`ROUNDOFF_STEP` and no longer shrinking by half), else 0 (go on)."""
    if step < tol:
        return 1
    if previous is not None and step < ROUNDOFF_STEP and step > 0.5 * previous:
        return 2
    return 0


def _replan(problem, x, A, P, free, eliminate):
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


def _far_columns(problem, x, cols) -> np.ndarray:
    """Mask over parameter indices ``cols``: coordinates of far points (:func:`baarda.datum.far_points`)."""
    far = datum_mod.far_points(problem, x)
    pt = problem.params.point[cols]
    return (pt >= 0) & (problem.params.kind[cols] == "k") & far[np.maximum(pt, 0)]


def _gradient_small(g: np.ndarray, diagN: np.ndarray, cost: float) -> bool:
    """Gradient tolerance: max |g_i| / √N_ii ≤ :data:`GRADIENT_TOL` · √(vᵀPv) (the scaled
    gradient of Ceres' test, unit-free; at the fixed point it is round-off)."""
    d = np.sqrt(np.maximum(diagN, 1e-300))
    return float(np.abs(g / d).max(initial=0.0)) <= GRADIENT_TOL * np.sqrt(max(cost, 1e-300))


def _factor(st, Ar, P, labels, backend, lam, problem, plan):
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
        if backend != "numpy" and schur.StepFactor.applicable(st, P):
            return schur.StepFactor(st, Ar, P, damping=damping)
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
        undetermined = [err.unknown if err.unknown is not None else str(err)]
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

