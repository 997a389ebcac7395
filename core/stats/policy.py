"""The test policy: α0, β0, Baarda's B-method and which σ0 the decisions use.

Every test decision of baarda — data snooping with w or τ, the multi-dimensional tests T of
hypotheses and observation groups, δ0 of the MDBs and of the lower-bound ellipses — asks one
:class:`TestPolicy` for its size, its critical value and its non-centrality:

- size of a q-dimensional test: α0, or with the B-method α_q such that it has the δ0 and β0 of
  the one-dimensional test (Baarda 1968; Förstner 1980, §7.2; :func:`baarda.distributions.alpha_b_method`);
- non-centrality δ0(q): the q-dimensional test of size α_q has power β0 (Förstner 1980, eq. 11),
  which with the B-method is δ0(α0, β0, 1) for every q;
- critical values: |w| > Φ⁻¹(1 − α0/2) (σ0 a priori), |τ| > τ_c(α0, r) (σ0 a posteriori, Pope
  1976), T > χ²_{1−α_q}(q), R > F_{1−α_q}(q, r − q) (Förstner 1980, eq. 12);
- the global test of Ω/σ0² (Förstner 1980, §4.1): one-sided (default) at size (1 − conf-pr)/2,
  i.e. rejected when σ0 a priori lies below the conf-pr confidence interval of σ̂0, so that
  error-free blocks of any redundancy fail at that rate; ``b-method``: one-sided at the
  B-method's α_r, the λ0 = δ0² and β0 of the one-dimensional test (Förstner 1980, §7.2; Baarda
  1968), which exceeds 50 % once r ≳ 200; ``two-sided``: gama-local's interval at ``conf-pr``.
  ``conf_pr`` None takes the file's (GNU Gama's ``conf-pr``, else 0.95).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OptionError
from . import distributions

#: Which σ0 the decisions of data snooping use: a priori (Baarda's w) or a posteriori (Pope's τ).
SIGMA0 = ("apriori", "aposteriori")


@dataclass(frozen=True)
class TestPolicy:
    """α0 (size of the one-dimensional tests), β0 (power), the B-method, ``sigma0``:
    ``"apriori"`` (decide on w) or ``"aposteriori"`` (decide on τ), and ``global_test``:
    ``"one-sided"`` (F80 §4.1 at (1 − conf_pr)/2), ``"b-method"`` (F80 §7.2, at the B-method's α_r)
    or ``"two-sided"`` (gama-local, at conf_pr); ``conf_pr``: the confidence level of the global
    test and of σ̂0's interval (None: the file's)."""

    __test__ = False       # not a pytest test class despite its name

    alpha0: float = 0.001
    beta0: float = 0.80
    b_method: bool = False
    sigma0: str = "apriori"
    global_test: str = "one-sided"
    conf_pr: float | None = None

    def __post_init__(self):
        for name in ("alpha0", "beta0"):
            value = getattr(self, name)
            if not 0 < value < 1:
                raise OptionError(name, value, (), f"{name} must lie strictly between 0 and 1 (got {value!r})")
        if self.sigma0 not in SIGMA0:
            raise OptionError("sigma0", self.sigma0, SIGMA0)
        if self.global_test not in distributions.GLOBAL_TESTS:
            raise OptionError("global_test", self.global_test, distributions.GLOBAL_TESTS)
        if self.conf_pr is not None and not 0 < self.conf_pr < 1:
            raise OptionError("conf_pr", self.conf_pr, (), f"conf_pr must lie strictly between 0 and 1 "
                                                           f"(got {self.conf_pr!r})")

    @classmethod
    def from_options(cls, options, sigma0: str | None = None) -> "TestPolicy":
        """The policy of :class:`baarda.adjust.Options` (``alpha0``, ``beta0``, ``b_method``,
        ``sigma0``, ``global_test``, ``conf_pr``); ``sigma0`` given here overrides the options'."""
        conf = getattr(options, "conf_pr", None)
        return cls(alpha0=float(options.alpha0), beta0=float(options.beta0), b_method=bool(options.b_method),
                   sigma0=sigma0 or getattr(options, "sigma0", "apriori"),
                   global_test=getattr(options, "global_test", "one-sided"),
                   conf_pr=None if conf is None else float(conf))

    # -- the B-method rule ------------------------------------------------------------------------
    def alpha(self, q: int = 1) -> float:
        """Size α_q of a q-dimensional test: α0, or with the B-method the α_q that gives the
        δ0 and β0 of the one-dimensional test (Förstner 1980, §7.2). q = 0 (a test that sees
        nothing) keeps α0."""
        q = int(q)
        return distributions.alpha_b_method(self.alpha0, self.beta0, q) if (self.b_method and q) else self.alpha0

    def delta0(self, q: int = 1) -> float:
        """Non-centrality δ0 at which the q-dimensional test of size α_q has power β0
        (Förstner 1980, eq. 11); the same δ0(α0, β0, 1) for every q with the B-method."""
        if self.b_method:
            return distributions.delta0(self.alpha0, self.beta0, 1)
        return distributions.delta0(self.alpha0, self.beta0, max(int(q), 1))

    # -- critical values ----------------------------------------------------------------------------
    @property
    def critical_w(self) -> float:
        """Critical value of |w|, Φ⁻¹(1 − α0/2) (σ0 a priori; Baarda 1968)."""
        return distributions.critical_normal(self.alpha0)

    def critical_tau(self, dof: int) -> float:
        """Critical value of |τ| with redundancy r = ``dof`` (σ0 a posteriori; Pope 1976)."""
        return distributions.critical_tau(self.alpha0, dof)

    def critical_T(self, q: int) -> float:
        """Critical value χ²_{1−α_q}(q) of T (Förstner 1980, eq. 12); inf for q = 0."""
        q = int(q)
        return distributions.critical_chi2(self.alpha(q), q) if q else float("inf")

    def critical_R(self, q: int, dof: int) -> float:
        """Critical value F_{1−α_q}(q, r − q) of R (σ0 estimated; Förstner 1980, eq. 12); inf
        when q = 0 or r ≤ q."""
        q = int(q)
        return distributions.critical_f(self.alpha(q), q, dof - q) if (q and dof > q) else float("inf")

    # -- the global test ------------------------------------------------------------------------------
    def alpha_global(self, dof: int, conf_pr: float = 0.95) -> float:
        """Size of the global test with redundancy r = ``dof``: (1 − conf_pr)/2 (one-sided,
        Förstner 1980, §4.1), the B-method's α_r (Förstner 1980, §7.2) or 1 − conf_pr
        (two-sided, gama-local); the policy's own ``conf_pr`` wins over the argument."""
        conf = self.conf_pr if self.conf_pr is not None else conf_pr
        if self.global_test == "two-sided":
            return 1.0 - conf
        if self.global_test == "one-sided":
            return (1.0 - conf) / 2.0
        return distributions.alpha_b_method(self.alpha0, self.beta0, int(dof)) if dof > 0 else self.alpha0

    def global_decision(self, statistic: float, dof: int, conf_pr: float = 0.95) -> dict:
        """The global test of Ω/σ0² ~ χ²(r) (Förstner 1980, §4.1;
        :func:`baarda.stats.distributions.global_test`) at the policy's conf_pr, else ``conf_pr``
        (the file's)."""
        conf = self.conf_pr if self.conf_pr is not None else conf_pr
        return distributions.global_test(statistic, dof, conf, test=self.global_test,
                                         alpha=self.alpha_global(dof, conf))

    # -- the decision of data snooping --------------------------------------------------------------
    @property
    def statistic_name(self) -> str:
        """"w" (σ0 a priori) or "τ" (σ0 a posteriori)."""
        return "τ" if self.sigma0 == "aposteriori" else "w"

    def statistic(self, w: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The statistic the decision uses: w or τ."""
        return tau if self.sigma0 == "aposteriori" else w

    def critical(self, dof: int) -> float:
        """Critical value of the statistic the decision uses (w or τ)."""
        return self.critical_tau(dof) if self.sigma0 == "aposteriori" else self.critical_w

    def rejected(self, w: np.ndarray, tau: np.ndarray, dof: int) -> np.ndarray:
        """Observations whose |statistic| exceeds its critical value (NaN — uncontrolled — is
        never rejected)."""
        return np.nan_to_num(np.abs(self.statistic(w, tau))) > self.critical(dof)
