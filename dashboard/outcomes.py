"""One hypothesis as the dashboard shows it: the typed outcome of its test.

:class:`Outcome` replaces the union "HypothesisTest, APTest, a message or None" the views used
to tell apart by type: every outcome has a ``status`` — ``"inactive"`` (switched off, or nothing
adjusted), ``"refused"`` (the core refused it; ``message`` says why), ``"test"`` (F80 eq. 10-17:
``test`` the core's :class:`~baarda.stats.hypotheses.HypothesisTest`, ``external`` its δ̄0(s),
F80 eq. 17) or ``"ap-test"`` (an estimated group of additional parameters, ``ap`` the core's
:class:`~baarda.stats.ap_tests.APTest`) — and the same accessors (``q``, ``T``, ``critical``,
``rejected``) whatever it is.

:meth:`Outcome.under` gives a test's outcome under another test policy without testing again:
of a hypothesis test only α_q, the critical values and δ0(q) depend on α0/β0 (F80 eq. 13-15,
17): the lower-bound semi-axes δ0/√λ, δ0′max = δ0 √μmax and δ̄0max = δ0 √λmax(M, W_s) scale
with δ0, while W_s, T, R, ∇ŝ, q and the directions do not.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from baarda.stats.ap_tests import APTest
from baarda.stats.hypotheses import ExternalReliability, HypothesisTest

#: The statuses of an :class:`Outcome`.
STATUSES = ("inactive", "refused", "test", "ap-test")


@dataclass(frozen=True, eq=False)
class Outcome:
    """What the test of one hypothesis gave (see the module docstring)."""

    status: str = "inactive"
    label: str = ""
    test: HypothesisTest | None = None
    ap: APTest | None = None
    external: ExternalReliability | None = None
    message: str = ""
    policy: object = None

    def __post_init__(self):
        if self.status not in STATUSES:
            raise ValueError(f"unknown outcome status {self.status!r}")

    @property
    def tested(self) -> bool:
        """True for a test's outcome (a hypothesis test or an AP group's test)."""
        return self.status in ("test", "ap-test")

    @property
    def q(self) -> int | None:
        """The test's dimension (rank of W_s; None when not tested)."""
        r = self.test or self.ap
        return None if r is None else int(r.q)

    @property
    def T(self) -> float | None:  # noqa: N802 - the papers' name
        """The test statistic T (F80 eq. 12), None when not tested."""
        r = self.test or self.ap
        return None if r is None else float(r.T)

    @property
    def critical(self) -> float | None:
        """The critical value of T under the outcome's policy, None when not tested."""
        if self.test is not None:
            return float(self.test.critical_T)
        return None if self.ap is None else float(self.ap.critical)

    @property
    def rejected(self) -> bool:
        """The test rejects (a hypothesis test's T, an AP group found significant)."""
        if self.test is not None:
            return self.test.rejected_T
        return bool(self.ap is not None and self.ap.significant)

    @property
    def rank_deficient(self) -> bool:
        """The test sees fewer dimensions than H has columns (W_s singular, F80 eq. 12)."""
        return self.test is not None and self.test.q < self.test.H.shape[1]

    @property
    def external_max(self) -> float:
        """δ̄0max (F80 eq. 17) of a hypothesis test, or of an AP group; NaN otherwise."""
        if self.external is not None:
            return float(self.external.max)
        if self.ap is not None:
            return float(self.ap.reliability_max)
        return float("nan")

    def under(self, policy) -> "Outcome":
        """This outcome under ``policy`` (module docstring): a hypothesis test rescaled to the
        policy's δ0(q) and critical values, without testing again; the others unchanged (an AP
        group's test is redone by the caller, :meth:`needs_retest`)."""
        h = self.test
        if h is None or policy == self.policy or self.policy is None:
            return self if h is None else replace(self, policy=policy)
        d0 = float(policy.delta0(h.q))
        k = d0 / h.delta0
        test = replace(h, alpha=policy.alpha(h.q), critical_T=policy.critical_T(h.q),
                       critical_R=policy.critical_R(h.q, h.dof), delta0=d0, ellipse_axes=h.ellipse_axes * k,
                       delta0_prime_max=h.delta0_prime_max * k, extra=dict(h.extra))
        ext = self.external
        if ext is not None:
            ext = replace(ext, delta0=d0, max=ext.max * k)
        return replace(self, test=test, external=ext, policy=policy)

    def needs_retest(self, policy) -> bool:
        """True when :meth:`under` cannot give the outcome under ``policy`` (an AP group's test,
        or a test whose δ0 is not a positive number)."""
        if policy == self.policy:
            return False
        if self.ap is not None:
            return True
        h = self.test
        return h is not None and not (np.isfinite(h.delta0) and h.delta0 > 0)
