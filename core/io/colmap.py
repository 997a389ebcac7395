"""COLMAP sparse models: ``cameras``, ``images`` and ``points3D`` as ``.txt`` or ``.bin``.

A model is a directory (``sparse/0``) holding the three files, either all as text or all as
binary (COLMAP's ``model_converter`` writes both; text wins when both are present). Other files
of COLMAP 3.12+ (``rigs``, ``frames``) are not needed: ``images`` carries every image's pose.

Text formats (COLMAP documentation, "Output format")::

    cameras.txt    CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]
    images.txt     IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME          (two lines per image)
                   X Y POINT3D_ID  ...                                    (POINT3D_ID −1: none)
    points3D.txt   POINT3D_ID X Y Z R G B ERROR (IMAGE_ID POINT2D_IDX)...

Binary formats: little-endian, the same fields; counts as uint64, ids as uint32 (images,
cameras) and uint64 (points, 2⁶⁴ − 1 meaning none), model ids as int32 (0 SIMPLE_PINHOLE,
1 PINHOLE, 2 SIMPLE_RADIAL, 3 RADIAL, 4 OPENCV, ...), names null-terminated. Errors in binary
files name the byte offset of the record at fault (``points3D.bin:byte 812: ...``). Each file may
be compressed (``images.txt.gz``, :mod:`baarda.io.source`).

Conventions: the pose (q, t) maps world to camera, q = (w, x, y, z) scalar first
(:func:`baarda.observations.rotation.R_from_quaternion`); the camera looks down +z; pixel coordinates have
their origin at the upper-left corner of the image (the centre of the first pixel is at
0.5, 0.5), y down. Projection: :mod:`baarda.model.sfm` with s = +1; camera models:
SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, and — their distortion always held at the
file's values (:mod:`baarda.observations.fixed_models`) — FULL_OPENCV, OPENCV_FISHEYE,
RADIAL_FISHEYE, SIMPLE_RADIAL_FISHEYE, FOV, THIN_PRISM_FISHEYE, RAD_TAN_THIN_PRISM_FISHEYE,
SIMPLE_DIVISION, DIVISION, SIMPLE_FISHEYE, FISHEYE, EUCM (EQUIRECTANGULAR, not a central
perspective camera, is refused, naming the camera). Intrinsics are held fixed unless ``refine_intrinsics``; then, like
COLMAP's bundle adjuster, the focal lengths and the distortion parameters of the first five
models are estimated and the principal point stays fixed. Ids in the output are COLMAP's
IMAGE_ID, POINT3D_ID and CAMERA_ID; the image names are kept in ``Problem.notes.image_names``.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..model.sfm import CAMERA_MODELS, SfmBlock, SfmCamera, SfmImage
from ..observations.rotation import R_from_quaternion, rodrigues_from_R
from .bal import check_block
from .source import EXTENSIONS, WHITESPACE, Numbers, logical_path, open_binary, read_bytes, read_text

MODEL_IDS = {0: "SIMPLE_PINHOLE", 1: "PINHOLE", 2: "SIMPLE_RADIAL", 3: "RADIAL", 4: "OPENCV",
             5: "OPENCV_FISHEYE", 6: "FULL_OPENCV", 7: "FOV", 8: "SIMPLE_RADIAL_FISHEYE",
             9: "RADIAL_FISHEYE", 10: "THIN_PRISM_FISHEYE", 11: "RAD_TAN_THIN_PRISM_FISHEYE",
             12: "SIMPLE_DIVISION", 13: "DIVISION", 14: "SIMPLE_FISHEYE", 15: "FISHEYE", 16: "EUCM",
             17: "EQUIRECTANGULAR"}
SUPPORTED = tuple(m for m in CAMERA_MODELS if m != "BAL")
FILES = ("cameras", "images", "points3D")
INVALID_ID = 2 ** 64 - 1


def find_file(d: Path, name: str, ext: str) -> Path | None:
    """``d/name.ext``, or the same compressed (``.gz``, ``.bz2``, ``.xz``), if it is a file."""
    for comp in ("", *EXTENSIONS):
        f = d / f"{name}{ext}{comp}"
        if f.is_file():
            return f
    return None


def model_files(path) -> tuple[Path, str, tuple[Path, Path, Path]] | None:
    """(directory, ".txt" or ".bin", (cameras, images, points3D) files) of the COLMAP model at
    ``path`` (the directory or one of its files, each perhaps compressed), or None."""
    p = Path(path)
    d = p if p.is_dir() else p.parent
    if not p.is_dir() and logical_path(p).stem not in FILES:
        return None
    for ext in (".txt", ".bin"):
        files = [find_file(d, name, ext) for name in FILES]
        if all(files):
            return d, ext, tuple(files)
    return None


def read_colmap(path, sigma_px: float = 1.0, refine_intrinsics: bool = False, check: bool = True) -> SfmBlock:
    """Read a COLMAP sparse model (directory or one of its files) into an SfmBlock.

    Several keypoints of one image may observe the same 3D point (COLMAP allows it, and real
    models have it): each is an observation of its own, named by its keypoint index
    (POINT2D_IDX) in ``block.extra["obs_keypoint"]``; ``block.extra["duplicate_keypoints"]``
    counts the points concerned and the observations beyond the first.
    """
    found = model_files(path)
    if found is None:
        p = Path(path)
        d = p if p.is_dir() else p.parent
        have = sorted(f.name for f in d.glob("*")) if d.is_dir() else []
        ext = ".bin" if any(".bin" in h for h in have) else ".txt"
        missing = [f"{n}{ext}" for n in FILES if find_file(d, n, ext) is None]
        raise InputError(path, 0, f"not a complete COLMAP model: missing {', '.join(missing) or 'files'} "
                         f"(found: {', '.join(have[:8]) or 'nothing'})")
    d, ext, (cam_path, img_path, pt_path) = found
    if ext == ".txt":
        cams = _cameras_txt(cam_path)
        imgs = _images_txt(img_path)
        pts = _points_txt(pt_path)
    else:
        cams = _cameras_bin(cam_path)
        imgs = _images_bin(img_path)
        pts = _points_bin(pt_path)
    block = _assemble(d, ext == ".bin", (cam_path, img_path, pt_path), cams, imgs, pts, sigma_px,
                      refine_intrinsics)
    return check_block(pt_path, block, image_path=img_path) if check else block


def _error(path, where: int, message: str, binary: bool) -> InputError:
    """InputError at a line of a text file, or at a byte offset of a binary one."""
    return InputError(path, 0, message, offset=where) if binary else InputError(path, where, message)


# --------------------------------------------------------------------------------------------
# validation shared by text and binary
# --------------------------------------------------------------------------------------------
def _camera(path, line, cid, model, width, height, params) -> SfmCamera:
    if model not in SUPPORTED:
        raise InputError(path, line, f"camera {cid}: unknown/unsupported camera model {model} "
                         f"(supported: {', '.join(SUPPORTED)})")
    names = CAMERA_MODELS[model][0]
    if len(params) != len(names):
        raise InputError(path, line, f"camera {cid}: model {model} has {len(names)} parameters "
                         f"({' '.join(names)}), found {len(params)}")
    if width <= 0 or height <= 0:
        raise InputError(path, line, f"camera {cid}: image size {width} × {height} must be positive")
    for nm, v in zip(names, params):
        if not np.isfinite(v):
            raise InputError(path, line, f"camera {cid}: parameter {nm} = {v} is not finite")
        if nm in ("f", "fx", "fy") and v <= 0:
            raise InputError(path, line, f"camera {cid}: focal length {nm} = {v:g} must be > 0")
    return SfmCamera(str(cid), model, tuple(float(v) for v in params), float(width), float(height), line)


def _pose(path, line, iid, q, t) -> tuple:
    q = np.asarray(q, dtype=float)
    t = np.asarray(t, dtype=float)
    if not (np.isfinite(q).all() and np.isfinite(t).all()):
        raise InputError(path, line, f"image {iid}: the pose has non-finite numbers")
    m = float(np.abs(q).max())
    nq = m * float(np.linalg.norm(q / m)) if m > 0 else 0.0     # scaled: 1e200² would overflow
    if not math.isfinite(nq):
        raise InputError(path, line, f"image {iid}: the quaternion QW QX QY QZ has norm > 1e308, not 1")
    if abs(nq - 1.0) > 1e-3:
        raise InputError(path, line, f"image {iid}: the quaternion QW QX QY QZ has norm {nq:.6g}, not 1")
    rho = rodrigues_from_R(R_from_quaternion(q))
    return tuple(float(v) for v in rho), tuple(float(v) for v in t)


class _Images:
    """Images as read: per image (where, q, t, camera id, name, where of its image points), and
    all image points in one array (xy, POINT3D_ID or −1), image k's from ``off[k]`` on."""

    def __init__(self):
        self.ids, self.recs, self.xy, self.p3d, self.counts = [], [], [], [], []

    def add(self, iid, where, q, t, cid, name, xy, p3d, pwhere):
        self.ids.append(iid)
        self.recs.append((where, q, t, cid, name, pwhere))
        self.xy.append(xy)
        self.p3d.append(p3d)
        self.counts.append(len(p3d))

    def done(self):
        self.count = np.asarray(self.counts, dtype=np.int64)
        self.off = np.concatenate([[0], np.cumsum(self.count)]).astype(np.int64)
        self.xy = np.concatenate(self.xy).reshape(-1, 2) if self.xy else np.zeros((0, 2))
        self.p3d = np.concatenate(self.p3d).astype(np.int64) if self.p3d else np.zeros(0, dtype=np.int64)
        return self


