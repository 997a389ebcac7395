"""Steps 1-2 of robust estimation (:mod:`baarda.stats.robust`, R84 §6, §8): iteratively
reweighted least squares — R84's start weights and Huber's function while large errors may act,
then reweighting after converged adjustments with the method's function (Huber H64, the Danish
method KJK80) — with the weight floor that keeps down-weighted observations' unknowns determined.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..adjust import adjust
from ..errors import DatumDefectError, SingularError
from .weights import danish, global_score, huber, start_factor

#: smallest weight factor: keeps a downweighted observation's parameters determined
WEIGHT_FLOOR = 1e-8
#: the redescending methods start with Huber's convex function until its weights change less
#: than this: a redescending function applied to a least-squares fit distorted by a large error
#: would reject the error's good neighbours with it
HUBER_START_TOL = 1e-2
NON_PHOTOGRAMMETRIC = ("control-", "coordinate-")
#: R84 §8: the start weight of non-photogrammetric observations (photogrammetric ones: 1)
R84_START_NONPHOTO = 1e-2
#: the start phase ends once the Gauss-Newton step is below this many conditional σ
START_STEP = 1.0


def residuals_at(problem, x) -> np.ndarray:
    """v = f(x) − l of every observation of ``problem`` at the parameters ``x`` (nonlinear).

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The observations and their functions.
    x : numpy.ndarray
        Parameters (the problem's units: metres, radians, image units).

    Returns
    -------
    numpy.ndarray
        The residual of each observation, in its own unit.
    """
    f = np.empty(problem.n)
    for s in problem.sets:
        f[s.rows] = s.evaluate(x)[0]
    return problem.misclosure(f)


def undetermined_ids(err) -> set:
    """Ids of the points or images whose unknowns a singular system's error names.

    ``P7.x`` → ``P7``, ``308.X0`` → ``308``.

    Parameters
    ----------
    err : baarda.errors.SingularError or baarda.errors.DatumDefectError
        The error of a singular adjustment.

    Returns
    -------
    set of str
        The ids (unitless).
    """
    names = list(getattr(err, "undetermined", []) or [])
    if getattr(err, "unknown", None) is not None:
        names.append(str(err.unknown))
    return {n.rsplit(".", 1)[0] for n in names}


def cluster_entities(problem) -> list[set]:
    """The ids of the points and images each covariance cluster observes.

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The observations, their clusters and their ids.

    Returns
    -------
    list of set of str
        Per cluster, the ids of the points and images it observes (unitless).
    """
    out = []
    for m in problem.cov.members:
        ids = set()
        for i in m:
            d = problem.info.ids[i]
            for key in ("point", "id", "from", "to", "image"):
                if key in d:
                    ids.add(str(d[key]))
        out.append(ids)
    return out


def per_observation(values, members, n) -> np.ndarray:
    """A value per covariance cluster spread to its observations.

    Parameters
    ----------
    values : numpy.ndarray
        One value per cluster (any unit).
    members : list of numpy.ndarray
        The observations of each cluster.
    n : int
        The number of observations.

    Returns
    -------
    numpy.ndarray
        Each observation's cluster value (the unit of ``values``).
    """
    out = np.empty(n)
    for c, m in enumerate(members):
        out[m] = values[c]
    return out


def irls(problem, method, options, tol, max_iter, k):
    """Steps 1-2 of robust estimation (R84 §6, §8; :mod:`baarda.stats.robust`).

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        The observations with their a priori covariance.
    method : str
        ``huber``, ``danish`` or ``r84``.
    options : baarda.adjust.Options
        Options of each adjustment.
    tol : float
        Largest change of a weight factor (unitless) at which the reweighting ends.
    max_iter : int
        At most this many adjustments.
    k : float or None
        The weight function's constant (in σ of the standardised residual; default 2 for Huber,
        3 for the Danish method).

    Returns
    -------
    tuple
        (the last adjustment, the weight factor per cluster (unitless), the standardised residual
        u per observation (σ), iterations, whether it converged, the history of the largest
        weight change, the floors raised (dicts)).
    """
    cov = problem.cov
    sigma = cov.sigma()
    members = cov.members
    ncl = len(members)
    kinds = problem.info.kind
    nonphoto = np.array([kinds[m[0]].startswith(NON_PHOTOGRAMMETRIC) for m in members])
    start = np.where(nonphoto, R84_START_NONPHOTO, 1.0) if method == "r84" else np.ones(ncl)
    s = start.copy()
    # large errors are found before the adjustment (R84 §6: they break the geometry of the first
    # step): the start factors follow Huber's function of the misclosures at the approximations
    v0 = residuals_at(problem, problem.params.x0)
    u0 = np.abs(v0) * np.sqrt(per_observation(s, members, problem.n)) / sigma
    f = huber(np.array([u0[m].max() for m in members]), 2.0)
    floor = np.full(ncl, WEIGHT_FLOOR)
    c_fun = k or (2.0 if method == "huber" else 3.0)
    entities = None
    floored = []
    x0, adj, u_obs = None, None, None
    converged = False
    history = []
    # R84 §6, §8: while large errors may act, the weights follow every Gauss-Newton step (the
    # adjustment is "stopped before reaching the point of convergence"), with Huber's convex
    # function; then reweighting after converged adjustments with the method's function
    phase = "start"
    g = 0.0
    one_step = dataclasses.replace(options, max_iter=1)
    it = 0
    tries = 0
    restarted = False
    while it < max_iter:
        total = np.maximum(s * f, floor)
        p = dataclasses.replace(problem, cov=cov.scaled(1.0 / total))
        try:
            adj = adjust(p, one_step if phase == "start" else options, x0=x0)
        except (DatumDefectError, SingularError) as err:
            if adj is None or tries >= 20:
                raise
            tries += 1
            if x0 is not None and not restarted:
                # singular after a long step from a distorted fit: again from the approximations
                x0, restarted = None, True
                continue
            # the down-weighted observations leave some points or images undetermined: raise the
            # floor of their observations (of all down-weighted ones if the error names none)
            entities = entities or cluster_entities(problem)
            bad = undetermined_ids(err)
            hit = np.array([bool(e & bad) for e in entities])
            if not hit.any():
                hit[:] = True
            low = hit & (s * f < 10 * floor)
            if not low.any():
                raise
            floor[low] = np.minimum(1.0, floor[low] * 10.0)
            floored.append({"unknowns": sorted(bad), "floor": float(floor[low].max()), "iteration": it + 1})
            continue
        it += 1
        restarted = False
        x0 = adj.x
        r = np.maximum(adj.r, 0.1)
        u_obs = np.abs(adj.v) * np.sqrt(per_observation(s, members, problem.n)) / (sigma * np.sqrt(r))
        u = np.array([u_obs[m].max() for m in members])
        if phase == "start":
            new_f = huber(u, c_fun if method == "huber" else 2.0)
        elif method == "huber":
            new_f = huber(u, c_fun)
        else:
            new_f = danish(u, c_fun)
        new_s = s
        if method == "r84":
            # the start weights only ever tend towards the a priori weights (g never decreases)
            g = max(g, float(danish(global_score(adj.vPv, adj.dof), c_fun)))
            new_s = start_factor(start, g)
        change = float(np.abs(new_s * new_f - s * f).max())
        history.append(change)
        f, s = new_f, new_s
        if phase == "start":
            step = adj.history[-1] if adj.history else 0.0
            if change < HUBER_START_TOL and step < START_STEP:
                phase = "reweight"        # the geometry has settled: on with converged fits
            continue
        if change < tol:
            converged = True
            break
    return adj, np.maximum(s * f, floor), u_obs, it, converged, tuple(history), tuple(floored)
