"""Robust estimation by iteratively reweighted least squares (M84 §3.1, R84 §6-8).

The strategy of R84, in three steps:

1. **Robust start (R84 §6, §8).** Large errors "change the geometry of the block severely and
   cause worse convergence or even divergence ... the adjustment must be stopped before
   reaching the point of convergence". So they are met before the first step: the first weight
   factors are Huber's function of the misclosures at the approximate values,
   u_i = |l_i − f_i(x0)| / σ_i; and while the geometry settles, the weights follow every single
   Gauss-Newton step (Huber's convex function) instead of converged adjustments, until the
   weights change by less than ``HUBER_START_TOL`` and the step is below ``START_STEP`` (:mod:`baarda.stats.irls`)
   conditional σ. With ``r84`` moreover, as "medium-sized gross errors and all the more large
   gross errors ... are independent from the a priori weights", the photogrammetric
   observations (image coordinates) start with the weight 1 and the non-photogrammetric ones
   (control, coordinates) with 1/100, in baarda as factors s_i on the a priori weights p_i.
   "This starting weight tends to the introduced specific a priori weight in dependency on the
   value of σ̂0 by a weight function": here s_i = s_i,start^(1 − g), g = f(z) the Danish
   function of the global test's normal score z = (Ω/σ0² − r) / √(2r) (Ω/σ0² ~ χ²(r) under H0,
   F80 §4.1), Ω of the current reweighted fit, g the largest value so far (the weights tend one
   way only). While gross errors inflate Ω, g ≈ 0 and the start weights hold; once the
   reweighting has taken them out, z ≤ 3, g = 1 and every observation is back at its a priori
   weight. (``huber`` and ``danish`` keep s_i = 1.)
2. **Reweighting (M84 §3.1, R84 §7).** Each iteration adjusts with weights p_i s_i f_i, f a
   weight function of the normalised residual u_i = |v_i| / (σ_i √r_i) of the previous fit,
   σ_i = the a priori σ at the current start factor (σ_i,0/√s_i) and r_i the local redundancy
   of that fit (at least 0.1; R84 §7 "the consideration of the local redundancy (formula 2)"):
   for a 2 × 2 or 3 × 3 cluster the largest member's u, so that a cluster keeps its covariance
   shape. Until no weight factor changes by more than ``tol``. Weight functions:

   - ``huber``:   f(u) = 1 for u ≤ k, k/u above (k = 2);
   - ``danish``:  f(u) = 1 for u ≤ c, exp(1 − (u/c)²) above (c = 3) — the Danish method of
     Krarup and Kubik in the exponential form of Kubik, Weng & Frederiksen, after the Huber
     start of step 1 (from a fit that a large error has distorted, a redescending function
     would reject the error's good neighbours with it);
   - ``r84``:     the Danish function with the start weights of step 1.

   A weight factor is floored at :data:`baarda.stats.irls.WEIGHT_FLOOR`. Where the down-weighted observations
   leave unknowns undetermined (the normal equations singular: all rays and the control of a
   point down-weighted, which is not a datum defect of the block), the floor of those points'
   observations is raised tenfold until the system is regular, and the raise is reported
   (``floored``) instead of an error.
3. **Least squares and data snooping on the cleaned set (M84 §3.2, R84 §7).** Robust
   estimation gives no reliability measures and no test of its own: its candidates (clusters
   with u above the w-test's critical value in the robust fit) are left out and the rest
   adjusted by least squares. Each candidate is then tested against that fit: its predicted
   error ∇̂ = l_c − f_c(x̂) (observed minus computed, nonlinear) with
   T = ∇̂ᵀ W_s ∇̂, W_s = Hᵀ P C_vv P H of the adjustment that includes it (F80 eq. 10-12, H the
   selection of the cluster; W_s = (C_c + A_c Q_x̂x̂ A_cᵀ)⁻¹ of the fit without it), and each
   member's w = (W_s ∇̂)_i / √(W_s)_ii. A candidate with T below the critical value of its
   q-dimensional test and every |w| below the w-test's is readmitted (the robust fit had
   inflated its residual). Iterative data snooping on the cleaned set, over the same clusters
   and with the same two tests (:func:`snoop_clusters`), finds what the robust fit missed (small errors whose weight
   the function hardly changed); readmission and snooping are repeated until neither changes
   the set (at most ``MAX_CONFIRM_PASSES``). A point keeps its control or two rays: of its
   left-out clusters the least suspect go back in rather than leave it undetermined. A cluster
   snooping rejects but cannot leave out for that reason (a ray of a 2-ray point) is tested in the
   final fit that includes it (F80 eq. 10-12) and reported as a suspect kept in, inseparable from
   the point's other ray(s) (it was "readmitted", and an error of 40σ at a 2-ray point missed). Where
   such an error is beyond the linear range (> 50σ, R84 §6) it would distort the fit it stays in
   (σ̂0 of 8.6-10.8 with a 300σ-1000σ error at a 2-ray point), and it cannot be located between the
   point's rays: the point itself is left out (R84 §7), all its rays and its coordinates
   (:func:`_leave_points_out`); the other candidates, judged in the distorted fit, are tested again
   against the fit without the point (readmitted where they pass), the rest snooped again, the
   suspect tested again in that fit with the point's rays back in (:func:`_retest`), and it says
   that its point was left out. The
   suspects are reported with their tests against the final fit.

Separability (M84 §3.3, F80 §7.4): where two hypotheses change the observations alike — the two
rays of a 2-ray point, a point-transfer error between two strips of three images each, which
the data cannot tell from the opposite transfer — the suspect may be either one.

Each confirmed error is classed after R84 §6 by its size, the predicted error ∇̂ of step 3 (not
the residual of a fit it has distorted): its size in σ, √(∇̂ᵀ C_c⁻¹ ∇̂) (|∇̂|/σ for one
observation or an isotropic cluster), and in base lengths |∇̂| / b — b = B c / H the image base
for image observations (image units), B the air base for control (metres). Below 4σ part of the
random errors; small 4σ-50σ; medium 50σ up to ``medium_base`` (2.5, R84: "2-3") base lengths;
large above.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..adjust import Options, adjust
from ..errors import BaardaError, DatumDefectError, SingularError
from ..model.problem import subset
from . import hypotheses, separability
from .reliability import policy_of, reliability_of
from .irls import NON_PHOTOGRAMMETRIC, irls, per_observation, residuals_at
from .weights import error_class

METHODS = ("huber", "danish", "r84")
#: how often a step-3 pass (readmission, data snooping) is repeated at most
MAX_CONFIRM_PASSES = 3
#: an alternative at the same point replaces a suspect only where its test's ratio to the critical
#: value is larger by more than this (relative): the w-tests of twins along a shared direction
#: are equal but for round-off and the curvature of the model (F80 §7.4), and the robust step's
#: choice stays among them
ATTRIBUTION_MARGIN = 0.01
#: an alternative is named inseparable from a suspect where their tests share a direction and at
#: least this part of the suspect's statistic lies along it (the error is seen there alike)
SHARED_PART = 0.5
#: R84 §6: errors up to this many σ are "small", within the tests' linear range
SMALL_LIMIT = 50.0


@dataclass(frozen=True, eq=False)
class RobustResult:
    """The robust fit (step 2), the confirmed suspects and the final least squares (step 3)."""

    method: str
    weights: np.ndarray          # final weight factor s_i f_i per observation (0..1) of the robust fit
    adjustment: object           # the last reweighted adjustment
    iterations: int
    converged: bool
    suspects: list               # dicts: index, members, kind, ids, size_sigma, size_base, class, T, ...
    final: object = None         # least squares without the suspects (data snooping's final fit)
    history: tuple = ()          # max weight change per iteration
    floored: tuple = ()          # dicts: points whose observations' weight floor was raised
    candidates: int = 0          # clusters the robust fit put forward (before step 3)
    readmitted: tuple = ()       # candidates the least-squares test cleared (observation indices)

    @property
    def cleaned(self) -> dict | None:
        """The least-squares fit without the suspects judged by the global test (F80 §4.1): σ̂0, the
        test's verdict, ``complete`` — False where that fit still fails high, i.e. the robust step
        did not take out every gross error (or σ0 a priori is too optimistic) — and ``reason``, why
        not (None when complete). None without a final fit.

        The reasons, most specific first: a suspect beyond R84 §6's small errors (> 50σ) kept in the
        adjustment because leaving it out would leave its point undetermined (a ray of a 2-ray
        point: the error cannot be told from the other ray's, F80 §7.4, and it distorts the fit it
        stays in; normally its point is left out instead, :func:`_leave_points_out`, and this is
        said only where the fit without the point is singular); the reweighting not converged; else errors the robust weights and data snooping
        did not find, or σ0 a priori too optimistic."""
        if self.final is None:
            return None
        g = reliability_of(self.final).global_test
        complete = not (g["passed"] is False and g["side"] == "high")
        reason = None
        if not complete:
            held = [sp for sp in self.suspects if sp.get("kept_in") and sp["size_sigma"] > SMALL_LIMIT]
            if held:
                names = ", ".join(" ".join(f"{a}={b}" for a, b in sp["ids"].items() if a != "component")
                                  for sp in held)
                reason = (f"an error beyond the linear range (> {SMALL_LIMIT:.0f}σ, R84 §6) stays in the "
                          f"adjustment at {names}: leaving it out would leave its point undetermined and "
                          f"its point's rays cannot be told apart (F80 §7.4); leave the point out or "
                          f"measure it in more images")
            elif not self.converged:
                reason = "the robust reweighting did not converge"
            else:
                reason = ("the least squares without the suspects still fails the global test: gross errors "
                          "remain that neither the robust weights nor data snooping isolate, or σ0 a priori "
                          "is too optimistic")
        return {"sigma0_aposteriori": float(self.final.sigma0_post), "global_test_passed": g["passed"],
                "complete": complete, "reason": reason}

    def summary(self) -> dict:
        """For the document's ``summary.robust``: the method, how many suspects, ``cleaned`` (the
        least squares without them passes the global test, or fails it low; None without that fit)
        and ``reason`` when it does not (:attr:`cleaned`)."""
        c = self.cleaned
        return {"method": self.method, "suspects": len(self.suspects),
                "cleaned": None if c is None else c["complete"],
                "reason": None if c is None else c["reason"]}

    def as_dict(self) -> dict:
        return {"method": self.method, "iterations": self.iterations, "converged": self.converged,
                "suspects": self.suspects, "candidates": self.candidates,
                "readmitted": [list(m) for m in self.readmitted], "floored": list(self.floored),
                "cleaned": self.cleaned}


def _bases(problem) -> tuple[float | None, float | None]:
    """(b, B): the image base b = B c / H (image units) and the air base B (object units, the
    median distance of consecutive images of a strip), from the block's geometry; (None, None)
    where the block has no flying height or principal distance (SfM, networks)."""
    geo = problem.geometry
    if geo is None or not geo.images or geo.flying_height is None or geo.camera is None or geo.camera.c is None:
        return None, None
    by_strip: dict = {}
    for im in geo.images:
        by_strip.setdefault(im.strip, []).append((im.X0, im.Y0))
    gaps = [np.hypot(*np.diff(np.array(v), axis=0).T) for v in by_strip.values() if len(v) > 1]
    if not gaps:
        return None, None
    B = float(np.median(np.concatenate(gaps)))
    return B * geo.camera.c / geo.flying_height, B


def _rows_in(keep: np.ndarray, rows) -> np.ndarray:
    """Positions of the original observations ``rows`` in the subset ``keep`` (sorted)."""
    return np.searchsorted(keep, np.asarray(rows))


def cluster_tests(adj) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """F80 eq. 12 for every covariance cluster of ``adj``, and the largest w² of its members (F80 §4.2).

    H is the cluster's selection (an image point, a control point, a single observation):
    T = gᵀ W_s⁺ g, g = (Pv)_c, W_s = P_c C_vv,c P_c, q = rank W_s; w² = g_i² / (W_s)_ii is
    Baarda's w for correlated observations (B68). From the cluster blocks of C_vv.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.

    Returns
    -------
    first : numpy.ndarray
        First member (observation index) of each cluster, sorted.
    T : numpy.ndarray
        T per cluster, dimensionless.
    q : numpy.ndarray
        Rank of each cluster's test.
    w2 : numpy.ndarray
        Largest w² per cluster, dimensionless.
    """
    first, T, q, w2 = [], [], [], []
    Pv = adj.Pv
    for members, C, Cvv in adj.cluster_cvv():
        Pc = np.linalg.inv(C)
        W = Pc @ Cvv @ Pc
        W = 0.5 * (W + np.swapaxes(W, 1, 2))
        lam, V = np.linalg.eigh(W)
        tol = 1e-10 * np.maximum(np.abs(np.diagonal(Pc, axis1=1, axis2=2)).max(axis=1), 1e-300)
        pos, Tj = hypotheses.counted_directions(lam, V, Pv[members], tol, adj.vPv)   # q = rank W_s
        T.append(Tj.sum(axis=1))
        q.append(pos.sum(axis=1))
        first.append(members[:, 0])
        Wd = np.diagonal(W, axis1=1, axis2=2)
        seen = Wd > tol[:, None]              # (W_s)_ii at round-off: no w (the division would overflow)
        w2.append(np.divide(Pv[members] ** 2, Wd, out=np.zeros_like(Wd), where=seen).max(axis=1))
    first, T, q, w2 = np.concatenate(first), np.concatenate(T), np.concatenate(q), np.concatenate(w2)
    order = np.argsort(first)
    return first[order], T[order], q[order], w2[order]


def _test_cluster(problem, members, clean, keep, options):
    """F80 eq. 10-12 for cluster ``members`` left out of ``clean`` (the least-squares fit of the
    observations ``keep``): the predicted error ∇̂ = l − f(x̂) and T = ∇̂ᵀ W_s ∇̂ with W_s of the
    adjustment including it. W_s depends on the geometry only: it is taken at x̂ from the
    adjustment with the cluster's observations set to their computed values f(x̂) (x̂ is then
    its solution: one step, of zero length). Rejected where T exceeds its critical value or a
    member's w = (W_s ∇̂)_i / √(W_s)_ii exceeds the w-test's, as in :func:`snoop_clusters`.
    Returns (∇̂, T, q, critical T, rejected). Where that adjustment's normal matrix is singular at
    x̂ (a fit distorted by large errors, R84 §6, ending at a degenerate point) the test does not
    exist: T and the critical value are NaN, q = 0, and the cluster stays out (rejected) — put
    forward by the robust weights, it cannot be cleared by a test that cannot be made."""
    v = residuals_at(problem, clean.x)[members]
    nabla = -v
    with_c = np.union1d(keep, members)
    l_at = problem.l.copy()
    l_at[members] = l_at[members] + v
    one_step = dataclasses.replace(options, max_iter=1)
    try:
        adj_c = adjust(subset(dataclasses.replace(problem, l=l_at), with_c), one_step, x0=clean.x)
        h = hypotheses.test(adj_c, hypotheses.selection(adj_c.n, _rows_in(with_c, members)))
    except (DatumDefectError, SingularError):
        return nabla, float("nan"), 0, float("nan"), True
    T = float(nabla @ h.W @ nabla)
    Wn = h.W @ nabla
    d = np.diag(h.W)
    w2 = float(np.max(np.where(d > 0, Wn ** 2 / np.maximum(d, 1e-300), 0.0)))
    crit = float(h.critical_T)
    rejected = T > crit or w2 > float(policy_of(adj_c).critical_T(1))
    return nabla, T, h.q, crit, rejected


def _smallest_critical(adj, q: int) -> float:
    """The smallest critical value of a test of up to ``q`` dimensions under ``adj``'s policy."""
    return min(float(policy_of(adj).critical_T(j)) for j in range(1, q + 1))


