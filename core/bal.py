"""Structure-from-motion blocks: the projective camera of BAL, Bundler and COLMAP as a Problem.

Bundle Adjustment in the Large (BAL), Bundler and COLMAP store the same thing — cameras with a
pose (world → camera), pinhole intrinsics with radial (and tangential) distortion, 3D points
and their image points — in different conventions. :class:`SfmBlock` holds any of them;
:func:`build_sfm_problem` turns it into a :class:`baarda.problem.Problem`.

Projection (one formula for all three formats)
----------------------------------------------
With the camera's Rodrigues vector ρ (R = exp([ρ]×), :func:`baarda.rotation.R_from_rodrigues`)
and translation t, a world point X is, in the camera frame,

.. math::

    P = R\\,X + t, \\qquad (u, v) = s\\,(P_x, P_y)/P_z,

with s = −1 for BAL and Bundler (the camera looks down −z, image y up; Snavely et al. 2006) and
s = +1 for COLMAP (the camera looks down +z, image y down; Schönberger & Frahm 2016). Distortion
and the pixel coordinates follow OpenCV's model (COLMAP ``OPENCV``, Bradski 2000):

.. math::

    ρ² = u² + v²,\\quad δ = k_1 ρ² + k_2 ρ⁴,

    u_d = u (1 + δ) + 2 p_1 u v + p_2 (ρ² + 2u²),\\quad
    v_d = v (1 + δ) + 2 p_2 u v + p_1 (ρ² + 2v²),

    x = f_x u_d + c_x, \\qquad y = f_y v_d + c_y.

Each camera model fills the eight intrinsics (f_x, f_y, c_x, c_y, k_1, k_2, p_1, p_2) from its
own parameters (:data:`CAMERA_MODELS`): BAL's camera is ``RADIAL`` with c_x = c_y = 0, so
p' = f (1 + k1‖p‖² + k2‖p‖⁴) p exactly as the BAL documentation states; ``SIMPLE_*`` models
share one f for f_x and f_y; missing intrinsics are zero.

The Jacobian is analytic. For the rotation, ∂(R X)/∂ρ = −R [X]× J_r(ρ) with the right Jacobian
of SO(3), J_r(ρ) = I − (1 − cos θ)/θ² [ρ]× + (θ − sin θ)/θ³ [ρ]×², θ = |ρ| (e.g. Chirikjian
2011, eq. 10.86; a series is used for θ < 1e-4).

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

References: Agarwal, S., Snavely, N., Seitz, S. M., Szeliski, R. (2010), Bundle adjustment in
the large, ECCV; Snavely, N., Seitz, S. M., Szeliski, R. (2006), Photo tourism, SIGGRAPH
(Bundler); Schönberger, J. L., Frahm, J.-M. (2016), Structure-from-motion revisited, CVPR
(COLMAP); Chirikjian, G. S. (2011), Stochastic Models, Information Theory, and Lie Groups,
vol. 2, Birkhäuser.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .datum import Datum
from .geodetic import LinearSet
from .problem import Covariance, ObservationInfo, Parameters, PointInfo, Problem
from .rotation import R_from_rodrigues, _skew

INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")

# model name → (parameter names in file order, the parameter feeding each of INTRINSICS or None)
CAMERA_MODELS = {
    "SIMPLE_PINHOLE": (("f", "cx", "cy"), ("f", "f", "cx", "cy", None, None, None, None)),
    "PINHOLE": (("fx", "fy", "cx", "cy"), ("fx", "fy", "cx", "cy", None, None, None, None)),
    "SIMPLE_RADIAL": (("f", "cx", "cy", "k"), ("f", "f", "cx", "cy", "k", None, None, None)),
    "RADIAL": (("f", "cx", "cy", "k1", "k2"), ("f", "f", "cx", "cy", "k1", "k2", None, None)),
    "OPENCV": (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"), INTRINSICS),
    "BAL": (("f", "k1", "k2"), ("f", "f", None, None, "k1", "k2", None, None)),
}
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
    """Known coordinates of a block point (model units) with σ per axis, from ``line``."""

    id: str
    xyz: tuple[float, float, float]
    sigma: tuple[float, float, float]
    line: int = 0


@dataclass(frozen=True, eq=False)
class SfmBlock:
    """A structure-from-motion block as read from a BAL, Bundler or COLMAP file.

    points: ids; X: (m × 3) approximate coordinates; point_line: source line per point.
    obs_image, obs_point (n,): indices into ``images`` and ``points`` of each image point;
    xy (n × 2): measured pixel coordinates; obs_line (n,): their source lines.
    convention: ``"bal"``, ``"bundler"`` or ``"colmap"`` (the sign s of the module docstring).
    sigma_px: σ of each image coordinate (pixels). refine_intrinsics: estimate the cameras'
    parameters. control: weighted control points (they make the datum ``"fixed"``).
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
    source: str = ""
    title: str = ""
    extra: dict = field(default_factory=dict)

    def replace(self, **changes) -> "SfmBlock":
        return dataclasses.replace(self, **changes)