class _Points:
    """Points as read: ids, where, coordinates, and all track elements (image id, POINT2D_IDX)
    in one array, point k's from ``off[k]`` on."""

    def __init__(self):
        self.ids, self.where, self.xyz, self.tracks = [], [], [], []

    def add(self, pid, where, xyz, track):
        self.ids.append(pid)
        self.where.append(where)
        self.xyz.append(xyz)
        self.tracks.append(track)

    def done(self):
        n = np.array([t.shape[0] for t in self.tracks], dtype=np.int64)
        self.off = np.concatenate([[0], np.cumsum(n)]).astype(np.int64)
        self.count = n
        tr = np.concatenate(self.tracks).reshape(-1, 2) if self.tracks else np.zeros((0, 2), dtype=np.int64)
        self.tracks = None
        self.t_img, self.t_idx = tr[:, 0].astype(np.int64), tr[:, 1].astype(np.int64)
        self.pid = np.asarray(self.ids, dtype=np.int64)
        self.X = np.asarray(self.xyz, dtype=float).reshape(-1, 3)
        self.xyz = None
        return self


def _assemble(d, binary, paths, cams, imgs: _Images, pts: _Points, sigma_px, refine) -> SfmBlock:
    cam_path, img_path, pt_path = paths
    cam_name, img_name, pt_name = (logical_path(p).name for p in paths)
    images = []
    for iid, (where, q, t, cid, name, _) in zip(imgs.ids, imgs.recs):
        if cid not in cams:
            raise _error(img_path, where, f"image {iid}: camera {cid} is not in {cam_name}", binary)
        rho, tt = _pose(img_path, where, iid, q, t) if not binary else _pose_bin(img_path, where, iid, q, t)
        images.append(SfmImage(str(iid), str(cid), rho, tt, name, 0 if binary else where))
    used = {rec[3] for rec in imgs.recs}
    cameras = tuple(c for cid, c in cams.items() if cid in used)
    # track elements → image index and image point (vectorised; errors in the order of the file)
    img_ids = np.asarray(imgs.ids, dtype=np.int64)
    order = np.argsort(img_ids, kind="stable")
    T = pts.t_img.size
    obs_point = np.repeat(np.arange(len(pts.ids), dtype=np.int64), pts.count)
    pos = np.searchsorted(img_ids[order], pts.t_img)
    pos = np.minimum(pos, max(len(order) - 1, 0))
    known = (img_ids[order][pos] == pts.t_img) if len(order) else np.zeros(T, dtype=bool)
    img = np.where(known, order[pos] if len(order) else 0, 0)
    in_range = known & (pts.t_idx < imgs.count[img])
    slot = np.where(in_range, imgs.off[img] + np.where(in_range, pts.t_idx, 0), 0)
    belongs = in_range & (imgs.p3d[slot] == pts.pid[obs_point]) if imgs.p3d.size else in_range
    bad = np.flatnonzero(~belongs)
    if bad.size:
        k = int(bad[0])
        p, iid, idx = int(obs_point[k]), int(pts.t_img[k]), int(pts.t_idx[k])
        pid, where = pts.ids[p], pts.where[p]
        if not known[k]:
            msg = f"point {pid}: image {iid} of its track is not in {img_name}"
        elif not in_range[k]:
            msg = (f"point {pid}: image {iid} has {imgs.count[img[k]]} image points, POINT2D_IDX {idx} is "
                   "out of range")
        else:
            msg = (f"point {pid}: image point {idx} of image {iid} belongs to point "
                   f"{_pid(int(imgs.p3d[slot[k]]))}, not to this one")
        raise _error(pt_path, where, msg, binary)
    linked = np.flatnonzero(imgs.p3d != -1)
    hit = np.zeros(imgs.p3d.size, dtype=bool)
    hit[slot[belongs]] = True
    if linked.size != T or not hit[linked].all():
        missing = linked[~hit[linked]]
        if missing.size:
            j = int(missing[0])
            k = int(np.searchsorted(imgs.off, j, side="right")) - 1
            iid, idx = imgs.ids[k], j - int(imgs.off[k])
            raise _error(img_path, imgs.recs[k][5], f"image {iid}: image point {idx} refers to point "
                         f"{int(imgs.p3d[j])}, whose track in {pt_name} does not list it", binary)
    xy = imgs.xy[slot] if T else np.zeros((0, 2))
    if not np.isfinite(xy).all():
        k = int(np.flatnonzero(~np.isfinite(xy).all(axis=1))[0])
        raise _error(img_path, imgs.recs[img[k]][5], f"image {images[img[k]].id}: image coordinates are "
                     "not finite", binary)
    obs_line = np.zeros(T, dtype=np.int64) if binary else \
        np.asarray([r[5] for r in imgs.recs], dtype=np.int64)[img]
    point_where = np.asarray(pts.where, dtype=np.int64)
    extra = {"obs_keypoint": pts.t_idx, "duplicate_keypoints": duplicate_keypoints(img, obs_point, len(pts.ids))}
    if binary:
        extra["point_offset"] = point_where
        extra["image_offset"] = np.asarray([r[0] for r in imgs.recs], dtype=np.int64)
    return SfmBlock(cameras=cameras, images=tuple(images), points=tuple(str(i) for i in pts.ids),
                    X=pts.X, point_line=np.zeros(len(pts.ids), dtype=np.int64) if binary else point_where,
                    obs_image=img.astype(np.int64), obs_point=obs_point, xy=np.ascontiguousarray(xy),
                    obs_line=obs_line, convention="colmap", sigma_px=sigma_px, refine_intrinsics=refine,
                    source=str(d), title=Path(d).name, extra=extra)