def _fit(problem, keep, options, x0):
    return adjust(subset(problem, keep), options, x0=x0)


def _fit_regular(problem, keep, options, x0):
    """:func:`_fit`, its normal matrix factorised at the solution: SingularError where the
    observations ``keep`` leave part of the model undetermined there (a fit that ends at a
    singular point — an image left with too few points, a point drifting to infinity — raises
    here, not later in its tests)."""
    adj = _fit(problem, keep, options, x0)
    adj.factor                       # noqa: B018 — the factor the tests use; SingularError if there is none
    return adj


def snoop_clusters(problem, keep, options, x0=None, point_of=None, held=None):
    """Iterative data snooping over covariance clusters (M84 §3.1; B68; F80 eq. 12).

    Each image point, control point or single observation is tested as a whole (T of F80 eq. 12
    against T_crit(q)) and per member (Baarda's w against the w-test's critical value); the cluster
    with the largest ratio of statistic to critical value above 1 is left out and the rest
    readjusted, until none is rejected or leaving one out would leave a point undetermined.

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The problem.
    keep : numpy.ndarray
        Indices of the observations to start from.
    options : baarda.adjust.Options
        Adjustment options.
    x0 : numpy.ndarray, optional
        Start values of the parameters (their own units: metres, radians, ...).
    point_of : numpy.ndarray, optional
        Per cluster the object point it observes or holds ("" for others): a point keeps its rays.
    held : list, optional
        Receives the clusters rejected but kept in (their point would be undetermined).

    Returns
    -------
    adj : baarda.result.Adjustment
        The final adjustment.
    keep : numpy.ndarray
        The kept observations.
    removed : list of numpy.ndarray
        The removed clusters' members.
    """
    cluster = problem.cov.cluster
    removed = []
    adj = _fit(problem, keep, options, x0)
    while True:
        first, T, q, w2 = cluster_tests(adj)
        crit = np.array([float(policy_of(adj).critical_T(int(j))) if j > 0 else np.inf for j in q])
        ratio = np.maximum(T / crit, w2 / float(policy_of(adj).critical_T(1)))
        k = int(np.argmax(ratio))
        if ratio[k] <= 1.0:
            return adj, keep, removed
        c = int(cluster[keep[first[k]]])
        m = problem.cov.members[c]
        if point_of is not None and point_of[c]:
            left = [m_ for m_ in removed if point_of[int(cluster[m_[0]])] == point_of[c]] + [m]
            if _determined(problem, left, point_of)[1]:
                if held is not None:           # rejected, but it cannot leave: tested in the fit
                    held.append(np.asarray(m))
                return adj, keep, removed      # the point would be undetermined: stop here
        new_keep = np.setdiff1d(keep, m)
        try:
            adj = _fit_regular(problem, new_keep, options, adj.x)
        except (DatumDefectError, SingularError):
            return adj, keep, removed           # leaving it out would leave the model undetermined
        keep = new_keep
        removed.append(m)


