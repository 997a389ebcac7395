"""Variance-component estimation per observation group (Förstner 1980, eq. 9).

D(l) = Σ_j σ0j² C_j with C_j the a priori covariance of group j (F80 eq. 2). With the
adjustment's P and C_vv, the estimate of each factor is

    σ̂0j² = vᵀ P C_j P v / tr(C_vv P C_j P) = v_jᵀ P_j v_j / Σ_{i∈j} r_i

(the second form for groups made of whole covariance clusters). The covariance of group j is
rescaled by σ̂0j², the problem readjusted, and this repeated until every new estimate is 1 within
``tol`` (Förstner's iterated estimator). The standard error of a factor is approximately
σ̂0j² √(2 / r_j) with r_j = Σ_{i∈j} r_i the group's redundancy.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .adjust import Options, adjust
from .errors import BaardaError

KIND_FAMILIES = {
    "distance": "distances", "slope-distance": "distances",
    "direction": "angles", "angle": "angles", "azimuth": "angles", "zenith-angle": "angles",
    "height-diff": "height differences", "dx": "vectors", "dy": "vectors", "dz": "vectors",
    "coordinate-x": "coordinates", "coordinate-y": "coordinates", "coordinate-z": "coordinates",
    "image-x": "image observations", "image-y": "image observations",
    "control-x": "control", "control-y": "control", "control-z": "control",
    "model-x": "model observations", "model-y": "model observations",
}


@dataclass(frozen=True, eq=False)
class VarianceComponents:
    """Estimated variance factors σ̂0j² (relative to the a priori covariances) per group."""

    names: tuple[str, ...]
    factors: np.ndarray
    redundancy: np.ndarray
    std_error: np.ndarray
    iterations: int
    converged: bool
    adjustment: object

    def as_dict(self) -> list[dict]:
        return [{"group": n, "factor": float(f), "sigma_factor": float(np.sqrt(f)),
                 "redundancy": float(r), "std_error": float(s)}
                for n, f, r, s in zip(self.names, self.factors, self.redundancy, self.std_error)]


def groups_by_kind(problem) -> dict[str, np.ndarray]:
    """Default groups: observation kinds of one family (distances, angles, image observations...)."""
    out: dict[str, list[int]] = {}
    for i, k in enumerate(problem.info.kind):
        out.setdefault(KIND_FAMILIES.get(k, k), []).append(i)
    return {name: np.asarray(ix) for name, ix in out.items()}


def _cluster_factors(problem, groups, factors):
    per_obs = np.ones(problem.n)
    for f, ix in zip(factors, groups.values()):
        per_obs[ix] = f
    per_cluster = np.array([per_obs[m[0]] for m in problem.cov.members])
    return per_cluster


def estimate(problem, groups: dict[str, np.ndarray] | None = None, options: Options | None = None,
             tol: float = 1e-4, max_iter: int = 50) -> VarianceComponents:
    """Iterated variance-component estimation (F80 eq. 9) for ``groups`` (name → observations).

    Every covariance cluster must lie in one group; a group without redundancy cannot be estimated.
    """
    groups = groups if groups is not None else groups_by_kind(problem)
    owner = np.full(problem.n, -1)
    for j, ix in enumerate(groups.values()):
        if (owner[ix] >= 0).any():
            raise BaardaError("variance components: an observation is in two groups")
        owner[ix] = j
    for m in problem.cov.members:
        if len(set(owner[m])) != 1:
            raise BaardaError("variance components: a covariance cluster is split between groups")
    if (owner < 0).any():
        raise BaardaError("variance components: some observations are in no group")
    factors = np.ones(len(groups))
    x0 = None
    converged = False
    adj = None
    it = 0
    for it in range(1, max_iter + 1):
        cov = problem.cov.scaled(_cluster_factors(problem, groups, factors))
        p = dataclasses.replace(problem, cov=cov)
        adj = adjust(p, options, x0=x0)
        x0 = adj.x
        Pv = adj.Pv
        new = np.empty(len(groups))
        red = np.empty(len(groups))
        for j, ix in enumerate(groups.values()):
            red[j] = adj.r[ix].sum()
            if red[j] <= 1e-9:
                raise BaardaError(f"variance components: group '{list(groups)[j]}' has no redundancy")
            new[j] = float(adj.v[ix] @ Pv[ix]) / red[j]
        factors = factors * new
        if np.abs(new - 1.0).max() < tol:
            converged = True
            break
    red_final = np.array([adj.r[ix].sum() for ix in groups.values()])
    return VarianceComponents(tuple(groups), factors, red_final, factors * np.sqrt(2.0 / red_final),
                              it, converged, adj)