# --------------------------------------------------------------------------------------------
# the observation set
# --------------------------------------------------------------------------------------------
def right_jacobian(rho: np.ndarray) -> np.ndarray:
    """J_r(ρ) of SO(3) for Rodrigues vectors ρ (k × 3) → (k × 3 × 3) (module docstring)."""
    rho = np.asarray(rho, dtype=float)
    theta = np.linalg.norm(rho, axis=-1)
    small = theta < 1e-4
    th = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta ** 2 / 24.0, (1.0 - np.cos(th)) / th ** 2)
    b = np.where(small, 1.0 / 6.0 - theta ** 2 / 120.0, (th - np.sin(th)) / th ** 3)
    K = _skew(rho)
    return np.eye(3) - a[..., None, None] * K + b[..., None, None] * (K @ K)


@dataclass(frozen=True, eq=False)
class ProjectionSet:
    """Image points of a structure-from-motion block (vectorised, module docstring).

    rows: global rows (x of point k at 2k, y at 2k + 1). ipt (m × 3): parameter indices of the
    point; irot, itr (m × 3): of the image's ρ and t; iint (m × 8): of the camera's
    intrinsics in the order of :data:`INTRINSICS`, −1 where the intrinsic is zero.
    sign: s of the module docstring.
    """

    rows: np.ndarray
    ipt: np.ndarray
    irot: np.ndarray
    itr: np.ndarray
    iint: np.ndarray
    sign: float

    @property
    def angular(self) -> np.ndarray:
        return np.zeros(self.rows.size, dtype=bool)

    def camera_frame(self, x):
        """P = R X + t (m × 3), R (m × 3 × 3) and the world points X (m × 3)."""
        X = x[self.ipt]
        R = R_from_rodrigues(x[self.irot])
        return np.einsum("mij,mj->mi", R, X) + x[self.itr], R, X

    def evaluate(self, x):
        m = self.ipt.shape[0]
        P, R, X = self.camera_frame(x)
        xe = np.append(x, 0.0)
        fx, fy, cx, cy, k1, k2, p1, p2 = (xe[self.iint[:, j]] for j in range(8))
        s = self.sign
        u, v = s * P[:, 0] / P[:, 2], s * P[:, 1] / P[:, 2]
        r2 = u * u + v * v
        dk = k1 + 2.0 * k2 * r2                       # ∂δ/∂ρ²
        rad = 1.0 + k1 * r2 + k2 * r2 * r2
        ud = u * rad + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
        vd = v * rad + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
        f = np.empty(2 * m)
        f[0::2] = fx * ud + cx
        f[1::2] = fy * vd + cy
        # ∂(u_d, v_d)/∂(u, v)
        duu = rad + 2 * u * u * dk + 2 * p1 * v + 6 * p2 * u
        duv = 2 * u * v * dk + 2 * p1 * u + 2 * p2 * v
        dvu = 2 * u * v * dk + 2 * p2 * v + 2 * p1 * u
        dvv = rad + 2 * v * v * dk + 2 * p2 * u + 6 * p1 * v
        # ∂(x, y)/∂P (m × 2 × 3) = diag(fx, fy) ∂(u_d, v_d)/∂(u, v) ∂(u, v)/∂P
        iz = 1.0 / P[:, 2]
        dUV = np.zeros((m, 2, 3))
        dUV[:, 0, 0] = s * iz
        dUV[:, 0, 2] = -u * iz
        dUV[:, 1, 1] = s * iz
        dUV[:, 1, 2] = -v * iz
        D = np.stack([np.stack([duu, duv], -1), np.stack([dvu, dvv], -1)], -2)
        dxdP = np.einsum("mab,mbc->mac", D, dUV) * np.stack([fx, fy], -1)[:, :, None]
        # ∂P/∂X = R, ∂P/∂t = I, ∂P/∂ρ = −R [X]× J_r(ρ)
        dPdrho = -np.einsum("mij,mjk,mkl->mil", R, _skew(X), right_jacobian(x[self.irot]))
        cols = [self.ipt, self.itr, self.irot]
        vals = [np.einsum("mac,mcj->maj", dxdP, R), dxdP, np.einsum("mac,mcj->maj", dxdP, dPdrho)]
        # intrinsics: columns in INTRINSICS order
        z = np.zeros(m)
        dint = np.empty((m, 2, 8))
        dint[:, 0] = np.stack([ud, z, np.ones(m), z, fx * u * r2, fx * u * r2 * r2,
                               fx * 2 * u * v, fx * (r2 + 2 * u * u)], -1)
        dint[:, 1] = np.stack([z, vd, z, np.ones(m), fy * v * r2, fy * v * r2 * r2,
                               fy * (r2 + 2 * v * v), fy * 2 * u * v], -1)
        cols.append(self.iint)
        vals.append(dint)
        C = np.concatenate(cols, 1)                   # (m × q)
        V = np.concatenate(vals, 2)                   # (m × 2 × q)
        q = C.shape[1]
        lr = np.arange(m)
        jrows = np.concatenate([np.repeat(2 * lr, q), np.repeat(2 * lr + 1, q)])
        jcols = np.concatenate([C.ravel(), C.ravel()])
        jvals = np.concatenate([V[:, 0].ravel(), V[:, 1].ravel()])
        keep = jcols >= 0
        return f, jrows[keep], jcols[keep], jvals[keep]


