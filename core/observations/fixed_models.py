"""COLMAP's other camera models, their distortion held at the file's values.

COLMAP writes, besides the radial-tangential models of :mod:`baarda.observations.distortion`
(``SIMPLE_PINHOLE`` … ``OPENCV``), models whose distortion baarda does not estimate: their
coefficients stay at the file's values (as when COLMAP's bundle adjuster is told to keep the
intrinsics), while the focal lengths may still be refined. At the normalised point (u, v) of
:mod:`baarda.observations.projection` each gives the distorted point (u_d, v_d), then
x = f_x u_d + c_x, y = f_y v_d + c_y (Schönberger & Frahm 2016, the camera models of COLMAP's
``src/colmap/sensor/models.h``; r² = u² + v²):

* ``FULL_OPENCV`` (code 1; k1, k2, p1, p2, k3, k4, k5, k6): the rational radial factor
  g = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶),
  u_d = u g + 2 p1 u v + p2 (r² + 2u²), v_d = v g + 2 p2 u v + p1 (r² + 2v²).
* ``OPENCV_FISHEYE``, ``RADIAL_FISHEYE``, ``SIMPLE_RADIAL_FISHEYE``, ``FISHEYE``,
  ``SIMPLE_FISHEYE`` (code 2; k1 … k4, the others with fewer terms or none, equidistant): θ = atan r, θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸),
  (u_d, v_d) = (θ_d / r)(u, v); the point itself for r ≤ machine ε.
* ``FOV`` (code 3; ω): (u_d, v_d) = F(r²)(u, v), F = atan(2 r tan(ω/2)) / (r ω), with
  COLMAP's series for ω² < 10⁻⁴ and for r² < 10⁻⁴.
* ``THIN_PRISM_FISHEYE`` (code 4; k1, k2, p1, p2, k3, k4, sx1, sy1): the fisheye angle first,
  (ū, v̄) = (θ / r)(u, v), then ρ² = ū² + v̄², a = k1 ρ² + k2 ρ⁴ + k3 ρ⁶ + k4 ρ⁸,
  u_d = ū (1 + a) + 2 p1 ū v̄ + p2 (ρ² + 2ū²) + sx1 ρ², v_d = v̄ (1 + a) + 2 p2 ū v̄ + p1 (ρ² + 2v̄²) + sy1 ρ².
* ``RAD_TAN_THIN_PRISM_FISHEYE`` (code 5; k0 … k5, p0, p1, s0 … s3; Project Aria's
  Fisheye624): the fisheye angle (ū, v̄) as above, t² = ū² + v̄², (x_r, y_r) = (1 + k0 t² + … +
  k5 t¹²)(ū, v̄), ρ² = x_r² + y_r², u_d = x_r + 2 p1 x_r y_r + p0 (ρ² + 2x_r²) + s0 ρ² + s1 ρ⁴,
  v_d = y_r + 2 p0 x_r y_r + p1 (ρ² + 2y_r²) + s2 ρ² + s3 ρ⁴.
* ``SIMPLE_DIVISION``, ``DIVISION`` (code 6; k): the division model's distorted point,
  (u_d, v_d) = 2 (u, v) / (1 + √(1 − 4 k r²)) (undistorting it, (u, v) = (u_d, v_d) / (1 + k r_d²)).
* ``EUCM`` (code 7; α, β): (u_d, v_d) = (u, v) / (α √(β r² + 1) + 1 − α) (the enhanced unified
  model, points in front of the camera).

Each function returns (u_d, v_d, J00, J01, J10, J11), J = ∂(u_d, v_d)/∂(u, v), analytic.
:func:`fixed_distortion` is the numpy reference (arrays); :func:`fixed_distortion_scalar` the
same formulas one point at a time for the compiled projection kernel (numba), tested equal, and
both against pycolmap's own projection (``tests/observations/test_projection.py``).
"""

from __future__ import annotations

import types

import numpy as np

from ..solve.compiled import njit

#: model → (code, names of its distortion coefficients in the order the formulas read them)
FIXED_MODELS = {
    "FULL_OPENCV": (1, ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),
    "OPENCV_FISHEYE": (2, ("k1", "k2", "k3", "k4")),
    "RADIAL_FISHEYE": (2, ("k1", "k2")),
    "SIMPLE_RADIAL_FISHEYE": (2, ("k",)),
    "FOV": (3, ("omega",)),
    "THIN_PRISM_FISHEYE": (4, ("k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1")),
    "RAD_TAN_THIN_PRISM_FISHEYE": (5, ("k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1", "s2", "s3")),
    "SIMPLE_DIVISION": (6, ("k",)),
    "DIVISION": (6, ("k",)),
    "EUCM": (7, ("alpha", "beta")),
    "SIMPLE_FISHEYE": (2, ()),
    "FISHEYE": (2, ()),
}
#: the most coefficients a model has (the width of :class:`~baarda.observations.projection.ProjectionSet`'s table)
MAX_COEFFICIENTS = 12
EPS = float(np.finfo(float).eps)
FOV_EPS = 1e-4


