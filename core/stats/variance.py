"""Variance-component estimation per observation group (Förstner 1980, eq. 9).

D(l) = Σ_j σ0j² C_j with C_j the a priori covariance of group j (F80 eq. 2). With the
adjustment's P and C_vv, the estimate of each factor is

    σ̂0j² = vᵀ P C_j P v / tr(C_vv P C_j P) = v_jᵀ P_j v_j / Σ_{i∈j} r_i

(the second form for groups made of whole covariance clusters). The covariance of group j is
rescaled by σ̂0j², the problem readjusted, and this repeated until every new estimate is 1 within
``tol`` (Förstner's iterated estimator). At convergence the standard error of a factor is
σ̂0j² √(2 (S⁻¹)_jj) with S_jk = tr(W C_j W C_k), W = P Q_vv P and C_j the group's covariance as it
stands (Förstner 1979); σ̂0j² √(2 / r_j), r_j = Σ_{i∈j} r_i, is its diagonal approximation, used
above :data:`RIGOROUS_MAX_N` observations.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..adjust import Options, adjust
from ..errors import BaardaError

#: a group with less redundancy than this cannot be estimated (its factor would be noise)
MIN_GROUP_REDUNDANCY = 0.5
#: up to this many observations the standard errors are the rigorous f_j √(2 (S⁻¹)_jj) (dense
#: n × n matrices); above it the approximation f_j √(2 / r_j)
RIGOROUS_MAX_N = 3000

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
    #: "rigorous": f_j √(2 (S⁻¹)_jj); "approximate": f_j √(2 / r_j) (problems above RIGOROUS_MAX_N)
    std_error_method: str = "rigorous"

    def summary(self) -> dict:
        """How the estimate ended: ``converged``, ``iterations`` and the standard errors' method."""
        return {"kind": "families", "converged": bool(self.converged), "iterations": int(self.iterations),
                "std_error": self.std_error_method}

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
            if red[j] <= MIN_GROUP_REDUNDANCY:
                raise BaardaError(f"variance components: group '{list(groups)[j]}' has no redundancy "
                                  f"to estimate from (Σ r_i = {red[j]:.2g}): merge it with another group")
            new[j] = float(adj.v[ix] @ Pv[ix]) / red[j]
        factors = factors * new
        if np.abs(new - 1.0).max() < tol:
            converged = True
            break
    red_final = np.array([adj.r[ix].sum() for ix in groups.values()])
    if problem.n <= RIGOROUS_MAX_N:
        masks = [np.isin(np.arange(problem.n), ix) for ix in groups.values()]
        C = np.linalg.inv(adj.P.toarray())
        S, _ = _trace_matrix(adj, [C * (m[:, None] & m[None, :]) for m in masks])
        se, method = factors * np.sqrt(2.0 * np.diag(np.linalg.inv(S))), "rigorous"
    else:
        se, method = factors * np.sqrt(2.0 / red_final), "approximate"
    return VarianceComponents(tuple(groups), factors, red_final, se, it, converged, adj, method)


# -- additive components: the radial model of F80 §2.1 ---------------------------------------------

@dataclass(frozen=True, eq=False)
class ComponentEstimate:
    """Estimated variance components θ_j of D(l) = Σ_j θ_j C_j (F80 eq. 2, eq. 9)."""

    names: tuple[str, ...]
    theta: np.ndarray
    redundancy: np.ndarray       # tr(C_vv P Q_j P), the share of the redundancy of component j
    std_error: np.ndarray        # √(2 (S⁻¹)_jj) at convergence; θ_j √(2 / r_j) otherwise
    iterations: int
    converged: bool
    adjustment: object

    def as_dict(self) -> list[dict]:
        return [{"component": n, "theta": float(t), "redundancy": float(r), "std_error": float(s)}
                for n, t, r, s in zip(self.names, self.theta, self.redundancy, self.std_error)]


def _cluster_stack(blocks, members):
    return np.array([blocks[c] for c in members])


