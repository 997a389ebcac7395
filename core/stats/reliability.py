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
from .groups import group_statistics
from .policy import TestPolicy
from ..model.problem import LazySequence


class GroupTests(LazySequence):
    """The group tests of :attr:`Reliability.groups` as arrays; item k is the dict
    {group, members, T, dimension, redundancy, critical, rejected, alpha, nabla, R, critical_R,
    delta0, nabla_sigma, ellipse_axes, delta0_prime_max} of group k (members sorted, ∇ŝ and σ∇ŝ in
    their order; the q semi-axes δ0/√λ(W_s) ascending in λ, F80 eq. 10-14), made on demand.

    ``per_group`` and ``per_member`` name the arrays indexed by group and by member position
    (``members[ptr[k]:ptr[k + 1]]``); each is an attribute too (``groups.T``). The arrays that
    follow from the others and the policy (α_q, the critical values, δ0(q), R, δ0′max, the
    semi-axes: :class:`_Derived`) may be given as ``derive`` instead: they are then made when
    asked for and not kept (a block of a million image points holds seven arrays fewer)."""

    PER_GROUP = ("T", "dimension", "redundancy", "critical", "rejected", "alpha", "R", "critical_R",
                 "delta0", "delta0_prime_max")
    PER_MEMBER = ("nabla", "nabla_sigma", "ellipse_axes")

    def __init__(self, group, ptr, members, derive=None, **arrays):
        self.group, self.ptr, self.members = group, ptr, members
        self._derive = derive
        for name in self.PER_GROUP + self.PER_MEMBER:
            if derive is None or name not in derive.NAMES:
                setattr(self, name, arrays[name])

    def __getattr__(self, name):
        derive = self.__dict__.get("_derive")
        if derive is not None and name in derive.NAMES:
            return derive.array(name)          # made on demand, not kept
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @classmethod
    def empty(cls) -> "GroupTests":
        z, i = np.zeros(0), np.zeros(0, dtype=np.int64)
        arrays = {name: z for name in cls.PER_GROUP + cls.PER_MEMBER}
        arrays.update(dimension=i, rejected=np.zeros(0, dtype=bool))
        return cls(i, np.zeros(1, dtype=np.int64), i, **arrays)

    def __len__(self):
        return self.group.size

    def _item(self, k):
        a, b = int(self.ptr[k]), int(self.ptr[k + 1])
        q = int(self.dimension[k])
        d = self._derive
        if d is not None:
            der = d.item(k, a, b)
        else:
            der = {"critical": float(self.critical[k]), "alpha": float(self.alpha[k]), "R": float(self.R[k]),
                   "critical_R": float(self.critical_R[k]), "delta0": float(self.delta0[k]),
                   "delta0_prime_max": float(self.delta0_prime_max[k]), "ellipse_axes": self.ellipse_axes[a:b]}
        axes = der["ellipse_axes"]
        return {"group": int(self.group[k]), "members": self.members[a:b], "T": float(self.T[k]),
                "dimension": q, "redundancy": float(self.redundancy[k]),
                "critical": der["critical"], "rejected": bool(self.rejected[k]),
                "alpha": der["alpha"], "nabla": self.nabla[a:b], "R": der["R"],
                "critical_R": der["critical_R"], "delta0": der["delta0"],
                "nabla_sigma": self.nabla_sigma[a:b], "ellipse_axes": axes[np.isfinite(axes)],
                "delta0_prime_max": der["delta0_prime_max"]}

    def take(self, idx):
        idx = np.asarray(idx, dtype=np.int64)
        sizes = self.ptr[idx + 1] - self.ptr[idx]
        flat = np.repeat(self.ptr[idx], sizes) + (np.arange(int(sizes.sum())) -
                                                   np.repeat(np.cumsum(sizes) - sizes, sizes))
        arrays = {name: getattr(self, name)[idx] for name in self.PER_GROUP}
        arrays.update({name: getattr(self, name)[flat] for name in self.PER_MEMBER})
        return GroupTests(self.group[idx], np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
                          self.members[flat], **arrays)