# --------------------------------------------------------------------------------------------
# the Problem
# --------------------------------------------------------------------------------------------
def build_sfm_problem(block: SfmBlock) -> Problem:
    """Turn an :class:`SfmBlock` into an adjustment :class:`~baarda.problem.Problem`.

    Layout, datum and units: see the module docstring. ``Problem.extra["block"]`` holds the
    geometry the dashboard draws (images with their projection centres X0, Y0, Z0; no
    footprints) and ``extra["image_names"]`` maps image ids to file names.
    """
    labels, x0, kind, fixed, point, axis = [], [], [], [], [], []

    def add(label, value, k, fix=False, p=-1, a=-1):
        labels.append(label)
        x0.append(float(value))
        kind.append(k)
        fixed.append(fix)
        point.append(p)
        axis.append(a)
        return len(x0) - 1

    pose = np.array([[add(f"image {im.id}.{nm}", val, "t") for nm, val in
                      zip(("rho1", "rho2", "rho3", "tx", "ty", "tz"), (*im.rodrigues, *im.t))]
                     for im in block.images], dtype=np.int64).reshape(-1, 6)
    cam_index = {}
    intrinsics = np.full((len(block.cameras), 8), -1, dtype=np.int64)
    for c, cam in enumerate(block.cameras):
        names, feeds = CAMERA_MODELS[cam.model]
        where = {nm: add(f"camera {cam.id}.{nm}", val, "t",
                         fix=not block.refine_intrinsics or nm in ("cx", "cy"))
                 for nm, val in zip(names, cam.params)}
        intrinsics[c] = [where[nm] if nm is not None else -1 for nm in feeds]
        cam_index[cam.id] = c
    index = np.array([[add(f"point {pid}.{nm}", block.X[i, a], "k", p=i, a=a) for a, nm in enumerate("xyz")]
                      for i, pid in enumerate(block.points)], dtype=np.int64).reshape(-1, 3)
    params = Parameters(np.asarray(x0), tuple(labels), np.array(kind), np.array(fixed, dtype=bool),
                        np.array(point, dtype=np.int64), np.array(axis, dtype=np.int64))

    m = block.obs_image.size
    img_cam = np.array([cam_index[im.camera] for im in block.images], dtype=np.int64)
    ii, pp = block.obs_image, block.obs_point
    sets = [ProjectionSet(rows=np.arange(2 * m), ipt=index[pp], irot=pose[ii, :3], itr=pose[ii, 3:],
                          iint=intrinsics[img_cam[ii]], sign=SIGN[block.convention])]
    s2 = block.sigma_px ** 2
    members = [np.array([2 * k, 2 * k + 1]) for k in range(m)]
    blocks = [np.diag([s2, s2])] * m
    img_ids = [im.id for im in block.images]
    kinds = ["image-x", "image-y"] * m
    ids = [{"image": img_ids[ii[k]], "point": block.points[pp[k]], "component": c}
           for k in range(m) for c in "xy"]
    kp = block.extra.get("obs_keypoint")
    if kp is not None and m:
        # several keypoints of one image on one point (COLMAP): each an observation of its own,
        # told apart by its keypoint index (POINT2D_IDX)
        _, inv, cnt = np.unique(ii * len(block.points) + pp, return_inverse=True, return_counts=True)
        for k in np.flatnonzero(cnt[inv] > 1):
            for c in (0, 1):
                ids[2 * k + c] = {"image": img_ids[ii[k]], "point": block.points[pp[k]],
                                  "keypoint": int(kp[k]), "component": "xy"[c]}
    l = [block.xy.ravel()]
    units = ["px"] * (2 * m)
    sfile = [block.sigma_px] * (2 * m)
    lines = list(np.repeat(block.obs_line, 2))
    group = list(np.repeat(np.arange(m), 2))

    pindex = {pid: i for i, pid in enumerate(block.points)}
    row, g = 2 * m, m
    crow, cidx = [], []
    for cp in block.control:
        i = pindex[cp.id]
        members.append(np.arange(row, row + 3))
        blocks.append(np.diag(np.square(cp.sigma)))
        for a, nm in enumerate("xyz"):
            crow.append(row)
            cidx.append(index[i, a])
            kinds.append(f"control-{nm}")
            ids.append({"id": cp.id})
            units.append("m")
            sfile.append(cp.sigma[a])
            lines.append(cp.line)
            group.append(g)
            row += 1
        l.append(np.asarray(cp.xyz, dtype=float))
        g += 1
    if crow:
        sets.append(LinearSet("coordinate", np.array(crow, dtype=np.int64),
                              np.full(len(crow), -1, dtype=np.int64), np.array(cidx, dtype=np.int64)))
    lvec = np.concatenate(l)
    cov = Covariance.from_blocks(row, members, blocks)
    info = ObservationInfo(kind=tuple(kinds), ids=tuple(ids), value_file=lvec.copy(), unit=tuple(units),
                           sigma_file=np.array(sfile, dtype=float), sigma_unit=tuple(units),
                           line=np.array(lines, dtype=np.int64), group=np.array(group, dtype=np.int64))
    controlled = {cp.id for cp in block.control}
    status = tuple("control" if pid in controlled else "tie" for pid in block.points)
    pts = PointInfo(tuple(block.points), index, status, 3)
    datum = Datum("fixed") if block.control else Datum("free", ())
    return Problem(params=params, sets=tuple(sets), l=lvec, cov=cov, info=info, points=pts, datum=datum,
                   sigma0=1.0, sigma_act="apriori", source=block.source, title=block.title,
                   extra={"block": sfm_geometry(block), "convention": block.convention,
                          "image_names": {im.id: im.name for im in block.images},
                          "duplicate_keypoints": block.extra.get("duplicate_keypoints")})