def _point_of(problem) -> np.ndarray:
    """Per covariance cluster: the object point it observes (image point) or holds (control
    point), "" for other observations."""
    out = []
    for m in problem.cov.members:
        d = problem.info.ids[m[0]]
        k = problem.info.kind[m[0]]
        out.append(str(d.get("point", "")) if k.startswith("image-") else
                   str(d.get("id", "")) if k.startswith(NON_PHOTOGRAMMETRIC) else "")
    return np.array(out, dtype=object)


def _determined(problem, out, point_of):
    """Split the left-out clusters ``out`` (most suspect first) into those that may stay out and
    those that must go back: a point keeps its control or at least two rays, else the least
    suspect of its left-out clusters go back in (without them the point is undetermined, and
    nothing could test them)."""
    cluster = problem.cov.cluster
    kinds = problem.info.kind
    cl_out = {int(cluster[m[0]]) for m in out}
    back = []
    for pt in {point_of[c] for c in cl_out} - {""}:
        mine = np.flatnonzero(point_of == pt)
        control_in = any(kinds[problem.cov.members[c][0]].startswith(NON_PHOTOGRAMMETRIC) and c not in cl_out
                         for c in mine)
        rays_in = sum(1 for c in mine if kinds[problem.cov.members[c][0]].startswith("image-") and c not in cl_out)
        if control_in or rays_in >= 2:
            continue
        for m in reversed(out):                        # the least suspect first
            c = int(cluster[m[0]])
            if point_of[c] == pt and kinds[m[0]].startswith("image-") and c in cl_out:
                back.append(c)
                cl_out.discard(c)
                rays_in += 1
                if rays_in >= 2:
                    break
    stay = [m for m in out if int(cluster[m[0]]) not in back]
    return stay, [m for m in out if int(cluster[m[0]]) in back]


