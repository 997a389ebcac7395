"""Observation equations of local geodetic networks, and the Problem built from a Network.

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

from ..datum import Datum
from ..errors import InputError
from ..model.network import Network
from ..model.problem import Covariance, ObservationInfo, ParameterList, PointInfo, Problem

AXES = "xyz"
NEEDS = {
    "distance": "xy", "direction": "xy", "angle": "xy", "azimuth": "xy",
    "slope-distance": "xyz", "zenith-angle": "xyz", "height-diff": "z",
    "dx": "x", "dy": "y", "dz": "z", "coordinate-x": "x", "coordinate-y": "y", "coordinate-z": "z",
}


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


def point_axes(net: Network) -> list[str]:
    """The axes each point needs: its declared axes and those its observations use."""
    pindex = net.point_index()
    need = [set() for _ in net.points]
    for o in net.observations:
        for pid in o.points:
            need[pindex[pid]].update(NEEDS[o.kind])
    return ["".join(a for a in AXES if a in s) for s in need]


def build_problem(net: Network, jacobian_at_marks: bool = False) -> Problem:
    """Turn a network into an adjustment problem (parameters, observation sets, datum).

    ``jacobian_at_marks`` reproduces gama-local's linearisation of slope distances and zenith
    angles, whose design matrix leaves out the instrument and target heights (the observation
    equations keep them); baarda's default is the rigorous derivative.

    Coordinates of points with ``fixed`` axes are parameters held fixed; axes that are neither
    fixed, adjusted nor constrained but have a coordinate are held fixed too (known points).
    A point that an observation needs on an axis without any coordinate is an InputError.
    """
    pindex = net.point_index()
    axes_needed = point_axes(net)
    pl = ParameterList()
    index = np.full((len(net.points), 3), -1, dtype=np.int64)
    status = []
    for i, (p, need) in enumerate(zip(net.points, axes_needed)):
        declared = set(p.fixed.lower() + p.adjusted.lower() + p.constrained.lower())
        for a in AXES:
            if a not in need and a not in declared:
                continue
            val = getattr(p, a)
            if val is None:
                raise InputError(net.source, p.line, f"point {p.id} has no {a} coordinate "
                                 "(and none could be computed)", field=a)
            estimated = a in p.adjusted.lower() or a in p.constrained.lower()
            index[i, AXES.index(a)] = pl.add(f"{p.id}.{a}", val, "k", i, AXES.index(a), fixed=not estimated)
        if p.constrained:
            status.append("constrained")
        elif p.adjusted:
            status.append("adjusted")
        else:
            status.append("fixed")
    # orientation unknowns, one per direction set, started at the mean misclosure
    station = {}
    for o in net.observations:
        if o.kind == "direction":
            station.setdefault(o.set_id, o.points[0])
    set_ids = sorted(station)
    ori_index = {}
    for s in set_ids:
        ori_index[s] = pl.add(f"orientation {s} ({station[s]})", 0.0, "t")
    params = pl.parameters()
    n = len(net.observations)

    def pidx(pid, a):
        return index[pindex[pid], AXES.index(a)]

    by_kind: dict[str, list[int]] = {}
    for k, o in enumerate(net.observations):
        by_kind.setdefault(o.kind, []).append(k)
    sets = []
    obs = net.observations
    for kd, rows in by_kind.items():
        rows = np.asarray(rows, dtype=np.int64)
        if kd in ("distance", "direction", "azimuth", "angle"):
            roles = 3 if kd == "angle" else 2
            # point of each role looked up once, then the x and y parameters of all at once
            pts = np.array([[pindex[obs[r].points[j]] for j in range(roles)] for r in rows.tolist()],
                           dtype=np.int64).reshape(rows.size, roles)
            ix = np.zeros((rows.size, 3), dtype=np.int64)
            iy = np.zeros((rows.size, 3), dtype=np.int64)
            ix[:, :roles], iy[:, :roles] = index[pts, 0], index[pts, 1]
            ori = np.array([ori_index.get(obs[r].set_id, -1) for r in rows], dtype=np.int64)
            sets.append(PlanarSet(kd, rows, ix, iy, ori, float(net.angle_sign), float(net.azimuth_offset)))
        elif kd in ("slope-distance", "zenith-angle"):
            idx = np.array([[[pidx(obs[r].points[j], a) for a in AXES] for j in range(2)] for r in rows])
            sets.append(SpatialSet(kd, rows, idx, np.array([obs[r].from_dh for r in rows]),
                                   np.array([obs[r].to_dh for r in rows]), jacobian_at_marks))
        else:
            a = {"height-diff": "z", "dx": "x", "dy": "y", "dz": "z"}.get(kd, kd[-1])
            if kd.startswith("coordinate"):
                i_from = np.full(rows.size, -1, dtype=np.int64)
                i_to = np.array([pidx(obs[r].points[0], a) for r in rows])
            else:
                i_from = np.array([pidx(obs[r].points[0], a) for r in rows])
                i_to = np.array([pidx(obs[r].points[1], a) for r in rows])
            offset = None
            if kd == "dz":
                h = np.array([obs[r].to_dh - obs[r].from_dh for r in rows], dtype=float)
                offset = h if h.any() else None
            sets.append(LinearSet(kd, rows, i_from, i_to, offset))
    l = np.array([o.value for o in obs], dtype=float)
    # initial orientations: circular mean of bearing − direction over each set
    if set_ids:
        _init_orientations(sets, params, l, ori_index)
        for s_id, value in (net.extra.get("orientations") or {}).items():
            if s_id in ori_index:  # <obs orientation>: the file's own starting value
                params.x0[ori_index[s_id]] = value
    cov = Covariance.from_blocks(n, [c.indices for c in net.clusters], [c.cov for c in net.clusters])
    group = _groups(net)
    roles_of = {"angle": ("from", "left", "right")}
    ids = []
    for o in obs:
        if o.kind.startswith("coordinate"):
            ids.append({"id": o.points[0]})
        else:
            ids.append(dict(zip(roles_of.get(o.kind, ("from", "to")), o.points)))
    info = ObservationInfo(
        kind=tuple(o.kind for o in obs), ids=tuple(ids),
        value_file=np.array([o.value_file for o in obs]), unit=tuple(o.unit for o in obs),
        sigma_file=np.array([o.sigma_file for o in obs]), sigma_unit=tuple(o.sigma_unit for o in obs),
        line=np.array([o.line for o in obs]), group=group)
    dim = 3 if (index[:, :2] >= 0).any() and (index[:, 2] >= 0).any() else (2 if (index[:, :2] >= 0).any() else 1)
    constrained = tuple(f"{p.id}.{a}" for p in net.points for a in p.constrained.lower())
    datum = Datum("free", constrained) if constrained else Datum("fixed")
    pts = PointInfo(tuple(p.id for p in net.points), index, tuple(status), dim)
    return Problem(params=params, sets=tuple(sets), l=l, cov=cov, info=info, points=pts,
                   datum=datum, sigma0=net.sigma0, sigma_act=net.sigma_act, conf_pr=net.conf_pr,
                   source=net.source, title=net.description.strip().splitlines()[0] if net.description.strip() else "",
                   axes_xy=net.axes_xy,
                   extra={"tol_abs": net.tol_abs, "angles": net.angles,
                          "dropped_observations": [dict(d) for d in net.extra.get("dropped", ())],
                          "reader_notes": list(net.extra.get("reader_notes", ()))},
                   positions=np.array([[np.nan if p.x is None else p.x, np.nan if p.y is None else p.y]
                                       for p in net.points], dtype=float).reshape(-1, 2))


def _init_orientations(sets, params, l, ori_index):
    x = params.x0
    for s in sets:
        if getattr(s, "kind", "") != "direction":
            continue
        f, *_ = s.evaluate(x)  # bearing − 0
        z = np.exp(1j * (l[s.rows] - f))
        mean = np.zeros(x.size, dtype=complex)
        np.add.at(mean, s.ori, z)
        used = np.unique(s.ori)
        x[used] = -np.angle(mean[used])


def _groups(net: Network) -> np.ndarray:
    """Test-group id per observation: one group per vector (dx, dy, dz) or coordinate triple."""
    group = np.full(len(net.observations), -1, dtype=np.int64)
    keys: dict = {}
    for ci, c in enumerate(net.clusters):
        if not c.group:
            continue
        for i in c.indices:
            o = net.observations[i]
            key = (ci, tuple(o.points), getattr(o, "group_key", None))
            group[i] = keys.setdefault(key, len(keys))
    return group


