"""Test distributions: critical values, the non-centrality δ0, Baarda's B-method.

F80 §4-§5; M84 §3.1-§3.2; B68 (w); P76 (τ).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from ..lazy import lazy
from ..errors import OptionError

optimize, stats = lazy("scipy.optimize"), lazy("scipy.stats")     # imported when first used (start-up)


def critical_normal(alpha: float) -> float:
    """Two-sided critical value of a standard normal test statistic, Φ⁻¹(1 − α/2) (B68; F80 §4).

    Parameters
    ----------
    alpha : float
        Size of the test, in (0, 1), dimensionless.

    Returns
    -------
    float
        The critical value of |w|, dimensionless.
    """
    return float(stats.norm.isf(alpha / 2.0))


def critical_chi2(alpha: float, q: int) -> float:
    """Critical value χ²_{1−α}(q) of a q-dimensional test statistic T (F80 eq. 12).

    Parameters
    ----------
    alpha : float
        Size of the test, in (0, 1), dimensionless.
    q : int
        Dimension of the test (degrees of freedom).

    Returns
    -------
    float
        The critical value of T, dimensionless.
    """
    return float(stats.chi2.isf(alpha, q))


def critical_f(alpha: float, q: int, dof: float) -> float:
    """Critical value F_{1−α}(q, dof) of R (F80 eq. 12, σ0 estimated).

    Parameters
    ----------
    alpha : float
        Size of the test, in (0, 1), dimensionless.
    q : int
        Dimension of the test (numerator degrees of freedom).
    dof : float
        Denominator degrees of freedom r − q.

    Returns
    -------
    float
        The critical value of R, dimensionless; inf when ``dof`` ≤ 0.
    """
    return float(stats.f.isf(alpha, q, dof)) if dof > 0 else float("inf")


def critical_tau(alpha: float, dof: int) -> float:
    """Critical value of Pope's τ (P76; F80 §4): τ²/r ~ Beta(1/2, (r−1)/2).

    Through t = τ √(r−1) / √(r − τ²) ~ t(r−1): τ_c = √(r t_c² / (r − 1 + t_c²)).

    Parameters
    ----------
    alpha : float
        Size of the two-sided test, in (0, 1), dimensionless.
    dof : int
        Redundancy r.

    Returns
    -------
    float
        The critical value of |τ|, dimensionless; inf when r ≤ 1.
    """
    if dof <= 1:
        return float("inf")
    t = stats.t.isf(alpha / 2.0, dof - 1)
    return float(np.sqrt(dof * t * t / (dof - 1 + t * t)))


@lru_cache(maxsize=256)
def delta0(alpha: float, beta: float, q: int = 1) -> float:
    """Non-centrality δ0 at which a q-dimensional χ² test of size α has power β (F80 §5).

    Solves P(χ'²(q, δ0²) > χ²_{1−α}(q)) = β with scipy's non-central χ². For q = 1 this is
    the two-sided normal test; its value differs from the approximation
    Φ⁻¹(1 − α/2) + Φ⁻¹(β) only by the far tail (F80 §5: 4.13 for α = 0.1 %, β = 80 %).

    Parameters
    ----------
    alpha : float
        Size of the test, in (0, 1), dimensionless.
    beta : float
        Power, in (0, 1), dimensionless.
    q : int
        Dimension of the test, ≥ 1.

    Returns
    -------
    float
        δ0, dimensionless (√ of the non-centrality λ0).

    Raises
    ------
    baarda.errors.OptionError
        For α or β outside (0, 1) or q < 1.
    """
    if not (0 < alpha < 1 and 0 < beta < 1) or q < 1:
        bad = "q" if 0 < alpha < 1 and 0 < beta < 1 else "beta" if 0 < alpha < 1 else "alpha"
        raise OptionError(bad, {"alpha": alpha, "beta": beta, "q": q}[bad], (),
                          f"need 0 < alpha, beta < 1 and q ≥ 1 (alpha={alpha}, beta={beta}, q={q})")
    c = stats.chi2.isf(alpha, q)

    def power_gap(lam):
        return stats.ncx2.sf(c, q, lam) - beta

    hi = (np.sqrt(c) + stats.norm.isf(1 - beta) + 10.0) ** 2
    lam = optimize.brentq(power_gap, 1e-12, hi, xtol=1e-14, rtol=1e-14)
    return float(np.sqrt(lam))


def delta0_normal(alpha: float, beta: float) -> float:
    """The normal approximation δ0 = Φ⁻¹(1 − α/2) + Φ⁻¹(β) (F80 §5).

    Parameters
    ----------
    alpha : float
        Size of the two-sided test, in (0, 1), dimensionless.
    beta : float
        Power, in (0, 1), dimensionless.

    Returns
    -------
    float
        δ0, dimensionless.
    """
    return float(stats.norm.isf(alpha / 2.0) + stats.norm.ppf(beta))


@lru_cache(maxsize=256)
def alpha_b_method(alpha1: float, beta: float, q: int) -> float:
    """Baarda's B-method: the size α_q of a q-dimensional test with the δ0 of the 1D test (B68; F80 §7.2).

    Tests of any dimension get the same δ0 and β0; α_q solves
    P(χ'²(q, δ0(α1, β, 1)²) > χ²_{1−α_q}(q)) = β.

    Parameters
    ----------
    alpha1 : float
        Size α0 of the one-dimensional test, in (0, 1), dimensionless.
    beta : float
        Power β0, in (0, 1), dimensionless.
    q : int
        Dimension of the test, ≥ 1.

    Returns
    -------
    float
        α_q, a probability (``alpha1`` for q = 1).
    """
    if q == 1:
        return alpha1
    lam = delta0(alpha1, beta, 1) ** 2

    def gap(log_a):
        return stats.ncx2.sf(stats.chi2.isf(np.exp(log_a), q), q, lam) - beta

    return float(np.exp(optimize.brentq(gap, np.log(1e-15), np.log(0.999999), xtol=1e-13)))


#: The global tests (F80 §4.1): ``one-sided`` (default) rejects Ω/σ0² above the upper end of the
#: conf-pr interval, size (1 − conf-pr)/2; ``two-sided`` (gama-local) rejects outside that interval,
#: size 1 − conf-pr; ``b-method`` is one-sided at the B-method's α_r (F80 §7.2, Baarda 1968).
GLOBAL_TESTS = ("one-sided", "two-sided", "b-method")

#: What a value of Ω/σ0² below the lower bound means: the a priori variances are too large,
#: not an error in the data.
TOO_PESSIMISTIC = "σ0 a priori too pessimistic (Ω/r far below σ0²)"
#: What a value above the upper bound means (F80 §4.1: model errors accumulate in Ω).
TOO_LARGE = "Ω/σ0² too large: errors in the model or σ0 a priori too optimistic"
#: A B-method rejection that the conf-pr interval of σ̂0 does not confirm (α_r is large).
STRICT = ("above the B-method's bound only: σ0 a priori lies within σ̂0's confidence interval, the "
          "excess of Ω is not significant at conf-pr")


def sigma0_interval(statistic: float, dof: int, conf_pr: float = 0.95) -> tuple[float, float]:
    """Confidence interval of σ/σ0 at level ``conf_pr`` (F80 eq. 3, §4.1).

    σ is the true standard deviation of unit weight in units of σ0 a priori. Ω/σ² ~ χ²(r) under H0,
    so [√(Ω/σ0² / χ²_{1−γ/2}(r)), √(Ω/σ0² / χ²_{γ/2}(r))], γ = 1 − conf_pr. σ̂0/σ0 = √(Ω/σ0²/r)
    lies inside; σ0 a priori (ratio 1) lies below the interval exactly when Ω/σ0² exceeds
    χ²_{1−γ/2}(r), the bound of the one-sided test.

    Parameters
    ----------
    statistic : float
        Ω/σ0², dimensionless.
    dof : int
        Redundancy r.
    conf_pr : float
        Confidence level, in (0, 1).

    Returns
    -------
    tuple of float
        Lower and upper bound of σ/σ0, dimensionless; (nan, nan) when r ≤ 0.
    """
    if dof <= 0:
        return (float("nan"), float("nan"))
    tail = (1.0 - conf_pr) / 2.0
    t = max(float(statistic), 0.0)
    return (float(np.sqrt(t / stats.chi2.isf(tail, dof))), float(np.sqrt(t / stats.chi2.ppf(tail, dof))))


def global_test(statistic: float, dof: int, conf_pr: float = 0.95, test: str = "two-sided",
                alpha: float | None = None) -> dict:
    """Global test of Ω/σ0² ~ χ²(r) under H0 (F80 §4.1, §7.2).

    Model errors only enlarge Ω (T ~ χ'²(r, δ²), F80 eq. 10-11), so F80's test is one-sided;
    its size is free (F80 §4.1: "depending on the significance level 1 − α").

    - ``test="one-sided"``: reject above χ²_{1−α}(r) with α = (1 − conf_pr)/2 unless
      ``alpha`` is given, i.e. when
      σ0 a priori lies below the conf_pr confidence interval of σ (:func:`sigma0_interval`); every
      error-free block, of any redundancy, fails at rate α (2.5 % at conf_pr 0.95).
    - ``test="b-method"``: one-sided at ``alpha`` = the B-method's α_r (:func:`alpha_b_method`
      with q = r): the λ0 = δ0² and β0 of the one-dimensional test (F80 §7.2, Baarda 1968).
      α_r grows with r towards β0 (52 % at r = 216 for α0 = 0.1 %, β0 = 80 %), so an error-free
      large block fails more often than not; a rejection the interval does not confirm is said so
      (:data:`STRICT`).
    - ``test="two-sided"`` (gama-local; the default of this function): accept within
      [χ²_{γ/2}(r), χ²_{1−γ/2}(r)], γ = α = 1 − conf_pr; a value below fails, reported as σ0 a priori
      too pessimistic (``side`` "low").

    In the one-sided tests ``lower`` = χ²_{γ/2}(r) (the interval's) marks a low value for the note
    only (σ0 a priori too pessimistic; the test passes); ``lower`` < ``upper`` always (None when it
    would not be).

    Parameters
    ----------
    statistic : float
        Ω/σ0², dimensionless.
    dof : int
        Redundancy r.
    conf_pr : float
        Confidence level, in (0, 1).
    test : str
        One of :data:`GLOBAL_TESTS`.
    alpha : float, optional
        Size of a one-sided test (required for "b-method"); ignored by "two-sided".

    Returns
    -------
    dict
        statistic, dof, test, alpha, conf_pr, lower, upper (bounds of Ω/σ0², dimensionless), passed
        (None with r = 0), side (None, "low", "high"), verdict (words), ratio σ̂0/σ0 and
        ratio_interval (the conf_pr interval of σ/σ0), all dimensionless.

    Raises
    ------
    baarda.errors.OptionError
        For an unknown ``test``, ``conf_pr`` outside (0, 1) or a missing or bad ``alpha``.
    """
    if test not in GLOBAL_TESTS:
        raise OptionError("global-test", test, GLOBAL_TESTS, f"the global test is one of {', '.join(GLOBAL_TESTS)}")
    if not 0 < conf_pr < 1:
        raise OptionError("conf-pr", conf_pr, (), f"need 0 < conf-pr < 1 for the global test (conf-pr={conf_pr})")
    gamma = 1.0 - conf_pr
    if test == "two-sided":
        alpha = gamma
    elif test == "one-sided" and alpha is None:
        alpha = gamma / 2.0
    if alpha is None or not 0 < alpha < 1:
        raise OptionError("alpha", alpha, (), f"need 0 < alpha < 1 for the global test (alpha={alpha})")
    out = {"statistic": float(statistic), "dof": int(dof), "test": test, "alpha": float(alpha),
           "conf_pr": float(conf_pr), "lower": None, "upper": None, "passed": None, "side": None,
           "verdict": "not applicable (no redundancy)", "ratio": None, "ratio_interval": None}
    if dof <= 0:
        return out
    lower = float(stats.chi2.ppf(gamma / 2.0, dof))
    upper = float(stats.chi2.isf(gamma / 2.0 if test == "two-sided" else alpha, dof))
    if not lower < upper:             # the B-method with β0 above (1 + conf_pr)/2: no low note
        lower = None
    side = "high" if statistic > upper else "low" if lower is not None and statistic < lower else None
    passed = side is None or (side == "low" and test != "two-sided")
    verdict = {None: "accepted", "high": TOO_LARGE, "low": TOO_PESSIMISTIC}[side]
    beyond_interval = statistic > float(stats.chi2.isf(gamma / 2.0, dof))
    if side == "high" and not beyond_interval:
        verdict = STRICT
    out.update(lower=lower, upper=upper, passed=bool(passed), side=side,
               verdict=verdict, ratio=float(np.sqrt(max(float(statistic), 0.0) / dof)),
               ratio_interval=list(sigma0_interval(statistic, dof, conf_pr)))
    return out
