"""The test policy: α0, β0, Baarda's B-method and which σ0 the decisions use.

Every test decision of baarda — data snooping with w or τ, the multi-dimensional tests T of
hypotheses and observation groups, δ0 of the MDBs and of the lower-bound ellipses — asks one
:class:`TestPolicy` for its size, its critical value and its non-centrality:

- size of a q-dimensional test: α0, or with the B-method α_q such that it has the δ0 and β0 of
  the one-dimensional test (Baarda 1968; Förstner 1980, §7.2; :func:`baarda.distributions.alpha_b_method`);
- non-centrality δ0(q): the q-dimensional test of size α_q has power β0 (Förstner 1980, eq. 11),
  which with the B-method is δ0(α0, β0, 1) for every q;
- critical values: |w| > Φ⁻¹(1 − α0/2) (σ0 a priori), |τ| > τ_c(α0, r) (σ0 a posteriori, Pope
  1976), T > χ²_{1−α_q}(q), R > F_{1−α_q}(q, r − q) (Förstner 1980, eq. 12).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import distributions

#: Which σ0 the decisions of data snooping use: a priori (Baarda's w) or a posteriori (Pope's τ).
SIGMA0 = ("apriori", "aposteriori")


@dataclass(frozen=True)
class TestPolicy:
    """α0 (size of the one-dimensional tests), β0 (power), the B-method, and ``sigma0``:
    ``"apriori"`` (decide on w) or ``"aposteriori"`` (decide on τ)."""

    __test__ = False       # not a pytest test class despite its name

    alpha0: float = 0.001
    beta0: float = 0.80
    b_method: bool = False
    sigma0: str = "apriori"

    def __post_init__(self):
        if not (0 < self.alpha0 < 1 and 0 < self.beta0 < 1):
            raise ValueError(f"need 0 < alpha0, beta0 < 1 (alpha0={self.alpha0}, beta0={self.beta0})")
        if self.sigma0 not in SIGMA0:
            raise ValueError(f"sigma0 must be one of {SIGMA0}, got {self.sigma0!r}")

    @classmethod
    def from_options(cls, options, sigma0: str = "apriori") -> "TestPolicy":
        """The policy of :class:`baarda.adjust.Options` (``alpha``, ``beta``, ``b_method``)."""
        return cls(alpha0=float(options.alpha), beta0=float(options.beta), b_method=bool(options.b_method),
                   sigma0=sigma0)

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
