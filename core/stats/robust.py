"""Robust estimation by iteratively reweighted least squares (M84 §3.1, R84).

Each iteration adjusts with weights p_i f(u_i), f a weight function of the normalised residual
u_i = |v_i| / (σ_i √r_i) of the previous iteration, with σ_i the a priori standard deviation and
r_i the redundancy number of the starting adjustment (at least 0.1), so that u is Baarda's w in
the first iteration and an error does not hide in its well-controlled neighbours' residuals
(for a 2 × 2 or 3 × 3 cluster the largest member's u, so that a cluster keeps its covariance
shape); until no weight factor changes by more than ``tol``. Weight functions:

- ``huber``:   f(u) = 1 for u ≤ k, k/u above (k = 2);
- ``danish``:  f(u) = 1 for u ≤ c, exp(1 − (u/c)²) above (c = 3) — the Danish method of Krarup
  and Kubik in the exponential form of Kubik, Weng & Frederiksen; weights fall fast, so a gross
  error ends with a weight near 0 while the rest keep theirs. It starts from Huber's weights
  (``HUBER_START_TOL``): from a least-squares fit that a large error has distorted, a
  redescending function would reject the error's neighbours along with it;
- ``r84``:      the scheme of the ISPRS 1984 report (R84): photogrammetric observations start with
  weight 1 and non-photogrammetric ones (control, coordinates) with 1/100, so that large errors in
  control cannot pull the block while the image geometry settles; the starting factor of the latter
  grows tenfold per iteration up to its a priori weight, and the Danish function acts on all.

Robust estimation gives no reliability measures of its own (M84 §3.2): the result carries the
final least-squares adjustment with the robust weights' suspects left out, whose data snooping is
reported beside the robust findings.

Detected errors are classed after R84 §6 by their size |∇̂| ≈ |v_i| (the residual of an observation
with weight ≈ 0 is its error): below 4σ part of the random errors; small 4σ-50σ; medium 50σ to
``medium_base`` base lengths; large above that (in image units, the base is the image base b = B c/H
of the block, when known).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..adjust import Options, adjust
from ..errors import BaardaError
from ..model.problem import subset

METHODS = ("huber", "danish", "r84")
#: smallest weight factor: keeps a downweighted observation's parameters determined
WEIGHT_FLOOR = 1e-4
#: the redescending methods start with Huber's convex function until its weights change less
#: than this: a redescending function applied to a least-squares fit distorted by a large error
#: would reject the error's good neighbours with it
HUBER_START_TOL = 1e-2
NON_PHOTOGRAMMETRIC = ("control-", "coordinate-")


def huber(u, k=2.0):
    """Huber's weight function: 1 for u ≤ k, k/u above."""
    u = np.asarray(u, dtype=float)
    return np.where(u <= k, 1.0, k / np.maximum(u, 1e-300))


def danish(u, c=3.0):
    """Danish method (Krarup, Kubik): 1 for u ≤ c, exp(1 − (u/c)²) above."""
    u = np.asarray(u, dtype=float)
    return np.where(u <= c, 1.0, np.exp(np.minimum(0.0, 1.0 - (u / c) ** 2)))


def error_class(size_sigma: float, size_base: float | None = None, medium_base: float = 2.5) -> str:
    """R84 §6 class of a gross error of ``size_sigma`` σ (and ``size_base`` base lengths)."""
    if size_sigma < 4:
        return "random"
    if size_sigma <= 50:
        return "small"
    if size_base is None or size_base <= medium_base:
        return "medium"
    return "large"


@dataclass(frozen=True, eq=False)
class RobustResult:
    method: str
    weights: np.ndarray          # final weight factor per observation (0..1)
    adjustment: object           # the last reweighted adjustment
    iterations: int
    converged: bool
    suspects: list               # dicts: index, weight, residual, size_sigma, class
    final: object = None         # least squares without the suspects (for data snooping beside)
    history: tuple = ()

    def as_dict(self) -> dict:
        return {"method": self.method, "iterations": self.iterations, "converged": self.converged,
                "suspects": self.suspects}


def _image_base(problem) -> float | None:
    """The image base b = B c / H of a block (image units), from Problem.extra["block"]."""
    blk = problem.extra.get("block") if problem.extra else None
    if not blk or not blk.get("images"):
        return None
    try:
        by_strip: dict = {}
        for im in blk["images"]:
            by_strip.setdefault(im.get("strip", 0), []).append((im["X0"], im["Y0"]))
        gaps = [np.hypot(*np.diff(np.array(v), axis=0).T) for v in by_strip.values() if len(v) > 1]
        B = float(np.median(np.concatenate(gaps)))
        c = float(blk["camera"]["c"]) if "c" in blk.get("camera", {}) else float(blk["camera"]["principal_distance"])
        H = float(blk.get("flying_height"))
        return B * c / H
    except (KeyError, TypeError, ValueError):
        return None


