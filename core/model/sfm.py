"""Structure-from-motion blocks: the projective camera of BAL, Bundler and COLMAP as a Problem.

Bundle Adjustment in the Large (BAL), Bundler and COLMAP store the same thing — cameras with a
pose (world → camera), pinhole intrinsics with radial (and tangential) distortion, 3D points
and their image points — in different conventions. :class:`SfmBlock` holds any of them;
:func:`build_sfm_problem` turns it into a :class:`baarda.model.problem.Problem`.

The projection, its distortion and its analytic Jacobian are in
:mod:`baarda.observations.projection`.

Each camera model fills the eight intrinsics (f_x, f_y, c_x, c_y, k_1, k_2, p_1, p_2) from its
own parameters (:data:`CAMERA_MODELS`): BAL's camera is ``RADIAL`` with c_x = c_y = 0, so
p' = f (1 + k1‖p‖² + k2‖p‖⁴) p exactly as the BAL documentation states; ``SIMPLE_*`` models
share one f for f_x and f_y; missing intrinsics are zero.

Problem layout
--------------
Parameters, in this order: per image ρ (3) and t (3), kind ``"t"``; per camera its model's
parameters, kind ``"t"``, held fixed unless ``refine_intrinsics`` (BAL and Bundler refine f,
k1, k2 of every camera, as those formats define; COLMAP holds them fixed by default and, like
COLMAP's bundle adjuster, never refines the principal point c_x, c_y); per point X, Y, Z, kind
``"k"``. Labels: ``"image 3.rho1"``, ``"camera 1.f"``, ``"point 17.x"``. Observations: x and y
of image point k in rows 2k and 2k + 1 (pixels, σ ``sigma_px``, one 2 × 2 cluster and one
test group each), then the weighted control coordinates (the model's units and frame), one
cluster and group per control point.

Datum: without control a free block (:class:`baarda.datum.Datum` ``"free"``, S-base all
points): the 7-parameter similarity gauge is found by :func:`baarda.datum.null_space` from the
point coordinates, the camera parameters following by least squares. With control the weighted
control points define the datum (``"fixed"``).

References (full in the package docstring): BAL10; S06 (Bundler); SF16 (COLMAP); B00 (OpenCV);
C11 (J_r of SO(3)).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from types import MappingProxyType

import numpy as np

from ..datum import Datum
from ..errors import ConversionError
from ..observations.geodetic import LinearSet
from ..observations.fixed_models import FIXED_MODELS, MAX_COEFFICIENTS
from ..observations.projection import INTRINSICS, ProjectionSet
from ..observations.rotation import R_from_rodrigues, opk_from_R
from .bundle import Block, Camera, Image, ImageObservations, ObjectPoint
from .geometry import BlockGeometry, CameraGeometry, ImageGeometry
from .problem import (Categorical, Covariance, JoinedLabels, ObservationInfo, ParameterList, Parameters, PointInfo,
                      Problem, ProblemNotes, RecordIds)


# model name → (parameter names in file order, the parameter feeding each of INTRINSICS or None)
CAMERA_MODELS = {
    "SIMPLE_PINHOLE": (("f", "cx", "cy"), ("f", "f", "cx", "cy", None, None, None, None)),
    "PINHOLE": (("fx", "fy", "cx", "cy"), ("fx", "fy", "cx", "cy", None, None, None, None)),
    "SIMPLE_RADIAL": (("f", "cx", "cy", "k"), ("f", "f", "cx", "cy", "k", None, None, None)),
    "RADIAL": (("f", "cx", "cy", "k1", "k2"), ("f", "f", "cx", "cy", "k1", "k2", None, None)),
    "OPENCV": (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"), INTRINSICS),
    "BAL": (("f", "k1", "k2"), ("f", "f", None, None, "k1", "k2", None, None)),
}
# COLMAP's other models: their distortion is held at the file's values (fixed_models)
for _model, (_code, _names) in FIXED_MODELS.items():
    _one = _model in ("SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "SIMPLE_FISHEYE", "SIMPLE_DIVISION")
    CAMERA_MODELS[_model] = ((("f",) if _one else ("fx", "fy")) + ("cx", "cy") + _names,
                             (("f", "f") if _one else ("fx", "fy")) + ("cx", "cy", None, None, None, None))


def held_coefficients(model: str) -> tuple[str, ...]:
    """The parameters of a camera model that are never estimated: the distortion coefficients of
    the models of :mod:`baarda.observations.fixed_models`, besides c_x, c_y of every model."""
    return ("cx", "cy") + (FIXED_MODELS[model][1] if model in FIXED_MODELS else ())
SIGN = {"bal": -1.0, "bundler": -1.0, "colmap": 1.0}


# --------------------------------------------------------------------------------------------
# file-level model
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SfmCamera:
    """Intrinsics of a camera: ``model`` (a key of :data:`CAMERA_MODELS`), ``params`` in the
    model's order (pixels; k, k1, k2 per unit ρ², p1, p2 per unit ρ), image ``width`` and
    ``height`` in pixels (0 when the file does not say), source ``line``."""

    id: str
    model: str
    params: tuple[float, ...]
    width: float = 0.0
    height: float = 0.0
    line: int = 0


@dataclass(frozen=True)
class SfmImage:
    """An image: its camera, pose world → camera (Rodrigues ρ in radians, t in model units),
    file name and source ``line``."""

    id: str
    camera: str
    rodrigues: tuple[float, float, float]
    t: tuple[float, float, float]
    name: str = ""
    line: int = 0

    @property
    def R(self) -> np.ndarray:
        return R_from_rodrigues(np.asarray(self.rodrigues))

    @property
    def centre(self) -> np.ndarray:
        """Projection centre −Rᵀt (model units)."""
        return -self.R.T @ np.asarray(self.t)


@dataclass(frozen=True)
class ControlPoint:
    """Known coordinates of a block point (model units) with σ per axis, from ``line``; ``role``
    ``"control"`` (an observation of the point) or ``"check"`` (compared after the adjustment)."""

    id: str
    xyz: tuple[float, float, float]
    sigma: tuple[float, float, float]
    line: int = 0
    role: str = "control"


@dataclass(frozen=True, eq=False)
class SfmBlock:
    """A structure-from-motion block as read from a BAL, Bundler or COLMAP file.

    points: ids; X: (m × 3) approximate coordinates; point_line: source line per point.
    obs_image, obs_point (n,): indices into ``images`` and ``points`` of each image point;
    xy (n × 2): measured pixel coordinates; obs_line (n,): their source lines.
    convention: ``"bal"``, ``"bundler"`` or ``"colmap"`` (the sign s of the module docstring).
    sigma_px: σ of each image coordinate (pixels). refine_intrinsics: estimate the cameras'
    parameters. control: weighted control points (they make the datum ``"fixed"``). check: check
    points (tie points of the adjustment, compared with their known coordinates afterwards).
    """

    cameras: tuple[SfmCamera, ...]
    images: tuple[SfmImage, ...]
    points: tuple[str, ...]
    X: np.ndarray
    point_line: np.ndarray
    obs_image: np.ndarray
    obs_point: np.ndarray
    xy: np.ndarray
    obs_line: np.ndarray
    convention: str
    sigma_px: float = 1.0
    refine_intrinsics: bool = False
    control: tuple[ControlPoint, ...] = ()
    check: tuple[ControlPoint, ...] = ()
    source: str = ""
    title: str = ""
    extra: dict = field(default_factory=dict)

    def replace(self, **changes) -> "SfmBlock":
        return dataclasses.replace(self, **changes)


# --------------------------------------------------------------------------------------------
# the Problem
# --------------------------------------------------------------------------------------------
def build_sfm_problem(block: SfmBlock) -> Problem:
    """Turn an :class:`SfmBlock` into an adjustment :class:`~baarda.model.problem.Problem`.

    Layout, datum and units: see the module docstring. ``Problem.geometry`` holds the images
    with their projection centres X0, Y0, Z0 (no footprints) and the cameras
    (:func:`sfm_geometry`); ``problem.notes.image_names`` maps image ids to file names.
    """
    # parameters: the (few) image and camera parameters one by one, the points as arrays
    pl = ParameterList()
    pose = np.array([[pl.add(f"image {im.id}.{nm}", val, "t") for nm, val in
                      zip(("rho1", "rho2", "rho3", "tx", "ty", "tz"), (*im.rodrigues, *im.t))]
                     for im in block.images], dtype=np.int64).reshape(-1, 6)
    cam_index = {}
    intrinsics = np.full((len(block.cameras), 8), -1, dtype=np.int64)
    dtab = np.full((len(block.cameras), 1 + MAX_COEFFICIENTS), -1, dtype=np.int64)   # held-distortion models
    dtab[:, 0] = 0
    for c, cam in enumerate(block.cameras):
        names, feeds = CAMERA_MODELS[cam.model]
        held = held_coefficients(cam.model)
        where = {nm: pl.add(f"camera {cam.id}.{nm}", val, "t",
                            fixed=not block.refine_intrinsics or nm in held)
                 for nm, val in zip(names, cam.params)}
        intrinsics[c] = [where[nm] if nm is not None else -1 for nm in feeds]
        if cam.model in FIXED_MODELS:
            code, coef = FIXED_MODELS[cam.model]
            dtab[c, 0] = code
            dtab[c, 1:1 + len(coef)] = [where[nm] for nm in coef]
        cam_index[cam.id] = c
    h = len(pl)
    npt = len(block.points)
    index = (h + np.arange(3 * npt, dtype=np.int64)).reshape(-1, 3)
    points = Parameters(np.asarray(block.X, dtype=float).ravel(), (), np.full(3 * npt, "k", dtype="<U1"),
                        np.zeros(3 * npt, dtype=bool), np.repeat(np.arange(npt, dtype=np.int64), 3),
                        np.tile(np.arange(3, dtype=np.int64), npt))
    params = pl.parameters(points, labels=JoinedLabels(pl.labels, block.points))

    m = block.obs_image.size
    img_cam = np.array([cam_index[im.camera] for im in block.images], dtype=np.int64)
    ii, pp = block.obs_image, block.obs_point
    # int32 indices where they fit (kept with the problem: 5 × 4 bytes per image point saved)
    it = np.int32 if max(params.size, 2 * m) < 2 ** 31 - 1 else np.int64
    pose_i, cam_i = pose.astype(it), intrinsics.astype(it)
    fixed = {} if not (dtab[:, 0] > 0).any() else {"dcam": img_cam[ii].astype(it), "dtab": dtab}
    sets = [ProjectionSet(rows=np.arange(2 * m, dtype=it), ipt=index.astype(it)[pp], irot=pose_i[ii, :3],
                          itr=pose_i[ii, 3:], iint=cam_i[img_cam[ii]], sign=SIGN[block.convention], **fixed)]
    s2 = block.sigma_px ** 2
    # covariance: the image points stacked (one 2 × 2 matrix broadcast), then the control points
    groups = [(2, np.arange(m, dtype=np.int64), np.arange(2 * m, dtype=np.int64).reshape(m, 2),
               np.broadcast_to(np.diag([s2, s2]), (m, 2, 2)))]
    nc = len(block.control)
    n = 2 * m + 3 * nc
    l = np.empty(n)
    l[:2 * m] = block.xy.ravel()
    sfile = np.full(n, block.sigma_px, dtype=float)
    lines = np.empty(n, dtype=np.int64)
    lines[:2 * m] = np.repeat(block.obs_line, 2)
    group = np.empty(n, dtype=np.int64)
    group[:2 * m] = np.repeat(np.arange(m, dtype=np.int64), 2)
    kind_codes = np.empty(n, dtype=np.int8)              # KINDS: image-x, image-y, control-x/y/z
    kind_codes[:2 * m] = np.tile(np.array([0, 1], dtype=np.int8), m)
    unit_codes = np.zeros(n, dtype=np.int8)              # "px", "m"
    # ids: image, point, component of each image point; the id of each control point
    itype = np.int32 if max(len(block.images), npt, nc) < 2 ** 31 - 1 else np.int64
    codes = np.full((n, 4), -1, dtype=itype)
    codes[:2 * m, 0] = np.repeat(ii, 2)
    codes[:2 * m, 1] = np.repeat(pp, 2)
    codes[:2 * m, 2] = np.tile(np.array([0, 1], dtype=itype), m)
    pindex = {pid: i for i, pid in enumerate(block.points)} if nc else {}
    row = 2 * m
    crow, cidx, cmem, cblk = [], [], [], []
    for k, cp in enumerate(block.control):
        i = pindex[cp.id]
        cmem.append(np.arange(row, row + 3))
        cblk.append(np.diag(np.square(cp.sigma)))
        for a in range(3):
            crow.append(row)
            cidx.append(index[i, a])
            kind_codes[row] = 2 + a
            unit_codes[row] = 1
            sfile[row] = cp.sigma[a]
            lines[row] = cp.line
            group[row] = m + k
            codes[row, 3] = k
            l[row] = float(cp.xyz[a])
            row += 1
    if crow:
        sets.append(LinearSet("coordinate", np.array(crow, dtype=np.int64),
                              np.full(len(crow), -1, dtype=np.int64), np.array(cidx, dtype=np.int64)))
        groups.append((3, m + np.arange(nc, dtype=np.int64), np.array(cmem), np.array(cblk)))
    cov = Covariance.from_groups(n, groups)
    units = Categorical(("px", "m"), unit_codes)
    roles = ("image", "point", "component", "id")
    values = (tuple(im.id for im in block.images), block.points, ("x", "y"), tuple(cp.id for cp in block.control))
    kp = block.extra.get("obs_keypoint")
    if kp is not None and m and (block.extra.get("duplicate_keypoints") or {}).get("observations"):
        # several keypoints of one image on one point (COLMAP): each an observation of its own,
        # told apart by its keypoint index (POINT2D_IDX)
        _, inv, cnt = np.unique(ii * max(npt, 1) + pp, return_inverse=True, return_counts=True)
        kcol = np.full(n, -1, dtype=np.int64)
        kcol[:2 * m] = np.repeat(np.where(cnt[inv] > 1, kp, -1), 2)
        codes = np.column_stack([codes[:, :2], kcol.astype(codes.dtype), codes[:, 2:]])
        roles = ("image", "point", "keypoint", "component", "id")
        values = (*values[:2], range(int(kp.max()) + 1), *values[2:])
    ids = RecordIds(roles, values, codes)
    if not nc:
        # one σ for every image point: broadcast (read-only), not n copies of it
        sfile = np.broadcast_to(np.float64(block.sigma_px), (n,))
    info = ObservationInfo(kind=Categorical(("image-x", "image-y", "control-x", "control-y", "control-z"), kind_codes),
                           ids=ids, value_file=l, unit=units, sigma_file=sfile, sigma_unit=units,
                           line=lines, group=group)
    role = {**{cp.id: "check" for cp in block.check}, **{cp.id: "control" for cp in block.control}}
    status = tuple(role.get(pid, "tie") for pid in block.points) if role else ("tie",) * npt
    pts = PointInfo(tuple(block.points), index, status, 3)
    datum = Datum("fixed") if block.control else Datum("free", ())
    return Problem(params=params, sets=tuple(sets), l=l, cov=cov, info=info, points=pts, datum=datum,
                   sigma0=1.0, sigma_act="apriori", source=block.source, title=block.title,
                   geometry=sfm_geometry(block),
                   notes=ProblemNotes(image_names={im.id: im.name for im in block.images},
                                      duplicate_keypoints=block.extra.get("duplicate_keypoints"),
                                      reader_notes=tuple(block.extra.get("reader_notes", ()))))


def sfm_geometry(block: SfmBlock) -> BlockGeometry:
    """The block's images with their projection centres and file names, its cameras
    (:class:`baarda.model.geometry.BlockGeometry`; no attitudes or footprints)."""
    images = []
    for im in block.images:
        C = im.centre
        images.append(ImageGeometry(im.id, im.camera, float(C[0]), float(C[1]), float(C[2]),
                                    details=MappingProxyType({"name": im.name})))
    cams = tuple(CameraGeometry(c.id, "px", c.width, c.height,
                                details=MappingProxyType({"id": c.id, "model": c.model, "params": list(c.params),
                                                          "width": c.width, "height": c.height, "unit": "px"}))
                 for c in block.cameras)
    size = (block.cameras[0].width, block.cameras[0].height) if block.cameras else (0.0, 0.0)
    return BlockGeometry(tuple(images), cams, image_unit="px",
                         image_size=size if size[0] > 0 and size[1] > 0 else None, convention=block.convention)


def initial_cost(problem: Problem) -> float:
    """½ Σ (v_i/σ_i)² at the initial values (BAL's and Ceres' "initial cost" when σ = 1 px)."""
    f, _ = problem.evaluate(problem.params.x0)
    v = problem.misclosure(f) / problem.cov.sigma()
    return 0.5 * float(v @ v)


def to_block(block: SfmBlock):
    """The block as a :class:`baarda.model.bundle.Block` (ω-φ-κ collinearity) for the native format.

    Exact for the projection (same residuals at the initial values) with the intrinsics held at
    their values: the native format has no per-camera f, k1, k2 refinement. Mapping (module
    docstring and :mod:`baarda.model.bundle`): BAL/Bundler R_ωφκ = Rᵀ, image points as they are;
    COLMAP R_ωφκ = (D R)ᵀ with D = diag(1, −1, −1), y → −y, x0 = c_x, y0 = −c_y, p1' = p2/f,
    p2' = −p1/f; always k1' = k1/f², k2' = k2/f⁴ (Brown's coefficients in pixel units).
    ConversionError for a camera with f_x ≠ f_y or control with sx ≠ sy.
    """
    colmap = block.convention == "colmap"
    D = np.diag([1.0, -1.0, -1.0]) if colmap else np.eye(3)
    flip = np.array([1.0, -1.0]) if colmap else np.ones(2)
    img_cam = {im.id: im.camera for im in block.images}
    cams = []
    for cam in block.cameras:
        if cam.model in FIXED_MODELS:
            raise ConversionError(f"camera {cam.id}", f"the {cam.model} model has no native equivalent")
        names, feeds = CAMERA_MODELS[cam.model]
        val = dict(zip(names, cam.params))
        fx, fy, cx, cy, k1, k2, p1, p2 = (val[nm] if nm is not None else 0.0 for nm in feeds)
        if fx != fy:
            raise ConversionError(f"camera {cam.id}", f"f_x ≠ f_y ({fx:g}, {fy:g}) has no native equivalent")
        width, height = cam.width, cam.height
        if width <= 0 or height <= 0:
            on = np.isin(block.obs_image, [k for k, im in enumerate(block.images) if im.camera == cam.id])
            ext = 2.0 * np.abs(block.xy[on]).max(axis=0) if on.any() else np.array([1.0, 1.0])
            width, height = float(np.ceil(ext[0])), float(np.ceil(ext[1]))
        cams.append(Camera(cam.id, c=fx, x0=cx, y0=-cy if colmap else cy, unit="px", width=width, height=height,
                           k1=k1 / fx ** 2, k2=k2 / fx ** 4, p1=p2 / fx if colmap else 0.0,
                           p2=-p1 / fx if colmap else 0.0, line=cam.line))
    images = []
    for im in block.images:
        Ropk = (D @ im.R).T
        w, p, k = opk_from_R(Ropk)
        C = im.centre
        images.append(Image(im.id, img_cam[im.id], float(C[0]), float(C[1]), float(C[2]),
                            float(w), float(p), float(k), line=im.line))
    ctrl = {cp.id: cp for cp in block.control}
    checks = {cp.id: cp for cp in block.check}
    points = []
    for i, pid in enumerate(block.points):
        X = tuple(float(v) for v in block.X[i])
        cp = ctrl.get(pid)
        if cp is None and pid in checks:
            points.append(ObjectPoint(pid, *X, status="check", ref=checks[pid].xyz, line=checks[pid].line))
            continue
        if cp is None:
            points.append(ObjectPoint(pid, *X, line=int(block.point_line[i])))
            continue
        if cp.sigma[0] != cp.sigma[1]:
            raise ConversionError(f"control point {pid}", "the native format takes one horizontal σ (sx = sy)")
        points.append(ObjectPoint(pid, *X, status="control", ref=cp.xyz, sigma_h=cp.sigma[0],
                                  sigma_v=cp.sigma[2], line=cp.line))
    m = block.obs_image.size
    cov = np.broadcast_to(np.eye(2) * block.sigma_px ** 2, (m, 2, 2)).copy()
    obs = ImageObservations(block.obs_image.copy(), block.obs_point.copy(), block.xy * flip, cov,
                            block.obs_line.copy())
    return Block(cameras=tuple(cams), images=tuple(images), points=tuple(points), obs=obs,
                 datum="control" if block.control else "free", title=block.title, source=block.source,
                 extra={"converted_from": block.convention,
                        "image_names": {im.id: im.name for im in block.images if im.name}})
