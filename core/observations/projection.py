"""The projective camera of structure-from-motion blocks (BAL, Bundler, COLMAP).

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

The Jacobian is analytic. For the rotation, ∂(R X)/∂ρ = −R [X]× J_r(ρ) with the right Jacobian
of SO(3), J_r(ρ) = I − (1 − cos θ)/θ² [ρ]× + (θ − sin θ)/θ³ [ρ]×², θ = |ρ| (e.g. Chirikjian
2011, eq. 10.86; a series is used for θ < 1e-4).

:class:`ProjectionSet` evaluates f and the Jacobian of every image point of a block (numpy,
:meth:`ProjectionSet.evaluate_numpy`; compiled by numba where installed, same numbers).

References (full in the package docstring): BAL10; S06 (Bundler); SF16 (COLMAP); B00 (OpenCV);
C11 (J_r of SO(3)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..solve.compiled import njit
from .distortion import brown
from .fixed_models import MAX_COEFFICIENTS, compiled_distortion, fixed_distortion, fixed_distortion_scalar
from .rotation import R_from_rodrigues, skew

#: The eight intrinsics of the projective camera, in the order of :attr:`ProjectionSet.iint`.
INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")


def right_jacobian(rho: np.ndarray) -> np.ndarray:
    """The right Jacobian J_r(ρ) of SO(3) for Rodrigues vectors ρ (C11 eq. 10.86; module docstring).

    J_r(ρ) = I − (1 − cos θ)/θ² [ρ]× + (θ − sin θ)/θ³ [ρ]×², θ = |ρ|; a series for θ < 1e-4.

    Parameters
    ----------
    rho : numpy.ndarray
        k × 3 Rodrigues vectors, radians.

    Returns
    -------
    numpy.ndarray
        k × 3 × 3 matrices, dimensionless.
    """
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
    sign: s of the module docstring. Cameras of the models of :mod:`baarda.observations.fixed_models`
    (distortion held): ``dtab`` (cameras × 13) their model code (0: the OPENCV family above) and
    the parameter indices of their coefficients (−1: none), ``dcam`` (m,) each point's row of
    dtab; both None when every camera is of the OPENCV family.
    """

    rows: np.ndarray
    ipt: np.ndarray
    irot: np.ndarray
    itr: np.ndarray
    iint: np.ndarray
    sign: float
    dcam: np.ndarray | None = None
    dtab: np.ndarray | None = None

    def _fixed(self):
        """(dcam, dtab) for the kernel: empty arrays when no camera has a held-distortion model."""
        if self.dcam is None:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 1 + MAX_COEFFICIENTS), dtype=np.int64)
        return self.dcam, self.dtab

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
            return self.evaluate_numpy(x)
        m = self.ipt.shape[0]
        jr, jc, start = self._pattern()
        f = np.empty(2 * m)
        jv = np.empty(jr.size)
        kernel(np.ascontiguousarray(x, dtype=float), self.ipt, self.irot, self.itr, self.iint,
               float(self.sign), *self._fixed(), start, start[:0, 0], f, jv)
        return f, jr, jc, jv

    def values(self, x):
        """f(x) alone (a trial point's; no Jacobian values stored)."""
        kernel = _compiled_projection()
        if kernel is None:
            return self.evaluate_numpy(x)[0]
        start = self._starts()
        f = np.empty(2 * self.ipt.shape[0])
        kernel(np.ascontiguousarray(x, dtype=float), self.ipt, self.irot, self.itr, self.iint,
               float(self.sign), *self._fixed(), start, start[:0, 0], f, np.empty(0))
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
            f, _, _, jv = self.evaluate_numpy(x)
            out[dest] = jv
            return f
        start = self._starts()
        f = np.empty(2 * self.ipt.shape[0])
        kernel(np.ascontiguousarray(x, dtype=float), self.ipt, self.irot, self.itr, self.iint,
               float(self.sign), *self._fixed(), start, dest, f, out)
        return f

    #: the Jacobian pattern is a function of the (frozen) index arrays alone: once the design
    #: matrix's layout is known, :class:`baarda.adjust.Linearisation` needs neither the rows and
    #: columns of the entries nor a comparison with them (:meth:`release_entries`)
    pattern_fixed = True

    @property
    def pattern_held(self) -> bool:
        """Whether the Jacobian pattern is held (made by the first evaluation, kept for the whole
        adjustment; :meth:`release` lets it go)."""
        return "_pat" in self.__dict__

    def _pattern(self):
        """Rows and columns of the Jacobian entries (fixed per set; the order of
        :meth:`evaluate_numpy`) and the place of the first value of each row among them
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
            self.__dict__["_start"] = start
        return pat

    def _starts(self):
        """The place of the first value of each row (:meth:`_pattern`'s third array), kept after
        :meth:`release_entries`."""
        start = self.__dict__.get("_start")
        return self._pattern()[2] if start is None else start

    def release_entries(self) -> None:
        """Forget the rows and columns of the Jacobian entries (int32, two per entry), keep each
        row's start (what :meth:`values` and :meth:`evaluate_into` need); :meth:`evaluate` and
        :meth:`pattern` make them again (the same arrays)."""
        self.__dict__.pop("_pat", None)

    def release(self) -> None:
        """Forget the cached Jacobian pattern (made again by the next :meth:`evaluate`)."""
        self.__dict__.pop("_pat", None)
        self.__dict__.pop("_start", None)

    def evaluate_numpy(self, x):
        """The reference formulas (vectorised numpy); :meth:`evaluate` compiles the same."""
        m = self.ipt.shape[0]
        P, R, X = self.camera_frame(x)
        xe = np.append(x, 0.0)
        fx, fy, cx, cy, k1, k2, p1, p2 = (xe[self.iint[:, j]] for j in range(8))
        s = self.sign
        u, v = s * P[:, 0] / P[:, 2], s * P[:, 1] / P[:, 2]
        r2 = u * u + v * v
        # ∂(u_d, v_d)/∂(u, v): duu, duv = dvu, dvv (OpenCV's p1, p2 are Brown's p2, p1)
        dx, dy, duu, duv, dvv = brown(u, v, k1, k2, 0.0, p2, p1)
        ud, vd, dvu = u + dx, v + dy, duv
        if self.dcam is not None:          # the held-distortion models (fixed_models)
            ud, vd, duu, duv, dvu, dvv = (np.array(a, dtype=float, copy=True) for a in (ud, vd, duu, duv, dvu, dvv))
            code = self.dtab[self.dcam, 0]
            for c in np.unique(self.dcam[code > 0]):
                on = self.dcam == c
                d = np.array([xe[j] for j in self.dtab[c, 1:]])
                ud[on], vd[on], duu[on], duv[on], dvu[on], dvv[on] = fixed_distortion(int(self.dtab[c, 0]), d, u[on], v[on])
        f = np.empty(2 * m)
        f[0::2] = fx * ud + cx
        f[1::2] = fy * vd + cy
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


def _projection_kernel(x, ipt, irot, itr, iint, s, dcam, dtab, start, dest, f, jv):
    """f and the Jacobian values of every image point: the formulas of
    :meth:`ProjectionSet.evaluate_numpy`, one observation at a time (compiled by numba).
    The values of row r (x, y) of point i (17: point, t, ρ, the eight intrinsics) go to
    jv[start[r, i]:] in column order (to jv[dest[k]] for entry k when dest is given; none
    when jv is empty), those of absent intrinsics and the structural zeros
    (:data:`_STRUCTURAL_ZERO`) left out. dcam, dtab: :class:`ProjectionSet`'s (empty: none)."""
    store, direct = jv.size > 0, dest.size == 0
    held = dcam.size > 0
    dp = np.zeros(dtab.shape[1] - 1)
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
        code = dtab[dcam[i], 0] if held else 0
        if code == 0:
            dx, dy, duu, duv, dvv = _brown(u, v, k1, k2, 0.0, p2, p1)
            ud, vd, dvu = u + dx, v + dy, duv
        else:
            for j in range(dp.size):
                dp[j] = x[dtab[dcam[i], 1 + j]] if dtab[dcam[i], 1 + j] >= 0 else 0.0
            ud, vd, duu, duv, dvu, dvv = _fixed_scalar(code, dp, u, v)
        f[2 * i] = fx * ud + cx
        f[2 * i + 1] = fy * vd + cy
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
_brown = brown                   # compiled in place by _compiled_projection
_fixed_scalar = fixed_distortion_scalar


def _compiled_projection():
    """:func:`_projection_kernel` compiled by numba (None without it)."""
    if "p" not in _KERNEL:
        jit = njit(cache=True)
        if jit is None:
            return None
        global _mat3, _brown, _fixed_scalar   # the kernel calls the compiled product and distortions
        _mat3 = njit(cache=True, inline="always")(_mat3)
        _brown = njit(cache=True, inline="always")(brown)
        _fixed_scalar = compiled_distortion()
        _KERNEL["p"] = jit(_projection_kernel)
    return _KERNEL["p"]
