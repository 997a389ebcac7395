"""Observation equations of local geodetic networks (the Problem of a Network is built from them by
:func:`baarda.model.network_problem.build_problem`).

All equations are vectorised over the observations of one kind and return their Jacobian in
COO form (see :class:`baarda.model.problem.ObservationSet`). Angle conventions are those of
:mod:`baarda.model.network`: bearing(i→j) = s·atan2(Δy, Δx) + c with the network's ``angle_sign`` s
and ``azimuth_offset`` c.

- distance (horizontal) d = √(Δx² + Δy²)
- direction  d = bearing − o (one orientation unknown o per set)
- angle      a = bearing(from→right) − bearing(from→left)
- azimuth    a = bearing
- slope distance s = √(Δx² + Δy² + Δz'²), Δz' = (z_to + h_to) − (z_from + h_from)
- zenith angle   z = atan2(√(Δx² + Δy²), Δz')
- height difference Δz; coordinate observations x, y or z.
- vector components Δx, Δy and Δz' = Δz + h_to − h_from: a vector joins the instrument
  (antenna) positions, ``from_dh``/``to_dh`` above the marks. (gama-local reads these
  heights but leaves them out of its vector equations; baarda applies them.)

Instrument and target heights have no effect on horizontal distances, directions, angles and
azimuths (they are horizontal quantities). ``<obs orientation>`` only starts the iteration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _coo(n, cols_list, vals_list):
    """Stack per-role columns/derivatives (each (n,)) into COO triplets."""
    rows = np.tile(np.arange(n), len(cols_list))
    return rows, np.concatenate(cols_list), np.concatenate(vals_list)


@dataclass(frozen=True, eq=False)
class PlanarSet:
    """distance, direction, angle or azimuth observations (vectorised)."""

    kind: str
    rows: np.ndarray
    ix: np.ndarray        # (n, 3): x index of from, to, right (angles: from, left, right)
    iy: np.ndarray
    ori: np.ndarray       # orientation parameter index (directions) or -1
    sign: float
    offset: float

    @property
    def angular(self):
        return np.full(self.rows.size, self.kind != "distance")

    def _bearing(self, x, a, b):
        dx = x[self.ix[:, b]] - x[self.ix[:, a]]
        dy = x[self.iy[:, b]] - x[self.iy[:, a]]
        d2 = dx * dx + dy * dy
        t = self.sign * np.arctan2(dy, dx) + self.offset
        # derivatives with respect to the 'b' point (the 'a' point gets the negatives)
        return t, dx, dy, d2

    def evaluate(self, x):
        """Values and Jacobian at ``x``. Points at one place make a distance or a direction
        undefined: NaN there, without a warning (the caller names the observation,
        ``baarda.validate._check_defined``)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self._values(x)

    def _values(self, x):
        n = self.rows.size
        if self.kind == "distance":
            dx = x[self.ix[:, 1]] - x[self.ix[:, 0]]
            dy = x[self.iy[:, 1]] - x[self.iy[:, 0]]
            d = np.hypot(dx, dy)
            gx, gy = dx / d, dy / d
            return d, *_coo(n, [self.ix[:, 1], self.iy[:, 1], self.ix[:, 0], self.iy[:, 0]],
                            [gx, gy, -gx, -gy])
        if self.kind in ("direction", "azimuth"):
            t, dx, dy, d2 = self._bearing(x, 0, 1)
            gx, gy = -self.sign * dy / d2, self.sign * dx / d2
            cols = [self.ix[:, 1], self.iy[:, 1], self.ix[:, 0], self.iy[:, 0]]
            vals = [gx, gy, -gx, -gy]
            if self.kind == "direction":
                t = t - x[self.ori]
                cols.append(self.ori)
                vals.append(-np.ones(n))
            return np.mod(t, 2 * np.pi), *_coo(n, cols, vals)
        # angle: from = 0, left = 1, right = 2
        tl, dxl, dyl, dl2 = self._bearing(x, 0, 1)
        tr, dxr, dyr, dr2 = self._bearing(x, 0, 2)
        gxl, gyl = -self.sign * dyl / dl2, self.sign * dxl / dl2
        gxr, gyr = -self.sign * dyr / dr2, self.sign * dxr / dr2
        cols = [self.ix[:, 2], self.iy[:, 2], self.ix[:, 1], self.iy[:, 1], self.ix[:, 0], self.iy[:, 0]]
        vals = [gxr, gyr, -gxl, -gyl, gxl - gxr, gyl - gyr]
        return np.mod(tr - tl, 2 * np.pi), *_coo(n, cols, vals)


@dataclass(frozen=True, eq=False)
class SpatialSet:
    """slope distances and zenith angles with instrument/target heights (vectorised)."""

    kind: str
    rows: np.ndarray
    idx: np.ndarray       # (n, 2, 3): parameter index of (from, to) × (x, y, z)
    hf: np.ndarray
    ht: np.ndarray
    jacobian_at_marks: bool = False

    @property
    def angular(self):
        return np.full(self.rows.size, self.kind == "zenith-angle")

    def evaluate(self, x):
        f, r, c, v = self._evaluate(x, self.hf, self.ht)
        if self.jacobian_at_marks and (self.hf.any() or self.ht.any()):
            # gama-local's linearisation: derivatives at the marks, heights left out
            _, r, c, v = self._evaluate(x, 0.0 * self.hf, 0.0 * self.ht)
        return f, r, c, v

    def _evaluate(self, x, hf, ht):
        n = self.rows.size
        dx = x[self.idx[:, 1, 0]] - x[self.idx[:, 0, 0]]
        dy = x[self.idx[:, 1, 1]] - x[self.idx[:, 0, 1]]
        dz = x[self.idx[:, 1, 2]] + ht - x[self.idx[:, 0, 2]] - hf
        cols = [self.idx[:, 1, 0], self.idx[:, 1, 1], self.idx[:, 1, 2],
                self.idx[:, 0, 0], self.idx[:, 0, 1], self.idx[:, 0, 2]]
        if self.kind == "slope-distance":
            s = np.sqrt(dx * dx + dy * dy + dz * dz)
            g = [dx / s, dy / s, dz / s]
            return s, *_coo(n, cols, g + [-gi for gi in g])
        h = np.hypot(dx, dy)
        s2 = h * h + dz * dz
        z = np.arctan2(h, dz)
        gh = dz / s2
        g = [gh * dx / h, gh * dy / h, -h / s2]
        return z, *_coo(n, cols, g + [-gi for gi in g])


@dataclass(frozen=True, eq=False)
class LinearSet:
    """Coordinate differences (height differences, vector components) and coordinates."""

    kind: str
    rows: np.ndarray
    i_from: np.ndarray    # parameter index, -1 for coordinate observations
    i_to: np.ndarray
    offset: np.ndarray | None = None  # h_to − h_from of Δz vector components, else None

    @property
    def angular(self):
        return np.zeros(self.rows.size, dtype=bool)

    def evaluate(self, x):
        n = self.rows.size
        if (self.i_from < 0).all():
            return x[self.i_to].copy(), np.arange(n), self.i_to.copy(), np.ones(n)
        f = x[self.i_to] - x[self.i_from]
        if self.offset is not None:
            f = f + self.offset
        return f, *_coo(n, [self.i_to, self.i_from], [np.ones(n), -np.ones(n)])
