"""The test of the check points: do the adjusted coordinates agree with the known ones?

A check point k takes part only through its image measurements; its known coordinates X_ref,k
(σ per axis from the file, independent of the block's observations) are compared afterwards
(:func:`baarda.model.bundle.check_points`). Under H0 — no gross error in the check point's
measurements or its known coordinates, and no systematic error of the block — the difference
d_k = X̂_k − X_ref,k has expectation 0 and covariance

.. math:: Σ_{d,k} = Σ_{\\hat x \\hat x, k} + Σ_{ref, k}

(the 3 × 3 block of the adjusted point, in the datum of the control points, σ0 as the problem
uses it; Σ_ref diagonal). The test statistic T_k = d_kᵀ Σ_{d,k}⁻¹ d_k ~ χ²(3) is that of a
q-dimensional hypothesis with known covariance (F80 eq. 10-12); it is rejected when T_k exceeds
χ²_{1−α_q}(q) with the policy's α_q (α0, or the B-method's). The RMSE the precision predicts
per axis, √(mean_k Σ_d,k,aa), says how far the observed RMSE is from what the block promises.

In a free block (S-base datum) the known coordinates are in another frame than the adjusted
ones: no test is made there.

References (full in the package docstring): F80; M84 (check points as an independent judgement
of a block's accuracy, §1).
"""

from __future__ import annotations

import numpy as np


def check_point_tests(adj, rep: dict, policy) -> dict:
    """The check-point report ``rep`` with the test of each point (module docstring).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    rep : dict
        :func:`baarda.model.bundle.check_points` of it (lengths in object units, m).
    policy : baarda.stats.policy.TestPolicy
        The test decision (α0, β0, B-method).

    Returns
    -------
    dict
        A new dict: ``rep`` with ``expected_rms`` (m, per axis), ``critical`` χ²_{1−α}(3),
        ``alpha``, ``n_rejected`` and per point ``T`` (dimensionless) and ``rejected``; in a free
        block (no test) ``expected_rms``, ``T`` and ``critical`` are NaN, ``rejected`` False and
        ``note`` says why.
    """
    out = dict(rep)
    points = [dict(p) for p in rep["points"]]
    out["points"] = points
    free = adj.problem.datum.kind == "free"
    where = {str(pid): i for i, pid in enumerate(adj.problem.points.ids)}
    q = 3
    crit = float("nan") if free else float(policy.critical_T(q))
    var = []
    for p in points:
        i = where[str(p["id"])]
        Sd = adj.point_cov[i] + np.diag(np.asarray(p.get("ref_sigma", (0.0, 0.0, 0.0)), dtype=float) ** 2)
        var.append(np.diag(Sd))
        d = np.asarray(p["diff"], dtype=float)
        if free or not np.isfinite(d).all() or np.linalg.eigvalsh(Sd)[0] <= 0:
            p["T"], p["rejected"] = float("nan"), False
            continue
        T = float(d @ np.linalg.solve(Sd, d))
        p["T"], p["rejected"] = T, bool(T > crit)
    var = np.array(var, dtype=float).reshape(-1, 3)
    out["expected_rms"] = (np.sqrt(var.mean(axis=0)).tolist() if points and not free else [float("nan")] * 3)
    out["critical"], out["q"] = crit, q
    out["alpha"] = float(policy.alpha(q))
    out["n_rejected"] = sum(p["rejected"] for p in points)
    if free:
        out["note"] = ("a free block: the adjusted coordinates are in the S-base's frame, not the known "
                       "coordinates' — no test")
    return out
