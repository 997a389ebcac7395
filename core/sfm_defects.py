"""Local defects of bundle blocks: points, images and cameras the observations do not determine.

A structure-from-motion block (:class:`baarda.model.sfm.SfmBlock`) or a photogrammetric block
(:class:`baarda.model.bundle.Block`) may hold entities whose unknowns its image points leave
undetermined, while the rest of the block is sound: a point seen from two images with the same
projection centre (zero baseline), a point on a single ray, an image that sees fewer than three
points, a camera whose refined intrinsics (or APs) get fewer equations than unknowns. Such a
*local* defect is not the 7-parameter gauge of a free block (that is the datum,
:mod:`baarda.datum`); baarda names each one (:class:`baarda.defects.LocalDefect`), leaves it out
and analyses the rest. ``baarda analyze --strict`` refuses the block instead.

The geometric pre-pass (:func:`find_defects`)
---------------------------------------------
Repeated until nothing changes (leaving out a point can starve an image; leaving out an image
can leave a point on one ray):

* **points** (not weighted control, whose coordinates are observed): fewer than two images
  (rays), or a largest angle γ between its rays so small that its depth is not determined.
  Two rays with an angular precision σ_θ = σ/f (σ of an image coordinate, f the principal
  distance in the same unit) meeting at the angle γ at a distance d fix the depth with

  .. math:: σ_d ≈ \\sqrt{2}\\, d\\, σ_θ / γ

  — the normal case of stereo photogrammetry, σ_Z = (Z/B)(Z/c) σ_px with the x-parallax
  σ_px = √2 σ and γ = B/Z (Kraus 2007, the normal case; Hartley & Zisserman 2004, §12.6 on
  the uncertainty of a triangulated point).
  A point is a defect when σ_d would exceed ``K`` × the block extent L (K = 10⁶ by default,
  :data:`DEPTH_FACTOR`), i.e. when

  .. math:: γ < \\sqrt{2}\\, d\\, σ_θ / (K L).

  The bound is deliberately extreme: it catches the numerically zero baselines (identical
  poses, γ ≈ 10⁻¹⁶ rad) that make the normal matrix singular, and never a point that is only
  weakly determined: such a point keeps its tests (its small r_i say what it is worth; far
  points are named apart, :func:`baarda.datum.far_points`). L is the larger of the diagonal of
  the projection centres' bounding box and the median distance of the points from their
  centroid. γ is the intersection angle atan2(|u×v|, |u·v|) of the rays' lines: accurate near
  0, and 0 for opposite rays (a point between two centres on their baseline), which fix no
  depth either.
* **points at a projection centre**: a point whose distance ρ from the centre of an image
  that observes it is within round-off of zero, relative to that image's mean distance s to
  its points:

  .. math:: ρ < \\sqrt{ε}\\, s \\qquad (ε = 2^{-52},\\ \\sqrt{ε} ≈ 1.5·10^{-8})

  (:data:`CENTRE_TOL`).
  Its projection stays finite (x/z as z → 0), but the Jacobian of its image point with respect
  to the image's pose grows like 1/ρ (HZ04, §6.2: ∂(x/z) ∝ 1/z, and z ≤ ρ), so its share of
  the image's 6 × 6 block of the normal equations grows like 1/ρ² against 1/s² for every other
  point: beyond (s/ρ)² > 1/ε the other points' share is lost to rounding and the block looks
  singular — the pose test below would blame the image (and its rotation-only twin) although
  only the point is at fault. Such a point is typically triangulated from two images taken
  from one position (its rays meet at their common centre). It is named with the image and left
  out alone (all its image points); the images keep every other point. s is the geometric
  mean of the image's ρ (a few far points do not inflate it).

  Farther out its share still dominates the image's pose block after scaling (its relative
  smallest eigenvalue falls like (ρ/s)²), and the pose test below may find the block singular.
  So when an image fails the pose test, the points within :data:`NEAR_TOL` × s of its centre
  are taken out of its block and the test repeated: if the block is regular then, those points
  are named and left out instead of the image.
* **images**: fewer than 3 distinct points (6 pose unknowns need at least 6 equations), or
  points that do not fix the pose although there are enough of them (all on one line: the
  camera can turn about it): the image's own 6 × 6 block of the normal equations, its points
  held fixed, is singular (:func:`_pose_conditions`; smallest over largest eigenvalue of the
  scaled block below :data:`POSE_TOL` = 10⁻¹⁰, where rounding leaves ~10⁻¹⁶ for an exact
  defect and the images of real blocks stay above 10⁻⁵). A singular diagonal block makes the whole normal matrix
  singular, and it never flags the gauge of a free block (that moves every image and point).
* **cameras** whose intrinsics (SfM ``refine_intrinsics``) or additional parameters (native
  blocks) are estimated: the images of the camera give Σ (2 p_i − 6) equations beyond their
  poses; fewer than the camera's estimated parameters leave them undetermined: the camera and
  its images are left out.

Counting is necessary, not sufficient. As a safety net, :func:`adjust_block` catches a
:class:`baarda.errors.DatumDefectError` whose undetermined unknowns belong to a few points,
images or cameras (not the whole block: then it is the datum and is raised as before), leaves
those out, records them and adjusts again (at most :data:`MAX_ROUNDS` times).

The input model is never changed: the returned model is a reduced copy.

References (full in the package docstring): K07; HZ04.
"""

