"""Misidentified and exchanged points in one image (F80 §7.1), tested beyond the linear range.

F80 §7.1 counts "misidentification of groups of points, exchange of points" among the gross errors
a hypothesis H tests, "as long as the gross errors are not too large, because the tests are
developed within a linear functional model". The hypothesis (:func:`baarda.stats.hypotheses.h_exchanged`):
point a was measured where point b is imaged, so its measurement in image i is off by
e_a = p_b − p_a (p the image positions of the points); in an *exchange* b was measured at a as well,
e_b = p_a − p_b. With one factor s (0: nothing wrong, 1: the full exchange)

    E(l) = f(x) + h(x) s,   h = (… p_b − p_a … p_a − p_b …)ᵀ,        (F80 eq. 5 with H = h, q = 1)

which is exact in s for fixed x: the rows of a model (1 − s) p_a + s p_b. The linear test (F80
eq. 10-12) takes h at the adjustment and gives ∇ŝ and T. Two things can go wrong:

- h ∈ range(A) (W_s = hᵀP C_vv P h = 0, q = 0): the displacement is absorbed by the unknowns — for
  points seen in two images only, a displacement along the base changes only their heights; two
  points placed symmetrically in an image of a flat, regular block can be exchanged by a change of
  orientation and heights. No test can see the exchange; :class:`ExchangeTest` says so instead of
  returning a test.
- the exchange is a large error: points tens of millimetres apart are ~10⁴ σ, far beyond the
  "small" gross errors (< 50 σ, R84 §6) for which the adjustment with the error stays in the linear
  range. Then the alternative is evaluated exactly: the adjustment is repeated with the exchange
  undone (the two measurements swapped back), Ω1 = vᵀPv there, and the model is linearised again
  at that solution (test T1, ∇ŝ1 of the same hypothesis, which now undoes the swap). The extended
  model's statistic T = Ω0 − min_s Ω(s) (F80 eq. 12 at its solution) is then max(T_lin,
  Ω0 − Ω1 + T1), with ŝ = 0 + ∇ŝ or 1 − ∇ŝ1 from the branch that attains it — the step from s = 1
  only where it stays in its own linear range (|∇ŝ1| × size ≤ 50 σ), else Ω0 − Ω1 alone (exact at
  s = 1). Where the swapped-back block cannot be adjusted or tested (a 2-ray point left
  undetermined) the linear test is the result, said so.
- a one-sided misidentification beyond the linear range: the refit leaves the measurement of a out;
  s is not identifiable there and D = Ω0 − Ω1 is the 2-D deletion test of a's measurement (χ²(2)),
  reported beside the linear test, which stays the decision on s (q = 1).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..adjust import adjust
from ..errors import BaardaError
from ..model.bundle import image_rows
from ..model.problem import subset
from .hypotheses import HypothesisTest, h_exchanged, test
from .reliability import policy_of

#: errors up to this many σ are "small" (R84 §6): the linearised test is trusted
LINEAR_LIMIT_SIGMA = 50.0


@dataclass(frozen=True, eq=False)
class ExchangeTest:
    """Test of a misidentification / exchange of ``point_a`` and ``point_b`` in ``image``.

    ``linear``: F80 eq. 10-12 at the adjustment (None when the hypothesis is not testable, q = 0);
    ``size_sigma``: the hypothesised error, max_i |h_i| / σ_i over its rows; ``refit``: the
    adjustment with the exchange undone (only beyond :data:`LINEAR_LIMIT_SIGMA`), ``omega0``,
    ``omega1``: vᵀPv (σ0 absorbed) without and with the exchange undone; ``T``, ``s_hat``: the
    statistic and the estimated factor of the iterated test (module docstring); ``critical``: the
    χ²(1) critical value of the policy (q = 1); ``message``: what was done and why.
    """

    image: str
    point_a: str
    point_b: str
    both: bool
    linear: HypothesisTest | None
    size_sigma: float
    testable: bool
    refit: object = None
    omega0: float = float("nan")
    omega1: float = float("nan")
    T1: float = float("nan")
    T: float = float("nan")
    s_hat: float = float("nan")
    critical: float = float("nan")
    message: str = ""

    @property
    def iterated(self) -> bool:
        return self.refit is not None

    @property
    def rejected(self) -> bool:
        """H0 (no exchange) rejected: T above the critical value of the q = 1 test."""
        return bool(self.testable and self.T > self.critical)

    def as_dict(self) -> dict:
        """JSON-ready: quantities not computed (NaN) are None."""
        d = {"image": self.image, "point_a": self.point_a, "point_b": self.point_b,
                "exchange": self.both, "testable": self.testable, "size_sigma": self.size_sigma,
                "linear_range": self.size_sigma <= LINEAR_LIMIT_SIGMA, "iterated": self.iterated,
                "T": self.T, "critical_T": self.critical, "rejected": self.rejected, "s_hat": self.s_hat,
                "T_linear": self.linear.T if self.linear is not None else None,
                "nabla_linear": float(self.linear.nabla[0]) if self.linear is not None else None,
                "omega0": self.omega0, "omega1": self.omega1, "T1": self.T1, "message": self.message}
        return {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in d.items()}


def _sigma(cov, rows) -> np.ndarray:
    """σ_i = √C_ii of the observations ``rows`` (from their covariance clusters)."""
    out = []
    for i in rows.tolist():
        c = int(cov.cluster[i])
        k = int(np.flatnonzero(np.asarray(cov.members[c]) == i)[0])
        out.append(cov.blocks[c][k, k])
    return np.sqrt(np.asarray(out))


def _undone(adj, ra, rb, both: bool):
    """The problem with the exchange undone: measurements of a and b swapped back in the image,
    or (one-sided) the measurement of a left out."""
    p = adj.problem
    if both:
        l = p.l.copy()
        l[ra], l[rb] = p.l[rb], p.l[ra]
        return dataclasses.replace(p, l=l)
    return subset(p, np.setdiff1d(np.arange(p.n), ra))


def _refit(problem1, adj):
    """Adjust ``problem1`` (the exchange undone) from the solution of ``adj`` where it converged,
    else — or where that start fails (a point the exchange drove towards infinity stays there:
    a local defect) — from the problem's own approximations. Returns (adjustment or None,
    converged, why not)."""
    why = "did not converge"
    for x0 in ((adj.x, None) if adj.converged else (None,)):
        try:
            adj1 = adjust(problem1, adj.options, x0=x0)
        except BaardaError as err:
            why = str(err)
            continue
        if adj1.converged:
            return adj1, True, ""
        why = getattr(adj1, "termination", "") or "did not converge"
    return None, False, why


def _far_from_one(test: ExchangeTest) -> ExchangeTest:
    """Add to the message of a rejected test whose ŝ is far from 1 that the data show an error in
    these measurements, but not this exchange."""
    if test.rejected and test.size_sigma > LINEAR_LIMIT_SIGMA and abs(test.s_hat - 1.0) > 0.5:
        return dataclasses.replace(test, message=test.message + (
            f"; the test rejects, but ŝ = {test.s_hat:.3g} is far from 1 (the full exchange): the data show a "
            "smaller error in these measurements, not this exchange"))
    return test


def exchange_test(adj, image: str, point_a: str, point_b: str, both: bool = True,
                  policy=None) -> ExchangeTest:
    """Test the misidentification or exchange of two points in one image (F80 §7.1, eq. 10-12).

    Linear (F80 eq. 10-12) where the hypothesised error is small (below
    :data:`LINEAR_LIMIT_SIGMA` σ, R84 §6), iterated through a refit with the exchange undone where
    it is not (module docstring); q = 0 said, not tested.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment of a bundle block.
    image, point_a, point_b : str
        Image id and the ids of the two points.
    both : bool
        An exchange (both measurements swapped) rather than a misidentification of a alone.
    policy : baarda.stats.policy.TestPolicy, optional
        Gives the critical value (default :func:`~baarda.stats.reliability.policy_of` ``(adj)``).

    Returns
    -------
    ExchangeTest
        T, ŝ, the hypothesised error in multiples of σ and the critical value (dimensionless);
        Ω0, Ω1 (vᵀPv, σ0 absorbed, dimensionless).
    """
    policy = policy_of(adj) if policy is None else policy
    ra, rb = image_rows(adj.problem, image, point_a), image_rows(adj.problem, image, point_b)
    H = h_exchanged(adj, image, point_a, point_b, both=both)
    rows = H.indices
    size = float(np.max(np.abs(H.data) / _sigma(adj.problem.cov, rows))) if rows.size else 0.0
    crit = policy.critical_T(1)
    label = f"{'exchange' if both else 'misidentification'} {point_a}/{point_b} in {image}"
    common = dict(image=image, point_a=point_a, point_b=point_b, both=both, size_sigma=size, critical=crit)
    try:
        h = test(adj, H, label=label, policy=policy)
    except BaardaError as err:           # a diverged adjustment (the exchange itself can cause it)
        h, failed = None, f"no linear test at this solution ({err})"
    else:
        failed = "" if adj.converged else "the adjustment did not converge"
    if h is not None and h.q == 0:
        r = adj.r[rows]
        return ExchangeTest(linear=None, testable=False, message=(
            f"not testable (q = 0): the linearised displacement of {point_a}/{point_b} in image {image} lies in "
            "the column space of A (hᵀP C_vv P h = 0) — a change of the unknowns (the image's orientation, the "
            "points' coordinates: e.g. the height of a point seen in two images takes up a displacement along the "
            f"base) reproduces it, no residual shows it and no test can detect it (redundancy numbers of its rows "
            f"{', '.join(f'{x:.2g}' for x in r)})"), **common)
    nabla = float(h.nabla[0]) if h is not None else float("nan")
    T_lin = h.T if h is not None else float("nan")
    if size <= LINEAR_LIMIT_SIGMA and not failed:
        return ExchangeTest(linear=h, testable=True, T=h.T, s_hat=nabla, omega0=adj.vPv, message=(
            f"linear test (F80 eq. 12): the hypothesised error is {size:.3g} σ, within the linear range "
            f"(≤ {LINEAR_LIMIT_SIGMA:g} σ, R84 §6)"), **common)
    why_iterate = failed or f"the hypothesised error is {size:.3g} σ, beyond the linear range (> {LINEAR_LIMIT_SIGMA:g} σ, R84 §6)"
    problem1 = _undone(adj, ra, rb, both)
    adj1, ok, why = _refit(problem1, adj)
    if not ok:
        return _far_from_one(ExchangeTest(linear=h, testable=h is not None, T=T_lin, s_hat=nabla, omega0=adj.vPv,
                                          message=(f"{why_iterate}; the adjustment with "
                                                   f"{'the exchange undone' if both else f'the measurement of {point_a} left out'}"
                                                   f" failed ({why}): only the linear test, which may misjudge so "
                                                   "large an error"), **common))
    what = "swapped back" if both else f"of {point_a} left out"
    if not both:
        # a's measurement left out: the refit has no measurement whose factor s could be estimated, and
        # D = Ω0 − Ω1 is the deletion statistic of a's image point — the 2-D test of that measurement
        # (F80 eq. 12 with q = 2, exact for a linear model), not a test of s. The decision on s stays
        # the linear test's (q = 1); D is reported with its own χ²(2) critical value.
        D = adj.vPv - adj1.vPv
        crit2 = policy.critical_T(2)
        return _far_from_one(ExchangeTest(linear=h, testable=True, refit=adj1, omega0=adj.vPv, omega1=adj1.vPv,
                                          T=T_lin, s_hat=nabla, message=(
                                              f"{why_iterate}: readjusted with the measurement {what} (vᵀPv "
                                              f"{adj.vPv:.4g} → {adj1.vPv:.4g}): D = Ω0 − Ω1 = {D:.4g} is the 2-D test "
                                              f"of that measurement (critical {crit2:.4g}, q = 2: "
                                              f"{'rejected' if D > crit2 else 'accepted'}); s is not identifiable "
                                              "without it, so T and ŝ are the linear test's (q = 1)"), **common))
    try:
        h1 = test(adj1, h_exchanged(adj1, image, point_a, point_b, both=True), policy=policy)   # s' = 1 − s
    except BaardaError as err:      # the swapped-back block leaves an unknown undetermined (a 2-ray point)
        return _far_from_one(ExchangeTest(linear=h, testable=h is not None, T=T_lin, s_hat=nabla, omega0=adj.vPv,
                                          message=(f"{why_iterate}; the adjustment with the exchange undone has no "
                                                   f"test ({err}): only the linear test, which may misjudge so "
                                                   "large an error"), **common))
    T1, d1 = (h1.T, float(h1.nabla[0])) if h1.q else (0.0, 0.0)
    # the linear step from s = 1 holds within its own linear range (R84 §6): a step of |∇ŝ1| full
    # exchanges moves the measurements by |∇ŝ1| × size σ. Beyond it the minimum of Ω(s) is not near
    # s = 1, and only the exact Ω0 − Ω1 (a lower bound of Ω0 − min Ω(s)) is used
    if abs(d1) * size <= LINEAR_LIMIT_SIGMA:
        T_exact, s1, step = adj.vPv - adj1.vPv + T1, 1.0 - d1, "Ω0 − Ω1 + T1"
    else:
        T_exact, s1, step = adj.vPv - adj1.vPv, 1.0, "Ω0 − Ω1 (the step from s = 1 leaves its linear range)"
    T, s = (T_exact, s1) if not T_exact <= T_lin else (T_lin, nabla)
    return _far_from_one(ExchangeTest(linear=h, testable=True, refit=adj1, omega0=adj.vPv, omega1=adj1.vPv, T1=T1, T=T,
                        s_hat=s, message=(
                            f"{why_iterate}: iterated — readjusted with the measurements {what} "
                            f"(vᵀPv {adj.vPv:.4g} → {adj1.vPv:.4g}); T = max(T_linear, {step})"),
                        **common))
