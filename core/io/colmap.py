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
files report line 0 and the byte offset.

Conventions: the pose (q, t) maps world to camera, q = (w, x, y, z) scalar first
(:func:`baarda.rotation.R_from_quaternion`); the camera looks down +z; pixel coordinates have
their origin at the upper-left corner of the image (the centre of the first pixel is at
0.5, 0.5), y down. Projection: :mod:`baarda.bal` with s = +1; supported camera models:
SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV. Intrinsics are held fixed unless
``refine_intrinsics``; then, like COLMAP's bundle adjuster, the focal lengths and distortion
parameters are estimated and the principal point stays fixed. Ids in the output are COLMAP's
IMAGE_ID, POINT3D_ID and CAMERA_ID; the image names are kept in ``Problem.extra["image_names"]``.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ..bal import CAMERA_MODELS, SfmBlock, SfmCamera, SfmImage
from ..errors import InputError
from ..rotation import R_from_quaternion, rodrigues_from_R
from .bal import check_block, read_text

MODEL_IDS = {0: "SIMPLE_PINHOLE", 1: "PINHOLE", 2: "SIMPLE_RADIAL", 3: "RADIAL", 4: "OPENCV",
             5: "OPENCV_FISHEYE", 6: "FULL_OPENCV", 7: "FOV", 8: "SIMPLE_RADIAL_FISHEYE",
             9: "RADIAL_FISHEYE", 10: "THIN_PRISM_FISHEYE", 11: "RAD_TAN_THIN_PRISM_FISHEYE"}
SUPPORTED = tuple(m for m in CAMERA_MODELS if m != "BAL")
FILES = ("cameras", "images", "points3D")
INVALID_ID = 2 ** 64 - 1


def model_files(path) -> tuple[Path, str] | None:
    """(directory, ".txt" or ".bin") of the COLMAP model at ``path`` (the directory or one of
    its files), or None when there is none."""
    p = Path(path)
    d = p if p.is_dir() else p.parent
    if not p.is_dir() and p.stem not in FILES:
        return None
    for ext in (".txt", ".bin"):
        if all((d / f"{name}{ext}").is_file() for name in FILES):
            return d, ext
    return None


def read_colmap(path, sigma_px: float = 1.0, refine_intrinsics: bool = False, check: bool = True) -> SfmBlock:
    """Read a COLMAP sparse model (directory or one of its files) into an SfmBlock."""
    found = model_files(path)
    if found is None:
        p = Path(path)
        d = p if p.is_dir() else p.parent
        have = sorted(f.name for f in d.glob("*")) if d.is_dir() else []
        ext = ".bin" if any(h.endswith(".bin") for h in have) else ".txt"
        missing = [f"{n}{ext}" for n in FILES if f"{n}{ext}" not in have]
        raise InputError(path, 0, f"not a complete COLMAP model: missing {', '.join(missing) or 'files'} "
                         f"(found: {', '.join(have[:8]) or 'nothing'})")
    d, ext = found
    if ext == ".txt":
        cams = _cameras_txt(d / "cameras.txt")
        imgs = _images_txt(d / "images.txt")
        pts = _points_txt(d / "points3D.txt")
    else:
        cams = _cameras_bin(d / "cameras.bin")
        imgs = _images_bin(d / "images.bin")
        pts = _points_bin(d / "points3D.bin")
    block = _assemble(d, ext, cams, imgs, pts, sigma_px, refine_intrinsics)
    return check_block(d / f"points3D{ext}", block) if check else block


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
    nq = float(np.linalg.norm(q))
    if abs(nq - 1.0) > 1e-3:
        raise InputError(path, line, f"image {iid}: the quaternion QW QX QY QZ has norm {nq:.6g}, not 1")
    rho = rodrigues_from_R(R_from_quaternion(q))
    return tuple(float(v) for v in rho), tuple(float(v) for v in t)