from __future__ import annotations

import math

import numpy as np

from .defects import LocalDefect, adjust_setting_aside
from .errors import InputError
from .model.bundle import AP_GROUPS, ImageObservations, build_block_problem
from .model.sfm import CAMERA_MODELS, SfmBlock, build_sfm_problem, held_coefficients

DEPTH_FACTOR = 1e6   # K: a depth σ beyond K × the block extent is "not determined"
MIN_POINTS = 3       # points an image needs to fix its 6 pose unknowns
MAX_ROUNDS = 4       # retries of the safety net in adjust_block
POSE_TOL = 1e-10     # an image's equilibrated pose block with a smaller eigenvalue is singular
CENTRE_TOL = math.sqrt(np.finfo(float).eps)   # a point nearer a centre than this × s is at it
NEAR_TOL = 1e-2      # a point this near a centre is blamed for a singular pose block it causes
POSE_SFM = ("rho1", "rho2", "rho3", "tx", "ty", "tz")
POSE_BLOCK = ("X0", "Y0", "Z0", "omega", "phi", "kappa")


# --------------------------------------------------------------------------------------------
# a common view of both block types
# --------------------------------------------------------------------------------------------
class _View:
    """Arrays the pre-pass needs, from an SfmBlock or a Block (read only)."""

    def __init__(self, model):
        self.model = model
        self.sfm = isinstance(model, SfmBlock)
        if self.sfm:
            b = model
            self.image_ids = [im.id for im in b.images]
            self.point_ids = list(b.points)
            self.camera_ids = [c.id for c in b.cameras]
            cam_index = {c: k for k, c in enumerate(self.camera_ids)}
            self.image_camera = np.array([cam_index[im.camera] for im in b.images], dtype=np.int64)
            self.centres = np.array([im.centre for im in b.images], dtype=float).reshape(-1, 3)
            self.X = np.asarray(b.X, dtype=float)
            self.obs_image = np.asarray(b.obs_image, dtype=np.int64)
            self.obs_point = np.asarray(b.obs_point, dtype=np.int64)
            f = []
            self.camera_free = []
            for c in b.cameras:
                names, feeds = CAMERA_MODELS[c.model]
                val = dict(zip(names, c.params))
                f.append(abs(val[feeds[0]]) if feeds[0] is not None else 0.0)
                self.camera_free.append(tuple(nm for nm in names if nm not in held_coefficients(c.model))
                                        if b.refine_intrinsics else ())
            self.focal = np.array(f, dtype=float)
            self.obs_sigma = np.full(self.obs_image.size, float(b.sigma_px))
            controlled = {cp.id for cp in b.control}
            self.controlled = np.array([p in controlled for p in b.points], dtype=bool)
            self.pose_names = POSE_SFM
        else:
            b = model
            self.image_ids = [im.id for im in b.images]
            self.point_ids = [p.id for p in b.points]
            self.camera_ids = [c.id for c in b.cameras]
            cam_index = {c: k for k, c in enumerate(self.camera_ids)}
            self.image_camera = np.array([cam_index[im.camera] for im in b.images], dtype=np.int64)
            self.centres = np.array([(im.X0, im.Y0, im.Z0) for im in b.images], dtype=float).reshape(-1, 3)
            self.X = np.array([(p.X, p.Y, p.Z) for p in b.points], dtype=float).reshape(-1, 3)
            self.obs_image = np.asarray(b.obs.image, dtype=np.int64)
            self.obs_point = np.asarray(b.obs.point, dtype=np.int64)
            self.focal = np.array([abs(c.c) for c in b.cameras], dtype=float)
            self.camera_free = [tuple(f"{g}.{nm}" for g in c.ap for nm in AP_GROUPS.get(g, ()))
                                for c in b.cameras]
            cov = np.asarray(b.obs.cov, dtype=float).reshape(-1, 2, 2)
            self.obs_sigma = np.sqrt(np.maximum(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]), 0.0))
            self.controlled = np.array([p.status == "control" and b.datum != "free" and bool(p.axes)
                                        for p in b.points], dtype=bool)
            self.pose_names = POSE_BLOCK

    def extent(self) -> float:
        """L of the module docstring."""
        c = self.centres
        diag = float(np.linalg.norm(c.max(axis=0) - c.min(axis=0))) if len(c) else 0.0
        X = self.X[np.isfinite(self.X).all(axis=1)]
        spread = float(np.median(np.linalg.norm(X - c.mean(axis=0), axis=1))) if len(X) and len(c) else 0.0
        L = max(diag, spread)
        return L if L > 0 else 1.0


# --------------------------------------------------------------------------------------------
# the geometric pre-pass
# --------------------------------------------------------------------------------------------
def _angle(u, w):
    """Intersection angles of lines along unit vectors (rows), in [0, π/2] and accurate near 0:
    atan2(|u×w|, |u·w|) — opposite rays (a point between two centres on their baseline) meet
    at 0 too: they fix no depth either."""
    return np.arctan2(np.linalg.norm(np.cross(u, w), axis=-1), np.abs(np.einsum("...i,...i->...", u, w)))