def _confirm(problem, candidates, options, x0):
    """Step 3 (module docstring). ``candidates``: clusters (arrays of observation indices) put
    forward by the robust fit, most suspect first. Returns (suspect clusters with their tests,
    the final least squares, readmitted clusters)."""
    out = [np.asarray(m) for m in candidates]
    readmitted = []
    final = None
    point_of = _point_of(problem)
    for _ in range(MAX_CONFIRM_PASSES):
        out, back = _determined(problem, out, point_of)
        readmitted += back
        drop = np.concatenate(out) if out else np.zeros(0, dtype=np.int64)
        keep = np.setdiff1d(np.arange(problem.n), drop)
        while True:
            try:
                if keep.size == 0:
                    raise DatumDefectError(0, [], "every observation is a candidate")
                clean = _fit_regular(problem, keep, options, x0)
                break
            except (DatumDefectError, SingularError):
                if not out:
                    raise
                # leaving all candidates out leaves part of the model undetermined: the least
                # suspect goes back in (it cannot be tested against a fit that does not determine it)
                readmitted.append(out.pop())
                keep = np.union1d(keep, readmitted[-1])
        x0 = clean.x
        v_all = residuals_at(problem, clean.x)
        kept_out, back = [], []
        for m in out:
            # T ≤ ∇̂ᵀ C_c⁻¹ ∇̂ (W_s ≤ C_c⁻¹): a candidate whose bound is below every critical
            # value goes back without a test
            c = int(problem.cov.cluster[m[0]])
            bound = float(v_all[m] @ np.linalg.solve(np.asarray(problem.cov.blocks[c]), v_all[m]))
            if bound <= _smallest_critical(clean, m.size):
                back.append(m)
                continue
            rejected = _test_cluster(problem, m, clean, keep, options)[4]
            (kept_out if rejected else back).append(m)
        readmitted += back
        keep = np.setdiff1d(np.arange(problem.n), np.concatenate(kept_out)) if kept_out else np.arange(problem.n)
        # data snooping on the cleaned set: what the robust weights missed
        held = []
        final, keep, found = snoop_clusters(problem, keep, options, x0, point_of, held)
        out = kept_out + found
        if not found and not back:
            break
        x0 = final.x
    # the cluster snooping rejected but could not leave out (its point would be undetermined):
    # tested in the final fit that includes it (F80 eq. 10-12)
    kept_in = []
    for m in held:
        if not np.isin(m, keep).all():
            continue
        h = hypotheses.test(final, hypotheses.selection(final.n, _rows_in(keep, m)))
        if h.q and h.T > h.critical_T:
            kept_in.append((m, np.asarray(h.nabla, dtype=float), float(h.T), h.q, float(h.critical_T), True,
                            "kept in"))
    gone, final, keep, problem_f = _leave_points_out(problem, kept_in, final, keep, options, point_of)
    if gone:
        # the kept-in error distorted the fit the other candidates were judged in: those whose test
        # passes against the fit without its point go back in (as the readmission above), and
        # without the distortion snooping may find what it hid (M84 §3.1)
        back = [m for m in out if not _test_cluster(problem_f, m, final, keep, options)[4]]
        if back:
            keep2 = np.union1d(keep, np.concatenate(back))
            try:
                final, keep = _fit_regular(problem_f, keep2, options, final.x), keep2
                out = [m for m in out if not any(m is b for b in back)]
                readmitted += back
            except (DatumDefectError, SingularError):
                pass
        final, keep, found = snoop_clusters(problem_f, keep, options, final.x, point_of)
        out = out + found
        kept_in = [e for e in kept_in if not any(e[0] is g[0][0] for g in gone)]
        gone = [(_retest(problem, entry, final, keep, options), alts) for entry, alts in gone]
    tested = [(m, *_test_cluster(problem_f, m, final, keep, options)) for m in out] + kept_in
    tested, final, keep, alternatives = _attribute(problem_f, tested, final, keep, options, point_of)
    for entry, alts in gone:
        tested.append(entry)
        alternatives.append(alts)
    return tested, final, readmitted, alternatives