# ---- plain arithmetic: the same source serves numpy arrays and, compiled, single points ----
def _scaled(u, v, s, h):
    """(u, v) scaled by s(r²): (u_d, v_d, J00, J01, J10, J11) with h = ∂s/∂(r²)."""
    c = 2.0 * u * v * h
    return u * s, v * s, s + 2.0 * u * u * h, c, c, s + 2.0 * v * v * h


def _full_opencv(d, u, v):
    """FULL_OPENCV (code 1)."""
    k1, k2, p1, p2, k3, k4, k5, k6 = d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]
    u2, v2, uv = u * u, v * v, u * v
    r2 = u2 + v2
    r4 = r2 * r2
    r6 = r4 * r2
    num = 1.0 + k1 * r2 + k2 * r4 + k3 * r6
    den = 1.0 + k4 * r2 + k5 * r4 + k6 * r6
    g = num / den
    dg = ((k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4) * den - num * (k4 + 2.0 * k5 * r2 + 3.0 * k6 * r4)) / (den * den)
    c = 2.0 * uv * dg + 2.0 * p1 * u + 2.0 * p2 * v
    return (u * g + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2), v * g + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2),
            g + 2.0 * u2 * dg + 2.0 * p1 * v + 6.0 * p2 * u, c, c, g + 2.0 * v2 * dg + 2.0 * p2 * u + 6.0 * p1 * v)


def _division(d, u, v):
    """SIMPLE_DIVISION, DIVISION (code 6): s = 2 / (1 + √(1 − 4 k r²))."""
    q = np.sqrt(1.0 - 4.0 * d[0] * (u * u + v * v))
    return _scaled(u, v, 2.0 / (1.0 + q), 4.0 * d[0] / (q * (1.0 + q) * (1.0 + q)))


def _eucm(d, u, v):
    """EUCM (code 7): s = 1 / (α √(β r² + 1) + 1 − α)."""
    w = np.sqrt(d[1] * (u * u + v * v) + 1.0)
    den = d[0] * w + 1.0 - d[0]
    return _scaled(u, v, 1.0 / den, -d[0] * d[1] / (2.0 * w * den * den))


def _compose(d00, d01, d10, d11, f00, f01, f10, f11):
    """D F of two 2 × 2 Jacobians (a distortion D after the fisheye angle F)."""
    return d00 * f00 + d01 * f10, d00 * f01 + d01 * f11, d10 * f00 + d11 * f10, d10 * f01 + d11 * f11


def _prism(d, uu, vv, f00, f01, f10, f11):
    """THIN_PRISM_FISHEYE (code 4) at the fisheye angle (ū, v̄) whose Jacobian is F."""
    k1, k2, p1, p2, k3, k4, sx, sy = d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]
    w2, z2, wz = uu * uu, vv * vv, uu * vv
    R2 = w2 + z2
    rad = R2 * (k1 + R2 * (k2 + R2 * (k3 + R2 * k4)))
    drad = k1 + R2 * (2.0 * k2 + R2 * (3.0 * k3 + R2 * 4.0 * k4))
    ud = uu * (1.0 + rad) + 2.0 * p1 * wz + p2 * (R2 + 2.0 * w2) + sx * R2
    vd = vv * (1.0 + rad) + 2.0 * p2 * wz + p1 * (R2 + 2.0 * z2) + sy * R2
    j = _compose(1.0 + rad + 2.0 * w2 * drad + 2.0 * p1 * vv + 6.0 * p2 * uu + 2.0 * sx * uu,
                 2.0 * wz * drad + 2.0 * p1 * uu + 2.0 * p2 * vv + 2.0 * sx * vv,
                 2.0 * wz * drad + 2.0 * p2 * vv + 2.0 * p1 * uu + 2.0 * sy * uu,
                 1.0 + rad + 2.0 * z2 * drad + 2.0 * p2 * uu + 6.0 * p1 * vv + 2.0 * sy * vv, f00, f01, f10, f11)
    return ud, vd, j[0], j[1], j[2], j[3]


