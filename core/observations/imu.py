"""IMU attitudes of images with a boresight rotation (aerial triangulation as it is flown).

The IMU observes the attitude of its own body frame; the camera is mounted with a small fixed
rotation, the boresight R_b. With R(ω, φ, κ) = R_ω R_φ R_κ of an image
(:func:`baarda.observations.rotation.R_opk`, camera → object) the IMU's rotation is

.. math:: R_{IMU} = R(ω, φ, κ)\\, R(b_ω, b_φ, b_κ)

and the observations are its three angles, read off the matrix as R_opk builds it:

.. math:: ω = \\operatorname{atan2}(−R_{23}, R_{33}),\\quad φ = \\arcsin R_{13},\\quad
          κ = \\operatorname{atan2}(−R_{12}, R_{11})

(radians; the misclosures are wrapped to (−π, π]). Their Jacobian follows from
dω = (−R_{33}\\, dR_{23} + R_{23}\\, dR_{33}) / (R_{23}^2 + R_{33}^2),
dφ = dR_{13} / \\sqrt{1 − R_{13}^2}, dκ = (−R_{11}\\, dR_{12} + R_{12}\\, dR_{11}) / (R_{11}^2 + R_{12}^2)
with dR = (∂R/∂θ) R_b for the image's angles θ and R (∂R_b/∂θ_b) for the boresight's.

References (full in the package docstring): F80; Cramer, M., Stallmann, D., Haala, N. (2000),
Direct georeferencing using GPS/inertial exterior orientations for photogrammetric
applications, IAPRS 33(B3), 198-205.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rotation import R_opk_derivatives, opk_from_R


def angles_of(R: np.ndarray) -> np.ndarray:
    """The angles (ω, φ, κ) of rotation matrices built as R = R_ω R_φ R_κ (K07, the IMU's attitude).

    :func:`baarda.observations.rotation.opk_from_R`, stacked.

    Parameters
    ----------
    R : numpy.ndarray
        (..., 3, 3) rotation matrices, dimensionless.

    Returns
    -------
    numpy.ndarray
        (..., 3) angles ω, φ, κ in radians.
    """
    return np.stack(opk_from_R(R), axis=-1)


def angle_derivatives(R: np.ndarray, dR: np.ndarray) -> np.ndarray:
    """The change d(ω, φ, κ) of the angles of R for a change dR of R (the IMU Jacobian's chain rule).

    Parameters
    ----------
    R : numpy.ndarray
        (..., 3, 3) rotation matrices R_ω R_φ R_κ, dimensionless.
    dR : numpy.ndarray
        (..., 3, 3) their changes (derivatives with respect to one unknown).

    Returns
    -------
    numpy.ndarray
        (..., 3) dω, dφ, dκ in radians per unit of that unknown.
    """
    dw = (-R[..., 2, 2] * dR[..., 1, 2] + R[..., 1, 2] * dR[..., 2, 2]) / (R[..., 1, 2] ** 2 + R[..., 2, 2] ** 2)
    dp = dR[..., 0, 2] / np.sqrt(np.maximum(1.0 - R[..., 0, 2] ** 2, 1e-300))
    dk = (-R[..., 0, 0] * dR[..., 0, 1] + R[..., 0, 1] * dR[..., 0, 0]) / (R[..., 0, 1] ** 2 + R[..., 0, 0] ** 2)
    return np.stack([dw, dp, dk], axis=-1)


@dataclass(frozen=True, eq=False)
class ImuSet:
    """IMU attitudes of k images, vectorised (3 rows per image: ω, φ, κ in radians).

    rows (3k,): global rows. ieo (k, 6): parameter indices of X0, Y0, Z0, ω, φ, κ of each image.
    boresight (3,): parameter indices of b_ω, b_φ, b_κ (held fixed unless estimated).
    """

    rows: np.ndarray
    ieo: np.ndarray
    boresight: np.ndarray
    kind: str = "imu"

    @property
    def angular(self):
        return np.ones(self.rows.size, dtype=bool)

    def evaluate(self, x: np.ndarray):
        """(f (3k,), local rows, global columns, values) — the module docstring's model."""
        k = self.ieo.shape[0]
        a = x[self.ieo[:, 3:]]
        b = x[self.boresight]
        R, Rw, Rp, Rk = R_opk_derivatives(a[:, 0], a[:, 1], a[:, 2])
        Rb, Bw, Bp, Bk = R_opk_derivatives(b[0], b[1], b[2])
        M = R @ Rb
        f = angles_of(M)
        base = 3 * np.arange(k)
        rows, cols, vals = [], [], []
        for j, dR in enumerate((Rw @ Rb, Rp @ Rb, Rk @ Rb)):          # the image's angles
            d = angle_derivatives(M, dR)
            for c in range(3):
                rows.append(base + c)
                cols.append(self.ieo[:, 3 + j])
                vals.append(d[:, c])
        for j, dB in enumerate((Bw, Bp, Bk)):                          # the boresight
            d = angle_derivatives(M, R @ dB)
            for c in range(3):
                rows.append(base + c)
                cols.append(np.full(k, self.boresight[j]))
                vals.append(d[:, c])
        return f.ravel(), np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
