"""Rotation matrices of exterior orientation: ω-φ-κ angles, Rodrigues vectors, quaternions.

Convention (the aerial one, e.g. Kraus, *Photogrammetry* vol. 1, and PAT-B):

.. math::

    R = R_ω R_φ R_κ,\\quad
    R_ω = \\begin{pmatrix}1&0&0\\\\0&\\cos ω&-\\sin ω\\\\0&\\sin ω&\\cos ω\\end{pmatrix},\\;
    R_φ = \\begin{pmatrix}\\cos φ&0&\\sin φ\\\\0&1&0\\\\-\\sin φ&0&\\cos φ\\end{pmatrix},\\;
    R_κ = \\begin{pmatrix}\\cos κ&-\\sin κ&0\\\\\\sin κ&\\cos κ&0\\\\0&0&1\\end{pmatrix}.

R turns image-space vectors into object space: X − X0 = λ R (x − x0, y − y0, −c)ᵀ; its
transpose turns object vectors into the image frame (see :mod:`baarda.model.bundle`). ω rotates about
the (fixed) object X axis, φ about the once-rotated Y axis, κ about the image z axis. Angles in
radians. All functions are vectorised: angle arrays of shape (...) give matrices (..., 3, 3).

Other conventions, for readers of other formats:

- Rodrigues / angle-axis vector ρ (Bundle Adjustment in the Large, BAL): R = exp([ρ]×), the
  rotation by |ρ| about ρ/|ρ|. BAL's R maps world to camera, i.e. it is the *transpose* of the
  R above up to BAL's axis flips; the readers that use these helpers say so.
- Unit quaternion q = (w, x, y, z), scalar first (COLMAP's ``qvec``; COLMAP's R maps world to
  camera as well).
"""

from __future__ import annotations

import numpy as np


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _drx(a):
    c, s = np.cos(a), np.sin(a)
    z = np.zeros_like(a)
    return np.stack([np.stack([z, z, z], -1), np.stack([z, -s, -c], -1), np.stack([z, c, -s], -1)], -2)


def _dry(a):
    c, s = np.cos(a), np.sin(a)
    z = np.zeros_like(a)
    return np.stack([np.stack([-s, z, c], -1), np.stack([z, z, z], -1), np.stack([-c, z, -s], -1)], -2)


def _drz(a):
    c, s = np.cos(a), np.sin(a)
    z = np.zeros_like(a)
    return np.stack([np.stack([-s, -c, z], -1), np.stack([c, -s, z], -1), np.stack([z, z, z], -1)], -2)


def R_opk(omega, phi, kappa) -> np.ndarray:
    """R = R_ω R_φ R_κ of the aerial ω-φ-κ convention (K07; module docstring).

    Parameters
    ----------
    omega, phi, kappa : array_like of float
        Angles (...), radians.

    Returns
    -------
    numpy.ndarray
        (..., 3, 3) rotation matrices, dimensionless.
    """
    omega, phi, kappa = (np.asarray(a, dtype=float) for a in (omega, phi, kappa))
    return _rx(omega) @ _ry(phi) @ _rz(kappa)


def R_opk_derivatives(omega, phi, kappa) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """R = R_ω R_φ R_κ and its partial derivatives ∂R/∂ω, ∂R/∂φ, ∂R/∂κ (K07; module docstring).

    Parameters
    ----------
    omega, phi, kappa : array_like of float
        Angles (...), radians.

    Returns
    -------
    R : numpy.ndarray
        (..., 3, 3), dimensionless.
    dR_domega : numpy.ndarray
        ∂R/∂ω (..., 3, 3), per radian.
    dR_dphi : numpy.ndarray
        ∂R/∂φ (..., 3, 3), per radian.
    dR_dkappa : numpy.ndarray
        ∂R/∂κ (..., 3, 3), per radian.
    """
    omega, phi, kappa = (np.asarray(a, dtype=float) for a in (omega, phi, kappa))
    Rw, Rp, Rk = _rx(omega), _ry(phi), _rz(kappa)
    return (Rw @ Rp @ Rk, _drx(omega) @ Rp @ Rk, Rw @ _dry(phi) @ Rk, Rw @ Rp @ _drz(kappa))