def _rad_tan(d, uu, vv, f00, f01, f10, f11):
    """RAD_TAN_THIN_PRISM_FISHEYE (code 5) at the fisheye angle (ū, v̄) whose Jacobian is F."""
    t2 = uu * uu + vv * vv
    rad = 1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * (d[3] + t2 * (d[4] + t2 * d[5])))))
    drad = d[0] + t2 * (2.0 * d[1] + t2 * (3.0 * d[2] + t2 * (4.0 * d[3] + t2 * (5.0 * d[4] + t2 * 6.0 * d[5]))))
    xr, yr, g00, g01, g10, g11 = _scaled(uu, vv, rad, drad)
    p0, p1, s0, s1, s2, s3 = d[6], d[7], d[8], d[9], d[10], d[11]
    r2 = xr * xr + yr * yr
    r4 = r2 * r2
    xd = xr + 2.0 * p1 * xr * yr + p0 * (r2 + 2.0 * xr * xr) + s0 * r2 + s1 * r4
    yd = yr + 2.0 * p0 * xr * yr + p1 * (r2 + 2.0 * yr * yr) + s2 * r2 + s3 * r4
    k = _compose(1.0 + 2.0 * p1 * yr + 6.0 * p0 * xr + 2.0 * s0 * xr + 4.0 * s1 * r2 * xr,
                 2.0 * p1 * xr + 2.0 * p0 * yr + 2.0 * s0 * yr + 4.0 * s1 * r2 * yr,
                 2.0 * p0 * yr + 2.0 * p1 * xr + 2.0 * s2 * xr + 4.0 * s3 * r2 * xr,
                 1.0 + 2.0 * p0 * xr + 6.0 * p1 * yr + 2.0 * s2 * yr + 4.0 * s3 * r2 * yr, g00, g01, g10, g11)
    j = _compose(k[0], k[1], k[2], k[3], f00, f01, f10, f11)
    return xd, yd, j[0], j[1], j[2], j[3]


# ---- the branches: one point (compiled) and arrays (numpy) ----
def _fisheye_scale(d, r2):
    """Equidistant fisheye (code 2): s = θ_d / r and h = ∂s/∂(r²) at one point; s = 1 for
    r ≤ ε (with d = 0 the fisheye angle ū = (θ / r) u of codes 4 and 5)."""
    r = np.sqrt(r2)
    if r <= EPS:
        return 1.0, 0.0
    th = np.arctan(r)
    t2 = th * th
    poly = 1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3])))
    dpoly = 1.0 + t2 * (3.0 * d[0] + t2 * (5.0 * d[1] + t2 * (7.0 * d[2] + t2 * 9.0 * d[3])))
    s = th * poly / r
    return s, 0.5 * (dpoly / (1.0 + r2) - s) / r2


def _fisheye_scale_array(d, r2):
    """:func:`_fisheye_scale` over an array of r²."""
    r = np.sqrt(r2)
    on = r > EPS
    th = np.arctan(r)
    t2 = th * th
    poly = 1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3])))
    dpoly = 1.0 + t2 * (3.0 * d[0] + t2 * (5.0 * d[1] + t2 * (7.0 * d[2] + t2 * 9.0 * d[3])))
    s = np.where(on, th * poly / r, 1.0)
    return s, np.where(on, 0.5 * (dpoly / (1.0 + r2) - s) / r2, 0.0)


def _fov_scale(om, r2):
    """FOV (code 3): F and ∂F/∂(r²) at one point, COLMAP's series for small ω² and r²."""
    om2 = om * om
    if om2 < FOV_EPS:
        return om2 * r2 / 3.0 - om2 / 12.0 + 1.0, om2 / 3.0
    t = np.tan(om / 2.0)
    if r2 < FOV_EPS:
        return -2.0 * t * (4.0 * r2 * t * t - 3.0) / (3.0 * om), -8.0 * t * t * t / (3.0 * om)
    r = np.sqrt(r2)
    a = np.arctan(2.0 * t * r)
    return a / (r * om), (2.0 * t * r / (1.0 + 4.0 * t * t * r2) - a) / (2.0 * r2 * r * om)


def _fov_scale_array(om, r2):
    """:func:`_fov_scale` over an array of r²."""
    om2 = om * om
    if om2 < FOV_EPS:
        return om2 * r2 / 3.0 - om2 / 12.0 + 1.0, np.full_like(r2, om2 / 3.0)
    t = np.tan(om / 2.0)
    r = np.sqrt(r2)
    a = np.arctan(2.0 * t * r)
    small = r2 < FOV_EPS
    return (np.where(small, -2.0 * t * (4.0 * r2 * t * t - 3.0) / (3.0 * om), a / (r * om)),
            np.where(small, -8.0 * t * t * t / (3.0 * om), (2.0 * t * r / (1.0 + 4.0 * t * t * r2) - a) / (2.0 * r2 * r * om)))