def duplicate_keypoints(obs_image, obs_point, npt: int) -> dict:
    """How many points are observed by more than one keypoint of some image, and how many
    observations there are beyond the first of each (image, point) pair."""
    key = obs_image.astype(np.int64) * max(npt, 1) + obs_point
    key.sort()
    dup = np.flatnonzero(np.diff(key) == 0) + 1
    return {"points": int(np.unique(key[dup] % max(npt, 1)).size), "observations": int(dup.size)}


def _pid(p):
    return "none (−1)" if p == -1 else p


def _pose_bin(path, at, iid, q, t):
    try:
        return _pose(path, 0, iid, q, t)
    except InputError as err:
        raise InputError(path, 0, err.message, offset=at) from None


# --------------------------------------------------------------------------------------------
# text
# --------------------------------------------------------------------------------------------
def _records(path):
    """Non-comment lines as (line number, tokens)."""
    text = read_text(path)
    return [(ln, s.split()) for ln, s in enumerate(text.splitlines(), 1)
            if s.strip() and not s.lstrip().startswith("#")], text


def _lines(path):
    """(line number, bytes) of each line of a (perhaps compressed) text file, read as a stream."""
    with open_binary(path) as f:
        yield from enumerate(f, 1)


def _text(path, line: int, raw: bytes) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise InputError(path, line, f"not UTF-8 text (byte {err.start} of the line)") from None


