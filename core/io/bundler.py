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
"""

from __future__ import annotations

import numpy as np

from ..bal import SfmBlock
from ..errors import InputError
from ..rotation import rodrigues_from_R
from .bal import Tokens, bal_block, check_block, check_rotation, read_text

HEADER = "# Bundle file v0.3"


def looks_like_bundler(head: str) -> bool:
    return head.lstrip().startswith("# Bundle file")


def read_bundler(path, sigma_px: float = 1.0, refine_intrinsics: bool = True, check: bool = True) -> SfmBlock:
    """Read a Bundler v0.3 file into an :class:`baarda.bal.SfmBlock` (module docstring)."""
    text = read_text(path)
    first = text.lstrip().splitlines()[0].strip() if text.strip() else ""
    if first.startswith("# Bundle file") and first != HEADER:
        raise InputError(path, 1, f"unsupported Bundler version '{first[2:]}' (supported: v0.3)")
    tk = Tokens(path, text, comment="#")
    if not tk.toks:
        tk.fail("empty file: expected 'num_cameras num_points'", 1)
    head_line = tk.line
    ncam, npt = tk.ints(2, "header 'num_cameras num_points'")
    if ncam == 0 or npt == 0:
        tk.fail(f"empty block: {ncam} cameras, {npt} points", head_line)
    if 15 * ncam + 7 * npt > tk.left:
        tk.fail(f"the header announces {ncam} cameras and {npt} points (at least {15 * ncam + 7 * npt} "
                f"numbers) but the file holds {tk.left} numbers after it", head_line)
    cams = np.empty((ncam, 9))
    rho = np.empty((ncam, 3))
    cam_line = np.empty(ncam, dtype=np.int64)
    valid = np.ones(ncam, dtype=bool)
    for c in range(ncam):
        cam_line[c] = tk.line
        fk = tk.floats(3, f"camera {c}: f k1 k2")
        R = tk.floats(9, f"camera {c}: rotation matrix (3 lines of 3)").reshape(3, 3)
        t = tk.floats(3, f"camera {c}: translation")
        if fk[0] == 0 and not R.any():
            valid[c] = False
            cams[c] = 0.0
            rho[c] = 0.0
            continue
        if fk[0] <= 0:
            tk.fail(f"camera {c}: focal length f = {fk[0]:g} must be > 0", int(cam_line[c]))
        check_rotation(path, int(cam_line[c]) + 1, R, f"camera {c}")
        rho[c] = rodrigues_from_R(R)
        cams[c] = np.r_[0.0, 0.0, 0.0, t, fk]
    X = np.empty((npt, 3))
    pt_line = np.empty(npt, dtype=np.int64)
    idx, xy, obs_line = [], [], []
    for p in range(npt):
        pt_line[p] = tk.line
        X[p] = tk.floats(3, f"point {p}: X Y Z")
        tk.floats(3, f"point {p}: colour R G B")
        n_line = tk.line
        (nv,) = tk.ints(1, f"point {p}: number of views")
        if nv > ncam:
            tk.fail(f"point {p}: {nv} views but only {ncam} cameras", n_line)
        for _ in range(nv):
            line = tk.line
            c, _key = tk.ints(2, f"point {p}: view 'camera key x y'")
            if c >= ncam:
                tk.fail(f"point {p}: camera index {c} out of range (the header has {ncam} cameras)", line)
            if not valid[c]:
                tk.fail(f"point {p}: camera {c} was not reconstructed (all zeros) but has a view", line)
            idx.append((c, p))
            xy.append(tk.floats(2, f"point {p}: view image coordinates"))
            obs_line.append(line)
    tk.end("the last point")
    idx = np.array(idx, dtype=np.int64).reshape(-1, 2)
    xy = np.array(xy, dtype=float).reshape(-1, 2)
    keep = np.flatnonzero(valid)
    renumber = np.full(ncam, -1, dtype=np.int64)
    renumber[keep] = np.arange(keep.size)
    block = bal_block(cams[keep], X, np.c_[renumber[idx[:, 0]], idx[:, 1]], xy, np.array(obs_line, dtype=np.int64),
                      cam_line[keep], pt_line, "bundler", path, sigma_px, refine_intrinsics, rodrigues=rho[keep])
    if keep.size < ncam:
        ids = [str(c) for c in keep]
        block = block.replace(cameras=tuple(c.__class__(ids[k], c.model, c.params, line=c.line)
                                            for k, c in enumerate(block.cameras)),
                              images=tuple(im.__class__(ids[k], ids[k], im.rodrigues, im.t, line=im.line)
                                           for k, im in enumerate(block.images)))
    return check_block(path, block) if check else block