def estimate(problem, method: str = "danish", options: Options | None = None, tol: float = 1e-3,
             max_iter: int = 100, min_size: float = 4.0, medium_base: float = 2.5,
             k: float | None = None) -> RobustResult:
    """IRLS with ``method`` (huber, danish, r84).

    Suspects are the clusters (image points, vectors, single observations) whose normalised
    residual u in the robust fit exceeds the w-test's critical value, whose estimated error is at
    least ``min_size`` σ (R84 §6: below 4σ errors are random) and — for the redescending methods,
    which separate errors sharply — whose weight the method halved at least.
    """
    if method not in METHODS:
        raise BaardaError(f"unknown robust method '{method}' (known: {', '.join(METHODS)})")
    options = options or Options()
    cov = problem.cov
    sigma = cov.sigma()
    members = cov.members
    nonphoto = np.array([k_.startswith(NON_PHOTOGRAMMETRIC) for k_ in problem.info.kind])
    start = np.ones(len(members))
    if method == "r84":
        start = np.array([0.01 if nonphoto[m[0]] else 1.0 for m in members])
    f = start.copy()
    x0 = None
    adj = None
    converged = False
    history = []
    it = 0
    r0 = None
    phase = "huber"
    for it in range(1, max_iter + 1):
        p = dataclasses.replace(problem, cov=cov.scaled(1.0 / np.maximum(f, WEIGHT_FLOOR)))
        adj = adjust(p, options, x0=x0)
        x0 = adj.x
        if r0 is None:
            r0 = np.maximum(adj.r, 0.1)
        u_obs = np.abs(adj.v) / (sigma * np.sqrt(r0))
        u = np.array([u_obs[m].max() for m in members])
        if method == "huber" or (phase == "huber"):
            new = huber(u, 2.0 if method != "huber" else (k or 2.0))
            if method != "huber" and float(np.abs(new - f).max()) < HUBER_START_TOL:
                phase = "redescending"     # Huber has settled: switch to the Danish function
                history.append(float(np.abs(new - f).max()))
                f = new
                continue
        elif method == "danish":
            new = danish(u, k or 3.0)
        else:
            # R84: the ramp of the current iteration sets the σ the residuals are judged with,
            # so that control held loosely at first is not mistaken for erroneous control
            ramp_now = np.minimum(1.0, start * 10.0 ** (it - 1))
            ramp = np.minimum(1.0, start * 10.0 ** it)
            new = danish(u * np.sqrt(ramp_now), k or 3.0) * ramp
        change = float(np.abs(new - f).max())
        history.append(change)
        f = new
        if change < tol:
            converged = True
            break
    w_obs = np.empty(problem.n)
    for c, m in enumerate(members):
        w_obs[m] = f[c]
    base = _image_base(problem)
    crit = adj.critical_w
    suspects = []
    image_kind = np.array([k_.startswith("image-") for k_ in problem.info.kind])
    u_obs = np.abs(adj.v) / (sigma * np.sqrt(r0))
    for c, m in enumerate(members):
        i = int(m[np.argmax(u_obs[m])])
        if u_obs[i] <= crit or (method != "huber" and w_obs[i] >= 0.5):
            continue
        # the error estimate: the residual itself once downweighted, else v/r (F80 eq. 10)
        err_m = np.abs(adj.v[m]) / (1.0 if w_obs[i] < 0.5 else r0[m])
        j = int(np.argmax(err_m / sigma[m]))
        err = float(err_m[j])
        size = float(err / sigma[m[j]])
        if size < min_size:
            continue
        size_base = float(err / base) if (base and image_kind[i]) else None
        suspects.append({"index": i, "members": [int(j) for j in m], "kind": problem.info.kind[i],
                         "ids": problem.info.ids[i], "weight": float(w_obs[i]),
                         "residual": float(adj.v[i]), "statistic": float(u_obs[i]), "size_sigma": size,
                         "size_base": size_base, "class": error_class(size, size_base, medium_base)})
    suspects.sort(key=lambda d: -d["size_sigma"])
    out = sorted(j for d in suspects for j in d["members"])
    keep = np.setdiff1d(np.arange(problem.n), out)
    final = None
    if 0 < keep.size < problem.n:      # every observation suspect: nothing left to adjust
        try:
            final = adjust(subset(problem, keep), options, x0=adj.x)
        except BaardaError:
            final = None
    return RobustResult(method, w_obs, adj, it, converged, suspects, final, tuple(history))