def opk_from_R(R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ω, φ, κ of R = R_ω R_φ R_κ, φ in [−π/2, π/2] (K07; module docstring).

    From r13 = sin φ, r23 = −sin ω cos φ, r33 = cos ω cos φ, r12 = −cos φ sin κ,
    r11 = cos φ cos κ.

    Parameters
    ----------
    R : array_like of float
        (..., 3, 3) rotation matrices.

    Returns
    -------
    omega : numpy.ndarray
        ω (...), radians.
    phi : numpy.ndarray
        φ (...), radians, in [−π/2, π/2].
    kappa : numpy.ndarray
        κ (...), radians.
    """
    R = np.asarray(R, dtype=float)
    phi = np.arcsin(np.clip(R[..., 0, 2], -1.0, 1.0))
    omega = np.arctan2(-R[..., 1, 2], R[..., 2, 2])
    kappa = np.arctan2(-R[..., 0, 1], R[..., 0, 0])
    return omega, phi, kappa


def R_from_rodrigues(rho) -> np.ndarray:
    """Rotation matrix exp([ρ]×) of Rodrigues (angle-axis) vectors ρ (BAL10; C11).

    R = I + sin θ [k]× + (1 − cos θ) [k]×², θ = |ρ|, k = ρ/θ (Rodrigues' formula); a series is
    used for θ < 1e-8.

    Parameters
    ----------
    rho : array_like of float
        (..., 3) vectors, radians (the rotation angle is |ρ|).

    Returns
    -------
    numpy.ndarray
        (..., 3, 3) rotation matrices, dimensionless.
    """
    rho = np.asarray(rho, dtype=float)
    theta = np.linalg.norm(rho, axis=-1)
    small = theta < 1e-8
    th = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta ** 2 / 6.0, np.sin(th) / th)
    b = np.where(small, 0.5 - theta ** 2 / 24.0, (1.0 - np.cos(th)) / th ** 2)
    K = skew(rho)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def rodrigues_from_R(R) -> np.ndarray:
    """Rodrigues vector ρ of rotation matrices (the log map of SO(3); C11), θ = |ρ| ∈ [0, π].

    Parameters
    ----------
    R : array_like of float
        (..., 3, 3) rotation matrices.

    Returns
    -------
    numpy.ndarray
        (..., 3) vectors ρ, radians.
    """
    R = np.asarray(R, dtype=float)
    return _axis_angle_from_quaternion(quaternion_from_R(R))


def R_from_quaternion(q) -> np.ndarray:
    """Rotation matrix of unit quaternions q = (w, x, y, z), scalar first (COLMAP, SF16).

    q is normalised first; q and −q give the same matrix.

    Parameters
    ----------
    q : array_like of float
        (..., 4) quaternions, dimensionless.

    Returns
    -------
    numpy.ndarray
        (..., 3, 3) rotation matrices, dimensionless.
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def quaternion_from_R(R) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w ≥ 0 of rotation matrices (Shepperd's method; SF16's order).

    Parameters
    ----------
    R : array_like of float
        (..., 3, 3) rotation matrices.

    Returns
    -------
    numpy.ndarray
        (..., 4) quaternions, scalar first, dimensionless.
    """
    R = np.asarray(R, dtype=float)
    shape = R.shape[:-2]
    Rf = R.reshape(-1, 3, 3)
    out = np.empty((Rf.shape[0], 4))
    tr = np.trace(Rf, axis1=1, axis2=2)
    diag = np.diagonal(Rf, axis1=1, axis2=2)
    choice = np.argmax(np.column_stack([tr, diag]), axis=1)
    for k, M in enumerate(Rf):
        c = choice[k]
        if c == 0:
            s = 2.0 * np.sqrt(1.0 + tr[k])
            q = [0.25 * s, (M[2, 1] - M[1, 2]) / s, (M[0, 2] - M[2, 0]) / s, (M[1, 0] - M[0, 1]) / s]
        else:
            i = c - 1
            j, l = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * np.sqrt(max(1.0 + M[i, i] - M[j, j] - M[l, l], 0.0))
            q = [0.0] * 4
            q[0] = (M[l, j] - M[j, l]) / s
            q[1 + i] = 0.25 * s
            q[1 + j] = (M[j, i] + M[i, j]) / s
            q[1 + l] = (M[l, i] + M[i, l]) / s
        out[k] = q
    out *= np.where(out[:, :1] < 0, -1.0, 1.0)
    return out.reshape(shape + (4,))


def _axis_angle_from_quaternion(q):
    q = np.asarray(q, dtype=float)
    w = np.clip(q[..., 0], -1.0, 1.0)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    theta = 2.0 * np.arctan2(s, w)
    scale = np.where(s < 1e-12, 2.0, theta / np.where(s < 1e-12, 1.0, s))
    return v * scale[..., None]


def skew(v):
    """The cross-product matrix [v]× of vectors v, [v]× a = v × a (C11).

    Parameters
    ----------
    v : array_like of float
        (..., 3) vectors, any unit.

    Returns
    -------
    numpy.ndarray
        (..., 3, 3) skew-symmetric matrices, same units as ``v``.
    """
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)