class _Derived:
    """The group-test arrays that follow from q, T, μmax, the eigenvalues λ(W_s) and the policy:
    α_q, χ²_{1−α_q}(q), F_{1−α_q}(q, r − q) and δ0(q) (tabled per q), R = (T/q)/((vᵀPv − T)/(r − q)),
    δ0′max = δ0 √μmax and the semi-axes δ0/√λ (Förstner 1980, eq. 10-14) — the formulas
    :attr:`Reliability.groups` used to store, the same numbers, made when asked for."""

    NAMES = ("alpha", "critical", "critical_R", "delta0", "R", "delta0_prime_max", "ellipse_axes")

    def __init__(self, q, T, ptr, wlam, mu_max, table, dof, vPv):
        self.q, self.T, self.ptr, self.wlam, self.mu_max = q, T, ptr, wlam, mu_max
        self.table, self.dof, self.vPv = table, dof, vPv      # table: q → (α, crit, crit_R, δ0)
        self.qs = np.array(sorted(table), dtype=np.int64)

    def _by_q(self, j: int, q=None) -> np.ndarray:
        q = self.q if q is None else q
        vals = np.array([self.table[int(v)][j] for v in self.qs.tolist()], dtype=float)
        return vals[np.searchsorted(self.qs, q)] if q.size else np.empty(0)

    def array(self, name: str) -> np.ndarray:
        if name in ("alpha", "critical", "critical_R", "delta0"):
            return self._by_q(("alpha", "critical", "critical_R", "delta0").index(name))
        q, T, dof, vPv = self.q, self.T, self.dof, self.vPv
        d0 = self._by_q(3)
        with np.errstate(divide="ignore", invalid="ignore"):
            if name == "R":
                ok = (q > 0) & (dof > q) & (vPv > T)
                return np.where(ok, (T / np.maximum(q, 1)) / ((vPv - T) / np.maximum(dof - q, 1)), np.nan)
            if name == "delta0_prime_max":
                return d0 * np.sqrt(np.maximum(self.mu_max, 0.0))
            d0_member = np.repeat(d0, np.diff(self.ptr))
            wlam = self.wlam
            return np.where(wlam > 0, d0_member / np.sqrt(np.where(wlam > 0, wlam, 1.0)), np.inf)

    def item(self, k: int, a: int, b: int) -> dict:
        """The values of group k (members at a:b), by the same formulas on its own numbers."""
        q, T = self.q[k:k + 1], self.T[k:k + 1]
        alpha, crit, crit_R, d0 = self.table[int(q[0])]
        dof, vPv = self.dof, self.vPv
        with np.errstate(divide="ignore", invalid="ignore"):
            ok = (q > 0) & (dof > q) & (vPv > T)
            R = np.where(ok, (T / np.maximum(q, 1)) / ((vPv - T) / np.maximum(dof - q, 1)), np.nan)
            d0a = np.array([d0])
            dprime = d0a * np.sqrt(np.maximum(self.mu_max[k:k + 1], 0.0))
            wlam = self.wlam[a:b]
            axes = np.where(wlam > 0, d0a / np.sqrt(np.where(wlam > 0, wlam, 1.0)), np.inf)
        return {"alpha": float(alpha), "critical": float(crit), "critical_R": float(crit_R),
                "delta0": float(d0), "R": float(R[0]), "delta0_prime_max": float(dprime[0]),
                "ellipse_axes": axes}


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

    @cached_property
    def global_test(self) -> dict:
        """The global test of Ω/σ0² = vᵀPv ~ χ²(r) under the policy (Förstner 1980, §4.1, §7.2;
        :meth:`baarda.stats.policy.TestPolicy.global_decision`), at the problem's conf-pr when
        two-sided."""
        return self.policy.global_decision(self.result.vPv, self.result.dof,
                                           getattr(self.result.problem, "conf_pr", 0.95))

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
        T, q, ∇ŝ, σ∇ŝ and the eigenvalues of W_s from :func:`baarda.stats.groups.group_statistics`;
        α_q, the critical values χ²_{1−α_q}(q) of T and F_{1−α_q}(q, r − q) of
        R = (T/q)/((vᵀPv − T)/(r − q)), δ0(q), the lower-bound semi-axes δ0/√λ(W_s) and
        δ0′max = δ0 √μmax from the policy (Förstner 1980, eq. 10-14)."""
        g = group_statistics(self.result)
        if g is None:
            return GroupTests.empty()
        keys, ptr, members, T, q = g.keys, g.ptr, g.members, g.T, g.q
        red, nabla, nabla_sigma, wlam, mu_max = g.redundancy, g.nabla, g.nabla_sigma, g.w_eigenvalues, g.mu_max
        dof, vPv = self.result.dof, self.result.vPv
        # α_q, the critical values and δ0(q) per dimension q; every array that follows from them
        # (and R, δ0′max, the semi-axes) is made when asked for (:class:`_Derived`)
        table = {qq: (self.policy.alpha(qq), self.policy.critical_T(qq), self.policy.critical_R(qq, dof),
                      self.policy.delta0(qq)) for qq in np.unique(q).tolist()}
        derive = _Derived(q, T, ptr, wlam, mu_max, table, dof, vPv)
        rejected = (q > 0) & (T > derive.array("critical"))
        return GroupTests(keys, ptr, members, derive=derive, T=T, dimension=q, redundancy=red,
                          rejected=rejected, nabla=nabla, nabla_sigma=nabla_sigma)

    def test(self, H, label: str = ""):
        """Multi-dimensional test of a hypothesis matrix H (n × q) under the policy
        (:func:`baarda.stats.hypotheses.test`; Förstner 1980, eq. 10-15)."""
        return hypotheses.test(self.result, H, label=label, policy=self.policy)


def policy_of(adj) -> TestPolicy:
    """The test policy that an adjustment's options name (:meth:`TestPolicy.from_options`).

    The result of :func:`baarda.adjust.adjust` knows no policy; a caller that wants the decisions
    of the options it adjusted with gets them here, made once per result (``adj.memo``).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        An adjustment result.

    Returns
    -------
    TestPolicy
        α0, β0, B-method, σ0 of the decisions and global test of ``adj.options``.
    """
    policy = adj.memo.get("policy")
    if policy is None:
        policy = adj.memo["policy"] = TestPolicy.from_options(adj.options)
    return policy


def reliability_of(adj, policy: TestPolicy | None = None) -> "Reliability":
    """The tests and reliability measures of an adjustment under a policy (F80 §4-7).

    Made once per result and policy and kept with the result (``adj.memo``): every caller asking
    for the same policy shares one :class:`Reliability` and its cached arrays.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        An adjustment result.
    policy : TestPolicy, optional
        The test policy; default :func:`policy_of` ``(adj)``, the policy of its options.

    Returns
    -------
    Reliability
        Decisions, MDBs (units of the observations), external reliability (dimensionless) and
        group tests of ``adj`` under ``policy``.
    """
    policy = policy_of(adj) if policy is None else policy
    key = ("reliability", policy)
    rel = adj.memo.get(key)
    if rel is None:
        rel = adj.memo[key] = Reliability(adj, policy)
    return rel
