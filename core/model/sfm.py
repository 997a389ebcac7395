"""Structure-from-motion blocks: the projective camera of BAL, Bundler and COLMAP as a Problem.

Bundle Adjustment in the Large (BAL), Bundler and COLMAP store the same thing — cameras with a
pose (world → camera), pinhole intrinsics with radial (and tangential) distortion, 3D points
and their image points — in different conventions. :class:`SfmBlock` holds any of them;
:func:`build_sfm_problem` turns it into a :class:`baarda.model.problem.Problem`.

Projection (one formula for all three formats)
----------------------------------------------
With the camera's Rodrigues vector ρ (R = exp([ρ]×), :func:`baarda.observations.rotation.R_from_rodrigues`)
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
from ..observations.rotation import R_from_rodrigues, opk_from_R, skew
from .bundle import Block, Camera, Image, ImageObservations, ObjectPoint
from .geometry import BlockGeometry, CameraGeometry, ImageGeometry
from .problem import (Categorical, Covariance, JoinedLabels, ObservationInfo, ParameterList, Parameters, PointInfo,
                      Problem, RecordIds)

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
    K = skew(rho)
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
        kernel = _compiled_projection()
        if kernel is None:
            return self._evaluate_numpy(x)
        m = self.ipt.shape[0]
        jr, jc, start = self._pattern()
        f = np.empty(2 * m)
        jv = np.empty(jr.size)
        kernel(np.ascontiguousarray(x, dtype=float), self.ipt, self.irot, self.itr, self.iint,
               float(self.sign), start, start[:0, 0], f, jv)
        return f, jr, jc, jv

    def values(self, x):
        """f(x) alone (a trial point's; no Jacobian values stored)."""
        kernel = _compiled_projection()
        if kernel is None:
            return self._evaluate_numpy(x)[0]
        start = self._pattern()[2]
        f = np.empty(2 * self.ipt.shape[0])
        kernel(np.ascontiguousarray(x, dtype=float), self.ipt, self.irot, self.itr, self.iint,
               float(self.sign), start, start[:0, 0], f, np.empty(0))
        return f

    def pattern(self):
        """The rows and columns :meth:`evaluate` returns (the cached arrays)."""
        jr, jc, _ = self._pattern()
        return jr, jc

    def evaluate_into(self, x, dest, out):
        """f(x), the Jacobian value of :meth:`evaluate`'s entry k written to out[dest[k]] (the
        design matrix's data in its own order: no array of the entries besides it)."""
        kernel = _compiled_projection()
        if kernel is None:
            f, _, _, jv = self._evaluate_numpy(x)
            out[dest] = jv
            return f
        start = self._pattern()[2]
        f = np.empty(2 * self.ipt.shape[0])
        kernel(np.ascontiguousarray(x, dtype=float), self.ipt, self.irot, self.itr, self.iint,
               float(self.sign), start, dest, f, out)
        return f

    @property
    def pattern_held(self) -> bool:
        """Whether the Jacobian pattern is held (made by the first evaluation, kept for the whole
        adjustment; :meth:`release` lets it go)."""
        return "_pat" in self.__dict__

    def _pattern(self):
        """Rows and columns of the Jacobian entries (fixed per set; the order of
        :meth:`_evaluate_numpy`) and the place of the first value of each row among them
        (2, m: x rows, y rows; the row's kept values follow in column order)."""
        pat = self.__dict__.get("_pat")
        if pat is None:
            m = self.ipt.shape[0]
            C = np.concatenate([self.ipt, self.itr, self.irot, self.iint], 1)
            q = C.shape[1]
            # int32 where the numbers fit (the pattern is kept for the whole adjustment)
            nnz = 2 * m * q
            small = nnz < 2 ** 31 - 1 and (C.size == 0 or int(C.max()) < 2 ** 31 - 1)
            itype = np.int32 if small else np.int64
            keep = _kept_entries(np.concatenate([C.ravel(), C.ravel()]), m)
            kr = keep.reshape(2, m, q)
            lr = np.arange(m, dtype=itype)
            jrows = np.concatenate([np.repeat(2 * lr, q)[kr[0].ravel()],
                                    np.repeat(2 * lr + 1, q)[kr[1].ravel()]])
            C = C.astype(itype, copy=False).ravel()
            jcols = np.concatenate([C[kr[0].ravel()], C[kr[1].ravel()]])
            del C
            counts = kr.sum(axis=2, dtype=itype).ravel()
            del keep, kr
            start = (np.cumsum(counts, dtype=itype) - counts).reshape(2, m)
            pat = (jrows, jcols, start)
            self.__dict__["_pat"] = pat
        return pat

    def release(self) -> None:
        """Forget the cached Jacobian pattern (made again by the next :meth:`evaluate`)."""
        self.__dict__.pop("_pat", None)

    def _evaluate_numpy(self, x):
        """The reference formulas (vectorised numpy); :meth:`evaluate` compiles the same."""
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
        dPdrho = -np.einsum("mij,mjk,mkl->mil", R, skew(X), right_jacobian(x[self.irot]))
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
        keep = _kept_entries(jcols, m)
        return f, jrows[keep], jcols[keep], jvals[keep]


#: the (row, column) of the 2 × 17 value block that are zero by the model: x does not depend on
#: f_y, c_y, nor y on f_x, c_x (left out, so a camera sharing f for f_x and f_y gets one entry)
_STRUCTURAL_ZERO = ((0, 10), (0, 12), (1, 9), (1, 11))


def _kept_entries(jcols: np.ndarray, m: int) -> np.ndarray:
    """Mask over the (2, m, 17) entries (x rows first): parameters that exist, structural zeros out."""
    keep = (jcols >= 0).reshape(2, m, 17)
    for r, j in _STRUCTURAL_ZERO:
        keep[r, :, j] = False
    return keep.ravel()


def _projection_kernel(x, ipt, irot, itr, iint, s, start, dest, f, jv):
    """f and the Jacobian values of every image point: the formulas of
    :meth:`ProjectionSet._evaluate_numpy`, one observation at a time (compiled by numba).
    The values of row r (x, y) of point i (17: point, t, ρ, the eight intrinsics) go to
    jv[start[r, i]:] in column order (to jv[dest[k]] for entry k when dest is given; none
    when jv is empty), those of absent intrinsics and the structural zeros
    (:data:`_STRUCTURAL_ZERO`) left out."""
    store, direct = jv.size > 0, dest.size == 0
    K, K2, R, Jr = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    SX, RS, dPr = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    P, ins, g = np.empty(3), np.empty(8), np.empty((2, 3))
    V = np.empty((2, 17))
    for i in range(ipt.shape[0]):
        r0, r1, r2_ = x[irot[i, 0]], x[irot[i, 1]], x[irot[i, 2]]
        th2 = r0 * r0 + r1 * r1 + r2_ * r2_
        th = np.sqrt(th2)
        # R = I + a K + b K², K = [ρ]× (rotation.R_from_rodrigues)
        if th < 1e-8:
            a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
        else:
            a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th2
        # J_r = I − c K + d K² (right_jacobian)
        if th < 1e-4:
            c, d = 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
        else:
            c, d = (1.0 - np.cos(th)) / th2, (th - np.sin(th)) / (th2 * th)
        K[0, 0], K[0, 1], K[0, 2] = 0.0, -r2_, r1
        K[1, 0], K[1, 1], K[1, 2] = r2_, 0.0, -r0
        K[2, 0], K[2, 1], K[2, 2] = -r1, r0, 0.0
        _mat3(K, K, K2)
        for p in range(3):
            for q in range(3):
                e = 1.0 if p == q else 0.0
                R[p, q] = e + a * K[p, q] + b * K2[p, q]
                Jr[p, q] = e - c * K[p, q] + d * K2[p, q]
        X0, X1, X2 = x[ipt[i, 0]], x[ipt[i, 1]], x[ipt[i, 2]]
        for p in range(3):
            P[p] = R[p, 0] * X0 + R[p, 1] * X1 + R[p, 2] * X2 + x[itr[i, p]]
        for j in range(8):
            ins[j] = x[iint[i, j]] if iint[i, j] >= 0 else 0.0
        fx, fy, cx, cy, k1, k2, p1, p2 = ins[0], ins[1], ins[2], ins[3], ins[4], ins[5], ins[6], ins[7]
        iz = 1.0 / P[2]
        u, v = s * P[0] * iz, s * P[1] * iz
        r2 = u * u + v * v
        dk = k1 + 2.0 * k2 * r2
        rad = 1.0 + k1 * r2 + k2 * r2 * r2
        ud = u * rad + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
        vd = v * rad + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
        f[2 * i] = fx * ud + cx
        f[2 * i + 1] = fy * vd + cy
        duu = rad + 2 * u * u * dk + 2 * p1 * v + 6 * p2 * u
        duv = 2 * u * v * dk + 2 * p1 * u + 2 * p2 * v
        dvu = 2 * u * v * dk + 2 * p2 * v + 2 * p1 * u
        dvv = rad + 2 * v * v * dk + 2 * p2 * u + 6 * p1 * v
        # ∂(x, y)/∂P = diag(fx, fy) D ∂(u, v)/∂P
        g[0, 0] = fx * duu * s * iz
        g[0, 1] = fx * duv * s * iz
        g[0, 2] = fx * (-duu * u - duv * v) * iz
        g[1, 0] = fy * dvu * s * iz
        g[1, 1] = fy * dvv * s * iz
        g[1, 2] = fy * (-dvu * u - dvv * v) * iz
        # ∂P/∂ρ = −R [X]× J_r
        SX[0, 0], SX[0, 1], SX[0, 2] = 0.0, -X2, X1
        SX[1, 0], SX[1, 1], SX[1, 2] = X2, 0.0, -X0
        SX[2, 0], SX[2, 1], SX[2, 2] = -X1, X0, 0.0
        _mat3(R, SX, RS)
        _mat3(RS, Jr, dPr)
        for r in range(2):
            for j in range(3):
                V[r, j] = g[r, 0] * R[0, j] + g[r, 1] * R[1, j] + g[r, 2] * R[2, j]
                V[r, 3 + j] = g[r, j]
                V[r, 6 + j] = -(g[r, 0] * dPr[0, j] + g[r, 1] * dPr[1, j] + g[r, 2] * dPr[2, j])
        V[0, 9], V[0, 10], V[0, 11], V[0, 12] = ud, 0.0, 1.0, 0.0
        V[0, 13], V[0, 14] = fx * u * r2, fx * u * r2 * r2
        V[0, 15], V[0, 16] = fx * 2 * u * v, fx * (r2 + 2 * u * u)
        V[1, 9], V[1, 10], V[1, 11], V[1, 12] = 0.0, vd, 0.0, 1.0
        V[1, 13], V[1, 14] = fy * v * r2, fy * v * r2 * r2
        V[1, 15], V[1, 16] = fy * (r2 + 2 * v * v), fy * 2 * u * v
        for r in range(2):
            k = start[r, i]
            for j in range(17):
                col = ipt[i, j] if j < 3 else itr[i, j - 3] if j < 6 else irot[i, j - 6] if j < 9 else iint[i, j - 9]
                if col < 0 or (r == 0 and (j == 10 or j == 12)) or (r == 1 and (j == 9 or j == 11)):
                    continue           # (_kept_entries: absent parameters, _STRUCTURAL_ZERO)
                if store:
                    jv[k if direct else dest[k]] = V[r, j]
                k += 1


def _mat3(A, B, out):
    """out = A B for 3 × 3 arrays (no temporaries in the compiled loop)."""
    for p in range(3):
        for q in range(3):
            out[p, q] = A[p, 0] * B[0, q] + A[p, 1] * B[1, q] + A[p, 2] * B[2, q]


_KERNEL = {}


def _compiled_projection():
    try:
        import numba
    except ImportError:          # pragma: no cover - numba is optional
        return None
    if "p" not in _KERNEL:
        global _mat3                 # the kernel calls the compiled product
        _mat3 = numba.njit(cache=True, inline="always")(_mat3)
        _KERNEL["p"] = numba.njit(cache=True)(_projection_kernel)
    return _KERNEL["p"]


# --------------------------------------------------------------------------------------------
# the Problem
# --------------------------------------------------------------------------------------------
def build_sfm_problem(block: SfmBlock) -> Problem:
    """Turn an :class:`SfmBlock` into an adjustment :class:`~baarda.model.problem.Problem`.

    Layout, datum and units: see the module docstring. ``Problem.geometry`` holds the images
    with their projection centres X0, Y0, Z0 (no footprints) and the cameras
    (:func:`sfm_geometry`); ``extra["image_names"]`` maps image ids to file names.
    """
    # parameters: the (few) image and camera parameters one by one, the points as arrays
    pl = ParameterList()
    pose = np.array([[pl.add(f"image {im.id}.{nm}", val, "t") for nm, val in
                      zip(("rho1", "rho2", "rho3", "tx", "ty", "tz"), (*im.rodrigues, *im.t))]
                     for im in block.images], dtype=np.int64).reshape(-1, 6)
    cam_index = {}
    intrinsics = np.full((len(block.cameras), 8), -1, dtype=np.int64)
    for c, cam in enumerate(block.cameras):
        names, feeds = CAMERA_MODELS[cam.model]
        where = {nm: pl.add(f"camera {cam.id}.{nm}", val, "t",
                            fixed=not block.refine_intrinsics or nm in ("cx", "cy"))
                 for nm, val in zip(names, cam.params)}
        intrinsics[c] = [where[nm] if nm is not None else -1 for nm in feeds]
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
    sets = [ProjectionSet(rows=np.arange(2 * m, dtype=it), ipt=index.astype(it)[pp], irot=pose_i[ii, :3],
                          itr=pose_i[ii, 3:], iint=cam_i[img_cam[ii]], sign=SIGN[block.convention])]
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
    info = ObservationInfo(kind=Categorical(("image-x", "image-y", "control-x", "control-y", "control-z"), kind_codes),
                           ids=ids, value_file=l.copy(), unit=units, sigma_file=sfile, sigma_unit=units,
                           line=lines, group=group)
    controlled = {cp.id for cp in block.control}
    status = tuple("control" if pid in controlled else "tie" for pid in block.points) if controlled else \
        ("tie",) * npt
    pts = PointInfo(tuple(block.points), index, status, 3)
    datum = Datum("fixed") if block.control else Datum("free", ())
    return Problem(params=params, sets=tuple(sets), l=l, cov=cov, info=info, points=pts, datum=datum,
                   sigma0=1.0, sigma_act="apriori", source=block.source, title=block.title,
                   geometry=sfm_geometry(block), extra={"convention": block.convention,
                          "image_names": {im.id: im.name for im in block.images},
                          "duplicate_keypoints": block.extra.get("duplicate_keypoints")})


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
    points = []
    for i, pid in enumerate(block.points):
        X = tuple(float(v) for v in block.X[i])
        cp = ctrl.get(pid)
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