def _bound_angles(v: _View, obs: np.ndarray, npt: int):
    """Per point (all ``npt``) from the observations ``obs``: the largest angle of a ray to the
    point's first ray — a lower bound of the largest angle between its rays, and exact for two
    rays — and the mean distance from its centres. No sorting: linear in the observations."""
    op, oi = v.obs_point[obs], v.obs_image[obs]
    first = np.zeros(npt, dtype=np.int64)
    first[op[::-1]] = oi[::-1]                          # the image of each point's first ray
    # one gather of a 6-column table per point (X and its first ray): random row access is
    # what costs on millions of image points
    T = np.empty((npt, 6))
    T[:, :3] = v.X
    T[:, 3:] = v.X - v.centres[first]
    T = T[op]
    u = T[:, :3] - v.centres[oi]
    w = T[:, 3:]
    del T
    norm = np.sqrt(np.einsum("ij,ij->i", u, u))
    u /= np.where(norm > 0, norm, 1.0)[:, None]
    w /= np.maximum(np.sqrt(np.einsum("ij,ij->i", w, w)), 1e-300)[:, None]
    # tan of the intersection angle, |u×w| / |u·w| (monotone in the angle: its maximum per
    # point is that of the angle), column by column to spare temporaries
    c = np.square(u[:, 1] * w[:, 2] - u[:, 2] * w[:, 1])
    c += np.square(u[:, 2] * w[:, 0] - u[:, 0] * w[:, 2])
    c += np.square(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0])
    np.sqrt(c, out=c)
    d = np.abs(np.einsum("ij,ij->i", u, w))
    del u, w
    with np.errstate(divide="ignore", invalid="ignore"):
        tan = np.where(d > 0, c / d, np.inf)
    tan[c == 0] = 0.0
    gamma = np.zeros(npt)
    np.maximum.at(gamma, op, tan)
    gamma = np.arctan(gamma)
    cnt = np.bincount(op, minlength=npt)
    dist = np.bincount(op, weights=norm, minlength=npt) / np.maximum(cnt, 1)
    return gamma, dist


def _exact_angles(v: _View, obs: np.ndarray, points: np.ndarray):
    """For a few ``points`` (each with rays from two images at least among ``obs``): the
    largest intersection angle over all pairs of rays from distinct images, and the pair."""
    sel = np.isin(v.obs_point[obs], points)
    op, oi = v.obs_point[obs][sel], v.obs_image[obs][sel]
    order = np.lexsort((oi, op))
    op, oi = op[order], oi[order]
    start = np.searchsorted(op, points)
    stop = np.searchsorted(op, points, side="right")
    gamma = np.zeros(points.size)
    pair = np.full((points.size, 2), -1, dtype=np.int64)
    for j, p in enumerate(points):
        mine = oi[start[j]:stop[j]]
        U = v.X[p] - v.centres[mine]
        U /= np.maximum(np.linalg.norm(U, axis=1), 1e-300)[:, None]
        G = _angle(U[:, None, :], U[None, :, :])
        G[mine[:, None] == mine[None, :]] = -1.0      # pairs of rays from two distinct images
        a, b = np.unravel_index(int(np.argmax(G)), G.shape)
        gamma[j] = G[a, b]
        pair[j] = mine[a], mine[b]
    return gamma, pair


