"""Collinearity: image measurements of a photogrammetric camera (bundle blocks).

Collinearity (sign convention)
------------------------------
With R = R_ω R_φ R_κ (:mod:`baarda.observations.rotation`, R turns image vectors into object space) and the
object-to-image vector (U, V, W)ᵀ = Rᵀ (X − X0, Y − Y0, Z − Z0)ᵀ,

.. math::

    \\bar x = -c\\,U/W = -c\\,\\frac{r_{11}ΔX + r_{21}ΔY + r_{31}ΔZ}{r_{13}ΔX + r_{23}ΔY + r_{33}ΔZ},
    \\qquad \\bar y = -c\\,V/W = -c\\,\\frac{r_{12}ΔX + r_{22}ΔY + r_{32}ΔZ}{r_{13}ΔX + r_{23}ΔY + r_{33}ΔZ},

    x = x_0 + \\bar x + Δx(\\bar x, \\bar y), \\qquad y = y_0 + \\bar y + Δy(\\bar x, \\bar y).

A nadir image (ω = φ = κ = 0) looks down (W < 0): image x points along object X, image y along
object Y, c > 0. The distortion Δ is *added* to the ideal point (the measured point is where
the distorted ray meets the image plane) and is evaluated at the ideal coordinates.

Δ is the sum of the camera's calibrated distortion (Brown's form, fixed, standard units:
k1 in unit⁻², k2 in unit⁻⁴, k3 in unit⁻⁶, p1, p2 in unit⁻¹, r² = x̄² + ȳ²)

    Δx = x̄ (k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2x̄²) + 2 p2 x̄ȳ,
    Δy = ȳ (k1 r² + k2 r⁴ + k3 r⁶) + p2 (r² + 2ȳ²) + 2 p1 x̄ȳ,

and of the estimated *additional parameters* (APs, kind ``"t"``), in normalised coordinates
u = x̄/s, v = ȳ/s with the camera's reference length s (``Camera.scale``), so that every AP is
in image units (mm or px) — the size of its correction at u or v = 1:

- ``"io"``: corrections of the interior orientation Δc, Δx0, Δy0 (c + Δc, x0 + Δx0, y0 + Δy0);
- ``"brown"``: Brown's physical set (Brown 1971; affinity and shear as in Fraser 1997)
  Δx = u (a1 ρ² + a2 ρ⁴ + a3 ρ⁶) + a4 (ρ² + 2u²) + 2 a5 uv + a6 u + a7 v,
  Δy = v (a1 ρ² + a2 ρ⁴ + a3 ρ⁶) + a5 (ρ² + 2v²) + 2 a4 uv, ρ² = u² + v²
  (so k1 = a1/s³, p1 = a4/s², ...);
- ``"ebner"``: Ebner's (1976) 12 orthogonal parameters for the 3 × 3 von Gruber pattern with
  base s (x = s u); e = 2/3,
  Δx = a1 u + a2 v − a3 (2u² − 4/3) + a4 uv + a5 (v² − e) + a7 u (v² − e) + a9 v (u² − e)
  + a11 (u² − e)(v² − e),
  Δy = −a1 v + a2 u + a3 uv − a4 (2v² − 4/3) + a6 (u² − e) + a8 v (u² − e) + a10 u (v² − e)
  + a12 (u² − e)(v² − e).

Units: object coordinates and X0 in metres, angles in radians, image coordinates, c, x0, y0,
their σ and the APs in the camera's unit (``"mm"`` or ``"px"``).

:class:`CollinearitySet` evaluates f and the Jacobian of the image points of one camera (numpy,
:meth:`CollinearitySet.evaluate_numpy`; compiled by numba where installed, same numbers);
:func:`project` projects object points through a camera (simulator, tests).

References (full in the package docstring): F80; B71 (Brown); E76 (Ebner); F97 (Fraser).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..solve.compiled import njit
from .distortion import brown
from .rotation import R_opk_derivatives

EO_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
AP_GROUPS = {
    "io": ("dc", "dx0", "dy0"),
    "brown": ("a1", "a2", "a3", "a4", "a5", "a6", "a7"),
    "ebner": tuple(f"b{i}" for i in range(1, 13)),
}


def brown_basis(u, v):
    """Brown's physical AP set at (u, v): Fx, Fy and their derivatives (B71; F97 for affinity and shear).

    Columns a1..a7 as in the module docstring (radial a1-a3, decentring a4, a5, affinity a6,
    shear a7).

    Parameters
    ----------
    u, v : array_like of float
        m normalised image coordinates x̄/s, ȳ/s, dimensionless.

    Returns
    -------
    Fx : numpy.ndarray
        m × 7 corrections Δx per unit of each AP, dimensionless (the APs are in image units).
    Fy : numpy.ndarray
        m × 7 corrections Δy per unit of each AP, dimensionless.
    Fxu : numpy.ndarray
        m × 7 derivatives ∂Fx/∂u, dimensionless.
    Fxv : numpy.ndarray
        m × 7 derivatives ∂Fx/∂v, dimensionless.
    Fyu : numpy.ndarray
        m × 7 derivatives ∂Fy/∂u, dimensionless.
    Fyv : numpy.ndarray
        m × 7 derivatives ∂Fy/∂v, dimensionless.
    """
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    r2 = u * u + v * v
    r4, r6 = r2 * r2, r2 * r2 * r2
    z, o = np.zeros_like(u), np.ones_like(u)
    Fx = np.stack([u * r2, u * r4, u * r6, r2 + 2 * u * u, 2 * u * v, u, v], -1)
    Fy = np.stack([v * r2, v * r4, v * r6, 2 * u * v, r2 + 2 * v * v, z, z], -1)
    Fxu = np.stack([r2 + 2 * u * u, r4 + 4 * u * u * r2, r6 + 6 * u * u * r4, 6 * u, 2 * v, o, z], -1)
    Fxv = np.stack([2 * u * v, 4 * u * v * r2, 6 * u * v * r4, 2 * v, 2 * u, z, o], -1)
    Fyu = np.stack([2 * u * v, 4 * u * v * r2, 6 * u * v * r4, 2 * v, 2 * u, z, z], -1)
    Fyv = np.stack([r2 + 2 * v * v, r4 + 4 * v * v * r2, r6 + 6 * v * v * r4, 2 * u, 6 * v, z, z], -1)
    return Fx, Fy, Fxu, Fxv, Fyu, Fyv


def ebner_basis(u, v):
    """Ebner's 12 orthogonal AP at (u, v) = (x, y)/b: Fx, Fy and their derivatives (E76).

    Parameters
    ----------
    u, v : array_like of float
        m image coordinates in units of the base b of the 3 × 3 von Gruber pattern, dimensionless.

    Returns
    -------
    Fx : numpy.ndarray
        m × 12 corrections Δx per unit of each AP, dimensionless (the APs are in image units).
    Fy : numpy.ndarray
        m × 12 corrections Δy per unit of each AP, dimensionless.
    Fxu : numpy.ndarray
        m × 12 derivatives ∂Fx/∂u, dimensionless.
    Fxv : numpy.ndarray
        m × 12 derivatives ∂Fx/∂v, dimensionless.
    Fyu : numpy.ndarray
        m × 12 derivatives ∂Fy/∂u, dimensionless.
    Fyv : numpy.ndarray
        m × 12 derivatives ∂Fy/∂v, dimensionless.
    """
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    e = 2.0 / 3.0
    z, o = np.zeros_like(u), np.ones_like(u)
    U, V = u * u - e, v * v - e
    Fx = np.stack([u, v, -(2 * u * u - 2 * e), u * v, V, z, u * V, z, v * U, z, U * V, z], -1)
    Fy = np.stack([-v, u, u * v, -(2 * v * v - 2 * e), z, U, z, v * U, z, u * V, z, U * V], -1)
    Fxu = np.stack([o, z, -4 * u, v, z, z, V, z, 2 * u * v, z, 2 * u * V, z], -1)
    Fxv = np.stack([z, o, z, u, 2 * v, z, 2 * u * v, z, U, z, 2 * v * U, z], -1)
    Fyu = np.stack([z, o, v, z, z, 2 * u, z, 2 * u * v, z, V, z, 2 * u * V], -1)
    Fyv = np.stack([-o, z, u, -4 * v, z, z, z, U, z, 2 * u * v, z, 2 * v * U], -1)
    return Fx, Fy, Fxu, Fxv, Fyu, Fyv


BASES = {"brown": brown_basis, "ebner": ebner_basis}


def _collinearity_kernel(ipt, ieo, inv, x, R, Rw, Rp, Rk, c, x0, y0, cal, f, vx, vy):
    """f and the 9 Jacobian columns (point x, y, z; centre X0, Y0, Z0; ω, φ, κ) of every image
    point, for a camera without additional parameters: the formulas of
    :meth:`CollinearitySet.evaluate`, one observation at a time (compiled by numba)."""
    k1, k2, k3, p1, p2 = cal[0], cal[1], cal[2], cal[3], cal[4]
    for i in range(ipt.shape[0]):
        g = inv[i]
        d0 = x[ipt[i, 0]] - x[ieo[i, 0]]
        d1 = x[ipt[i, 1]] - x[ieo[i, 1]]
        d2 = x[ipt[i, 2]] - x[ieo[i, 2]]
        U = R[g, 0, 0] * d0 + R[g, 1, 0] * d1 + R[g, 2, 0] * d2
        V = R[g, 0, 1] * d0 + R[g, 1, 1] * d1 + R[g, 2, 1] * d2
        W = R[g, 0, 2] * d0 + R[g, 1, 2] * d1 + R[g, 2, 2] * d2
        xb = -c * U / W
        yb = -c * V / W
        dx, dy, J00, cross, J11 = _brown(xb, yb, k1, k2, k3, p1, p2)
        f[2 * i] = x0 + xb + dx
        f[2 * i + 1] = y0 + yb + dy
        for j in range(3):
            # ∂(U,V,W)/∂X_j = row j of R; the centre's column is its negative
            gx = (-c * R[g, j, 0] - xb * R[g, j, 2]) / W
            gy = (-c * R[g, j, 1] - yb * R[g, j, 2]) / W
            ax = J00 * gx + cross * gy
            ay = cross * gx + J11 * gy
            vx[2 * j, i], vy[2 * j, i] = ax, ay
            vx[2 * j + 1, i], vy[2 * j + 1, i] = -ax, -ay
        for j in range(3):
            if j == 0:
                D = Rw
            elif j == 1:
                D = Rp
            else:
                D = Rk
            a0 = D[g, 0, 0] * d0 + D[g, 1, 0] * d1 + D[g, 2, 0] * d2
            a1 = D[g, 0, 1] * d0 + D[g, 1, 1] * d1 + D[g, 2, 1] * d2
            a2 = D[g, 0, 2] * d0 + D[g, 1, 2] * d1 + D[g, 2, 2] * d2
            gx = (-c * a0 - xb * a2) / W
            gy = (-c * a1 - yb * a2) / W
            vx[6 + j, i] = J00 * gx + cross * gy
            vy[6 + j, i] = cross * gx + J11 * gy


_KERNEL = {}
_brown = brown                   # compiled in place by _compiled_collinearity


def _compiled_collinearity():
    """:func:`_collinearity_kernel` compiled by numba (None without it)."""
    if "k" not in _KERNEL:
        jit = njit(cache=True)
        if jit is None:
            return None
        global _brown                # the kernel calls the compiled distortion
        _brown = njit(cache=True, inline="always")(brown)
        _KERNEL["k"] = jit(_collinearity_kernel)
    return _KERNEL["k"]


@dataclass(frozen=True, eq=False)
class CollinearitySet:
    """Image measurements of one camera (vectorised collinearity, module docstring).

    rows: global rows, x of measurement k at local row 2k, y at 2k + 1. ipt (m × 3), ieo
    (m × 6): parameter indices of the point and of the image orientation. ap: per AP group of
    the camera (name, parameter indices (q,)). cal: (k1, k2, k3, p1, p2) of the camera.
    """

    rows: np.ndarray
    ipt: np.ndarray
    ieo: np.ndarray
    c: float
    x0: float
    y0: float
    scale: float
    cal: tuple[float, ...]
    ap: tuple[tuple[str, np.ndarray], ...]

    @property
    def angular(self) -> np.ndarray:
        return np.zeros(self.rows.size, dtype=bool)

    def _interior(self, x):
        c, x0, y0 = self.c, self.x0, self.y0
        for name, idx in self.ap:
            if name == "io":
                c, x0, y0 = c + x[idx[0]], x0 + x[idx[1]], y0 + x[idx[2]]
        return c, x0, y0

    def ideal(self, x):
        """Ideal image coordinates x̄, ȳ (m,), the image vector (U, V, W) and the rotation."""
        P = x[self.ipt]
        X0 = x[self.ieo[:, :3]]
        # rotations once per image, then spread over its observations
        ang, inv = self._images()
        a = x[ang]
        R, Rw, Rp, Rk = (M[inv] for M in R_opk_derivatives(a[:, 0], a[:, 1], a[:, 2]))
        d = P - X0
        UVW = np.einsum("mji,mj->mi", R, d)
        c, _, _ = self._interior(x)
        xb = -c * UVW[:, 0] / UVW[:, 2]
        yb = -c * UVW[:, 1] / UVW[:, 2]
        return xb, yb, UVW, d, (R, Rw, Rp, Rk)

    def distortion(self, x, xb, yb):
        """Δx, Δy (m,) and the Jacobian ∂(x, y)/∂(x̄, ȳ) = I + ∂Δ/∂(x̄, ȳ) (m × 2 × 2)."""
        k1, k2, k3, p1, p2 = self.cal
        # the calibrated distortion (distortion.brown: Brown's basis times (k1, k2, k3, p1, p2, 0, 0)
        # without an m × 7 basis per evaluation)
        J = np.empty(xb.shape + (2, 2))
        if k1 == k2 == k3 == p1 == p2 == 0.0:
            dx = dy = np.zeros_like(xb)
            J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1] = 1.0, 0.0, 0.0, 1.0
        else:
            dx, dy, J[:, 0, 0], cross, J[:, 1, 1] = brown(xb, yb, k1, k2, k3, p1, p2)
            J[:, 0, 1] = cross
            J[:, 1, 0] = cross
        s = self.scale
        for name, idx in self.ap:
            if name == "io":
                continue
            a = x[idx]
            Fx, Fy, Fxu, Fxv, Fyu, Fyv = BASES[name](xb / s, yb / s)
            dx = dx + Fx @ a
            dy = dy + Fy @ a
            J[:, 0, 0] += Fxu @ a / s
            J[:, 0, 1] += Fxv @ a / s
            J[:, 1, 0] += Fyu @ a / s
            J[:, 1, 1] += Fyv @ a / s
        return dx, dy, J

    def ap_columns(self, xb, yb, name):
        """∂(x, y)/∂a of one basis group at the ideal coordinates: (m × q, m × q)."""
        Fx, Fy, *_ = BASES[name](xb / self.scale, yb / self.scale)
        return Fx, Fy

    def _images(self):
        img = self.__dict__.get("_img")
        if img is None:
            img = np.unique(self.ieo[:, 3:], axis=0, return_inverse=True)
            img = (img[0], np.asarray(img[1]).ravel())
            self.__dict__["_img"] = img
        return img

    def evaluate(self, x):
        kernel = None if self.ap else _compiled_collinearity()
        if kernel is not None:
            return self._evaluate_compiled(kernel, x)
        return self.evaluate_numpy(x)

    def _evaluate_compiled(self, kernel, x):
        """The same numbers as :meth:`evaluate_numpy` (a camera without APs), compiled."""
        m = self.ipt.shape[0]
        ang, inv = self._images()
        a = x[ang]
        R, Rw, Rp, Rk = (np.ascontiguousarray(M) for M in R_opk_derivatives(a[:, 0], a[:, 1], a[:, 2]))
        f = np.empty(2 * m)
        vx, vy = np.empty((9, m)), np.empty((9, m))
        kernel(self.ipt, self.ieo, inv, np.ascontiguousarray(x, dtype=float), R, Rw, Rp, Rk, float(self.c),
               float(self.x0), float(self.y0), np.asarray(self.cal, dtype=float), f, vx, vy)
        jr, jc = self._pattern()
        return f, jr, jc, np.concatenate([vx.ravel(), vy.ravel()])

    def _pattern(self):
        """Rows and columns of the Jacobian entries of a camera without APs (fixed per set)."""
        pat = self.__dict__.get("_pat")
        if pat is None:
            m = self.ipt.shape[0]
            C = np.stack([self.ipt[:, 0], self.ieo[:, 0], self.ipt[:, 1], self.ieo[:, 1], self.ipt[:, 2],
                          self.ieo[:, 2], self.ieo[:, 3], self.ieo[:, 4], self.ieo[:, 5]], 0)
            lr = np.arange(m)
            pat = (np.concatenate([np.tile(2 * lr, 9), np.tile(2 * lr + 1, 9)]),
                   np.concatenate([C.ravel(), C.ravel()]))
            self.__dict__["_pat"] = pat
        return pat

    def evaluate_numpy(self, x):
        """The reference formulas (vectorised numpy); :meth:`evaluate` compiles the same for a
        camera without APs."""
        m = self.ipt.shape[0]
        xb, yb, UVW, d, (R, Rw, Rp, Rk) = self.ideal(x)
        c, x0, y0 = self._interior(x)
        W = UVW[:, 2]
        dx, dy, J = self.distortion(x, xb, yb)
        f = np.empty(2 * m)
        f[0::2] = x0 + xb + dx
        f[1::2] = y0 + yb + dy
        # ∂(U,V,W)/∂(X,Y,Z) = Rᵀ, ∂/∂X0 = −Rᵀ, ∂/∂angle = (∂R/∂angle)ᵀ d
        dUVW = [np.transpose(R, (0, 2, 1))[:, :, j] for j in range(3)]
        dang = [np.einsum("mji,mj->mi", D, d) for D in (Rw, Rp, Rk)]

        def ideal_derivative(g):
            """∂(x̄, ȳ)/∂θ for ∂(U, V, W)/∂θ = g (m × 3)."""
            gx = (-c * g[:, 0] - xb * g[:, 2]) / W
            gy = (-c * g[:, 1] - yb * g[:, 2]) / W
            return gx, gy

        cols, gxs, gys = [], [], []
        for j in range(3):
            gx, gy = ideal_derivative(dUVW[j])
            cols += [self.ipt[:, j], self.ieo[:, j]]
            gxs += [gx, -gx]
            gys += [gy, -gy]
        for j in range(3):
            gx, gy = ideal_derivative(dang[j])
            cols.append(self.ieo[:, 3 + j])
            gxs.append(gx)
            gys.append(gy)
        for name, idx in self.ap:
            if name == "io":
                # c: ∂(x̄, ȳ)/∂c = (x̄, ȳ)/c; x0, y0: direct shifts
                cols.append(np.full(m, idx[0]))
                gxs.append(xb / c)
                gys.append(yb / c)
        # chain through the distortion: ∂(x, y)/∂θ = J ∂(x̄, ȳ)/∂θ; laid out column by column
        # ((ncol, m): contiguous copies, the CSR conversion sorts the entries anyway)
        GX = np.stack(gxs, 0)
        GY = np.stack(gys, 0)
        vx = J[None, :, 0, 0] * GX + J[None, :, 0, 1] * GY
        vy = J[None, :, 1, 0] * GX + J[None, :, 1, 1] * GY
        C = np.stack(cols, 0)
        extra_c, extra_x, extra_y = [], [], []
        for name, idx in self.ap:
            if name == "io":
                extra_c += [np.full(m, idx[1]), np.full(m, idx[2])]
                extra_x += [np.ones(m), np.zeros(m)]
                extra_y += [np.zeros(m), np.ones(m)]
            else:
                Fx, Fy = self.ap_columns(xb, yb, name)
                for k, i in enumerate(idx):
                    extra_c.append(np.full(m, i))
                    extra_x.append(Fx[:, k])
                    extra_y.append(Fy[:, k])
        if extra_c:
            C = np.vstack([C, np.stack(extra_c, 0)])
            vx = np.vstack([vx, np.stack(extra_x, 0)])
            vy = np.vstack([vy, np.stack(extra_y, 0)])
        ncol = C.shape[0]
        lr = np.arange(m)
        jrows = np.concatenate([np.tile(2 * lr, ncol), np.tile(2 * lr + 1, ncol)])
        jcols = np.concatenate([C.ravel(), C.ravel()])
        jvals = np.concatenate([vx.ravel(), vy.ravel()])
        return f, jrows, jcols, jvals


def project(camera, images, P, ap: dict | None = None) -> np.ndarray:
    """Image coordinates of object points by the collinearity equations (K07; module docstring).

    Applies the collinearity equations, the camera's calibrated distortion (B71) and, optionally, AP
    values. Used by the simulator and the tests.

    Parameters
    ----------
    camera : baarda.model.bundle.Camera
        The camera: c, x0, y0 and distortion in its unit (mm or px).
    images : sequence of baarda.model.bundle.Image
        m images, one per point (X0, Y0, Z0 in metres; ω, φ, κ in radians).
    P : array_like of float
        m × 3 object points, metres.
    ap : dict, optional
        ``{group: values}`` of :data:`AP_GROUPS`, in the camera's unit.

    Returns
    -------
    numpy.ndarray
        m × 2 image coordinates, the camera's unit (mm or pixels).
    """
    P = np.atleast_2d(np.asarray(P, dtype=float))
    m = P.shape[0]
    eo = np.array([[getattr(im, nm) for nm in EO_NAMES] for im in images], dtype=float).reshape(m, 6)
    ap = ap or {}
    groups = tuple(g for g in ap)
    x = np.concatenate([eo.ravel(), P.ravel()] + [np.asarray(ap[g], dtype=float) for g in groups])
    ieo = np.arange(6 * m).reshape(m, 6)
    ipt = 6 * m + np.arange(3 * m).reshape(m, 3)
    pos = 9 * m
    ap_idx = []
    for g in groups:
        q = len(AP_GROUPS[g])
        ap_idx.append((g, np.arange(pos, pos + q)))
        pos += q
    s = CollinearitySet(rows=np.arange(2 * m), ipt=ipt, ieo=ieo, c=camera.c, x0=camera.x0,
                        y0=camera.y0, scale=camera.scale,
                        cal=(camera.k1, camera.k2, camera.k3, camera.p1, camera.p2), ap=tuple(ap_idx))
    f, *_ = s.evaluate(x)
    return f.reshape(m, 2)
