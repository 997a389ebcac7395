"""GeoJSON of the analysed points, for GIS: where the network or block is weak.

One ``Point`` feature per point of the problem (RFC 7946 FeatureCollection). Geometry: the
adjusted coordinates [east, north(, height)] in the project's own frame — no CRS is implied
(RFC 7946 says WGS 84; GIS users assign the project's CRS on import). A Gama network's x, y
are turned to east, north by its ``axes-xy``; blocks are written X, Y, Z as they are.

Properties, over the observations that involve the point (a non-zero column of the point's
coordinates in the Jacobian, fixed coordinates included):

- ``r_min``: the smallest redundancy number r_i (F80 eq. 5);
- ``mdb_max``: the largest minimal detectable bias ∇0l_i, in the observation's SI unit;
- ``mdb_max_unit``: that unit; ``delta0bar_max``: the largest external reliability δ̄0,i;
- ``w_max``: the largest |w_i|; ``n_rejected``: how many of them the w-test rejects;
- ``n_obs``, ``status``, ``sx``, ``sy``, ``sz`` (standard deviations of the coordinates).

Infinite values (an uncontrolled observation has r = 0 and MDB = ∞) are written ``null``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from baarda.model.network import east_north_matrix

from .output import write_text
from ..stats.reliability import reliability_of


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _east_north(problem, xyz: np.ndarray) -> np.ndarray:
    if not problem.axes_xy:
        return xyz
    out = xyz.copy()
    out[:, :2] = xyz[:, :2] @ east_north_matrix(problem.axes_xy).T
    return out


def point_observations(problem, x: np.ndarray) -> sp.csc_matrix:
    """Incidence (n × m points): True where observation i involves a coordinate of point k."""
    _, J = problem.evaluate(x)
    idx = problem.points.index
    k, a = np.nonzero(idx >= 0)
    cols = idx[k, a]
    S = sp.csr_matrix((np.ones(cols.size), (cols, k)), shape=(problem.params.size, len(problem.points.ids)))
    M = (abs(J) @ S).tocsc()
    M.data[:] = 1.0
    M.eliminate_zeros()
    return M


def features(adj) -> list[dict]:
    """The GeoJSON features of ``adj``'s points (module docstring)."""
    problem = adj.problem
    pts = problem.points
    M = point_observations(problem, adj.x)
    xyz = np.nan_to_num(adj.coordinates)
    en = _east_north(problem, xyz)
    sig = adj.point_sigma
    rel = reliability_of(adj)
    r, mdb, ext, w, rej = adj.r, rel.mdb, rel.external, np.abs(adj.w), rel.rejected
    units = problem.info.unit
    out = []
    for k, pid in enumerate(pts.ids):
        rows = M.indices[M.indptr[k]:M.indptr[k + 1]]
        has = pts.index[k] >= 0
        coords = [float(en[k, 0]), float(en[k, 1])] + ([float(en[k, 2])] if pts.dim == 3 or has[2] else [])
        props = {"id": pid, "status": pts.status[k], "n_obs": int(rows.size)}
        for a, nm in enumerate(("sx", "sy", "sz")):
            if has[a]:
                props[nm] = _num(sig[k, a])
        if rows.size:
            j = rows[np.argmax(np.where(np.isfinite(mdb[rows]), mdb[rows], np.inf))]
            props.update({"r_min": _num(np.min(r[rows])), "mdb_max": _num(mdb[j]), "mdb_max_unit": units[j],
                          "delta0bar_max": _num(np.max(ext[rows])),
                          "w_max": _num(np.nanmax(w[rows])) if np.isfinite(w[rows]).any() else None,
                          "n_rejected": int(rej[rows].sum())})
        out.append({"type": "Feature", "id": pid, "geometry": {"type": "Point", "coordinates": coords},
                    "properties": props})
    return out


def write_geojson(adj, path) -> None:
    """Write the points of an adjustment as a GeoJSON FeatureCollection (module docstring)."""
    doc = {"type": "FeatureCollection",
           "name": adj.problem.title or Path(adj.problem.source).name,
           "features": features(adj)}
    write_text(path, json.dumps(doc, indent=1, allow_nan=False))
