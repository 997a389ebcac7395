"""Bundler v0.3 ``bundle.out`` files (Snavely et al. 2006).

Format (Bundler's user manual)::

    # Bundle file v0.3
    <num_cameras> <num_points>
    <camera>  × num_cameras:   f k1 k2 / R (3 lines of 3) / t (3)
    <point>   × num_points:    X Y Z / R G B (colour) / n  cam key x y  (n views)

Conventions (the same as BAL, :mod:`baarda.io.bal`): P = R X + t, p = −P/P_z, p' = f (1 +
k1‖p‖² + k2‖p‖⁴) p; image coordinates in pixels with the origin at the image centre, x right,
y up. ``key`` is the index of the SIFT feature and is not used. A camera Bundler did not
reconstruct is written as all zeros; it is left out (its index stays its id), and a view of it
is an error. Camera and point ids are the file's 0-based indices, as strings; f, k1, k2 are
estimated per camera by default, as in BAL.

Bundler files as they are written:

- **Rotations printed to a few digits.** Files are often written with printf's ``%g`` (6
  significant digits), and a rotation matrix so printed is orthonormal only to what 6 digits
  hold. Each printed entry r carries an error δ with |δ| ≤ ½·10⁻⁵·10^⌊log₁₀|r|⌋ ≤ 5·10⁻⁷
  (|r| ≤ 1), and (RᵀR − I)_ij = Σ_k (r_ki δ_kj + δ_ki r_kj) + O(δ²), so by Cauchy–Schwarz
  (unit columns, ‖δ_j‖ ≤ √3·5·10⁻⁷)

  .. math:: |RᵀR − I|_{max} ≤ 2√3 · 5·10^{-7} ≈ 1.73·10^{-6}  (:data:`PRINT_TOL`).

  A matrix within that bound (and det > 0) is replaced by the nearest rotation, the orthogonal
  polar factor U Vᵀ of its SVD U Σ Vᵀ (Higham 1986, "Computing the polar decomposition"), and
  the number of cameras so treated is recorded (``block.extra["reader_notes"]``, a warning line
  of ``baarda analyze``); a matrix farther from a rotation is refused at its line.
- **One point under two keys of one image.** ``key`` is the feature index; a point listed twice
  in one image under two keys is COLMAP's "two keypoints of one 3D point in one image" and is
  read as :mod:`baarda.io.colmap` reads it: each an observation of its own, told apart by its key
  (``block.extra["obs_keypoint"]``, counted in ``block.extra["duplicate_keypoints"]``). The same
  key twice in one image is an error.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..model.sfm import SfmBlock
from ..observations.rotation import rodrigues_from_R
from .bal import bal_block, check_block, check_rotation
from .colmap import duplicate_keypoints
from .source import Numbers, open_binary

HEADER = "# Bundle file v0.3"
#: |RᵀR − I| a rotation printed to 6 significant digits may show (module docstring); the
#: second-order term 3·(5·10⁻⁷)² is added for completeness
PRINT_TOL = 2.0 * math.sqrt(3.0) * 5e-7 + 3.0 * (5e-7) ** 2
EXACT_TOL = 1e-12    # |RᵀR − I| of a matrix written to (nearly) full precision: taken as it is


def looks_like_bundler(head: str) -> bool:
    return head.lstrip().startswith("# Bundle file")


def read_bundler(path, sigma_px: float = 1.0, refine_intrinsics: bool = True, check: bool = True) -> SfmBlock:
    """Read a Bundler v0.3 file into an :class:`baarda.model.sfm.SfmBlock` (module docstring).

    The file (plain or compressed) is read in chunks into one array of numbers
    (:class:`baarda.io.source.Numbers`); the structure (cameras, then points with their
    views) is then found by one pass over the points, and every check is vectorised.
    """
    with open_binary(path) as f:
        ln, prefix = 0, b""
        while True:
            raw = f.readline()
            if not raw:
                break
            ln += 1
            if raw.strip():
                first = raw.decode("utf-8", "replace").strip()
                if first.startswith("# Bundle file") and first != HEADER:
                    raise InputError(path, ln, f"unsupported Bundler version '{first[2:]}' (supported: v0.3)")
                if not first.startswith("#"):
                    prefix = raw
                    ln -= 1
                break
        _check_header_size(path, f, ln, prefix)
        num = Numbers(path, f, first_line=ln + 1, comment="#", prefix=prefix)
        vals, lines = num.take_rest()
    block = _bundler_block(path, num, vals, lines, sigma_px, refine_intrinsics)
    return check_block(path, block) if check else block


def _check_header_size(path, f, ln: int, prefix: bytearray | bytes) -> None:
    """Refuse a header 'num_cameras num_points' that announces more numbers than the file's
    size can hold (a plain file), before any number is read: the header is ``prefix`` (a line
    already read) or the first non-blank line ahead in the stream, peeked at, not consumed."""
    src = getattr(f, "source", None)
    size = getattr(src, "size", None)
    if size is None:
        return
    head, line = prefix, ln + 1
    if not head.strip():
        peek = f.peek(4096)[:4096]
        for k, raw in enumerate(peek.split(b"\n")[:-1]):
            if raw.strip():
                head, line = raw, ln + 1 + k
                break
    toks = head.split()
    if len(toks) < 2 or not (toks[0].isdigit() and toks[1].isdigit()) or len(toks[0]) > 12 or len(toks[1]) > 12:
        return                          # the reader says what is wrong with it
    ncam, npt = int(toks[0]), int(toks[1])
    need = 15 * ncam + 7 * npt
    if need > (size + 1) // 2:
        raise InputError(path, line, f"the header announces {ncam} cameras and {npt} points (at least {need} "
                         f"numbers) but the file of {size} bytes cannot hold them (at most {(size + 1) // 2})")


def _bundler_block(path, num, vals, lines, sigma_px, refine_intrinsics) -> SfmBlock:
    n = vals.size
    end_line = num.last_line
    if n == 0:
        raise InputError(path, 1, "empty file: expected 'num_cameras num_points'")
    if n < 2:
        raise InputError(path, end_line, "the file ends early: expected header 'num_cameras num_points' "
                         "(1 of 2 numbers present)")
    head_line = int(lines[0])
    num.check_ints(vals[:2], lines[:2], lambda j: j, lambda j: "header 'num_cameras num_points'")
    ncam, npt = int(vals[0]), int(vals[1])
    if ncam == 0 or npt == 0:
        raise InputError(path, head_line, f"empty block: {ncam} cameras, {npt} points")
    if 15 * ncam + 7 * npt > n - 2:
        raise InputError(path, head_line, f"the header announces {ncam} cameras and {npt} points (at least "
                         f"{15 * ncam + 7 * npt} numbers) but the file holds {n - 2} numbers after it")
    # cameras: f k1 k2 / R (9) / t (3)
    field = ("f k1 k2",) * 3 + ("rotation matrix (3 lines of 3)",) * 9 + ("translation",) * 3
    C = vals[2:2 + 15 * ncam]
    num.check_finite(C, lines[2:2 + 15 * ncam], lambda j: 2 + j, lambda j: f"camera {j // 15}: {field[j % 15]}")
    C = C.reshape(ncam, 15)
    cam_line = lines[2:2 + 15 * ncam:15]
    fk, R, t = C[:, :3], C[:, 3:12].reshape(ncam, 3, 3), C[:, 12:]
    valid = ~((fk[:, 0] == 0) & ~R.reshape(ncam, 9).any(axis=1))
    rho = np.zeros((ncam, 3))
    cams = np.zeros((ncam, 9))
    fixed: list[int] = []
    for c in np.flatnonzero(valid):
        if fk[c, 0] <= 0:
            raise InputError(path, int(cam_line[c]), f"camera {c}: focal length f = {fk[c, 0]:g} must be > 0")
        R[c] = _rotation(path, int(lines[2 + 15 * c + 3]), R[c], f"camera {c}", fixed)
        rho[c] = rodrigues_from_R(R[c])
        cams[c] = np.r_[0.0, 0.0, 0.0, t[c], fk[c]]
    # points: X Y Z / R G B / n, then n × (camera key x y); one pass finds where each starts
    offs, nview, stop, err = _point_offsets(vals, 2 + 15 * ncam, npt, ncam)
    # the first bad number before the structure broke (in file order) comes first
    span = slice(2 + 15 * ncam, stop)
    seg = vals[span]
    bad_at = None
    nonfinite = np.flatnonzero(~np.isfinite(seg))
    if nonfinite.size:
        bad_at = int(nonfinite[0]) + span.start
    view_start = np.repeat(offs[:len(nview)] + 7, nview) + 4 * _ranks(nview)
    int_pos = np.concatenate([view_start, view_start + 1])
    int_pos.sort()
    iv = vals[int_pos]
    not_int = np.flatnonzero(~(np.isfinite(iv) & (iv >= 0) & (iv == np.floor(iv)) & (iv < 1e17)))
    if not_int.size and (bad_at is None or int_pos[not_int[0]] < bad_at):
        bad_at = int(int_pos[not_int[0]])
    if err is not None and err[1] is None and (bad_at is None or err[0] < bad_at):
        bad_at = err[0]                     # a number of views that is not a count
    if bad_at is not None and (err is None or bad_at < err[0] or (bad_at == err[0] and err[1] is None)):
        p, what = _describe(bad_at, offs, nview)
        if np.isfinite(vals[bad_at]) or what.endswith("number of views"):
            num.check_ints(vals[bad_at:bad_at + 1], lines[bad_at:bad_at + 1], lambda j: bad_at, lambda j: what)
        num.check_finite(vals[bad_at:bad_at + 1], lines[bad_at:bad_at + 1], lambda j: bad_at, lambda j: what)
    if err is not None:
        raise InputError(path, int(lines[err[0]]) if err[0] < n else end_line, err[1])
    cam_of = vals[view_start].astype(np.int64)
    obs_pt = np.repeat(np.arange(npt), nview)
    bad = np.flatnonzero(cam_of >= ncam)
    if bad.size:
        k = int(bad[0])
        raise InputError(path, int(lines[view_start[k]]), f"point {obs_pt[k]}: camera index {cam_of[k]} out of "
                         f"range (the header has {ncam} cameras)")
    bad = np.flatnonzero(~valid[cam_of])
    if bad.size:
        k = int(bad[0])
        raise InputError(path, int(lines[view_start[k]]), f"point {obs_pt[k]}: camera {cam_of[k]} was not "
                         "reconstructed (all zeros) but has a view")
    if stop < n:
        t0 = num.text(stop, float(vals[stop]))
        raise InputError(path, int(lines[stop]), f"unexpected '{t0[:40]}' after the last point (the counts in "
                         "the header do not match the file)")
    keys = vals[view_start + 1].astype(np.int64)
    X = vals[offs[:, None] + np.arange(3)]
    xy = np.c_[vals[view_start + 2], vals[view_start + 3]]
    obs_line = lines[view_start]
    pt_line = lines[offs]
    keep = np.flatnonzero(valid)
    renumber = np.full(ncam, -1, dtype=np.int64)
    renumber[keep] = np.arange(keep.size)
    block = bal_block(cams[keep], X, np.c_[renumber[cam_of], obs_pt], xy, obs_line, cam_line[keep], pt_line,
                      "bundler", path, sigma_px, refine_intrinsics, rodrigues=rho[keep])
    extra = {"obs_keypoint": keys, "duplicate_keypoints": duplicate_keypoints(block.obs_image, block.obs_point, npt)}
    if fixed:
        extra["reader_notes"] = [
            f"{len(fixed)} rotation matrix(es) orthonormal only to the printed digits (|RᵀR − I| ≤ "
            f"{PRINT_TOL:.2g}, e.g. camera {fixed[0]}) replaced by the nearest rotation"]
    block = block.replace(extra={**block.extra, **extra})
    if keep.size < ncam:
        ids = [str(c) for c in keep]
        block = block.replace(cameras=tuple(c.__class__(ids[k], c.model, c.params, line=c.line)
                                            for k, c in enumerate(block.cameras)),
                              images=tuple(im.__class__(ids[k], ids[k], im.rodrigues, im.t, line=im.line)
                                           for k, im in enumerate(block.images)))
    return block


def _rotation(path, line: int, R: np.ndarray, what: str, fixed: list) -> np.ndarray:
    """R itself when orthonormal to rounding, its nearest rotation (the polar factor) when
    within what printing to 6 digits allows (its camera appended to ``fixed``), else
    InputError at ``line`` (module docstring)."""
    if not np.isfinite(R).all() or np.abs(R).max() > 2.0:
        check_rotation(path, line, R, what)                 # raises, saying which
    err, det = float(np.abs(R.T @ R - np.eye(3)).max()), float(np.linalg.det(R))
    if err > PRINT_TOL or det < 0:
        raise InputError(path, line, f"{what}: not a rotation matrix (|RᵀR − I| = {err:.2g}, beyond the "
                         f"{PRINT_TOL:.2g} that printing to 6 digits allows; det = {det:.3g})")
    if err <= EXACT_TOL:
        return R
    U, _, Vt = np.linalg.svd(R)
    fixed.append(what.split()[-1])
    return U @ Vt


def _ranks(counts: np.ndarray) -> np.ndarray:
    """0, 1, ..., counts[0] − 1, 0, 1, ... (the rank of each view within its point)."""
    total = int(counts.sum())
    starts = np.repeat(np.cumsum(counts) - counts, counts)
    return np.arange(total) - starts


def _point_offsets(vals, pos: int, npt: int, ncam: int):
    """Start of each point's numbers, its number of views, the position after the last point,
    and (position, message) of the first structural error or None."""
    n = vals.size
    offs = np.empty(npt, dtype=np.int64)
    nviews = []
    for p in range(npt):
        offs[p] = pos
        if pos + 7 > n:
            have = n - pos
            what = (f"point {p}: X Y Z ({have} of 3" if have < 3 else
                    f"point {p}: colour R G B ({have - 3} of 3" if have < 6 else
                    f"point {p}: number of views (0 of 1")
            return offs[:p + 1], np.array(nviews, dtype=np.int64), n, \
                (n, f"the file ends early: expected {what} numbers present)")
        nv = vals[pos + 6]
        if not (nv < 1e17 and nv >= 0 and nv == np.floor(nv)):
            return offs[:p + 1], np.array(nviews, dtype=np.int64), pos + 6, (pos + 6, None)
        nv = int(nv)              # may exceed the cameras: two keys of one image (module docstring)
        if pos + 7 + 4 * nv > n:
            have = n - pos - 7
            k, r = divmod(have, 4)
            what = (f"point {p}: view 'camera key x y' ({r} of 2" if r < 2 else
                    f"point {p}: view image coordinates ({r - 2} of 2")
            nviews.append(k)
            return offs[:p + 1], np.array(nviews, dtype=np.int64), n, \
                (n, f"the file ends early: expected {what} numbers present)")
        nviews.append(nv)
        pos += 7 + 4 * nv
    return offs, np.array(nviews, dtype=np.int64), pos, None


def _describe(at: int, offs, nview) -> tuple[int, str]:
    """(point, what) of the number at position ``at``."""
    p = int(np.searchsorted(offs, at, side="right")) - 1
    r = at - int(offs[p])
    if r < 3:
        return p, f"point {p}: X Y Z"
    if r < 6:
        return p, f"point {p}: colour R G B"
    if r == 6:
        return p, f"point {p}: number of views"
    return p, (f"point {p}: view 'camera key x y'" if (r - 7) % 4 < 2 else f"point {p}: view image coordinates")