def _retest(problem, entry, final, keep, options):
    """A left-out point's suspect (``entry`` of :func:`_leave_points_out`) tested again (F80 eq.
    10-12) in the fit with the point's rays back in, from the fit without it (the rest of the block
    no longer distorted by the other candidates): ∇̂, T, q and the critical value updated; as it
    was where that fit is singular."""
    m, rows = entry[0], entry[8]
    with_p = np.union1d(keep, rows)
    try:
        fit = _fit_regular(problem, with_p, options, final.x)
        h = hypotheses.test(fit, hypotheses.selection(fit.n, _rows_in(with_p, m)))
    except (BaardaError, np.linalg.LinAlgError):
        return entry
    if not h.q:
        return entry
    return (m, np.asarray(h.nabla, dtype=float), float(h.T), h.q, float(h.critical_T), *entry[5:])


def _hold_points(problem, points):
    """``problem`` with the coordinates of the object points ``points`` (ids) held at their values:
    a point whose observations are all left out has no unknowns left to determine (its coordinates
    would make the normal matrix singular), as :mod:`baarda.defects` leaves a local defect out."""
    params = problem.params
    pts = set(points)
    mine = np.array([params.kind[i] == "k" and params.labels[i].rsplit(".", 1)[0] in pts
                     for i in range(params.size)], dtype=bool)
    return dataclasses.replace(problem, params=dataclasses.replace(params, fixed=params.fixed | mine))


