"""Additional parameters of a bundle block: significance, determinability and reliability of a
camera's AP group (Förstner 1980, §7.2-§7.3, eq. 14-17)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as la

from ..errors import NotFoundError
from .hypotheses import coordinate_norm
from .reliability import policy_of


@dataclass(frozen=True, eq=False)
class APTest:
    """Tests of a group of estimated additional parameters (F80 §7.2). Units: image units.

    estimate ŝ, sigma σ_ŝ, cov Σ_ŝŝ (a priori σ0). T = ŝᵀΣ_ŝŝ⁻¹ŝ ~ χ²(q) under H0 (σ0 known),
    critical the χ² critical value at size ``alpha``. determinability ∇0s_j = δ0 σ_ŝj (F80
    eq. 15a, one parameter); ellipsoid_axes δ0(q) √eig(Σ_ŝŝ) (eq. 15a for the group).
    reliability δ̄0,j of each single parameter and reliability_max of the group (F80 eq. 17):
    the largest effect, in multiples of σ_f, of an undetectable AP error on any function f of
    the coordinates. weakest: direction s of largest δ'0(s) (eq. 14, F80 §7.3);
    most_influential: direction of largest δ̄0(s) (eq. 17).
    """

    labels: tuple[str, ...]
    estimate: np.ndarray
    cov: np.ndarray
    T: float
    q: int
    alpha: float
    critical: float
    delta0_1: float
    delta0_q: float
    determinability: np.ndarray
    ellipsoid_axes: np.ndarray
    reliability: np.ndarray
    reliability_max: float
    delta0_prime_max: float
    weakest: np.ndarray
    most_influential: np.ndarray

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    @property
    def significant(self) -> bool:
        return bool(self.T > self.critical)

    def as_dict(self) -> dict:
        return {"labels": list(self.labels), "estimate": self.estimate.tolist(),
                "sigma": self.sigma.tolist(), "T": self.T, "q": self.q, "alpha": self.alpha,
                "critical": self.critical, "significant": self.significant,
                "determinability": self.determinability.tolist(),
                "reliability": self.reliability.tolist(), "reliability_max": self.reliability_max,
                "delta0_prime_max": self.delta0_prime_max, "ellipsoid_axes": self.ellipsoid_axes.tolist(),
                "weakest": self.weakest.tolist(), "most_influential": self.most_influential.tolist(),
                "delta0_1": self.delta0_1, "delta0_q": self.delta0_q}


def ap_tests(adj, policy=None) -> list[dict]:
    """:func:`ap_test` of every AP group the model estimates (F80 §7.2-7.3).

    The groups are ``problem.notes.ap_groups``.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment of a bundle block with additional parameters.
    policy : baarda.stats.policy.TestPolicy, optional
        α0, β0 and the B-method (default :func:`~baarda.stats.reliability.policy_of` ``(adj)``).

    Returns
    -------
    list of dict
        Per group :meth:`APTest.as_dict` (estimates and σ in the units of the APs, T, δ0 and δ̄0
        dimensionless) with its ``camera`` and ``group``.
    """
    out = []
    for key in adj.problem.notes.ap_groups:
        camera, _, group = key.rpartition(":")
        out.append({"camera": camera, "group": group, **ap_test(adj, camera, group, policy=policy).as_dict()})
    return out


def ap_test(adj, camera: str, group: str, policy=None) -> APTest:
    """Significance, determinability and reliability of one camera's AP group (F80 §7.2).

    Uses ``adj.solve_normal`` for the q columns Σ e_j (so Σ_ŝŝ and Σ_kŝ), then
    ∇k = Σ_kŝ Σ_ŝŝ⁻¹ ∇s is the effect on the coordinates of leaving an error ∇s of the APs
    unmodelled, and δ̄0²(s) = δ0² ∇kᵀ(C̄ᵀPC̄)∇k / ∇sᵀΣ_ŝŝ⁻¹∇s (F80 eq. 17; the denominator
    is sᵀHᵀPQ_vvPHs of the model without the APs, H = ∂f/∂s). Determinability
    ∇0s_j = δ0 σ_ŝj (eq. 15a), weakest direction of δ'0(s) (eq. 14, §7.3).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment of a bundle block with additional parameters.
    camera : str
        Camera id.
    group : str
        AP group name of that camera (a key of ``problem.notes.ap_groups`` is ``camera:group``).
    policy : baarda.stats.policy.TestPolicy, optional
        Gives α_q, δ0 and the critical value (default :func:`~baarda.stats.reliability.policy_of` ``(adj)``).

    Returns
    -------
    APTest
        ŝ, Σ_ŝŝ, determinability and ellipsoid axes in the units of the APs (image units);
        T, δ0, δ̄0 and δ0′max dimensionless; directions as unit vectors.

    Raises
    ------
    baarda.errors.NotFoundError
        When a parameter of the group is not estimated.
    """
    policy = policy_of(adj) if policy is None else policy
    problem = adj.problem
    labels = problem.notes.ap_groups[f"{camera}:{group}"]
    # the group's parameters found by one pass over the labels (no array of every label)
    all_labels, want = problem.params.labels, set(labels)
    where = {all_labels[j]: j for j in range(len(all_labels)) if all_labels[j] in want}
    free, par = problem.params.free, np.array([where[lab] for lab in labels], dtype=np.int64)
    idx = np.searchsorted(free, par)
    if idx.size and (idx.max() >= free.size or not np.array_equal(free[idx], par)):
        raise NotFoundError("AP group", {"camera": camera, "group": group},
                            f"AP group {camera}:{group} has parameters that are not estimated")
    q = idx.size
    u = adj.A.shape[1]
    Eq = np.zeros((u, q))
    Eq[idx, np.arange(q)] = 1.0
    S = adj.solve_normal(Eq)
    Sss = 0.5 * (S[idx] + S[idx].T)
    s_hat = adj.x[problem.params.free][idx]
    W = la.inv(Sss)
    W = 0.5 * (W + W.T)
    T = float(s_hat @ W @ s_hat)
    alpha, d1, dq = policy.alpha(q), policy.delta0(1), policy.delta0(q)
    kind = problem.params.kind[problem.params.free]
    k = np.flatnonzero(kind == "k")
    # group: effect on k of unit AP errors, ∇k = Σ_kŝ Σ_ŝŝ⁻¹ ∇s
    Dk = S[k] @ W
    M = coordinate_norm(adj, Dk, idx)
    mu, Ur = la.eigh(M, W)
    rel_max = float(dq * np.sqrt(max(mu[-1], 0.0)))
    most = Ur[:, -1] / np.linalg.norm(Ur[:, -1])
    # determinability in direction s (F80 eq. 14): HᵀPH = A_sᵀ P A_s
    As = adj.A[:, idx]
    HPH = np.asarray((As.T @ adj.P @ As).todense())
    nu, Vd = la.eigh(HPH, W)
    dprime = float(dq * np.sqrt(max(nu[-1], 0.0)))
    weakest = Vd[:, -1] / np.linalg.norm(Vd[:, -1])
    # single parameters: s_j alone excluded, the others of the group kept
    rel = np.empty(q)
    for j in range(q):
        Dj = S[k][:, [j]] / Sss[j, j]
        Mj = coordinate_norm(adj, Dj, idx[[j]])[0, 0]
        rel[j] = d1 * np.sqrt(max(Mj, 0.0) * Sss[j, j])
    lam = np.maximum(la.eigvalsh(Sss), 0.0)
    return APTest(labels=tuple(labels), estimate=s_hat, cov=Sss, T=T, q=q, alpha=alpha,
                  critical=policy.critical_T(q), delta0_1=d1, delta0_q=dq,
                  determinability=d1 * np.sqrt(np.diag(Sss)), ellipsoid_axes=dq * np.sqrt(lam),
                  reliability=rel, reliability_max=rel_max, delta0_prime_max=dprime,
                  weakest=weakest, most_influential=most)