def _assemble(d, ext, cams, imgs, pts, sigma_px, refine) -> SfmBlock:
    cam_path, img_path, pt_path = (d / f"{name}{ext}" for name in FILES)
    images, where = [], {}
    for iid, (line, q, t, cid, name, xy, p3d, pline) in imgs.items():
        if cid not in cams:
            raise InputError(img_path, line, f"image {iid}: camera {cid} is not in {cam_path.name}")
        rho, tt = _pose(img_path, line, iid, q, t)
        where[iid] = len(images)
        images.append(SfmImage(str(iid), str(cid), rho, tt, name, line))
    used = {imgs[i][3] for i in imgs}
    cameras = tuple(c for cid, c in cams.items() if cid in used)
    point_ids, X, point_line = [], [], []
    oi, op, xy, oline = [], [], [], []
    for k, (pid, (line, xyz, track)) in enumerate(pts.items()):
        if not np.isfinite(xyz).all():
            raise InputError(pt_path, line, f"point {pid}: coordinates are not finite")
        for iid, idx in track:
            if iid not in imgs:
                raise InputError(pt_path, line, f"point {pid}: image {iid} of its track is not in {img_path.name}")
            rec = imgs[iid]
            if idx >= len(rec[6]):
                raise InputError(pt_path, line, f"point {pid}: image {iid} has {len(rec[6])} image points, "
                                 f"POINT2D_IDX {idx} is out of range")
            if rec[6][idx] != pid:
                raise InputError(pt_path, line, f"point {pid}: image point {idx} of image {iid} belongs to "
                                 f"point {_pid(rec[6][idx])}, not to this one")
            oi.append(where[iid])
            op.append(k)
            xy.append(rec[5][idx])
            oline.append(rec[7])
        point_ids.append(str(pid))
        X.append(xyz)
        point_line.append(line)
    n_linked = sum(int(np.sum(np.asarray(r[6]) != -1)) for r in imgs.values())
    if n_linked != len(oi):
        for iid, rec in imgs.items():
            for idx, pid in enumerate(rec[6]):
                if pid != -1 and (pid not in pts or (iid, idx) not in set(map(tuple, pts[pid][2]))):
                    raise InputError(img_path, rec[7], f"image {iid}: image point {idx} refers to point "
                                     f"{pid}, whose track in {pt_path.name} does not list it")
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if not np.isfinite(xy).all():
        k = int(np.flatnonzero(~np.isfinite(xy).all(axis=1))[0])
        raise InputError(img_path, oline[k], f"image {images[oi[k]].id}: image coordinates are not finite")
    return SfmBlock(cameras=cameras, images=tuple(images), points=tuple(point_ids),
                    X=np.asarray(X, dtype=float).reshape(-1, 3), point_line=np.asarray(point_line, dtype=np.int64),
                    obs_image=np.asarray(oi, dtype=np.int64), obs_point=np.asarray(op, dtype=np.int64), xy=xy,
                    obs_line=np.asarray(oline, dtype=np.int64), convention="colmap", sigma_px=sigma_px,
                    refine_intrinsics=refine, source=str(d), title=Path(d).name)


def _pid(p):
    return "none (−1)" if p == -1 else p


# --------------------------------------------------------------------------------------------
# text
# --------------------------------------------------------------------------------------------
def _records(path):
    """Non-comment lines as (line number, tokens)."""
    text = read_text(path)
    return [(ln, s.split()) for ln, s in enumerate(text.splitlines(), 1)
            if s.strip() and not s.lstrip().startswith("#")], text


def _int(path, line, tok, what, allow_negative=False):
    t = tok[1:] if allow_negative and tok.startswith("-") else tok
    if not (t.isascii() and t.isdigit()):         # str.isdigit accepts '²' and '①', int() does not
        raise InputError(path, line, f"{what}: '{tok[:40]}' is not an integer")
    if len(t) > 20:                                  # COLMAP ids are 64-bit at most
        raise InputError(path, line, f"{what}: {tok[:40]}... is too large")
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