def _trace_matrix(adj, Cj: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """S_jk = tr(W C_j W C_k) and r_j = tr(Q_vv P C_j P), W = P Q_vv P = P − P A N⁻¹ Aᵀ P, for dense n × n component
    matrices C_j (Förstner 1979; F80 eq. 9 is its diagonal form). At convergence of the iterated
    estimate, D(σ̂_j²) = 2 (S⁻¹)_jj with C_j the components as they stand (Förstner 1979)."""
    A = adj.Ar.toarray()
    P = adj.P.toarray()
    C = np.linalg.inv(P)
    R = (C - A @ adj.factor.solve(A.T)) @ P          # Q_vv P
    RC = [R @ (Cm @ P) for Cm in Cj]
    return np.array([[np.sum(X * Y.T) for Y in RC] for X in RC]), np.array([np.trace(X) for X in RC])


def _helmert_step(adj, components, names, problem):
    """One step of the full estimator: S θ = q with S_jk = tr(R C_j P R C_k P), R = C_vv P,
    q_j = vᵀ P C_j P v (Förstner 1979; F80 eq. 9 is its diagonal form). Dense in n."""
    Pv = adj.Pv
    Cj = []
    for n in names:
        M = np.zeros((problem.n, problem.n))
        for idx, b in zip(problem.cov.members, components[n]):
            M[np.ix_(idx, idx)] = b
        Cj.append(M)
    S, red = _trace_matrix(adj, Cj)
    q = np.array([Pv @ Cm @ Pv for Cm in Cj])
    theta = np.linalg.solve(S, q)
    return theta, np.sqrt(2.0 * np.diag(np.linalg.inv(S))), red



def estimate_components(problem, components: dict[str, tuple], theta0=None, options: Options | None = None,
                        tol: float = 1e-5, max_iter: int = 100, dense_max: int = 4000) -> ComponentEstimate:
    """Iterated estimation of additive variance components (F80 eq. 9).

    ``components`` maps a name to per-cluster blocks C_j (aligned with ``problem.cov.members``;
    zero blocks where a component does not act). Up to ``dense_max`` observations the full
    estimator is iterated (S θ = q, see :func:`_helmert_step`; it converges in a few steps even for
    nearly collinear components such as the radial model's a² and b²c²), with the standard errors
    √(2 (S⁻¹)_jj). Above, F80's form with Q_j = θ_j C_j:  θ_j ← θ_j · vᵀPQ_jPv / tr(C_vv P Q_j P),
    which needs only cluster blocks of C_vv but converges slowly for correlated components.
    """
    names = tuple(components)
    ncl = len(problem.cov.members)
    for name, blocks in components.items():
        if len(blocks) != ncl:
            raise BaardaError(f"variance component '{name}': {len(blocks)} blocks for {ncl} clusters")
    theta = np.ones(len(names)) if theta0 is None else np.asarray(theta0, dtype=float).copy()
    sizes = np.array([m.size for m in problem.cov.members])
    x0 = None
    adj = None
    converged = False
    it = 0
    red = np.zeros(len(names))
    for it in range(1, max_iter + 1):
        blocks = tuple(sum(t * np.asarray(components[n][c]) for t, n in zip(theta, names)) for c in range(ncl))
        cov = dataclasses.replace(problem.cov, blocks=blocks)
        p = dataclasses.replace(problem, cov=cov)
        adj = adjust(p, options, x0=x0)
        x0 = adj.x
        if problem.n <= dense_max:
            new_theta, se, red = _helmert_step(adj, components, names, problem)
            red = red * theta          # tr(C_vv P Q_j P) with Q_j = θ_j C_j of this adjustment
            if (new_theta <= 0).any():
                if it >= max_iter // 2:
                    bad = [f"{n} = {t:.3g}" for n, t in zip(names, new_theta) if t <= 0]
                    raise BaardaError(f"variance components: estimate {', '.join(bad)} is not positive "
                                      "(the model does not fit, or the component is not determinable)")
                new_theta = np.maximum(new_theta, 0.1 * theta)   # keep C positive definite, go on
            change = np.abs(new_theta / theta - 1.0).max()
            theta = new_theta
            if change < tol:
                converged = True
                return ComponentEstimate(names, theta, red, se, it, converged, adj)
            continue
        Pv = adj.Pv
        num = np.zeros(len(names))
        red = np.zeros(len(names))
        for members, C, Cvv in adj.cluster_cvv():
            cl = problem.cov.cluster[members[:, 0]]
            Pc = np.linalg.inv(C)
            pv = Pv[members]
            for j, n in enumerate(names):
                Q = theta[j] * _cluster_stack(components[n], cl).reshape(C.shape)
                num[j] += float(np.einsum("ki,kij,kj->", pv, Q, pv))
                red[j] += float(np.einsum("kij,kjl,klm,kmi->", Cvv, Pc, Q, Pc))
        if (red <= 1e-12).any():
            bad = [n for n, r in zip(names, red) if r <= 1e-12]
            raise BaardaError(f"variance components: {', '.join(bad)} without redundancy")
        factor = num / red
        theta = theta * factor
        if (theta <= 0).any():
            raise BaardaError("variance components: an estimate became negative (the model does not fit)")
        if np.abs(factor - 1.0).max() < tol:
            converged = True
            break
    del sizes
    return ComponentEstimate(names, theta, red, theta * np.sqrt(2.0 / red), it, converged, adj)


def radial_components(problem) -> dict[str, tuple]:
    """The radial model σ_r² = a² + b² c² / cos⁴α of F80 §2.1 for the image observations of a block.

    Components: ``a²`` (C = I on image coordinates), ``b²c²`` (C = diag(1/cos⁴α), α the angle of the
    ray to the optical axis, cos²α = c² / (c² + ρ²), ρ the radial distance of the observed point
    from the principal point), and ``other`` (the a priori covariance of every non-image cluster,
    e.g. control). Each 2 × 2 image cluster gets diagonal blocks.
    """
    blk = problem.extra.get("block") if problem.extra else None
    if not blk or "camera" not in blk:
        raise BaardaError("the radial variance model needs a block with a camera (principal distance)")
    cams = {c["id"]: c for c in blk.get("cameras", [blk["camera"]])}
    img_cam = {im["id"]: im.get("camera", blk["camera"]["id"]) for im in blk["images"]}
    info = problem.info
    kinds = info.kind
    a2, b2, other = [], [], []
    for c, idx in enumerate(problem.cov.members):
        m = idx.size
        if all(kinds[i].startswith("image-") for i in idx):
            ids = info.ids[idx[0]]
            cam = cams[img_cam[ids["image"]]]
            xy = {info.ids[i]["component"]: problem.l[i] for i in idx}
            rho2 = (xy.get("x", cam["x0"]) - cam["x0"]) ** 2 + (xy.get("y", cam["y0"]) - cam["y0"]) ** 2
            inv_cos4 = ((cam["c"] ** 2 + rho2) / cam["c"] ** 2) ** 2
            a2.append(np.eye(m))
            b2.append(np.eye(m) * inv_cos4)
            other.append(np.zeros((m, m)))
        else:
            a2.append(np.zeros((m, m)))
            b2.append(np.zeros((m, m)))
            other.append(np.asarray(problem.cov.blocks[c]))
    return {"a²": tuple(a2), "b²c²": tuple(b2), "other": tuple(other)}
