"""GNSS observations of projection centres (aerial triangulation as it is flown).

The antenna phase centre of image i, observed by GNSS (RTK or PPK), is

.. math:: X_{GNSS,i} = X_{0,i} + R(ω_i, φ_i, κ_i)\\, e + a_s + b_s (t_i − t_{0,s})

with X0 the projection centre, R the image's rotation (camera → object,
:func:`baarda.observations.rotation.R_opk`), e the lever arm from the projection centre to the
antenna in the camera frame (given, or estimated for the whole block), and per strip s an
optional shift a_s and drift b_s (the kinematic GPS model of PATB and MATCH-AT; Ackermann's
"GPS-supported aerial triangulation"); t0_s is the mean time of the strip. Three rows per centre
(X, Y, Z, metres), one 3 × 3 covariance cluster and one test group per centre, so that the group
test of a centre is the 3-D test of F80 eq. 10-12 and a strip's shift and drift are groups of
additional parameters tested as in F80 §7.2 (:func:`baarda.stats.ap_tests.ap_test`).

The Jacobian, all entries of one centre's row a:

- ∂/∂X0 = I (columns X0, Y0, Z0);
- ∂/∂ω = (∂R/∂ω) e, likewise φ, κ (:func:`baarda.observations.rotation.R_opk_derivatives`);
- ∂/∂e = R; ∂/∂a_s = I; ∂/∂b_s = (t − t0_s) I.

References (full in the package docstring): F80; M84 (auxiliary data as an element of block
design); Ackermann, F. (1992), Operational rules and accuracy models for GPS-aerotriangulation,
IAPRS 29(B3), 691-700.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rotation import R_opk_derivatives


@dataclass(frozen=True, eq=False)
class GnssSet:
    """GNSS observations of k projection centres, vectorised (3 rows per centre, X, Y, Z).

    rows (3k,): global rows, centre j's X, Y, Z at 3j, 3j + 1, 3j + 2. ieo (k, 6): parameter
    indices of X0, Y0, Z0, ω, φ, κ of each centre's image. lever (3,): parameter indices of the
    lever arm e (held fixed unless estimated). shift, drift (k, 3): parameter indices of the
    strip's a_s and b_s, -1 where not modelled. dt (k,): t − t0_s (the drift's time unit).
    """

    rows: np.ndarray
    ieo: np.ndarray
    lever: np.ndarray
    shift: np.ndarray
    drift: np.ndarray
    dt: np.ndarray
    kind: str = "gnss"

    @property
    def angular(self):
        return np.zeros(self.rows.size, dtype=bool)

    def evaluate(self, x: np.ndarray):
        """(f (3k,), local rows, global columns, values) — the module docstring's model."""
        k = self.ieo.shape[0]
        eo = x[self.ieo]
        e = x[self.lever]
        R, Rw, Rp, Rk = R_opk_derivatives(eo[:, 3], eo[:, 4], eo[:, 5])
        f = eo[:, :3] + R @ e
        has_shift, has_drift = self.shift[:, 0] >= 0, self.drift[:, 0] >= 0
        if has_shift.any():
            f[has_shift] += x[self.shift[has_shift]]
        if has_drift.any():
            f[has_drift] += x[self.drift[has_drift]] * self.dt[has_drift, None]
        base = 3 * np.arange(k)
        rows, cols, vals = [], [], []
        for a in range(3):                       # row a of every centre
            r = base + a
            rows.append(r)                       # ∂/∂X0_a = 1
            cols.append(self.ieo[:, a])
            vals.append(np.ones(k))
            for j, dR in enumerate((Rw, Rp, Rk)):    # ∂/∂(ω, φ, κ) = (∂R) e
                rows.append(r)
                cols.append(self.ieo[:, 3 + j])
                vals.append(dR[:, a, :] @ e)
            for c in range(3):                   # ∂/∂e_c = R[a, c]
                rows.append(r)
                cols.append(np.full(k, self.lever[c]))
                vals.append(R[:, a, c])
            if has_shift.any():
                rows.append(r[has_shift])
                cols.append(self.shift[has_shift, a])
                vals.append(np.ones(int(has_shift.sum())))
            if has_drift.any():
                rows.append(r[has_drift])
                cols.append(self.drift[has_drift, a])
                vals.append(self.dt[has_drift].astype(float))
        return f.ravel(), np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