def _images_txt(path) -> dict:
    text = read_text(path)
    lines = text.splitlines()
    imgs = {}
    k = 0
    while k < len(lines):
        s = lines[k]
        k += 1
        if not s.strip() or s.lstrip().startswith("#"):
            continue
        line = k
        tok = s.split()
        if len(tok) < 10:
            raise InputError(path, line, "expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        iid = _int(path, line, tok[0], "IMAGE_ID")
        if iid in imgs:
            raise InputError(path, line, f"duplicate IMAGE_ID {iid} (first at line {imgs[iid][0]})")
        pose = _floats(path, line, tok[1:8], f"image {iid}: pose")
        cid = _int(path, line, tok[8], f"image {iid}: CAMERA_ID")
        name = " ".join(tok[9:])
        if k >= len(lines):
            raise InputError(path, line, f"image {iid}: the file ends before its line of image points")
        pline = k + 1
        ptok = lines[k].split()
        k += 1
        if len(ptok) % 3:
            raise InputError(path, pline, f"image {iid}: image points must come as 'X Y POINT3D_ID' triples "
                             f"({len(ptok)} numbers)")
        m = len(ptok) // 3
        trip = np.array(ptok, dtype=object).reshape(m, 3)
        xy = _floats(path, pline, list(trip[:, :2].ravel()), f"image {iid}: image point").reshape(m, 2)
        p3d = [_int(path, pline, t, f"image {iid}: POINT3D_ID", allow_negative=True) for t in trip[:, 2]]
        if any(p < -1 for p in p3d):
            raise InputError(path, pline, f"image {iid}: POINT3D_ID {min(p3d)} is invalid (−1 means none)")
        imgs[iid] = (line, pose[:4], pose[4:], cid, name, xy, p3d, pline)
    if not imgs:
        raise InputError(path, 1, "no images")
    return imgs


def _points_txt(path) -> dict:
    recs, _ = _records(path)
    pts = {}
    for line, tok in recs:
        if len(tok) < 8:
            raise InputError(path, line, "expected 'POINT3D_ID X Y Z R G B ERROR TRACK[]'")
        pid = _int(path, line, tok[0], "POINT3D_ID")
        if pid in pts:
            raise InputError(path, line, f"duplicate POINT3D_ID {pid} (first at line {pts[pid][0]})")
        xyz = _floats(path, line, tok[1:4], f"point {pid}: X Y Z")
        track = tok[8:]
        if len(track) % 2:
            raise InputError(path, line, f"point {pid}: the track must come as 'IMAGE_ID POINT2D_IDX' pairs")
        el = [_int(path, line, t, f"point {pid}: track") for t in track]
        pts[pid] = (line, xyz, [(el[j], el[j + 1]) for j in range(0, len(el), 2)])
    if not pts:
        raise InputError(path, 1, "no points")
    return pts


# --------------------------------------------------------------------------------------------
# binary
# --------------------------------------------------------------------------------------------
class _Bytes:
    def __init__(self, path):
        self.path = path
        try:
            self.data = Path(path).read_bytes()
        except OSError as err:
            raise InputError(path, 0, f"cannot read: {err.strerror}") from None
        self.pos = 0

    def read(self, fmt: str, what: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise InputError(self.path, 0, f"the file ends early at byte {len(self.data)}: expected {what}")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def count(self, what: str, item_size: int) -> int:
        (n,) = self.read("Q", f"the number of {what}")
        if n * item_size > len(self.data) - self.pos:
            raise InputError(self.path, 0, f"byte {self.pos - 8}: {n} {what} cannot fit in the "
                             f"{len(self.data)}-byte file")
        return n

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise InputError(self.path, 0, f"the file ends early: expected {what}")
        raw = self.data[self.pos:end]
        self.pos = end + 1
        return raw.decode("utf-8", "replace")

    def end(self):
        if self.pos != len(self.data):
            raise InputError(self.path, 0, f"{len(self.data) - self.pos} bytes left after the last "
                             f"record (byte {self.pos}): wrong counts or not a COLMAP file")


def _cameras_bin(path) -> dict:
    b = _Bytes(path)
    cams = {}
    for _ in range(b.count("cameras", 24)):
        at = b.pos
        cid, mid, w, h = b.read("IiQQ", "a camera record")
        model = MODEL_IDS.get(mid, f"id {mid}")
        if model not in SUPPORTED:
            raise InputError(path, 0, f"byte {at}: camera {cid}: unknown/unsupported camera model {model} "
                             f"(supported: {', '.join(SUPPORTED)})")
        k = len(CAMERA_MODELS[model][0])
        params = np.array(b.read("d" * k, f"camera {cid}: {k} parameters"))
        if cid in cams:
            raise InputError(path, 0, f"byte {at}: duplicate CAMERA_ID {cid}")
        try:
            cams[cid] = _camera(path, 0, cid, model, w, h, params)
        except InputError as err:
            raise InputError(path, 0, f"byte {at}: {err.message}") from None
    b.end()
    if not cams:
        raise InputError(path, 0, "no cameras")
    return cams


def _images_bin(path) -> dict:
    b = _Bytes(path)
    imgs = {}
    for _ in range(b.count("images", 64)):
        at = b.pos
        rec = b.read("I7dI", "an image record")
        iid, pose, cid = rec[0], np.array(rec[1:8]), rec[8]
        if iid in imgs:
            raise InputError(path, 0, f"byte {at}: duplicate IMAGE_ID {iid}")
        name = b.name(f"image {iid}: its name")
        m = b.count(f"image points of image {iid}", 24)
        arr = np.frombuffer(b.data, dtype=np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<u8")]),
                            count=m, offset=b.pos)
        b.pos += 24 * m
        xy = np.column_stack([arr["x"], arr["y"]])
        p3d = [(-1 if p == INVALID_ID else int(p)) for p in arr["id"]]
        if not np.isfinite(pose).all():
            raise InputError(path, 0, f"byte {at}: image {iid}: the pose has non-finite numbers")
        imgs[iid] = (0, pose[:4], pose[4:], cid, name, xy, p3d, 0)
    b.end()
    if not imgs:
        raise InputError(path, 0, "no images")
    return imgs


def _points_bin(path) -> dict:
    b = _Bytes(path)
    pts = {}
    for _ in range(b.count("points", 43)):
        at = b.pos
        rec = b.read("Q3d3BdQ", "a point record")
        pid, xyz, n = rec[0], np.array(rec[1:4]), rec[8]
        if pid in pts:
            raise InputError(path, 0, f"byte {at}: duplicate POINT3D_ID {pid}")
        if 8 * n > len(b.data) - b.pos:
            raise InputError(path, 0, f"byte {at}: point {pid}: a track of {n} elements cannot fit in the file")
        tr = np.frombuffer(b.data, dtype="<u4", count=2 * n, offset=b.pos).reshape(n, 2)
        b.pos += 8 * n
        if not np.isfinite(xyz).all():
            raise InputError(path, 0, f"byte {at}: point {pid}: coordinates are not finite")
        pts[pid] = (0, xyz, [(int(i), int(j)) for i, j in tr])
    b.end()
    if not pts:
        raise InputError(path, 0, "no points")
    return pts


# --------------------------------------------------------------------------------------------
# writing (text), for tests and conversions
# --------------------------------------------------------------------------------------------
def write_colmap_text(block: SfmBlock, directory) -> None:
    """Write a COLMAP-convention block as ``cameras.txt``, ``images.txt``, ``points3D.txt``."""
    from ..rotation import R_from_rodrigues, quaternion_from_R

    if block.convention != "colmap":
        raise ValueError("only COLMAP blocks can be written as a COLMAP model")
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    cams = [f"{c.id} {c.model} {int(c.width)} {int(c.height)} " + " ".join(f"{v:.17g}" for v in c.params)
            for c in block.cameras]
    (d / "cameras.txt").write_text("\n".join(cams) + "\n")
    per_image = [np.flatnonzero(block.obs_image == k) for k in range(len(block.images))]
    slot = {}
    lines = []
    for k, im in enumerate(block.images):
        q = quaternion_from_R(R_from_rodrigues(np.asarray(im.rodrigues)))
        lines.append(f"{im.id} " + " ".join(f"{v:.17g}" for v in (*q, *im.t)) + f" {im.camera} {im.name or im.id}")
        lines.append(" ".join(f"{block.xy[o, 0]:.17g} {block.xy[o, 1]:.17g} {block.points[block.obs_point[o]]}"
                              for o in per_image[k]))
        for j, o in enumerate(per_image[k]):
            slot[o] = j
    (d / "images.txt").write_text("\n".join(lines) + "\n")
    pts = []
    for i, pid in enumerate(block.points):
        obs = np.flatnonzero(block.obs_point == i)
        track = " ".join(f"{block.images[block.obs_image[o]].id} {slot[o]}" for o in obs)
        pts.append(f"{pid} " + " ".join(f"{v:.17g}" for v in block.X[i]) + f" 0 0 0 0 {track}")
    (d / "points3D.txt").write_text("\n".join(pts) + "\n")
