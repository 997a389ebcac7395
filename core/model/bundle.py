"""Bundle blocks: collinearity equations, additional parameters, block hypotheses, AP tests.

The file-level model is a frozen :class:`Block` (cameras, images with exterior orientation,
object points, image measurements, control); :func:`build_block_problem` turns it into the
generic :class:`baarda.model.problem.Problem` that :func:`baarda.adjust.adjust` works on.

The collinearity equations, the calibrated distortion and the additional parameters are in
:mod:`baarda.observations.collinearity`.

Units: object coordinates and X0 in metres, angles in radians, image coordinates, c, x0, y0,
their σ and the APs in the camera's unit (``"mm"`` or ``"px"``).

Problem layout: parameters are, in this order, per image X0, Y0, Z0, ω, φ, κ (kind ``"t"``),
per camera its AP groups (kind ``"t"``), per point X, Y, Z (kind ``"k"``; F80 eq. 16 splits
by kind). Observations are, in this order, x and y of every image measurement (rows 2i and
2i + 1 for measurement i: one 2 × 2 covariance cluster and one test group each), then the
control coordinates point by point (one cluster and one test group per control point).

Datum: ``Block.datum == "control"`` — the weighted control points (:class:`Datum` ``"fixed"``);
``"free"`` — a free block whose 7-parameter defect is removed by inner constraints over the
S-base (``Block.sbase``, empty = all points); control coordinates are then not used.

References (full in the package docstring): F80; B71 (Brown); E76 (Ebner); F97 (Fraser).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import MappingProxyType

import numpy as np

from ..datum import Datum
from ..errors import NotFoundError, OptionError
from ..observations.geodetic import LinearSet
from ..observations.collinearity import AP_GROUPS, EO_NAMES, CollinearitySet
from ..observations.rotation import R_opk
from . import gnss
from .geometry import BlockGeometry, CameraGeometry, ImageGeometry
from .problem import Covariance, ObservationInfo, ParameterList, PointInfo, Problem, ProblemNotes, image_point_index

POINT_STATUS = ("tie", "control", "check")


# --------------------------------------------------------------------------------------------
# file-level model
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Camera:
    """A camera (interior orientation). Lengths in ``unit`` ("mm" or "px").

    c: principal distance; x0, y0: principal point; width, height: image format;
    pixel_size: mm per pixel (information only); k1, k2, k3, p1, p2: calibrated distortion
    (fixed, see the module docstring); ap: the AP groups to estimate ("io", "brown", "ebner");
    ap_scale: reference length s of the APs (0 → 0.4 · max(width, height), the von Gruber base
    of a 60 % overlap).
    """

    id: str
    c: float
    x0: float = 0.0
    y0: float = 0.0
    unit: str = "mm"
    width: float = 230.0
    height: float = 230.0
    pixel_size: float | None = None
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    ap: tuple[str, ...] = ()
    ap_scale: float = 0.0
    line: int = 0

    @property
    def scale(self) -> float:
        return self.ap_scale if self.ap_scale > 0 else 0.4 * max(self.width, self.height)


@dataclass(frozen=True)
class Image:
    """An image: camera id, projection centre X0, Y0, Z0 (m), ω, φ, κ (rad), strip label.

    The orientation values are the approximations (or, in design mode, the truth).
    """

    id: str
    camera: str
    X0: float
    Y0: float
    Z0: float
    omega: float
    phi: float
    kappa: float
    strip: str = ""
    line: int = 0


@dataclass(frozen=True)
class ObjectPoint:
    """An object point: X, Y, Z approximate coordinates (m), status tie/control/check.

    ref: the known coordinates of control and check points (m). Control points enter the
    adjustment as observations of ``axes`` with σ ``sigma_h`` (X, Y) and ``sigma_v`` (Z) in m;
    check points only through their image measurements, ``ref`` is compared afterwards.
    """

    id: str
    X: float
    Y: float
    Z: float
    status: str = "tie"
    ref: tuple[float, float, float] | None = None
    sigma_h: float = 0.0
    sigma_v: float = 0.0
    axes: str = "xyz"
    line: int = 0


@dataclass(frozen=True, eq=False)
class ImageObservations:
    """Image measurements, m of them: image and point indices into the block's tuples,
    ``xy`` (m × 2, camera unit), covariance ``cov`` (m × 2 × 2, unit²), source ``line``."""

    image: np.ndarray
    point: np.ndarray
    xy: np.ndarray
    cov: np.ndarray
    line: np.ndarray

    @property
    def size(self) -> int:
        return int(self.image.size)


@dataclass(frozen=True, eq=False)
class Block:
    """A photogrammetric bundle block as read from a file (see the module docstring).

    datum: "control" (weighted control points) or "free" (inner constraints over ``sbase``,
    point ids, empty = all points). sigma0: a priori σ0 (dimensionless). gnss: the GNSS
    projection centres (:class:`baarda.model.gnss.GnssSpec`, or None); imu: the IMU attitudes
    (:class:`baarda.model.gnss.ImuSpec`, or None); with them the datum is "control" (GNSS centres,
    IMU attitudes and control points define it).
    """

    cameras: tuple[Camera, ...]
    images: tuple[Image, ...]
    points: tuple[ObjectPoint, ...]
    obs: ImageObservations
    datum: str = "control"
    sbase: tuple[str, ...] = ()
    sigma0: float = 1.0
    title: str = ""
    source: str = ""
    extra: dict = field(default_factory=dict)
    gnss: object = None
    imu: object = None

    def replace(self, **changes) -> "Block":
        return replace(self, **changes)


# --------------------------------------------------------------------------------------------
# Problem
# --------------------------------------------------------------------------------------------
def footprint(image: Image, camera: Camera, Z: float) -> list[list[float]]:
    """Ground polygon (4 × [X, Y], m) of the image format projected to the plane Z (m).

    Rays X − X0 = λ R (x − x0, y − y0, −c)ᵀ through the format corners (distortion ignored).
    """
    R = R_opk(image.omega, image.phi, image.kappa)
    w, h = camera.width / 2, camera.height / 2
    out = []
    for cx, cy in ((-w, -h), (w, -h), (w, h), (-w, h)):
        d = R @ np.array([cx, cy, -camera.c])
        lam = (Z - image.Z0) / d[2]
        out.append([float(image.X0 + lam * d[0]), float(image.Y0 + lam * d[1])])
    return out


def build_block_problem(block: Block) -> Problem:
    """Turn a :class:`Block` into an adjustment :class:`~baarda.model.problem.Problem`.

    Layout of parameters and observations, datum and units: see the module docstring.
    ``Problem.geometry`` holds the images with strip, EO and ground footprint at the mean
    terrain height, the cameras, image size and flying height (:func:`block_geometry`);
    ``Problem.notes.ap_groups`` maps "camera:group" to the AP parameters' labels.
    """
    cams = {c.id: c for c in block.cameras}
    pl = ParameterList()
    add = pl.add

    ieo_img = np.array([[add(f"{im.id}.{nm}", getattr(im, nm), "t") for nm in EO_NAMES]
                        for im in block.images], dtype=np.int64).reshape(-1, 6)
    ap_idx: dict[str, tuple] = {}
    ap_groups = {}
    for cam in block.cameras:
        groups = []
        for g in cam.ap:
            if g not in AP_GROUPS:
                raise OptionError("ap", g, tuple(AP_GROUPS),
                                  f"camera {cam.id}: unknown AP group '{g}' (known: {', '.join(AP_GROUPS)})")
            idx = np.array([add(f"{cam.id}.{g}.{nm}", 0.0, "t") for nm in AP_GROUPS[g]], dtype=np.int64)
            groups.append((g, idx))
            ap_groups[f"{cam.id}:{g}"] = [pl.labels[i] for i in idx]
        ap_idx[cam.id] = tuple(groups)
    gnss_layout = None
    if block.gnss is not None and block.gnss.centres:
        gnss_layout, gnss_groups = gnss.add_parameters(pl, block)
        ap_groups.update(gnss_groups)
    boresight = gnss.add_imu_parameters(pl, block) if block.imu is not None and block.imu.attitudes else None
    index = np.full((len(block.points), 3), -1, dtype=np.int64)
    for i, p in enumerate(block.points):
        for a, (nm, val) in enumerate(zip("xyz", (p.X, p.Y, p.Z))):
            index[i, a] = add(f"{p.id}.{nm}", val, "k", i, a)
    params = pl.parameters()

    obs = block.obs
    m = obs.size
    cam_of_image = np.array([list(cams).index(im.camera) for im in block.images], dtype=np.int64)
    obs_cam = cam_of_image[obs.image] if m else np.zeros(0, dtype=np.int64)
    sets = []
    for ci, cam in enumerate(block.cameras):
        k = np.flatnonzero(obs_cam == ci)
        if k.size == 0:
            continue
        rows = np.empty(2 * k.size, dtype=np.int64)
        rows[0::2] = 2 * k
        rows[1::2] = 2 * k + 1
        sets.append(CollinearitySet(rows=rows, ipt=index[obs.point[k]], ieo=ieo_img[obs.image[k]],
                                    c=cam.c, x0=cam.x0, y0=cam.y0, scale=cam.scale,
                                    cal=(cam.k1, cam.k2, cam.k3, cam.p1, cam.p2), ap=ap_idx[cam.id]))
    l = [obs.xy.ravel()]
    members = [np.array([2 * k, 2 * k + 1]) for k in range(m)]
    blocks = [obs.cov[k] for k in range(m)]
    unit = [cams[block.images[i].camera].unit for i in obs.image]
    kinds, ids, vfile, units, sfile, lines, group = [], [], [], [], [], [], []
    for k in range(m):
        im, pt = block.images[obs.image[k]].id, block.points[obs.point[k]].id
        for comp in (0, 1):
            kinds.append("image-" + "xy"[comp])
            ids.append({"image": im, "point": pt, "component": "xy"[comp]})
            vfile.append(obs.xy[k, comp])
            units.append(unit[k])
            sfile.append(np.sqrt(obs.cov[k, comp, comp]))
            lines.append(obs.line[k])
            group.append(k)
    # control observations
    use_control = block.datum != "free"
    n_img = 2 * m
    row = n_img
    ctrl_rows, ctrl_idx = [], []
    g = m
    for i, p in enumerate(block.points):
        if not (use_control and p.status == "control"):
            continue
        rr = []
        sig = []
        for a, nm in enumerate("xyz"):
            if nm not in p.axes:
                continue
            s = p.sigma_v if a == 2 else p.sigma_h
            rr.append(row)
            sig.append(s)
            ctrl_rows.append(row)
            ctrl_idx.append(index[i, a])
            l.append(np.array([p.ref[a]]))
            kinds.append(f"control-{nm}")
            ids.append({"id": p.id})
            vfile.append(p.ref[a])
            units.append("m")
            sfile.append(s)
            lines.append(p.line)
            group.append(g)
            row += 1
        members.append(np.array(rr))
        blocks.append(np.diag(np.square(sig)))
        g += 1
    if ctrl_rows:
        sets.append(LinearSet("coordinate", np.array(ctrl_rows, dtype=np.int64),
                              np.full(len(ctrl_rows), -1, dtype=np.int64), np.array(ctrl_idx, dtype=np.int64)))
    if gnss_layout is not None:
        row, g = gnss.add_observations(block, gnss_layout, ieo_img, row, g, {
            "l": l, "kinds": kinds, "ids": ids, "vfile": vfile, "units": units, "sfile": sfile, "lines": lines,
            "group": group, "members": members, "blocks": blocks, "sets": sets})
    if boresight is not None:
        row, g = gnss.add_imu_observations(block, boresight, ieo_img, row, g, {
            "l": l, "kinds": kinds, "ids": ids, "vfile": vfile, "units": units, "sfile": sfile, "lines": lines,
            "group": group, "members": members, "blocks": blocks, "sets": sets})
    n = row
    cov = Covariance.from_blocks(n, members, blocks)
    info = ObservationInfo(kind=tuple(kinds), ids=tuple(ids), value_file=np.array(vfile, dtype=float),
                           unit=tuple(units), sigma_file=np.array(sfile, dtype=float),
                           sigma_unit=tuple(units), line=np.array(lines, dtype=np.int64),
                           group=np.array(group, dtype=np.int64))
    status = tuple(p.status for p in block.points)
    pts = PointInfo(tuple(p.id for p in block.points), index, status, 3)
    datum = Datum("free", tuple(block.sbase)) if block.datum == "free" else \
        Datum("fixed", by=gnss.datum_text(block) if gnss_layout is not None or boresight is not None else "")
    return Problem(params=params, sets=tuple(sets), l=np.concatenate(l) if l else np.zeros(0),
                   cov=cov, info=info, points=pts, datum=datum, sigma0=block.sigma0,
                   sigma_act="apriori", source=block.source, title=block.title,
                   geometry=block_geometry(block), notes=ProblemNotes(ap_groups=ap_groups))


def block_geometry(block: Block) -> BlockGeometry:
    """The block's images with attitudes and footprints at the mean terrain height, its cameras,
    image size, flying and terrain height (:class:`baarda.model.geometry.BlockGeometry`)."""
    Z = np.array([p.Z for p in block.points]) if block.points else np.zeros(1)
    Zm = float(Z.mean())
    cams = {c.id: c for c in block.cameras}
    images = []
    for im in block.images:
        cam = cams[im.camera]
        images.append(ImageGeometry(im.id, im.camera, im.X0, im.Y0, im.Z0, strip=im.strip,
                                    details=MappingProxyType({"strip": im.strip, "omega": im.omega, "phi": im.phi,
                                                              "kappa": im.kappa, "footprint": footprint(im, cam, Zm)})))
    cam = block.cameras[0] if block.cameras else None
    z0 = np.array([im.Z0 for im in block.images]) if block.images else np.zeros(1)
    cameras = tuple(CameraGeometry(c.id, c.unit, c.width, c.height, c=c.c, x0=c.x0, y0=c.y0, ap_scale=c.scale,
                                   details=MappingProxyType(_camera_dict(c))) for c in block.cameras)
    return BlockGeometry(tuple(images), cameras, image_unit=cam.unit if cam else "mm",
                         image_size=(cam.width, cam.height) if cam else None,
                         flying_height=float(z0.mean() - Zm), terrain_height=Zm)


def _camera_dict(cam: Camera) -> dict:
    return {"id": cam.id, "c": cam.c, "x0": cam.x0, "y0": cam.y0, "unit": cam.unit,
            "width": cam.width, "height": cam.height, "pixel_size": cam.pixel_size,
            "k1": cam.k1, "k2": cam.k2, "k3": cam.k3, "p1": cam.p1, "p2": cam.p2,
            "ap": list(cam.ap), "ap_scale": cam.scale}


# --------------------------------------------------------------------------------------------
# hypotheses for blocks (F80 §2.2, §7.1)
# --------------------------------------------------------------------------------------------
def problem_of(obj):
    """The Problem of an Adjustment, or the Problem itself."""
    return getattr(obj, "problem", obj)


def image_rows(problem, image: str, point: str) -> np.ndarray:
    """Rows (x, y) of the measurement of ``point`` in ``image`` (looked up in
    :func:`baarda.model.problem.image_point_index`); NotFoundError if there is none, or if the
    image measures the point by several keypoints (COLMAP: each is an image point of its own)."""
    problem = problem_of(problem)
    index = image_point_index(problem)
    rows = index.get((str(image), str(point), None))
    if rows is None or len(rows) != 2:
        kps = sorted(str(kp) for (im, pt, kp) in index if im == str(image) and pt == str(point) and kp is not None)
        why = (f"point {point} is measured by keypoints {', '.join(kps)} in image {image}" if kps
               else f"no measurement of point {point} in image {image}")
        raise NotFoundError("image point", {"image": image, "point": point}, why)
    comp = [problem.info.ids[i].get("component") for i in rows]
    return np.array(rows if comp != ["y", "x"] else rows[::-1], dtype=np.int64)


def control_rows(problem, point: str) -> np.ndarray:
    """Rows of the control observations of ``point`` (x, y, z order)."""
    problem = problem_of(problem)
    rows = [i for i, (k, ids) in enumerate(zip(problem.info.kind, problem.info.ids))
            if k.startswith("control-") and ids["id"] == point]
    if not rows:
        raise NotFoundError("control point", {"point": point}, f"no control observations of point {point}")
    return np.array(rows, dtype=np.int64)


def gnss_rows(problem, image: str) -> np.ndarray:
    """Rows (x, y, z) of the GNSS observation of ``image``'s projection centre."""
    problem = problem_of(problem)
    rows = [i for i, (k, ids) in enumerate(zip(problem.info.kind, problem.info.ids))
            if k.startswith("gnss-") and str(ids.get("image")) == str(image)]
    if not rows:
        raise NotFoundError("GNSS centre", {"image": image}, f"no GNSS observation of image {image}")
    return np.array(rows, dtype=np.int64)


