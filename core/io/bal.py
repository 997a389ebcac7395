"""Bundle Adjustment in the Large (BAL) problem files, and the checks every SfM reader shares.

Format (Agarwal et al. 2010, https://grail.cs.washington.edu/projects/bal/)::

    <num_cameras> <num_points> <num_observations>
    <camera_index> <point_index> <x> <y>          (num_observations lines)
    <camera parameters>                           (9 per camera: ρ1 ρ2 ρ3 t1 t2 t3 f k1 k2)
    <point coordinates>                           (3 per point: X Y Z)

Parameters are one number a line in the published files; the reader takes any whitespace
layout. Image coordinates are pixels with the origin at the image centre, y up; the projection
is that of :mod:`baarda.model.sfm` with s = −1 (P = R X + t, p = −P/P_z, p' = f (1 + k1‖p‖² +
k2‖p‖⁴) p). Camera and point ids are the file's 0-based indices, as strings.

Every reader of structure-from-motion files reports errors as
:class:`baarda.errors.InputError` ``FILE:LINE: what is wrong`` and returns a block only when
all of it is valid (:func:`check_block`): counts as announced, finite numbers, indices in range,
no duplicate image point, each point in ≥ 2 images, each image with ≥ 3 points, one connected
block.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..errors import ConversionError, InputError
from ..model.sfm import SfmBlock, SfmCamera, SfmImage
from .output import write_text
from .source import Numbers, Truncated, open_binary
from .source import read_text as _read_text


#: the largest angle-axis length accepted (rad): a turn is 2π; far beyond it the rotation's
#: derivatives (sin θ / θ) vanish and the normal matrix is singular in double precision
MAX_ANGLE = 1.0e6


def read_text(path) -> str:
    """The text of ``path`` (UTF-8, decompressed when it is compressed), or InputError."""
    return _read_text(path)


# --------------------------------------------------------------------------------------------
# checks shared by the SfM readers
# --------------------------------------------------------------------------------------------
def check_block(path, block: SfmBlock, image_path=None, rays: bool = False) -> SfmBlock:
    """Validate the structure of a block (module docstring); return it or raise InputError.

    Points on fewer than two rays and images on fewer than three points are local defects
    (:mod:`baarda.sfm_defects` names them all and leaves them out, ``--strict`` refuses them);
    rays=True refuses them here instead, at the first one's line.

    A COLMAP block (``block.extra["obs_keypoint"]``) may observe a point by several keypoints of
    one image; only the same keypoint twice is an error there. COLMAP errors name the point's
    line of ``path`` (points3D) or the image's line of ``image_path`` (images), or, for binary
    files, the byte offset of the record (``extra["point_offset"]``, ``extra["image_offset"]``).
    """
    path = str(path)
    image_path = path if image_path is None else str(image_path)
    ni, npt, n = len(block.images), len(block.points), block.obs_image.size
    colmap = block.convention == "colmap"
    p_off, i_off = block.extra.get("point_offset"), block.extra.get("image_offset")

    def at_point(p: int, obs: int | None = None) -> InputError:
        def err(message):
            if p_off is not None:
                return InputError(path, 0, message, offset=int(p_off[p]))
            if colmap:
                return InputError(path, int(block.point_line[p]), message)
            return InputError(path, int(block.obs_line[obs]) if obs is not None else int(block.point_line[p]),
                              message)
        return err

    def at_image(k: int):
        def err(message):
            if i_off is not None:
                return InputError(image_path, 0, message, offset=int(i_off[k]))
            return InputError(image_path, int(block.images[k].line), message)
        return err

    if ni == 0 or npt == 0 or n == 0:
        raise InputError(path, 1, f"empty block: {ni} images, {npt} points, {n} image points")
    ii, pp = block.obs_image, block.obs_point
    kp = block.extra.get("obs_keypoint")
    key = ii * npt + pp
    order = np.argsort(key, kind="stable") if kp is None else np.lexsort((kp, key))
    same = np.diff(key[order]) == 0
    if kp is not None:
        same &= np.diff(kp[order]) == 0
    dup = np.flatnonzero(same)
    if dup.size:
        a, b = order[dup[0]], order[dup[0] + 1]
        if kp is not None:
            raise at_point(int(pp[b]))(f"point {block.points[pp[b]]}: its track lists image point {kp[b]} "
                                       f"of image {block.images[ii[b]].id} twice")
        raise InputError(path, int(block.obs_line[b]),
                         f"point {block.points[pp[b]]} is measured twice in image "
                         f"{block.images[ii[b]].id} (first at line {block.obs_line[a]})")
    # rays per point and points per image count distinct (image, point) pairs
    few_none = np.zeros(0, dtype=np.int64)
    first = np.ones(n, dtype=bool)
    first[order[1:]] = np.diff(key[order]) != 0
    per_point = np.bincount(pp[first], minlength=npt)
    few = np.flatnonzero(per_point < 2) if rays else few_none
    if few.size:
        p = int(few[0])
        where = np.flatnonzero(pp == p)
        more = f" (and {few.size - 1} more points)" if few.size > 1 else ""
        raise at_point(p, int(where[0]) if where.size else None)(
            f"point {block.points[p]} is seen by {per_point[p]} image{'' if per_point[p] == 1 else 's'}; "
            f"at least 2 are needed to intersect it{more}")
    per_image = np.bincount(ii[first], minlength=ni)
    few = np.flatnonzero(per_image < 3) if rays else few_none
    if few.size:
        k = int(few[0])
        more = f" (and {few.size - 1} more images)" if few.size > 1 else ""
        raise at_image(k)(f"image {block.images[k].id} sees {per_image[k]} point"
                          f"{'' if per_image[k] == 1 else 's'}; at least 3 are needed to orient it{more}")
    graph = coo_matrix((np.ones(n), (ii, ni + pp)), shape=(ni + npt, ni + npt))
    nc, label = connected_components(graph, directed=False)
    if not rays:
        # an image or point without any observation is a local defect (sfm_defects), not a part
        seen = np.zeros(ni + npt, dtype=bool)
        seen[ii] = True
        seen[ni + pp] = True
        _, label = np.unique(np.where(seen, label, -1), return_inverse=True)
        if not seen.all():
            label = label - 1                  # -1: unobserved
        nc = int(label.max()) + 1
    if nc > 1:
        parts = []
        for c in range(nc):
            imgs = [block.images[k].id for k in np.flatnonzero(label[:ni] == c)]
            npts = int((label[ni:] == c).sum())
            parts.append(f"images {', '.join(imgs[:6])}{' ...' if len(imgs) > 6 else ''} with {npts} points")
        sizes = np.bincount(label[:ni][label[:ni] >= 0], minlength=nc)
        small = int(np.argmin(sizes))
        k = int(np.flatnonzero(label[:ni] == small)[0])
        raise at_image(k)(f"the block falls apart into {nc} parts that share no point: "
                          + "; ".join(parts[:5]) + (" ..." if nc > 5 else ""))
    return block


def check_rotation(path, line: int, R: np.ndarray, what: str) -> None:
    """InputError unless R is a rotation matrix (orthonormal to 1e-6, determinant +1)."""
    if not np.isfinite(R).all() or np.abs(R).max() > 2.0:
        raise InputError(path, line, f"{what}: not a rotation matrix (entries beyond ±1 or not finite)")
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > 1e-6 or np.linalg.det(R) < 0:
        raise InputError(path, line, f"{what}: not a rotation matrix (|RᵀR − I| = {err:.2g}, "
                         f"det = {np.linalg.det(R):.3g})")


# --------------------------------------------------------------------------------------------
# BAL
# --------------------------------------------------------------------------------------------
def looks_like_bal(head: str) -> bool:
    """True if the text starts with a line of at most four numbers (a BAL header, perhaps a
    broken one: the reader then says what is wrong with it)."""
    lines = [ln.split() for ln in head.splitlines() if ln.strip()]
    if not lines or not 1 <= len(lines[0]) <= 4:
        return False
    try:
        [float(t) for t in lines[0]]
    except ValueError:
        return False
    return True


def read_bal(path, sigma_px: float = 1.0, refine_intrinsics: bool = True, check: bool = True) -> SfmBlock:
    """Read a BAL problem file into an :class:`baarda.model.sfm.SfmBlock` (module docstring).

    sigma_px: σ of each image coordinate (pixels). refine_intrinsics: estimate f, k1, k2 of
    every camera (BAL's definition; False holds them at the file's values). check: apply
    :func:`check_block` (False reads blocks that cannot be adjusted, e.g. to evaluate a cost).

    The file (plain or compressed, :mod:`baarda.io.source`) is read in chunks straight into
    the arrays of the block: a header announcing more numbers than the file's size can hold is
    refused before any number is read, and a file that ends early or goes on past the last
    point is refused where it does.
    """
    with open_binary(path) as f:
        block = _read_bal(path, Numbers(path, f), getattr(f, "source", None), sigma_px, refine_intrinsics)
    return check_block(path, block) if check else block


def _read_bal(path, num: Numbers, src, sigma_px, refine_intrinsics) -> SfmBlock:
    head_what = "header 'num_cameras num_points num_observations'"
    try:
        h, hl, hlast = num.take(3, 3)
    except Truncated as t:
        if t.have == 0:
            raise InputError(path, 1, f"empty file: expected the {head_what}") from None
        raise InputError(path, num.line, f"the file ends early: expected {head_what} ({t.have} of 3 "
                         "numbers present)") from None
    head_line = int(hl[0])
    num.check_ints(h, np.full(3, head_line), lambda j: j, lambda j: head_what)
    if hlast[0] != head_line:
        raise InputError(path, head_line, "the header must be 'num_cameras num_points num_observations' "
                         "on one line")
    ncam, npt, nobs = (int(v) for v in h)
    if ncam == 0 or npt == 0 or nobs == 0:
        raise InputError(path, head_line, f"empty block: {ncam} cameras, {npt} points, {nobs} observations")
    need = 4 * nobs + 9 * ncam + 3 * npt
    announce = f"the header announces {nobs} observations, {ncam} cameras and {npt} points ({need} numbers)"
    size = getattr(src, "size", None)
    if size is not None and need > (size + 1) // 2:
        raise InputError(path, head_line, f"{announce} but the file of {size} bytes cannot hold them "
                         f"(at most {(size + 1) // 2})")

    def truncated(before: int, t: Truncated):
        return InputError(path, head_line, f"{announce} but the file holds {before + t.have} numbers after it")

    try:
        v, first, last = num.take(4 * nobs, 4, what=lambda k: (
            (f"observation {k // 4 + 1}: camera and point index", "int") if k % 4 < 2 else
            (f"observation {k // 4 + 1}: image coordinates", "finite")))
    except Truncated as t:
        raise truncated(0, t) from None
    split = np.flatnonzero(first != last)
    if split.size:
        k = int(split[0])
        raise InputError(path, int(first[k]), f"observation {k + 1} must be one line 'camera point x y'")
    v = v.reshape(nobs, 4)
    num.check_ints(v[:, :2].ravel(), first, lambda j: 3 + 4 * (j // 2) + j % 2,
                   lambda j: f"observation {j // 2 + 1}: camera and point index")
    num.check_finite(v[:, 2:].ravel(), first, lambda j: 5 + 4 * (j // 2) + j % 2,
                     lambda j: f"observation {j // 2 + 1}: image coordinates")
    idx = v[:, :2].astype(np.int64)
    xy = np.ascontiguousarray(v[:, 2:])
    del v
    obs_line = first
    bad = np.flatnonzero(idx[:, 0] >= ncam)
    if bad.size:
        k = bad[0]
        raise InputError(path, int(obs_line[k]), f"camera index {idx[k, 0]} out of range (the header has "
                         f"{ncam} cameras)")
    bad = np.flatnonzero(idx[:, 1] >= npt)
    if bad.size:
        k = bad[0]
        raise InputError(path, int(obs_line[k]), f"point index {idx[k, 1]} out of range (the header has "
                         f"{npt} points)")
    base = 3 + 4 * nobs
    try:
        cams, cl, _ = num.take(9 * ncam, what=lambda k: (f"9 parameters for each of the {ncam} cameras", "finite"))
    except Truncated as t:
        raise truncated(4 * nobs, t) from None
    num.check_finite(cams, cl, lambda j: base + j, lambda j: f"9 parameters for each of the {ncam} cameras")
    cams = cams.reshape(ncam, 9)
    base += 9 * ncam
    try:
        X, pl, _ = num.take(3 * npt, what=lambda k: (f"3 coordinates for each of the {npt} points", "finite"))
    except Truncated as t:
        raise truncated(4 * nobs + 9 * ncam, t) from None
    num.check_finite(X, pl, lambda j: base + j, lambda j: f"3 coordinates for each of the {npt} points")
    X = X.reshape(npt, 3)
    num.end("the last point")
    angle = np.linalg.norm(cams[:, :3], axis=1)
    bad = np.flatnonzero(angle > MAX_ANGLE)
    if bad.size:
        c = int(bad[0])
        j = int(np.argmax(np.abs(cams[c, :3])))
        raise InputError(path, int(cl[9 * c + j]), f"camera {c}: rotation ρ{j + 1} = {cams[c, j]:g}: an angle-axis "
                         f"vector of length {angle[c]:.3g} rad (its angle) is beyond {MAX_ANGLE:g} rad, not a "
                         f"rotation double precision can adjust")
    bad = np.flatnonzero(cams[:, 6] <= 0)
    if bad.size:
        c = int(bad[0])
        raise InputError(path, int(cl[9 * c + 6]), f"camera {c}: focal length f = {cams[c, 6]:g} must be > 0")
    return bal_block(cams, X, idx, xy, obs_line, cl[::9], pl[::3].copy(), "bal", path, sigma_px, refine_intrinsics)


def bal_block(cams, X, idx, xy, obs_line, cam_line, pt_line, convention, path, sigma_px,
              refine_intrinsics, rodrigues=None) -> SfmBlock:
    """An SfmBlock of BAL-like cameras (one camera per image, params ρ t f k1 k2)."""
    ncam = cams.shape[0]
    rho = cams[:, :3] if rodrigues is None else rodrigues
    cameras = tuple(SfmCamera(str(c), "BAL", tuple(float(v) for v in cams[c, 6:9]), line=int(cam_line[c]))
                    for c in range(ncam))
    images = tuple(SfmImage(str(c), str(c), tuple(float(v) for v in rho[c]),
                            tuple(float(v) for v in cams[c, 3:6]), line=int(cam_line[c])) for c in range(ncam))
    return SfmBlock(cameras=cameras, images=images, points=tuple(str(i) for i in range(X.shape[0])),
                    X=X, point_line=np.asarray(pt_line, dtype=np.int64), obs_image=idx[:, 0].copy(),
                    obs_point=idx[:, 1].copy(), xy=xy, obs_line=np.asarray(obs_line, dtype=np.int64),
                    convention=convention, sigma_px=sigma_px, refine_intrinsics=refine_intrinsics,
                    source=str(path), title=Path(path).name)


def write_bal(block: SfmBlock, path) -> None:
    """Write a BAL-convention block (``bal`` or ``bundler``) as a BAL problem file."""
    if block.convention not in ("bal", "bundler"):
        raise ConversionError(block.convention, "only BAL and Bundler blocks can be written as BAL",
                              "only BAL and Bundler blocks can be written as BAL")
    out = [f"{len(block.images)} {len(block.points)} {block.obs_image.size}"]
    out += [f"{i} {p} {x:.17g} {y:.17g}" for i, p, (x, y) in zip(block.obs_image, block.obs_point, block.xy)]
    cams = {c.id: c for c in block.cameras}
    for im in block.images:
        out += [f"{v:.17g}" for v in (*im.rodrigues, *im.t, *cams[im.camera].params)]
    out += [f"{v:.17g}" for v in block.X.ravel()]
    write_text(path, "\n".join(out) + "\n")