def _ntok(raw: bytes) -> int:
    """Number of whitespace-separated tokens."""
    ws = WHITESPACE[np.frombuffer(raw, dtype=np.uint8)]
    return int(np.count_nonzero(~ws[1:] & ws[:-1])) + int(ws.size > 0 and not ws[0])


def _int(path, line, tok, what, allow_negative=False):
    t = tok[1:] if allow_negative and tok.startswith("-") else tok
    if not (t.isascii() and t.isdigit()):         # str.isdigit accepts '²' and '①', int() does not
        raise InputError(path, line, f"{what}: '{tok[:40]}' is not an integer")
    if len(t) > 19 or int(t) >= 2**63:               # ids are kept as 64-bit integers
        raise InputError(path, line, f"{what}: {tok[:40]}{'...' if len(tok) > 40 else ''} is too large")
    return int(tok)


def _floats(path, line, toks, what):
    try:
        a = np.array(toks, dtype=float)
    except ValueError:
        bad = next(t for t in toks if not _is_float(t))
        raise InputError(path, line, f"{what}: '{bad[:40]}' is not a number") from None
    if not np.isfinite(a).all():
        raise InputError(path, line, f"{what}: {toks[int(np.flatnonzero(~np.isfinite(a))[0])]} is not finite")
    return a