_ZERO4 = np.zeros(4)


def _distort(code, d, u, v):
    """The model ``code`` at (u, v): one source for both paths (:func:`fixed_distortion` runs a
    copy of it whose branch functions are the array ones; :func:`compiled_distortion` compiles
    it with every function it calls)."""
    if code == 1:
        return _full_opencv(d, u, v)
    if code == 6:
        return _division(d, u, v)
    if code == 7:
        return _eucm(d, u, v)
    r2 = u * u + v * v
    if code == 2:
        s, h = _fisheye_scale(d, r2)
        return _scaled(u, v, s, h)
    if code == 3:
        s, h = _fov_scale(d[0], r2)
        return _scaled(u, v, s, h)
    a, h = _fisheye_scale(_ZERO4, r2)               # the fisheye angle of codes 4 and 5
    uu, vv, f00, f01, f10, f11 = _scaled(u, v, a, h)
    if code == 4:
        return _prism(d, uu, vv, f00, f01, f10, f11)
    return _rad_tan(d, uu, vv, f00, f01, f10, f11)


def _rebound(f, names: dict):
    """``f`` with the global names in ``names`` bound to other functions (its own copy)."""
    g = dict(f.__globals__)
    g.update(names)
    return types.FunctionType(f.__code__, g, f.__name__)


_distort_array = _rebound(_distort, {"_fisheye_scale": _fisheye_scale_array, "_fov_scale": _fov_scale_array})


def fixed_distortion_scalar(code, d, u, v):
    """The distorted point and its Jacobian at one normalised point, for a COLMAP model (SF16).

    The formulas of the module docstring (COLMAP's ``models.h``) for the model ``code``.

    Parameters
    ----------
    code : int
        The model's code (:data:`FIXED_MODELS`, 1-7).
    d : numpy.ndarray
        The :data:`MAX_COEFFICIENTS` coefficients of the model (zeros after its own), in the units
        of the normalised coordinates (FOV's ω in radians).
    u, v : float
        Normalised image coordinates, dimensionless.

    Returns
    -------
    ud : float
        u_d, dimensionless.
    vd : float
        v_d, dimensionless.
    J00 : float
        ∂u_d/∂u, dimensionless.
    J01 : float
        ∂u_d/∂v, dimensionless.
    J10 : float
        ∂v_d/∂u, dimensionless.
    J11 : float
        ∂v_d/∂v, dimensionless.
    """
    return _distort(code, d, u, v)


def fixed_distortion(code: int, d, u: np.ndarray, v: np.ndarray):
    """:func:`fixed_distortion_scalar` over arrays, one model and one set of coefficients (SF16).

    The same formulas (the numpy reference).

    Parameters
    ----------
    code : int
        The model's code (:data:`FIXED_MODELS`, 1-7).
    d : array_like of float
        The :data:`MAX_COEFFICIENTS` coefficients (zeros after the model's own).
    u, v : numpy.ndarray
        Normalised image coordinates, dimensionless.

    Returns
    -------
    ud : numpy.ndarray
        u_d, dimensionless.
    vd : numpy.ndarray
        v_d, dimensionless.
    J00 : numpy.ndarray
        ∂u_d/∂u, dimensionless.
    J01 : numpy.ndarray
        ∂u_d/∂v, dimensionless.
    J10 : numpy.ndarray
        ∂v_d/∂u, dimensionless.
    J11 : numpy.ndarray
        ∂v_d/∂v, dimensionless.
    """
    u, v = np.asarray(u, dtype=float), np.asarray(v, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _distort_array(int(code), np.asarray(d, dtype=float), u, v)


_COMPILED = {}


def compiled_distortion():
    """:func:`fixed_distortion_scalar` compiled by numba with every function it calls (SF16's models).

    For the kernel of :mod:`baarda.observations.projection`; compiled once and cached.

    Returns
    -------
    callable or None
        ``f(code, d, u, v) -> (u_d, v_d, J00, J01, J10, J11)`` (dimensionless), or None without
        numba.
    """
    if "d" not in _COMPILED:
        jit = njit()
        if jit is None:
            return None
        g = dict(globals())
        for name in ("_scaled", "_compose", "_full_opencv", "_division", "_eucm", "_prism", "_rad_tan",
                     "_fisheye_scale", "_fov_scale", "_distort"):
            g[name] = jit(types.FunctionType(globals()[name].__code__, g, name))
        _COMPILED["d"] = g["_distort"]
    return _COMPILED["d"]
