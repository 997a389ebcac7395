"""Iterative data snooping (Baarda; F80 §4, M84 §3.1).

Test every observation with w (σ0 a priori) or τ (σ0 a posteriori); if the largest statistic
exceeds its critical value, remove that observation, readjust and test again, until nothing is
rejected (or the redundancy would fall below ``min_dof``). Each step is logged: which
observation, its statistic, the estimated error ∇̂ = −(Pv)_i/(P C_vv P)_ii (the w-test's ∇ŝ of
F80 eq. 10 for H = e_i; −v_i/r_i for an uncorrelated observation), σ̂0 before and after, and its
*twins*: the observations whose w-test is (near-)perfectly correlated with the removed one's
(|ρ| ≥ 0.99, :func:`baarda.stats.separability.twins`; F80 §7.4, M84 §3.3) — the two images of a
2-ray point, say. The data cannot tell an error in the removed observation from one in a twin: the
largest |w| picks one of them by round-off. With ``b_method`` the critical value is Baarda's
consistent one (the 1D test's α0), as for the single pass.

The "find the error" view (``leave_one_out``) shows how σ̂0 changes when each suspect is left out
in turn — the suspect whose removal lowers σ̂0 most is the likeliest culprit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..adjust import Options, adjust
from ..errors import BaardaError
from ..model.problem import subset
from .separability import THRESHOLD, twins
from .reliability import reliability_of


@dataclass(frozen=True)
class SnoopStep:
    removed: int              # index in the original problem
    statistic: float          # w (or τ) of the removed observation
    critical: float
    nabla: float              # estimated error −(Pv)_i / (P C_vv P)_ii (SI units; F80 eq. 10)
    sigma0_before: float
    sigma0_after: float
    twins: tuple[int, ...] = ()          # observations (original indices) with |ρ| ≥ 0.99 to the removed one
    twin_rho: tuple[float, ...] = ()     # their correlations ρ with the removed one's w (F80 §7.4)


@dataclass(frozen=True, eq=False)
class SnoopResult:
    steps: tuple[SnoopStep, ...]
    adjustment: object        # the final adjustment (without the removed observations)
    kept: np.ndarray          # original indices of the observations still in
    use_tau: bool = False
    log: list = field(default_factory=list)

    @property
    def removed(self) -> list[int]:
        return [s.removed for s in self.steps]


def iterate(problem, options: Options | None = None, use_tau: bool = False, max_steps: int | None = None,
            min_dof: int = 1, progress=None, check=None) -> SnoopResult:
    """Remove the worst rejected observation and readjust until no test rejects (B68; F80 §4, M84 §3.1).

    Baarda's w (σ0 a priori) or Pope's τ (σ0 a posteriori, P76); the estimated error of each removed
    observation is ∇̂ = −(Pv)_i/(P C_vv P)_ii (F80 eq. 10 for H = e_i).

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The problem.
    options : baarda.adjust.Options, optional
        Adjustment options.
    use_tau : bool
        Test with τ instead of w.
    max_steps : int, optional
        Observations removed at most (default: no limit).
    min_dof : int
        Smallest redundancy left.
    progress : callable, optional
        ``progress(step, SnoopStep)`` after each step.
    check : callable, optional
        Called before each readjustment and after each of its iterations (``adjust``'s
        ``progress``); it stops the run by raising (a cancelled dashboard task stops within the step
        it is in).

    Returns
    -------
    SnoopResult
        The steps (w or τ and σ̂0 dimensionless, ∇̂ in the units of the observation), the final
        adjustment and the kept observations.
    """
    options = options or Options()
    inner = None if check is None else (lambda _it, _step: check())
    kept = np.arange(problem.n)
    adj = adjust(problem, options)
    steps = []
    x = adj.x
    limit = max_steps if max_steps is not None else problem.n
    while len(steps) < limit:
        stat = np.abs(np.nan_to_num(adj.tau if use_tau else adj.w))
        crit = reliability_of(adj).critical_tau if use_tau else reliability_of(adj).critical_w
        i = int(np.argmax(stat))
        if stat[i] <= crit or adj.dof - 1 < min_dof:
            break
        qpp = adj.qvv_pp[i]
        nabla = float(-adj.Pv[i] / qpp) if qpp > 0 else float("nan")
        keep_local = np.setdiff1d(np.arange(adj.n), [i])
        reduced = subset(adj.problem, keep_local)
        if check is not None:
            check()
        try:
            new = adjust(reduced, options, x0=x, progress=inner)
        except BaardaError:
            break          # removing it would leave part of the model undetermined: stop here
        tw = twins(adj, i, THRESHOLD)
        steps.append(SnoopStep(int(kept[i]), float(stat[i]), float(crit), nabla,
                               float(adj.sigma0_post), float(new.sigma0_post),
                               tuple(int(kept[j]) for j, _ in tw), tuple(rho for _, rho in tw)))
        kept = kept[keep_local]
        adj, x = new, new.x
        if progress is not None:
            progress(len(steps), steps[-1])
    return SnoopResult(tuple(steps), adj, kept, use_tau)


def leave_one_out(adj, suspects, check=None) -> list[dict]:
    """σ̂0 with each suspect left out in turn (the "find the error" view; F80 §4).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    suspects : iterable of int
        Observation indices.
    check : callable, optional
        As for :func:`iterate`.

    Returns
    -------
    list of dict
        Per suspect: index, w, sigma0_without and ratio to σ̂0 (dimensionless; NaN where the
        reduced problem cannot be adjusted).
    """
    inner = None if check is None else (lambda _it, _step: check())
    out = []
    for i in suspects:
        if check is not None:
            check()
        keep = np.setdiff1d(np.arange(adj.n), [i])
        try:
            a = adjust(subset(adj.problem, keep), adj.options, x0=adj.x, progress=inner)
            s = float(a.sigma0_post)
        except BaardaError:
            s = float("nan")
        out.append({"index": int(i), "w": float(adj.w[i]), "sigma0_without": s,
                    "ratio": s / float(adj.sigma0_post) if adj.sigma0_post else float("nan")})
    return out
