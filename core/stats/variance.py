"""Variance-component estimation per observation group (Förstner 1980, eq. 9).

D(l) = Σ_j σ0j² C_j with C_j the a priori covariance of group j (F80 eq. 2). With the
adjustment's P and C_vv, the estimate of each factor is

    σ̂0j² = vᵀ P C_j P v / tr(C_vv P C_j P) = v_jᵀ P_j v_j / Σ_{i∈j} r_i

(the second form for groups made of whole covariance clusters). The covariance of group j is
rescaled by σ̂0j², the problem readjusted, and this repeated until every factor is within ``tol``
(relative) of the iteration's fixed point (Förstner's iterated estimator): the iteration contracts
linearly, by ρ per step, so the distance left after a step δ is about δ ρ/(1 − ρ), ρ estimated
from the last two steps — a step below ``tol`` alone left Niemeier's network 3e-4 short. At convergence the standard error of a factor is
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
    "gnss-x": "GNSS", "gnss-y": "GNSS", "gnss-z": "GNSS",
    "imu-omega": "IMU", "imu-phi": "IMU", "imu-kappa": "IMU",
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
    #: the stated tolerance: every factor within it (relative) of the iteration's fixed point
    tolerance: float = 1e-4
    #: the estimated relative distance of the factors from the fixed point at the end
    distance: float = float("nan")

    def summary(self) -> dict:
        """How the estimate ended: ``converged``, ``iterations``, the standard errors' method, the
        ``tolerance`` and the estimated ``distance`` from the fixed point."""
        return {"kind": "families", "converged": bool(self.converged), "iterations": int(self.iterations),
                "std_error": self.std_error_method, "tolerance": float(self.tolerance),
                "distance": float(self.distance) if np.isfinite(self.distance) else None}

    def as_dict(self) -> list[dict]:
        return [{"group": n, "factor": float(f), "sigma_factor": float(np.sqrt(f)),
                 "redundancy": float(r), "std_error": float(s)}
                for n, f, r, s in zip(self.names, self.factors, self.redundancy, self.std_error)]


def merge_groups(groups: dict[str, np.ndarray], spec: str) -> dict[str, np.ndarray]:
    """``groups`` with the sets of ``spec`` merged, estimated with one factor (F80 eq. 9).

    "control+image" (or several, comma-separated, "angles+distances,control+image") makes one group
    "control+image" of both — for a group with too little redundancy of its own.

    Parameters
    ----------
    groups : dict
        Group name -> observation indices.
    spec : str
        The merges, as above.

    Returns
    -------
    dict
        Group name -> sorted observation indices.

    Raises
    ------
    baarda.errors.BaardaError
        For unknown names (listing the groups there are) or a merge of one group.
    """
    out = dict(groups)
    for part in (x.strip() for x in spec.split(",") if x.strip()):
        names = [n.strip() for n in part.split("+") if n.strip()]
        unknown = [n for n in names if n not in out]
        if unknown or len(names) < 2:
            raise BaardaError(f"--merge-groups {spec!r}: " + (f"no group {', '.join(map(repr, unknown))}"
                                                               if unknown else f"{part!r} names one group")
                              + f" (the groups: {', '.join(out)})")
        merged = np.sort(np.concatenate([out.pop(n) for n in names]))
        out["+".join(names)] = merged
    return out


def groups_by_kind(problem) -> dict[str, np.ndarray]:
    """Default variance-component groups: observation kinds of one family (F80 eq. 9).

    Distances, angles, image observations, control...: :data:`KIND_FAMILIES`.

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The problem.

    Returns
    -------
    dict
        Group name -> observation indices.
    """
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

    σ̂0j² = vᵀ P Q_j P v / tr(Q_vv P Q_j P), iterated with rescaled Q_j to convergence. Every
    covariance cluster must lie in one group; a group without redundancy cannot be estimated.

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The problem.
    groups : dict, optional
        Group name -> observation indices (default :func:`groups_by_kind`).
    options : baarda.adjust.Options, optional
        Adjustment options.
    tol : float
        Relative change of the factors at convergence.
    max_iter : int
        Iterations at most.

    Returns
    -------
    VarianceComponents
        Per group the factor σ̂0j² relative to the a priori covariance (dimensionless), its
        redundancy and standard error, and the final adjustment.

    Raises
    ------
    baarda.errors.BaardaError
        For overlapping groups, split clusters or a group without redundancy.
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
    prev, remaining = 0.0, float("inf")
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
                                  f"to estimate from (Σ r_i = {red[j]:.2g}): merge it with another group "
                                  f"(--merge-groups {list(groups)[j]}+{next(n for n in groups if n != list(groups)[j])})"
                                  if len(groups) > 1 else
                                  f"variance components: group '{list(groups)[j]}' has no redundancy to estimate "
                                  f"from (Σ r_i = {red[j]:.2g})")
            new[j] = float(adj.v[ix] @ Pv[ix]) / red[j]
        factors = factors * new
        step = float(np.abs(new - 1.0).max())
        # the iteration contracts linearly, factor ρ per step (estimated from the last two steps):
        # the fixed point is about step · ρ/(1 − ρ) away — stop when that, not the step, is below tol
        rho = step / prev if prev > 0 else 1.0
        remaining = step * rho / (1.0 - rho) if rho < 0.95 else step / 0.05
        prev = step
        if max(step, remaining) < tol:
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
    return VarianceComponents(tuple(groups), factors, red_final, se, it, converged, adj, method, float(tol),
                              float(max(prev, remaining)) if it else float("nan"))


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
    #: components held at 0 because their estimate was not positive (the constrained estimate)
    at_zero: tuple = ()
    notes: tuple = ()

    def as_dict(self) -> list[dict]:
        return [{"component": n, "theta": float(t), "redundancy": float(r),
                 "std_error": None if n in self.at_zero else float(s), "at_zero": n in self.at_zero}
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


def _helmert_step(adj, components, names, problem, fixed=None):
    """One step of the full estimator: S θ = q with S_jk = tr(R C_j P R C_k P), R = C_vv P,
    q_j = vᵀ P C_j P v (Förstner 1979; F80 eq. 9 is its diagonal form). Dense in n. ``fixed``
    (name → θ) are components held at a value, not estimated: their part S_jk θ_k is taken from q_j."""
    fixed = {k: v for k, v in (fixed or {}).items() if v != 0.0}
    Pv = adj.Pv
    Cj = []
    for n in list(names) + list(fixed):
        M = np.zeros((problem.n, problem.n))
        for idx, b in zip(problem.cov.members, components[n]):
            M[np.ix_(idx, idx)] = b
        Cj.append(M)
    S_all, red_all = _trace_matrix(adj, Cj)
    q = np.array([Pv @ Cm @ Pv for Cm in Cj[:len(names)]])
    m = len(names)
    S = S_all[:m, :m]
    if fixed:
        q = q - S_all[:m, m:] @ np.array(list(fixed.values()))
    theta = np.linalg.solve(S, q)
    return theta, np.sqrt(2.0 * np.diag(np.linalg.inv(S))), red_all[:m]


#: a component whose estimate is ≤ 0 this many steps in a row is held at 0
NONPOSITIVE_STEPS = 3


def _positive_definite(components, names, theta, ncl) -> bool:
    """Whether Σ_j θ_j C_j is positive definite in every cluster."""
    for c in range(ncl):
        C = sum(t * np.asarray(components[n][c]) for t, n in zip(theta, names))
        if np.linalg.eigvalsh(np.atleast_2d(C)).min() <= 0:
            return False
    return True


def estimate_components(problem, components: dict[str, tuple], theta0=None, options: Options | None = None,
                        tol: float = 1e-5, max_iter: int = 100, dense_max: int = 4000) -> ComponentEstimate:
    """Iterated estimation of additive variance components θ_j of D(l) = Σ_j θ_j C_j (F80 eq. 2, 9).

    ``components`` maps a name to per-cluster blocks C_j (aligned with ``problem.cov.members``;
    zero blocks where a component does not act). Up to ``dense_max`` observations the full
    estimator is iterated (S θ = q, see :func:`_helmert_step`; it converges in a few steps even for
    nearly collinear components such as the radial model's a² and b²c²), with the standard errors
    √(2 (S⁻¹)_jj). Above, F80's form with Q_j = θ_j C_j: θ_j ← θ_j · vᵀPQ_jPv / tr(C_vv P Q_j P),
    which needs only cluster blocks of C_vv but converges slowly for correlated components.

    A component whose full estimate stays ≤ 0 for :data:`NONPOSITIVE_STEPS` steps is held at 0
    and the others are estimated without it (the estimate constrained to θ_j ≥ 0; ``at_zero``
    and ``notes`` of the result say so); where 0 would leave some cluster without a positive
    definite covariance (the only component of the control points) it is held at its starting
    value instead, not estimated, which ``notes`` says.

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The problem.
    components : dict
        Name -> tuple of per-cluster cofactor blocks C_j.
    theta0 : array_like of float, optional
        Start values of θ (default 1 each), units of the observations squared per unit of C_j.
    options : baarda.adjust.Options, optional
        Adjustment options.
    tol : float
        Relative change of θ at convergence.
    max_iter : int
        Iterations at most.
    dense_max : int
        Largest number of observations for the full estimator.

    Returns
    -------
    ComponentEstimate
        θ_j (units of the observations squared per unit of C_j), the redundancy shares, standard
        errors (units of θ_j) and the final adjustment.

    Raises
    ------
    baarda.errors.BaardaError
        For blocks not aligned with the clusters or an estimate that is not positive.
    """
    names = tuple(components)
    ncl = len(problem.cov.members)
    for name, blocks in components.items():
        if len(blocks) != ncl:
            raise BaardaError(f"variance component '{name}': {len(blocks)} blocks for {ncl} clusters")
    theta = np.ones(len(names)) if theta0 is None else np.asarray(theta0, dtype=float).copy()
    start = theta.copy()
    x0 = None
    adj = None
    converged = False
    it = 0
    red = np.zeros(len(names))
    active = list(range(len(names)))      # the components estimated (others held at 0)
    nonpositive = np.zeros(len(names), dtype=int)
    at_zero, notes = [], []
    for it in range(1, max_iter + 1):
        blocks = tuple(sum(t * np.asarray(components[n][c]) for t, n in zip(theta, names)) for c in range(ncl))
        cov = dataclasses.replace(problem.cov, blocks=blocks)
        p = dataclasses.replace(problem, cov=cov)
        adj = adjust(p, options, x0=x0)
        x0 = adj.x
        if problem.n <= dense_max:
            act = [names[j] for j in active]
            held_at = {names[j]: float(theta[j]) for j in range(len(names)) if j not in active}
            est, se_a, red_a = _helmert_step(adj, components, act, problem, held_at)
            new_theta = theta.copy()
            new_theta[active] = est
            se = np.full(len(names), np.nan)
            se[active] = se_a
            red = np.zeros(len(names))
            red[active] = red_a * theta[active]   # tr(C_vv P Q_j P) with Q_j = θ_j C_j of this adjustment
            bad = [j for j in active if new_theta[j] <= 0]
            nonpositive[bad] += 1
            nonpositive[[j for j in active if j not in bad]] = 0
            stuck = [j for j in bad if nonpositive[j] >= NONPOSITIVE_STEPS]
            if stuck and len(active) > len(stuck):
                # a component that alone gives some cluster its covariance cannot be 0: kept at its start
                kept = []
                for j in stuck:
                    alone = theta.copy()
                    alone[j] = 0.0
                    if not _positive_definite(components, names, alone, ncl):
                        kept.append(j)
                held = theta.copy()
                for j in stuck:
                    held[j] = start[j] if j in kept else 0.0
                if _positive_definite(components, names, held, ncl):
                    # the constrained estimate: a component whose estimate stays ≤ 0 is held at
                    # 0 (the data show none of it under this model) — or, where 0 would leave some
                    # observations without covariance, at its starting value — and the others
                    # re-estimated
                    for j in stuck:
                        if j in kept:
                            notes.append(f"{names[j]} = {new_theta[j]:.3g} is not positive in {nonpositive[j]} steps "
                                         f"and 0 would leave observations without variance: held at its a priori "
                                         f"value {start[j]:.3g}, not estimated")
                        else:
                            notes.append(f"{names[j]} = {new_theta[j]:.3g} is not positive in {nonpositive[j]} "
                                         f"steps: held at 0 (the data show none of it under this model)")
                            at_zero.append(names[j])
                        active.remove(j)
                    theta = held
                    continue
            if bad:
                if it >= max_iter // 2 or stuck:
                    txt = [f"{names[j]} = {new_theta[j]:.3g}" for j in bad]
                    raise BaardaError(f"variance components: estimate {', '.join(txt)} is not positive "
                                      "(the model does not fit, or the component is not determinable)")
                new_theta[bad] = 0.1 * theta[bad]          # keep C positive definite, go on
            change = np.abs(new_theta[active] / theta[active] - 1.0).max()
            theta = new_theta
            if change < tol:
                converged = True
                return ComponentEstimate(names, theta, red, se, it, converged, adj, tuple(at_zero), tuple(notes))
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
    return ComponentEstimate(names, theta, red, theta * np.sqrt(2.0 / red), it, converged, adj)


#: the radial variance model's structures of the b²c² component (:func:`radial_components`)
RADIAL_STRUCTURES = ("radial", "isotropic")


def radial_cofactor(dx: float, dy: float, c: float, structure: str = "radial") -> np.ndarray:
    r"""The 2 × 2 cofactor of (x, y) that the ray's angular σ b contributes, per unit b² (F80 §2.1).

    F80 §2.1: σ_r² = a² + b² c² / cos⁴α is the variance of the *radial* component of an image
    point; b is the standard deviation of the ray's angle α to the optical axis. Derivation: the
    image point lies at the radial distance ρ = c tan α from the principal point, in the
    direction u = (dx, dy) / ρ. An error dα of the angle moves it along u by
    dρ = c / cos²α · dα, so its contribution to (x, y) is u · c/cos²α · dα with the variance
    b² c² / cos⁴α · u uᵀ (rank 1; the tangential component gets nothing from b), and

    .. math::  C_{xy} = a^2 I + \frac{b^2 c^2}{\cos^4\alpha}\, u u^T,
               \qquad \frac{1}{\cos^4\alpha} = \Big(\frac{c^2 + \rho^2}{c^2}\Big)^2 .

    At the principal point (ρ = 0) u is undefined; the mean of u uᵀ over all directions, I/2, is
    taken there. ``structure="isotropic"``: (1/cos⁴α) I, b²c²/cos⁴α on x and y alike (baarda ≤ 0.x's
    reading, which gives the tangential component the radial variance too).

    Parameters
    ----------
    dx, dy : float
        Image coordinates relative to the principal point, pixels (image units).
    c : float
        Principal distance, same unit as dx, dy.
    structure : str
        "radial" or "isotropic".

    Returns
    -------
    numpy.ndarray
        (1/cos⁴α) u uᵀ, 2 × 2, dimensionless: the cofactor of the component θ = b²c² (the unit of
        the image coordinates squared).

    Raises
    ------
    baarda.errors.BaardaError
        For an unknown ``structure``.
    """
    if structure not in RADIAL_STRUCTURES:
        raise BaardaError(f"unknown radial structure '{structure}' (known: {', '.join(RADIAL_STRUCTURES)})")
    rho2 = dx * dx + dy * dy
    inv_cos4 = ((c * c + rho2) / (c * c)) ** 2
    if structure == "isotropic":
        return inv_cos4 * np.eye(2)
    if rho2 <= (1e-12 * c) ** 2:
        return inv_cos4 * 0.5 * np.eye(2)
    u = np.array([dx, dy]) / np.sqrt(rho2)
    return inv_cos4 * np.outer(u, u)


def radial_components(problem, structure: str = "radial") -> dict[str, tuple]:
    """The radial model σ_r² = a² + b² c² / cos⁴α of F80 §2.1 for the image observations of a block.

    Components: ``a²`` (C = I on image coordinates), ``b²c²`` (C = (1/cos⁴α) u uᵀ, u the radial
    unit vector of the observed point, α the angle of the ray to the optical axis,
    cos²α = c² / (c² + ρ²), ρ the radial distance from the principal point:
    :func:`radial_cofactor` derives it; ``structure="isotropic"``: (1/cos⁴α) I), and ``other``
    (the a priori covariance of every non-image cluster, e.g. control). Each image cluster gets
    its 2 × 2 block (the rows and columns of its members' components).

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        A block with cameras (principal distance known).
    structure : str
        "radial" or "isotropic".

    Returns
    -------
    dict
        "a²", "b²c²", "other" -> tuple of per-cluster blocks, dimensionless cofactors (``other`` in
        the units of the observations squared).

    Raises
    ------
    baarda.errors.BaardaError
        Without a camera with a principal distance.
    """
    geo = problem.geometry
    if geo is None or not geo.cameras or any(c.c is None for c in geo.cameras):
        raise BaardaError("the radial variance model needs a block with a camera (principal distance)")
    info = problem.info
    kinds = info.kind
    a2, b2, other = [], [], []
    for c, idx in enumerate(problem.cov.members):
        m = idx.size
        if all(kinds[i].startswith("image-") for i in idx):
            ids = info.ids[idx[0]]
            cam = geo.camera_of(ids["image"])
            comp = [info.ids[i]["component"] for i in idx]
            xy = dict(zip(comp, problem.l[idx]))
            Cb = radial_cofactor(xy.get("x", cam.x0) - cam.x0, xy.get("y", cam.y0) - cam.y0, cam.c, structure)
            sel = ["xy".index(k) for k in comp]
            a2.append(np.eye(m))
            b2.append(Cb[np.ix_(sel, sel)])
            other.append(np.zeros((m, m)))
        else:
            a2.append(np.zeros((m, m)))
            b2.append(np.zeros((m, m)))
            other.append(np.asarray(problem.cov.blocks[c]))
    return {"a²": tuple(a2), "b²c²": tuple(b2), "other": tuple(other)}