def _leave_points_out(problem, kept_in, final, keep, options, point_of):
    """R84 §7 at a point that leaving the suspect out would leave undetermined (a 2-ray point: one
    ray left cannot determine it). A suspect kept in there whose error is beyond the tests' linear
    range (> :data:`SMALL_LIMIT` σ, R84 §6) distorts the fit it stays in, and cannot be located
    between the point's rays (their tests coincide, F80 §7.4): the POINT is left out — all its image
    observations, its coordinates held (no unknowns left to it) — and the rest adjusted again.
    A point with control is not met here (its control determines it without the suspect ray).

    Returns (gone: [(entry, alternatives)] of the points left out, final, keep, the problem with
    their coordinates held). Where the fit without a point is singular (the point carried an image
    or the datum), it stays in (nothing changes)."""
    gone, pts, rows = [], [], []
    for entry in kept_in:
        m, nabla = entry[0], entry[1]
        c = int(problem.cov.cluster[m[0]])
        pt = point_of[c]
        size = float(np.sqrt(max(nabla @ np.linalg.solve(np.asarray(problem.cov.blocks[c]), nabla), 0.0)))
        if not pt or pt in pts or size <= SMALL_LIMIT:
            continue
        mine = [problem.cov.members[j] for j in np.flatnonzero(point_of == pt)]
        if any(problem.info.kind[mm[0]].startswith(NON_PHOTOGRAMMETRIC) for mm in mine):
            continue
        # the other rays, named as inseparable, from the fit that includes them all
        _, _, _, alts = _attribute(problem, [entry], final, keep, options, point_of)
        pts.append(pt)
        rows.append(np.concatenate(mine))
        gone.append(((m, *entry[1:6], "point out", pt, np.sort(np.concatenate(mine))), alts[0]))
    if not gone:
        return [], final, keep, problem
    held = _hold_points(problem, pts)
    keep2 = np.setdiff1d(keep, np.concatenate(rows))
    try:
        final2 = _fit_regular(held, keep2, options, final.x)
    except (DatumDefectError, SingularError):
        return [], final, keep, problem
    return gone, final2, keep2, held


