"""The adjustment problem of a local geodetic network (:class:`baarda.model.network.Network`),
built from the observation equations of :mod:`baarda.observations.geodetic`: parameters (the
points' adjusted axes, one orientation per direction set), observation sets, covariance and
datum.
"""

from __future__ import annotations

import numpy as np

from ..datum import Datum
from ..errors import InputError
from ..observations.geodetic import LinearSet, PlanarSet, SpatialSet
from .network import Network
from .problem import Covariance, ObservationInfo, ParameterList, PointInfo, Problem, ProblemNotes

AXES = "xyz"
NEEDS = {
    "distance": "xy", "direction": "xy", "angle": "xy", "azimuth": "xy",
    "slope-distance": "xyz", "zenith-angle": "xyz", "height-diff": "z",
    "dx": "x", "dy": "y", "dz": "z", "coordinate-x": "x", "coordinate-y": "y", "coordinate-z": "z",
}



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
                   notes=ProblemNotes(tol_abs=net.tol_abs, angles=net.angles,
                                      dropped_observations=tuple(dict(d) for d in net.extra.get("dropped", ())),
                                      reader_notes=tuple(net.extra.get("reader_notes", ()))),
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


