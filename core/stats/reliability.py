"""Reliability of an adjustment under a test policy: decisions, MDBs, external reliability.

:class:`Reliability` is a light object over an adjustment result (:class:`baarda.result.Adjustment`,
which holds what does not depend on α0, β0, the B-method or the σ0 of the decisions: v, r,
(P C_vv P)_ii, w, τ, the cluster blocks of C_vv) and a :class:`baarda.stats.policy.TestPolicy`. A new
policy is a new small object over the same result, as statsmodels' ``OLSInfluence(results)``:
nothing is solved again.

Per observation i (Förstner 1980; notation of :mod:`baarda.result`):

- decision: |w_i| > Φ⁻¹(1 − α0/2) or |τ_i| > τ_c (the policy's σ0);
- MDB ∇0l_i = δ0 / √(P C_vv P)_ii (Förstner 1980, §5);
- external reliability δ̄0,i = δ0 √((P H_k P)_ii / (P C_vv P)_ii) (Förstner 1980, eq. 18) and
  δ0 √((P H P)_ii / (P C_vv P)_ii) over all unknowns;
- group tests: T of each observation group with the policy's α_q and χ² critical value.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from . import hypotheses
from .policy import TestPolicy
from ..model.problem import LazySequence


class GroupTests(LazySequence):
    """The group tests of :attr:`Reliability.groups` as arrays; item k is the dict
    {group, members, T, dimension, redundancy, critical, rejected, alpha, nabla} of group k
    (members sorted, ∇ŝ in their order), made on demand."""

    def __init__(self, group, ptr, members, T, dimension, redundancy, critical, rejected, alpha, nabla):
        self.group, self.ptr, self.members = group, ptr, members
        self.T, self.dimension, self.redundancy = T, dimension, redundancy
        self.critical, self.rejected, self.alpha, self.nabla = critical, rejected, alpha, nabla

    @classmethod
    def empty(cls) -> "GroupTests":
        z, i = np.zeros(0), np.zeros(0, dtype=np.int64)
        return cls(i, np.zeros(1, dtype=np.int64), i, z, i, z, z, np.zeros(0, dtype=bool), z, z)

    def __len__(self):
        return self.group.size

    def _item(self, k):
        a, b = int(self.ptr[k]), int(self.ptr[k + 1])
        return {"group": int(self.group[k]), "members": self.members[a:b], "T": float(self.T[k]),
                "dimension": int(self.dimension[k]), "redundancy": float(self.redundancy[k]),
                "critical": float(self.critical[k]), "rejected": bool(self.rejected[k]),
                "alpha": float(self.alpha[k]), "nabla": self.nabla[a:b]}

    def take(self, idx):
        idx = np.asarray(idx, dtype=np.int64)
        sizes = self.ptr[idx + 1] - self.ptr[idx]
        flat = np.repeat(self.ptr[idx], sizes) + (np.arange(int(sizes.sum())) -
                                                   np.repeat(np.cumsum(sizes) - sizes, sizes))
        return GroupTests(self.group[idx], np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
                          self.members[flat], self.T[idx], self.dimension[idx], self.redundancy[idx],
                          self.critical[idx], self.rejected[idx], self.alpha[idx], self.nabla[flat])


@dataclass(frozen=True, eq=False)
class Reliability:
    """Tests and reliability measures of ``result`` under ``policy``; every quantity is a cached
    property read from the result's policy-free ones."""

    result: object
    policy: TestPolicy

    # -- decisions ------------------------------------------------------------------------------
    @property
    def w(self) -> np.ndarray:
        """Baarda's w (σ0 a priori), from the result."""
        return self.result.w

    @property
    def tau(self) -> np.ndarray:
        """Pope's τ (σ0 a posteriori), from the result."""
        return self.result.tau

    @cached_property
    def delta0(self) -> float:
        """δ0 of the one-dimensional test (α0, β0; Förstner 1980, eq. 11)."""
        return self.policy.delta0(1)

    @cached_property
    def critical_w(self) -> float:
        return self.policy.critical_w

    @cached_property
    def critical_tau(self) -> float:
        return self.policy.critical_tau(self.result.dof)

    @cached_property
    def critical(self) -> float:
        """Critical value of the statistic the policy decides on (w or τ)."""
        return self.policy.critical(self.result.dof)

    @cached_property
    def statistic(self) -> np.ndarray:
        """The statistic the policy decides on: w (σ0 a priori) or τ (σ0 a posteriori)."""
        return self.policy.statistic(self.result.w, self.result.tau)

    @cached_property
    def rejected(self) -> np.ndarray:
        """|statistic| above its critical value (the policy's σ0; NaN is never rejected)."""
        return self.policy.rejected(self.result.w, self.result.tau, self.result.dof)

    # -- internal and external reliability ------------------------------------------------------
    @cached_property
    def mdb(self) -> np.ndarray:
        """Minimal detectable bias ∇0l_i = δ0 / √(P C_vv P)_ii (SI units; Förstner 1980, §5);
        inf where r_i = 0."""
        with np.errstate(divide="ignore"):
            m = self.delta0 / np.sqrt(self.result.qvv_pp)
        m[self.result.uncontrolled] = np.inf
        return m

    @cached_property
    def external(self) -> np.ndarray:
        """δ̄0,i: the effect of an undetectable error on the coordinates (Förstner 1980, eq. 18)."""
        return self._external(self.result.php_k)

    @cached_property
    def external_all(self) -> np.ndarray:
        """δ0 √((P H P)_ii / (P C_vv P)_ii): the effect on all unknowns (Förstner 1980, after
        eq. 18; δ0 √((1 − r_i)/r_i) for an uncorrelated observation)."""
        return self._external(self.result.php)

    def _external(self, num: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            e = self.delta0 * np.sqrt(num / self.result.qvv_pp)
        e[self.result.uncontrolled] = np.inf
        return e

    # -- multi-dimensional tests ----------------------------------------------------------------
    @cached_property
    def groups(self) -> GroupTests:
        """Multi-dimensional tests of the problem's observation groups (vectors, image points):
        T, q and ∇ŝ from :attr:`baarda.result.Adjustment.group_statistics`, α_q and the critical
        value χ²_{1−α_q}(q) from the policy (Förstner 1980, eq. 12)."""
        g = self.result.group_statistics
        if g is None:
            return GroupTests.empty()
        keys, ptr, members, T, q, red, nabla = g
        alpha = np.empty(q.size)
        crit = np.empty(q.size)
        for qq in np.unique(q).tolist():
            alpha[q == qq] = self.policy.alpha(qq)
            crit[q == qq] = self.policy.critical_T(qq)
        rejected = (q > 0) & (T > crit)
        return GroupTests(keys, ptr, members, T, q, red, crit, rejected, alpha, nabla)

    def test(self, H, label: str = ""):
        """Multi-dimensional test of a hypothesis matrix H (n × q) under the policy
        (:func:`baarda.stats.hypotheses.test`; Förstner 1980, eq. 10-15)."""
        return hypotheses.test(self.result, H, label=label, policy=self.policy)