# --------------------------------------------------------------------------------------------
# check points
# --------------------------------------------------------------------------------------------
def check_points(adj, block) -> dict:
    """Differences adjusted − reference at the check points and their RMS per axis.

    ``block``: a native :class:`Block` (points of status ``"check"`` with ``ref``) or an SfM
    block (its ``check`` points, read from a control CSV's ``role`` column). Check points take
    part only through their image measurements (module docstring): their adjusted coordinates
    are intersected by the block like any tie point and compared with the known ones afterwards.
    Returns ``{"points": [{id, ref, adjusted, diff, sigma, ref_sigma, line}], "n", "rms", "mean", "max_abs"}``
    (``ref_sigma``: the known coordinates' σ as the file gives them, 0 where it gives none)
    (lengths in the block's object units; the statistics NaN per axis without check points).
    """
    coords, sig = adj.coordinates, adj.point_sigma
    where = {str(pid): i for i, pid in enumerate(adj.problem.points.ids)}
    if hasattr(block, "check"):                 # an SfM block
        refs = [(cp.id, cp.xyz, cp.sigma, cp.line) for cp in block.check]
    else:
        refs = [(p.id, p.ref, (p.sigma_h, p.sigma_h, p.sigma_v), p.line) for p in block.points
                if p.status == "check" and p.ref is not None]
    rows = []
    for pid, ref, ref_sigma, line in refs:
        i = where.get(str(pid))
        if i is None:
            continue
        d = coords[i] - np.asarray(ref, dtype=float)
        rows.append({"id": pid, "ref": [float(v) for v in ref], "adjusted": coords[i].tolist(), "diff": d.tolist(),
                     "sigma": sig[i].tolist(), "ref_sigma": [float(v) if np.isfinite(v) else 0.0 for v in ref_sigma], "line": int(line)})
    diffs = np.array([r["diff"] for r in rows], dtype=float).reshape(-1, 3)
    nan3 = [float("nan")] * 3
    return {"points": rows, "n": len(rows),
            "rms": np.sqrt((diffs ** 2).mean(axis=0)).tolist() if rows else nan3,
            "mean": diffs.mean(axis=0).tolist() if rows else nan3,
            "max_abs": np.abs(diffs).max(axis=0).tolist() if rows else nan3}


def has_check_points(block) -> bool:
    """Whether ``block`` (a native or SfM block, or None) holds check points."""
    if hasattr(block, "check"):                 # an SfM block: its points are ids
        return bool(block.check)
    return any(p.status == "check" for p in getattr(block, "points", ()))