def _is_float(t):
    try:
        float(t)
        return True
    except ValueError:
        return False


def _numbers(s: str) -> np.ndarray | None:
    """The numbers of a line parsed at once, or None when that fails (the caller then looks
    for the culprit token by token)."""
    if not s.strip():
        return np.zeros(0)
    try:
        a = np.fromstring(s, dtype=float, sep=" ")
    except ValueError:
        return None
    return a


def _cameras_txt(path) -> dict:
    recs, _ = _records(path)
    cams = {}
    for line, tok in recs:
        if len(tok) < 4:
            raise InputError(path, line, "expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]'")
        cid = _int(path, line, tok[0], "CAMERA_ID")
        if cid in cams:
            raise InputError(path, line, f"duplicate CAMERA_ID {cid} (first at line {cams[cid].line})")
        w = _int(path, line, tok[2], f"camera {cid}: WIDTH")
        h = _int(path, line, tok[3], f"camera {cid}: HEIGHT")
        params = _floats(path, line, tok[4:], f"camera {cid}: PARAMS")
        cams[cid] = _camera(path, line, cid, tok[1], w, h, params)
    if not cams:
        raise InputError(path, 1, "no cameras")
    return cams


_ID_EXACT = 2.0 ** 53


def _images_txt(path) -> _Images:
    imgs = _Images()
    first = {}
    it = _lines(path)
    for line, raw in it:
        if not raw.strip() or raw.lstrip().startswith(b"#"):
            continue
        tok = _text(path, line, raw).split()
        if len(tok) < 10:
            raise InputError(path, line, "expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        iid = _int(path, line, tok[0], "IMAGE_ID")
        if iid in first:
            raise InputError(path, line, f"duplicate IMAGE_ID {iid} (first at line {first[iid]})")
        first[iid] = line
        pose = _floats(path, line, tok[1:8], f"image {iid}: pose")
        cid = _int(path, line, tok[8], f"image {iid}: CAMERA_ID")
        name = " ".join(tok[9:])
        nxt = next(it, None)
        if nxt is None:
            raise InputError(path, line, f"image {iid}: the file ends before its line of image points")
        pline, ps = nxt
        a = _numbers(ps)
        ok = (a is not None and a.size % 3 == 0 and np.isfinite(a).all()
              and np.all(a[2::3] == np.floor(a[2::3])) and np.all(a[2::3] >= -1)
              and np.all(np.abs(a[2::3]) < _ID_EXACT) and a.size == _ntok(ps))
        if ok:
            a = a.reshape(-1, 3)
            xy, p3d = a[:, :2].copy(), a[:, 2].astype(np.int64)
        else:
            xy, p3d = _image_points_slow(path, pline, iid, _text(path, pline, ps).split())
        imgs.add(iid, line, pose[:4], pose[4:], cid, name, xy, p3d, pline)
    if not imgs.ids:
        raise InputError(path, 1, "no images")
    return imgs.done()


def _image_points_slow(path, pline, iid, ptok):
    if len(ptok) % 3:
        raise InputError(path, pline, f"image {iid}: image points must come as 'X Y POINT3D_ID' triples "
                         f"({len(ptok)} numbers)")
    m = len(ptok) // 3
    trip = np.array(ptok, dtype=object).reshape(m, 3)
    xy = _floats(path, pline, list(trip[:, :2].ravel()), f"image {iid}: image point").reshape(m, 2)
    p3d = [_int(path, pline, t, f"image {iid}: POINT3D_ID", allow_negative=True) for t in trip[:, 2]]
    if any(p < -1 for p in p3d):
        raise InputError(path, pline, f"image {iid}: POINT3D_ID {min(p3d)} is invalid (−1 means none)")
    if any(p >= 2 ** 63 for p in p3d):
        raise InputError(path, pline, f"image {iid}: POINT3D_ID {max(p3d)} is too large")
    return xy, np.asarray(p3d, dtype=np.int64)


def _points_txt(path) -> _Points:
    """points3D.txt read in chunks (:class:`baarda.io.source.Numbers`): one line per point,
    the lines told apart by the line of each number; a line that fails the vectorised checks
    is read again as text to say what is wrong with it."""
    with open_binary(path) as f:
        num = Numbers(path, f, comment="#")
        vals, lines = num.take_rest()
    if vals.size == 0:
        raise InputError(path, 1, "no points")
    new = np.flatnonzero(np.diff(lines)) + 1
    start = np.concatenate([[0], new])
    count = np.diff(np.append(start, vals.size))
    rank = np.arange(vals.size) - np.repeat(start, count)
    integral = np.isfinite(vals) & (vals >= 0) & (vals < _ID_EXACT) & (vals == np.floor(vals))
    finite = np.isfinite(vals)
    good_tok = np.where((rank == 0) | (rank >= 8), integral, finite)
    bad_line = (count < 8) | (count % 2 == 1)
    bad_line |= np.add.reduceat(~good_tok, start).astype(bool)
    ids = vals[start]
    order = np.argsort(ids, kind="stable")
    dup = np.flatnonzero(np.diff(ids[order]) == 0)
    second = int(order[dup + 1].min()) if dup.size else None      # the first repeated id in the file
    if bad_line.any() or second is not None:
        k = int(np.flatnonzero(bad_line)[0]) if bad_line.any() else None
        if k is not None and (second is None or k < second):
            ln = int(lines[start[k]])
            raw = next(r for i, r in _lines(path) if i == ln)
            _point_slow(path, ln, _text(path, ln, raw).split())
            raise InputError(path, ln, "POINT3D_ID, IMAGE_ID or POINT2D_IDX beyond 2⁵³ (not supported)")
        first = int(np.flatnonzero(ids == ids[second])[0])
        raise InputError(path, int(lines[start[second]]), f"duplicate POINT3D_ID {int(ids[second])} "
                         f"(first at line {int(lines[start[first]])})")
    pts = _Points()
    pts.ids = [int(v) for v in ids]
    pts.where = lines[start].tolist()
    pts.X = np.ascontiguousarray(vals[start[:, None] + np.arange(1, 4)])
    tr = vals[rank >= 8].astype(np.int64).reshape(-1, 2)
    pts.count = (count - 8) // 2
    pts.off = np.concatenate([[0], np.cumsum(pts.count)]).astype(np.int64)
    pts.t_img, pts.t_idx = tr[:, 0].copy(), tr[:, 1].copy()
    pts.pid = ids.astype(np.int64)
    return pts


def _point_slow(path, line, tok):
    if len(tok) < 8:
        raise InputError(path, line, "expected 'POINT3D_ID X Y Z R G B ERROR TRACK[]'")
    pid = _int(path, line, tok[0], "POINT3D_ID")
    xyz = _floats(path, line, tok[1:4], f"point {pid}: X Y Z")
    track = tok[8:]
    if len(track) % 2:
        raise InputError(path, line, f"point {pid}: the track must come as 'IMAGE_ID POINT2D_IDX' pairs")
    el = [_int(path, line, t, f"point {pid}: track") for t in track]
    if pid >= 2 ** 63 or any(e >= 2 ** 63 for e in el):
        raise InputError(path, line, f"point {pid}: an id or index is too large")
    return pid, xyz, np.asarray(el, dtype=np.int64).reshape(-1, 2)


# --------------------------------------------------------------------------------------------
# binary
# --------------------------------------------------------------------------------------------
class _Bytes:
    def __init__(self, path):
        self.path = path
        self.data = read_bytes(path)
        self.pos = 0

    def fail(self, at: int, message: str):
        raise InputError(self.path, 0, message, offset=at)

    def read(self, fmt: str, what: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            self.fail(len(self.data), f"the file ends early: expected {what}")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def count(self, what: str, item_size: int) -> int:
        (n,) = self.read("Q", f"the number of {what}")
        if n * item_size > len(self.data) - self.pos:
            self.fail(self.pos - 8, f"{n} {what} cannot fit in the {len(self.data)}-byte file")
        return n

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            self.fail(len(self.data), f"the file ends early: expected {what}")
        raw = self.data[self.pos:end]
        self.pos = end + 1
        return raw.decode("utf-8", "replace")

    def end(self):
        if self.pos != len(self.data):
            self.fail(self.pos, f"{len(self.data) - self.pos} bytes left after the last record: wrong counts "
                      "or not a COLMAP file")


def _cameras_bin(path) -> dict:
    b = _Bytes(path)
    cams = {}
    for _ in range(b.count("cameras", 24)):
        at = b.pos
        cid, mid, w, h = b.read("IiQQ", "a camera record")
        model = MODEL_IDS.get(mid, f"id {mid}")
        if model not in SUPPORTED:
            b.fail(at, f"camera {cid}: unknown/unsupported camera model {model} (supported: {', '.join(SUPPORTED)})")
        k = len(CAMERA_MODELS[model][0])
        params = np.array(b.read("d" * k, f"camera {cid}: {k} parameters"))
        if cid in cams:
            b.fail(at, f"duplicate CAMERA_ID {cid}")
        try:
            cams[cid] = _camera(path, 0, cid, model, w, h, params)
        except InputError as err:
            b.fail(at, err.message)
    b.end()
    if not cams:
        b.fail(0, "no cameras")
    return cams


_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<u8")])


def _images_bin(path) -> _Images:
    b = _Bytes(path)
    imgs = _Images()
    seen = set()
    for _ in range(b.count("images", 64)):
        at = b.pos
        rec = b.read("I7dI", "an image record")
        iid, pose, cid = rec[0], np.array(rec[1:8]), rec[8]
        if iid in seen:
            b.fail(at, f"duplicate IMAGE_ID {iid}")
        seen.add(iid)
        name = b.name(f"image {iid}: its name")
        m = b.count(f"image points of image {iid}", 24)
        pat = b.pos
        arr = np.frombuffer(b.data, dtype=_POINT2D, count=m, offset=b.pos)
        b.pos += 24 * m
        xy = np.column_stack([arr["x"], arr["y"]])
        ids = arr["id"]
        if np.any((ids >= 2 ** 63) & (ids != INVALID_ID)):
            b.fail(pat, f"image {iid}: a POINT3D_ID is too large")
        p3d = np.where(ids == INVALID_ID, -1, ids.astype(np.int64, casting="unsafe"))
        if not np.isfinite(pose).all():
            b.fail(at, f"image {iid}: the pose has non-finite numbers")
        imgs.add(iid, at, pose[:4], pose[4:], cid, name, xy, p3d, pat)
    b.end()
    if not imgs.ids:
        b.fail(0, "no images")
    return imgs.done()


def _points_bin(path) -> _Points:
    b = _Bytes(path)
    pts = _Points()
    seen = set()
    for _ in range(b.count("points", 43)):
        at = b.pos
        rec = b.read("Q3d3BdQ", "a point record")
        pid, xyz, n = rec[0], np.array(rec[1:4]), rec[8]
        if pid in seen:
            b.fail(at, f"duplicate POINT3D_ID {pid}")
        seen.add(pid)
        if pid >= 2 ** 63:
            b.fail(at, f"point {pid}: the id is too large")
        if 8 * n > len(b.data) - b.pos:
            b.fail(at, f"point {pid}: a track of {n} elements cannot fit in the file")
        tr = np.frombuffer(b.data, dtype="<u4", count=2 * n, offset=b.pos).reshape(n, 2)
        b.pos += 8 * n
        if not np.isfinite(xyz).all():
            b.fail(at, f"point {pid}: coordinates are not finite")
        pts.add(pid, at, xyz, tr.astype(np.int64))
    b.end()
    if not pts.ids:
        b.fail(0, "no points")
    return pts.done()