def _pose_conditions(v: _View, obs: np.ndarray, ni: int) -> np.ndarray:
    r"""Per image, the smallest eigenvalue of its pose block (6 × 6, its points held fixed) from
    the observations ``obs``: 0 (to rounding) when its points do not fix its pose — fewer than
    three, or all on one line through which the pose can turn.

    Each image point is taken as the direction u = (X − C)/ρ, ρ = |X − C|, of its ray; a turn δθ
    and shift δt of the camera move it by J = [−[u]×, (I − uuᵀ)/ρ] (the component across the
    ray), so that

    .. math:: JᵀJ = \\begin{pmatrix} I − uuᵀ & [u]_×/ρ \\\\ [u]_×ᵀ/ρ & (I − uuᵀ)/ρ² \\end{pmatrix}.

    This is the projection's Jacobian up to a regular 2 × 2 factor per point (the same rank),
    but bounded: a point near the camera's plane does not swamp the others. The rotation and
    the translation blocks are scaled by their mean diagonal (so the result does not depend on
    the frame). Linear in the observations (bincounts of 17 sums per image)."""
    oi = v.obs_image[obs]
    d = v.X[v.obs_point[obs]] - v.centres[oi]
    rho = np.sqrt(np.einsum("ij,ij->i", d, d))
    ok = rho > 0
    oi, d, rho = oi[ok], d[ok], rho[ok]
    u = d / rho[:, None]
    del d
    w = 1.0 / rho
    w2 = w * w

    def total(x):
        return np.bincount(oi, weights=x, minlength=ni)

    cnt = np.bincount(oi, minlength=ni).astype(float)
    UU = np.empty((ni, 3, 3))
    UW = np.empty((ni, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            p = u[:, a] * u[:, b]
            UU[:, a, b] = UU[:, b, a] = total(p)
            UW[:, a, b] = UW[:, b, a] = total(p * w2)
    s1 = np.stack([total(u[:, a] * w) for a in range(3)], axis=1)      # Σ u/ρ
    s2 = total(w2)                                                      # Σ 1/ρ²
    eye = np.eye(3)
    G = np.zeros((ni, 6, 6))
    G[:, :3, :3] = cnt[:, None, None] * eye - UU
    K = np.zeros((ni, 3, 3))                                             # Σ [u]×/ρ
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -s1[:, 2], s1[:, 1], -s1[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = s1[:, 2], -s1[:, 1], s1[:, 0]
    G[:, :3, 3:] = K
    G[:, 3:, :3] = np.swapaxes(K, 1, 2)
    G[:, 3:, 3:] = s2[:, None, None] * eye - UW
    sr = np.sqrt(np.maximum(np.einsum("kii->k", G[:, :3, :3]) / 3.0, 1e-300))
    st = np.sqrt(np.maximum(np.einsum("kii->k", G[:, 3:, 3:]) / 3.0, 1e-300))
    scale = np.concatenate([np.repeat(sr[:, None], 3, 1), np.repeat(st[:, None], 3, 1)], axis=1)
    G /= scale[:, :, None] * scale[:, None, :]
    lam = np.linalg.eigvalsh(G)
    return lam[:, 0] / np.maximum(lam[:, -1], 1e-300)


def _near_centres(v: _View, tol: float = NEAR_TOL):
    """The image points whose point is within ``tol`` × s of their image's centre, s the geometric
    mean of the distances ρ of the image's points (robust against a few far points; module
    docstring): (observation indices, ρ, ρ/s) — few, whatever the size of the block. Linear in
    the observations."""
    ni = len(v.image_ids)
    d = v.X[v.obs_point] - v.centres[v.obs_image]
    rho = np.sqrt(np.einsum("ij,ij->i", d, d))
    del d
    ok = np.isfinite(rho) & (rho > 0)
    cnt = np.bincount(v.obs_image[ok], minlength=ni)
    logs = np.bincount(v.obs_image[ok], weights=np.log(rho[ok]), minlength=ni)
    s = np.where(cnt > 0, np.exp(logs / np.maximum(cnt, 1)), v.extent())
    idx = np.flatnonzero(np.isfinite(rho) & (rho < tol * s[v.obs_image]))
    return idx, rho[idx], rho[idx] / s[v.obs_image[idx]]


def _at_centre(v: _View, near, allowed: np.ndarray, tol: float):
    """Of the image points ``near`` (:func:`_near_centres`) those ``allowed`` (a mask over all
    observations) within ``tol`` × s: [(point, image, ρ, ρ/s)], one per point (its nearest
    centre relative to s)."""
    idx, rho, rel = near
    sel = np.flatnonzero(allowed[idx] & (rel < tol))
    if sel.size == 0:
        return []
    sel = sel[np.lexsort((rel[sel], v.obs_point[idx[sel]]))]        # per point, its nearest first
    pts = v.obs_point[idx[sel]]
    first = np.ones(sel.size, dtype=bool)
    first[1:] = pts[1:] != pts[:-1]
    return [(int(v.obs_point[idx[j]]), int(v.obs_image[idx[j]]), float(rho[j]), float(rel[j])) for j in sel[first]]


def _centre_defect(v: _View, p, k, rho, rel, why) -> LocalDefect:
    return LocalDefect("point", str(v.point_ids[p]), ("x", "y", "z"),
                       f"at the projection centre of image {v.image_ids[k]}: {rho:.2g} from it, {rel:.1g} of "
                       f"the image's distance to its points ({why})")


def _distinct(key: np.ndarray) -> np.ndarray:
    """The distinct values of an integer array, sorted (a sort and a comparison: faster than
    np.unique's hashing on millions of keys)."""
    s = np.sort(key)
    if s.size < 2:
        return s
    keep = np.empty(s.size, dtype=bool)
    keep[0] = True
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]


def find_defects(model, factor: float = DEPTH_FACTOR):
    """The local defects of a block and the block without them (module docstring).

    Returns ``(reduced, defects)``: ``reduced`` is ``model`` itself when there is nothing to
    leave out, otherwise a new block (the input is not changed); ``defects`` a list of
    :class:`baarda.defects.LocalDefect` in the order they were found.
    """
    v = _View(model)
    ni, npt, ncam = len(v.image_ids), len(v.point_ids), len(v.camera_ids)
    L = v.extent()
    obs_on = np.ones(v.obs_image.size, dtype=bool)
    point_on = np.ones(npt, dtype=bool)
    image_on = np.ones(ni, dtype=bool)
    camera_on = np.ones(ncam, dtype=bool)
    left_images: list[str] = []
    defects: list[LocalDefect] = []
    sig_theta = v.obs_sigma / np.maximum(v.focal[v.image_camera[v.obs_image]], 1e-300)
    # points at a projection centre (module docstring): fixed by the geometry, found once
    near = _near_centres(v)
    for p, k, r, q in _at_centre(v, near, obs_on, CENTRE_TOL):
        point_on[p] = False
        defects.append(_centre_defect(v, p, k, r, q, "within round-off of zero: its Jacobian, ∝ 1/depth, "
                                                     "would swamp the image's pose"))
    obs_on &= point_on[v.obs_point]
    while True:
        changed = False
        idx = np.flatnonzero(obs_on)
        # distinct (point, image) pairs: duplicate keypoints are one ray
        pairs = _distinct(v.obs_point[idx] * max(ni, 1) + v.obs_image[idx])
        rays = np.bincount(pairs // max(ni, 1), minlength=npt)
        cand = point_on & ~v.controlled
        few = np.flatnonzero(cand & (rays < 2))
        seen = np.full(npt, -1, dtype=np.int64)
        seen[v.obs_point[idx]] = v.obs_image[idx]
        after = f" once image(s) {', '.join(left_images[:8])} were left out" if left_images else ""
        for p in few:
            if rays[p] == 0:
                reason = "no ray left: all its images were left out"
            else:
                reason = f"single ray: seen only from image {v.image_ids[seen[p]]}{after}"
            defects.append(LocalDefect("point", str(v.point_ids[p]), ("x", "y", "z"), reason))
        two = np.flatnonzero(cand & (rays >= 2))
        if two.size:
            st = np.bincount(v.obs_point[idx], weights=sig_theta[idx], minlength=npt)
            cnt = np.bincount(v.obs_point[idx], minlength=npt)
            # the limit of the module docstring; the cheap lower bound of γ clears almost every
            # point, the few left get the exact largest angle
            gamma, dist = _bound_angles(v, idx, npt)
            limit = math.sqrt(2.0) * dist * st / np.maximum(cnt, 1) / (factor * L)
            low = two[gamma[two] < limit[two]]
            flat_pts = low[:0]
            if low.size:
                g2, p2 = _exact_angles(v, idx, low)
                keep = g2 < limit[low]
                flat_pts, g2, p2 = low[keep], g2[keep], p2[keep]
            for p, gam, (a, b) in zip(flat_pts, g2 if low.size else (), p2 if low.size else ()):
                same = np.array_equal(v.centres[a], v.centres[b])
                how = (f"images {v.image_ids[a]}, {v.image_ids[b]} have the same centre" if same else
                       f"its rays meet at {gam:.2g} rad (largest angle; the depth σ would exceed "
                       f"{factor:.0e} × the block extent)")
                defects.append(LocalDefect("point", str(v.point_ids[p]), ("x", "y", "z"),
                                           f"zero baseline: {how}"))
            few = np.concatenate([few, flat_pts])
        if few.size:
            point_on[few] = False
            obs_on &= point_on[v.obs_point]
            changed = True
        # images: distinct points per image, from the pairs of the points kept
        pairs = pairs[point_on[pairs // max(ni, 1)]]
        pts = np.bincount(pairs % max(ni, 1), minlength=ni)
        starved = np.flatnonzero(image_on & (pts < MIN_POINTS))
        for k in starved:
            defects.append(LocalDefect("image", str(v.image_ids[k]), v.pose_names,
                                       f"sees {pts[k]} point{'' if pts[k] == 1 else 's'}; at least "
                                       f"{MIN_POINTS} are needed to fix its pose"))
        # enough points, but in a configuration that does not fix the pose (e.g. on one line)
        use = np.flatnonzero(obs_on & image_on[v.obs_image])
        lam = _pose_conditions(v, use, ni)
        weak = np.flatnonzero(image_on & (pts >= MIN_POINTS) & (lam < POSE_TOL))
        if weak.size:
            # a point near a centre may be what makes the pose block look singular: blame it,
            # not the image, when the block is regular without it (module docstring)
            in_weak = np.zeros(ni, dtype=bool)
            in_weak[weak] = True
            suspects = _at_centre(v, near, obs_on & in_weak[v.obs_image], NEAR_TOL)
            if suspects:
                gone = np.zeros(npt, dtype=bool)
                gone[[p for p, *_ in suspects]] = True
                lam2 = _pose_conditions(v, use[~gone[v.obs_point[use]]], ni)
                cured = weak[lam2[weak] >= POSE_TOL]
                for p, k, r, q in suspects:
                    if np.isin(v.obs_image[use][v.obs_point[use] == p], cured).any():
                        point_on[p] = False
                        defects.append(_centre_defect(
                            v, p, k, r, q, "its share of the image's pose block makes it look singular; "
                                           "without it the image's points fix its pose"))
                if cured.size:
                    obs_on &= point_on[v.obs_point]
                    changed = True
                    weak = np.setdiff1d(weak, cured)
        for k in weak:
            defects.append(LocalDefect("image", str(v.image_ids[k]), v.pose_names,
                                       f"its {pts[k]} points do not fix its pose (they lie on one line "
                                       f"or the like: its pose block is singular, relative smallest "
                                       f"eigenvalue {max(lam[k], 0.0):.1g})"))
        starved = np.concatenate([starved, weak])
        image_on[starved] = False
        left_images += [v.image_ids[k] for k in starved]
        # cameras with estimated intrinsics or APs
        for c in range(ncam):
            if not camera_on[c]:
                continue
            mine = np.flatnonzero(image_on & (v.image_camera == c))
            had = np.flatnonzero(v.image_camera == c)
            if mine.size == 0:
                camera_on[c] = False
                if had.size == 0 and v.camera_free[c]:
                    defects.append(LocalDefect("camera", str(v.camera_ids[c]), v.camera_free[c],
                                               "no image uses it; its parameters are estimated"))
                continue
            nfree = len(v.camera_free[c])
            if nfree == 0:
                continue
            surplus = int((2 * pts[mine] - 6).sum())
            if surplus < nfree:
                ids = [v.image_ids[k] for k in mine]
                defects.append(LocalDefect(
                    "camera", str(v.camera_ids[c]), v.camera_free[c],
                    f"its images {', '.join(ids[:8])}{' ...' if len(ids) > 8 else ''} give {surplus} "
                    f"equation(s) beyond their poses for {nfree} estimated parameters",
                    f"left out with its image{'s' if len(ids) > 1 else ''}"))
                for k in mine:
                    defects.append(LocalDefect("image", str(v.image_ids[k]), v.pose_names,
                                               f"its camera {v.camera_ids[c]} is not determined"))
                image_on[mine] = False
                left_images += ids
                camera_on[c] = False
                starved = np.concatenate([starved, mine])
        if starved.size:
            obs_on &= image_on[v.obs_image]
            changed = True
        if not changed:
            break
    if not defects:
        return model, []
    return _reduce(v, point_on, image_on, camera_on, obs_on), defects


def _subset_extra(extra: dict, n_obs: int, keep_obs, n_pts: int, keep_pts, n_img: int, keep_img) -> dict:
    """``extra`` with its arrays per observation, point or image (e.g. COLMAP's keypoint index
    per image point, byte offsets of records) cut like the block; other values as they are."""
    out = {}
    for k, val in extra.items():
        if isinstance(val, np.ndarray) and val.ndim >= 1:
            if val.shape[0] == n_obs:
                val = val[keep_obs]
            elif val.shape[0] == n_pts:
                val = val[keep_pts]
            elif val.shape[0] == n_img:
                val = val[keep_img]
        out[k] = val
    return out


def _reduce(v: _View, point_on, image_on, camera_on, obs_on):
    """A copy of the block with only the kept points, images, cameras and observations."""
    model = v.model
    new_point = np.cumsum(point_on) - 1
    new_image = np.cumsum(image_on) - 1
    keep = np.flatnonzero(obs_on)
    extra = _subset_extra(model.extra, obs_on.size, keep, point_on.size, np.flatnonzero(point_on),
                          image_on.size, np.flatnonzero(image_on))
    used_cams = {v.camera_ids[c] for c in np.unique(v.image_camera[image_on])}
    pts_kept = np.flatnonzero(point_on)
    if v.sfm:
        b = model
        kept_ids = {b.points[i] for i in pts_kept}
        return b.replace(
            cameras=tuple(c for c in b.cameras if c.id in used_cams),
            images=tuple(im for k, im in enumerate(b.images) if image_on[k]),
            points=tuple(b.points[i] for i in pts_kept),
            X=np.array(b.X[pts_kept], dtype=float),
            point_line=np.array(np.asarray(b.point_line)[pts_kept]),
            obs_image=new_image[b.obs_image[keep]].astype(np.int64),
            obs_point=new_point[b.obs_point[keep]].astype(np.int64),
            xy=np.array(b.xy[keep], dtype=float),
            obs_line=np.array(np.asarray(b.obs_line)[keep]),
            control=tuple(cp for cp in b.control if cp.id in kept_ids),
            check=tuple(cp for cp in b.check if cp.id in kept_ids),
            extra=extra)

    b = model
    o = b.obs
    kept_ids = {b.points[i].id for i in pts_kept}
    obs = ImageObservations(new_image[o.image[keep]].astype(np.int64), new_point[o.point[keep]].astype(np.int64),
                            np.array(o.xy[keep], dtype=float), np.array(o.cov[keep], dtype=float),
                            np.array(np.asarray(o.line)[keep]))
    images = tuple(im for k, im in enumerate(b.images) if image_on[k])
    gnss = b.gnss.keep_images(im.id for im in images) if b.gnss is not None else None
    imu = b.imu.keep_images(im.id for im in images) if b.imu is not None else None
    return b.replace(cameras=tuple(c for c in b.cameras if c.id in used_cams), images=images, gnss=gnss, imu=imu,
                     points=tuple(b.points[i] for i in pts_kept), obs=obs,
                     sbase=tuple(s for s in b.sbase if s in kept_ids), extra=extra)


def remove(model, points=(), images=(), cameras=()):
    """A copy of the block without the named points, images and cameras (ids) and their
    observations (images of a removed camera go too); nothing else is checked."""
    v = _View(model)
    point_on = ~np.isin(np.array(v.point_ids, dtype=object), list(points)) if v.point_ids else np.zeros(0, bool)
    camera_on = ~np.isin(np.array(v.camera_ids, dtype=object), list(cameras))
    image_on = ~np.isin(np.array(v.image_ids, dtype=object), list(images)) & camera_on[v.image_camera]
    obs_on = point_on[v.obs_point] & image_on[v.obs_image]
    return _reduce(v, point_on, image_on, camera_on, obs_on)


# --------------------------------------------------------------------------------------------
# degenerate geometry (the message of an adjustment that does not converge)
# --------------------------------------------------------------------------------------------
DEGENERATE_RATIO = 1e3   # centres spread beyond this × the points' spread: degenerate geometry
NARROW_ANGLE = 5e-3      # images that see their points within this (rad, median): degenerate


def degenerate_geometry(model, ratio: float = DEGENERATE_RATIO, narrow: float = NARROW_ANGLE) -> str | None:
    """Words naming a degenerate block geometry, or None.

    Two signs, each enough (either makes the normal equations ill-conditioned whatever the
    observations, so that an adjustment that does not converge says more about the geometry —
    often images registered far off — than about gross errors):

    * the projection centres spread over more than ``ratio`` × the spread of the points (the
      diagonal of the centres' bounding box against the median distance of the points from
      their median): images that far see the points at intersection angles near zero (the depth
      σ of the module docstring grows like d/γ);
    * the images see their points within a narrow angle: the median over the images of
      α = (RMS distance of the image's points from their centroid) / (their mean distance from
      its centre) is below ``narrow`` (rad). A bundle of rays that narrow does not tell a turn of
      the camera from a shift (the pose block of :func:`_pose_conditions` tends to singular as α → 0:
      the affine-camera limit, HZ04 §6.3).

    Used by ``baarda analyze`` when the adjustment does not converge (Ceres does not converge on
    such blocks either). None for anything that is not a bundle block."""
    if model is None or not hasattr(model, "images"):
        return None
    v = _View(model)
    good = np.isfinite(v.X).all(axis=1)
    X, c = v.X[good], v.centres[np.isfinite(v.centres).all(axis=1)]
    if len(X) < 2 or len(c) < 1 or v.obs_image.size == 0:
        return None
    mid = np.median(X, axis=0)
    centres = float(np.linalg.norm(c.max(axis=0) - c.min(axis=0)))
    points = float(np.median(np.linalg.norm(X - mid, axis=1)))
    ni = len(v.image_ids)
    ok = good[v.obs_point]
    oi, P = v.obs_image[ok], v.X[v.obs_point[ok]] - mid
    cnt = np.maximum(np.bincount(oi, minlength=ni), 1)
    mean = np.stack([np.bincount(oi, weights=P[:, a], minlength=ni) for a in range(3)], 1) / cnt[:, None]
    rms = np.sqrt(np.maximum(np.bincount(oi, weights=np.einsum("ij,ij->i", P, P), minlength=ni) / cnt
                             - np.einsum("ij,ij->i", mean, mean), 0.0))
    dist = np.bincount(oi, weights=np.linalg.norm(P + mid - v.centres[oi], axis=1), minlength=ni) / cnt
    seen = np.bincount(oi, minlength=ni) > 0
    alpha = rms[seen] / np.maximum(dist[seen], 1e-300)
    spread = centres > ratio * points
    thin = alpha.size and float(np.median(alpha)) < narrow
    if not (spread or thin):
        return None
    parts = []
    if spread:
        parts.append(f"its projection centres spread over {centres:.2g} units, its points over {points:.2g} "
                     f"(ratio {centres / max(points, 1e-300):.2g}, beyond {ratio:.0e})")
    if thin:
        ids = np.asarray(v.image_ids, dtype=object)[seen]
        k = int(np.argmin(alpha))
        parts.append(f"{int((alpha < narrow).sum())} of {alpha.size} images see their points within less than "
                     f"{narrow:.0e} rad (median {float(np.median(alpha)):.2g}; image {ids[k]}: {alpha[k]:.2g} rad)")
    return ("the block's geometry is degenerate: " + "; ".join(parts)
            + ": check the poses (images registered far off?) rather than the observations")


# --------------------------------------------------------------------------------------------
# building and adjusting
# --------------------------------------------------------------------------------------------
def strict_error(model, defects) -> InputError:
    """The error ``--strict`` raises: every defect named, at the file."""
    text = "; ".join(f"{d.entity} {d.id} ({', '.join(d.components)}): {d.reason}" for d in defects[:30]) \
        + (f"; ... ({len(defects)} in all)" if len(defects) > 30 else "")
    return InputError(getattr(model, "source", "") or "input", 0,
                      f"{len(defects)} local defect(s) (--strict): {text}")


def build(model, strict: bool = False):
    """The adjustment problem of a block without its local defects.

    ``problem.notes.local_defects`` lists them (:class:`baarda.defects.LocalDefect`),
    ``problem.notes.local_model`` holds the reduced block :func:`adjust_block` reduces further
    if needed. strict: raise :class:`baarda.errors.InputError` naming all defects instead.
    """
    reduced, defects = find_defects(model)
    if defects and strict:
        raise strict_error(model, defects)
    problem = build_sfm_problem(reduced) if isinstance(reduced, SfmBlock) else build_block_problem(reduced)
    return problem.with_notes(local_defects=(*problem.notes.local_defects, *defects), local_model=reduced)


def _entities(labels, model):
    """(points, images, cameras) named by the labels of undetermined unknowns, or None when a
    label is not one of a point, image or camera of ``model``."""
    v = _View(model)
    owner = {}
    if v.sfm:
        for pid in v.point_ids:
            for a in "xyz":
                owner[f"point {pid}.{a}"] = ("point", pid)
        for iid in v.image_ids:
            for nm in POSE_SFM:
                owner[f"image {iid}.{nm}"] = ("image", iid)
        for cid, cam in zip(v.camera_ids, model.cameras):
            for nm in CAMERA_MODELS[cam.model][0]:
                owner[f"camera {cid}.{nm}"] = ("camera", cid)
    else:
        for pid in v.point_ids:
            for a in "xyz":
                owner[f"{pid}.{a}"] = ("point", pid)
        for iid in v.image_ids:
            for nm in POSE_BLOCK:
                owner[f"{iid}.{nm}"] = ("image", iid)
        for cid, free in zip(v.camera_ids, v.camera_free):
            for nm in free:
                owner[f"{cid}.{nm}"] = ("camera", cid)
    out = {"point": [], "image": [], "camera": []}
    for lab in labels:
        hit = owner.get(str(lab))
        if hit is None:
            return None
        if hit[1] not in out[hit[0]]:
            out[hit[0]].append(hit[1])
    return out


def _local(named, model) -> bool:
    """Whether the named entities are a local part of the block (not its datum): a few points
    and images, at most a quarter of either."""
    if named is None or not any(named.values()):
        return False
    v = _View(model)
    return (len(named["point"]) <= max(1, len(v.point_ids) // 4)
            and len(named["image"]) <= max(0, len(v.image_ids) // 4)
            and len(named["camera"]) <= max(0, len(v.camera_ids) // 4))


def _intrinsics_refined(model) -> bool:
    """Whether ``model`` is a structure-from-motion block whose intrinsics are estimated."""
    return isinstance(model, SfmBlock) and model.refine_intrinsics


def _hold_intrinsics(model, problem, cameras):
    """The block with every camera's intrinsics held at the file's values, rebuilt; the cameras
    whose intrinsics the adjustment found undetermined are recorded as local defects."""
    held = model.replace(refine_intrinsics=False)
    found = []
    for cid, cam in zip(_View(model).camera_ids, model.cameras):
        if cid in cameras:
            names = tuple(n for n in CAMERA_MODELS[cam.model][0] if n not in held_coefficients(cam.model))
            found.append(LocalDefect("camera", str(cid), names,
                                     "the observations do not determine its intrinsics "
                                     "(singular normal equations with them estimated)",
                                     "intrinsics of all cameras held at the file's values"))
    old = problem.notes.local_defects
    reduced, more = find_defects(held)
    problem = build(reduced)
    return reduced, problem.with_notes(local_defects=(*old, *found, *more))


def adjust_block(problem, options=None, progress=None, strict: bool = False):
    """Adjust ``problem``; if it is a block from :func:`build` and the adjustment finds unknowns
    the observations do not determine that belong to a few points, images or cameras, leave
    them out (recorded as local defects), rebuild and adjust again (module docstring).

    Returns ``(adjustment, problem)`` — the problem actually adjusted. A defect of the whole
    block (the datum) raises :class:`baarda.errors.DatumDefectError` as :func:`baarda.adjust.adjust`
    does; so does any defect with ``strict``.
    """
    return adjust_setting_aside(problem, options, progress, MAX_ROUNDS,
                                lambda problem, err, first: _set_aside(problem, err, first, strict))


def _set_aside(problem, err, first, strict: bool):
    """The block's problem without the points, images or cameras ``err`` names, or with the
    intrinsics held (:func:`adjust_block`)."""
    model = problem.notes.local_model
    if model is None or strict:
        raise err
    named = _entities(err.undetermined, model)
    if named is not None and named["camera"] and _intrinsics_refined(model):
        # the cameras' f, k1, k2 are part of the null space: adjust what is determined,
        # holding the intrinsics at the file's values (as gama-local adjusts a point in
        # x, y when its height is undetermined), then look again
        return _hold_intrinsics(model, problem, named["camera"])[1]
    if not _local(named, model):
        raise first from None
    found = []
    for kind in ("point", "image", "camera"):
        for ident in named[kind]:
            vw = _View(model)
            what = {"point": ("x", "y", "z"), "image": vw.pose_names}.get(kind) or \
                vw.camera_free[vw.camera_ids.index(ident)] or ("intrinsics",)
            found.append(LocalDefect(kind, str(ident), what,
                                     "the adjustment finds its unknowns undetermined "
                                     "(singular normal equations)",
                                     "left out" if kind != "camera" else "left out with its images"))
    reduced = remove(model, named["point"], named["image"], named["camera"])
    reduced, more = find_defects(reduced)
    old = problem.notes.local_defects
    return build(reduced).with_notes(local_defects=(*old, *found, *more))