def _ratio(h, adj) -> float:
    """A test's statistic over its critical value, the larger of T/T_crit(q) and the largest
    member's w²/T_crit(1) (the two tests of :func:`snoop_clusters`); 0 for an untestable one."""
    if not h.q:
        return 0.0
    d = np.diag(h.W)
    Wn = h.W @ h.nabla
    w2 = float(np.max(np.where(d > 0, Wn ** 2 / np.maximum(d, 1e-300), 0.0)))
    return max(float(h.T) / float(h.critical_T), w2 / float(policy_of(adj).critical_T(1)))


def _attribute(problem, tested, final, keep, options, point_of):
    """Attribution among the clusters of one object point (F80 §7.4, M84 §3.1, §3.3).

    A suspect left out by the robust step was confirmed by its own test against the fit without
    it; an error in another image (or the control) of the same point may pass that test too,
    their statistics being correlated. So each suspect at a point is tested with its alternatives
    — the point's other image points and control still in the adjustment — in one adjustment
    that includes them all (data snooping's rule: the alternative whose statistic is largest
    against its critical value). Where an alternative's ratio is the larger (by more than
    :data:`ATTRIBUTION_MARGIN`) and the suspect's error is small (R84 §6, at most 50σ: a larger
    one distorts the fit that includes it beyond the tests' linear range), it becomes the
    suspect (the first goes back in) if the point stays determined and its own test, against the
    fit without it, rejects it. The alternatives whose test space shares a direction with the
    suspect's (largest canonical correlation ≥ :data:`~baarda.stats.separability.THRESHOLD`) along
    which lies at least :data:`SHARED_PART` of the suspect's statistic are returned with it: along
    that direction the data cannot tell them apart, and the error lies mostly there.

    Returns (tested, final, keep, alternatives per tested entry)."""
    cluster = problem.cov.cluster
    members = problem.cov.members
    alternatives = []
    out = list(tested)
    for k, entry in enumerate(tested):
        m, kept_in = entry[0], len(entry) > 6
        c = int(cluster[m[0]])
        pt = point_of[c]
        alts = []
        if pt:
            siblings = [members[j] for j in np.flatnonzero(point_of == pt)
                        if j != c and np.isin(members[j], keep).all()]
            with_m = keep if kept_in else np.union1d(keep, m)
            C = np.asarray(problem.cov.blocks[c])
            small = float(entry[1] @ np.linalg.solve(C, entry[1])) <= SMALL_LIMIT ** 2      # R84 §6: linear range
            try:
                if kept_in:
                    fit = final
                elif small:
                    fit = _fit(problem, with_m, options, final.x)
                else:
                    # a larger error would distort the fit that includes it: the geometry at x̂ with
                    # the cluster at its computed values (as _test_cluster), its signature W ∇̂
                    l_at = problem.l.copy()
                    l_at[m] = l_at[m] - entry[1]
                    fit = adjust(subset(dataclasses.replace(problem, l=l_at), with_m),
                                 dataclasses.replace(options, max_iter=1), x0=final.x)
                tests = [hypotheses.test(fit, hypotheses.selection(fit.n, _rows_in(with_m, mm)))
                         for mm in [m, *siblings]]
            except (BaardaError, np.linalg.LinAlgError):
                alternatives.append(alts)
                continue
            ratios = [_ratio(h, fit) for h in tests]
            g1 = None if (kept_in or small) else tests[0].W @ np.asarray(entry[1], dtype=float)
            for mm, h in zip(siblings, tests[1:]):
                if not (h.q and tests[0].q):
                    continue
                cc, part = separability.shared_part(
                    fit, hypotheses.selection(fit.n, _rows_in(with_m, m)),
                    hypotheses.selection(fit.n, _rows_in(with_m, mm)), g1=g1)
                if cc.size and cc[0] >= separability.THRESHOLD and part >= SHARED_PART:
                    alts.append({"members": [int(j) for j in mm], "largest": float(cc[0]),
                                 "smallest": float(cc[-1])})
            best = int(np.argmax(ratios))
            if best and small and not kept_in and ratios[best] > ratios[0] * (1 + ATTRIBUTION_MARGIN):
                other = siblings[best - 1]
                keep2 = np.setdiff1d(with_m, other)
                stay, back = _determined(problem, [other], point_of)
                if stay and not back:
                    try:
                        fit2 = _fit(problem, keep2, options, fit.x)
                        new = _test_cluster(problem, other, fit2, keep2, options)
                    except (BaardaError, np.linalg.LinAlgError):
                        new = None
                    if new is not None and new[4]:
                        out[k] = (other, *new)
                        alts = [{"members": [int(j) for j in m], "largest": a["largest"], "smallest": a["smallest"]}
                                if a["members"] == [int(j) for j in other] else a for a in alts]
                        final, keep = fit2, keep2
        alternatives.append(alts)
    return out, final, keep, alternatives