def sfm_geometry(block: SfmBlock) -> dict:
    """Geometry for the dashboard (JSON-able): images with projection centres, cameras."""
    images = []
    for im in block.images:
        C = im.centre
        images.append({"id": im.id, "camera": im.camera, "name": im.name,
                       "X0": float(C[0]), "Y0": float(C[1]), "Z0": float(C[2])})
    cams = [{"id": c.id, "model": c.model, "params": list(c.params), "width": c.width, "height": c.height,
             "unit": "px"} for c in block.cameras]
    size = [block.cameras[0].width, block.cameras[0].height] if block.cameras else [0.0, 0.0]
    out = {"images": images, "cameras": cams, "image_unit": "px", "convention": block.convention}
    if size[0] > 0 and size[1] > 0:
        out["image_size"] = size
    return out


def initial_cost(problem: Problem) -> float:
    """½ Σ (v_i/σ_i)² at the initial values (BAL's and Ceres' "initial cost" when σ = 1 px)."""
    f, _ = problem.evaluate(problem.params.x0)
    v = problem.misclosure(f) / problem.cov.sigma()
    return 0.5 * float(v @ v)


def to_block(block: SfmBlock):
    """The block as a :class:`baarda.bundle.Block` (ω-φ-κ collinearity) for the native format.

    Exact for the projection (same residuals at the initial values) with the intrinsics held at
    their values: the native format has no per-camera f, k1, k2 refinement. Mapping (module
    docstring and :mod:`baarda.bundle`): BAL/Bundler R_ωφκ = Rᵀ, image points as they are;
    COLMAP R_ωφκ = (D R)ᵀ with D = diag(1, −1, −1), y → −y, x0 = c_x, y0 = −c_y, p1' = p2/f,
    p2' = −p1/f; always k1' = k1/f², k2' = k2/f⁴ (Brown's coefficients in pixel units).
    ValueError for a camera with f_x ≠ f_y or control with sx ≠ sy.
    """
    from .bundle import Block, Camera, Image, ImageObservations, ObjectPoint
    from .rotation import opk_from_R

    colmap = block.convention == "colmap"
    D = np.diag([1.0, -1.0, -1.0]) if colmap else np.eye(3)
    flip = np.array([1.0, -1.0]) if colmap else np.ones(2)
    img_cam = {im.id: im.camera for im in block.images}
    cams = []
    for cam in block.cameras:
        names, feeds = CAMERA_MODELS[cam.model]
        val = dict(zip(names, cam.params))
        fx, fy, cx, cy, k1, k2, p1, p2 = (val[nm] if nm is not None else 0.0 for nm in feeds)
        if fx != fy:
            raise ValueError(f"camera {cam.id}: f_x ≠ f_y ({fx:g}, {fy:g}) has no native equivalent")
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
    points = []
    for i, pid in enumerate(block.points):
        X = tuple(float(v) for v in block.X[i])
        cp = ctrl.get(pid)
        if cp is None:
            points.append(ObjectPoint(pid, *X, line=int(block.point_line[i])))
            continue
        if cp.sigma[0] != cp.sigma[1]:
            raise ValueError(f"control point {pid}: the native format takes one horizontal σ (sx = sy)")
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