def estimate(problem, method: str = "r84", options: Options | None = None, tol: float = 1e-3,
             max_iter: int = 100, min_size: float = 4.0, medium_base: float = 2.5,
             k: float | None = None) -> RobustResult:
    """Robust estimation with ``method`` (huber, danish, r84): R84's three steps (module docstring).

    Iteratively reweighted least squares (M84 §3.1, R84 §7-8), then least squares and data snooping
    on the cleaned set. Suspects are the clusters that the least-squares test of step 3 confirms, with
    an estimated error of at least ``min_size`` σ (R84 §6: below 4σ errors are random), each with its
    R84 class.

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The problem.
    method : str
        One of :data:`METHODS`.
    options : baarda.adjust.Options, optional
        Adjustment options.
    tol : float
        Largest change of a weight factor at convergence, dimensionless.
    max_iter : int
        Iterations of the reweighting at most.
    min_size : float
        Smallest reported error, multiples of σ.
    medium_base : float
        Upper end of R84's medium class, base lengths.
    k : float, optional
        Threshold of the weight function, dimensionless (default per method: 2 Huber, 3 Danish).

    Returns
    -------
    RobustResult
        Weight factors (dimensionless), the robust and the final adjustment, suspects with ∇̂ in the
        units of the observations and their size in σ and base lengths.

    Raises
    ------
    baarda.errors.BaardaError
        For an unknown ``method``.
    """
    if method not in METHODS:
        raise BaardaError(f"unknown robust method '{method}' (known: {', '.join(METHODS)})")
    options = options or Options()
    adj, f, u_obs, it, converged, history, floored = irls(problem, method, options, tol, max_iter, k)
    members = problem.cov.members
    w_obs = per_observation(f, members, problem.n)
    crit = reliability_of(adj).critical_w
    cand = [(float(u_obs[m].max()), c) for c, m in enumerate(members) if u_obs[m].max() > crit]
    cand.sort(reverse=True)
    candidates = [members[c] for _, c in cand]
    tested, final, readmitted, alternatives = _confirm(problem, candidates, options, adj.x)
    b_img, B = _bases(problem)
    kinds = problem.info.kind
    sigma_c = problem.cov.blocks
    suspects = []
    for (m, nabla, T, q, crit_T, _, *how), alts in zip(tested, alternatives):
        kept_in = bool(how) and how[0] == "kept in"
        c = int(problem.cov.cluster[m[0]])
        C = np.asarray(sigma_c[c])
        size = float(np.sqrt(max(nabla @ np.linalg.solve(C, nabla), 0.0)))
        if size < min_size:
            continue
        kind = kinds[m[0]]
        base = b_img if kind.startswith("image-") else (B if kind.startswith(NON_PHOTOGRAMMETRIC) else None)
        size_base = float(np.linalg.norm(nabla) / base) if base else None
        i = int(m[np.argmax(np.abs(nabla) / np.sqrt(np.diag(C)))])
        suspects.append({"index": i, "members": [int(j) for j in m], "kind": kinds[i],
                         "ids": problem.info.ids[i], "weight": float(w_obs[i]),
                         "residual": float(adj.v[i]), "statistic": float(u_obs[i]),
                         "nabla": [float(v) for v in nabla], "T": T, "q": int(q), "critical_T": crit_T,
                         "size_sigma": size, "size_base": size_base,
                         "class": error_class(size, size_base, medium_base)})
        if alts:
            # F80 §7.4, M84 §3.3: tests sharing a direction with this one (largest canonical correlation)
            suspects[-1]["inseparable_from"] = [
                {"ids": problem.info.ids[int(a["members"][0])], "kind": kinds[int(a["members"][0])],
                 "canonical_correlations": [a["largest"], a["smallest"]]} for a in alts]
        if kept_in:
            suspects[-1]["kept_in"] = True
            suspects[-1]["note"] = ("kept in the adjustment (its point would be undetermined without it) and "
                                    "rejected by its test there (F80 eq. 10-12): ∇̂ is seen only along the "
                                    "directions that test sees, and the error may lie in another ray of the "
                                    "point (inseparable, F80 §7.4)")
        if how and how[0] == "point out":
            n_rays = sum(1 for j in how[2] if kinds[int(j)].startswith("image-")) // max(len(m), 1)
            suspects[-1]["point_left_out"] = str(how[1])
            suspects[-1]["left_out"] = [int(j) for j in how[2]]
            suspects[-1]["note"] = (f"point {how[1]} left out ({n_rays} rays: its error cannot be located "
                                    f"between them, R84 §7); tested in the fit that included it (F80 eq. "
                                    f"10-12), an error beyond the linear range (R84 §6)")
    suspects.sort(key=lambda d: -d["size_sigma"])
    return RobustResult(method, w_obs, adj, it, converged, suspects, final, history, floored,
                        len(candidates), tuple(tuple(int(j) for j in m) for m in readmitted))
