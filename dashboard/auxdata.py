"""GNSS projection centres, IMU attitudes and check points in the dashboard (issue 28, item 6).

The tables the maps, the analysis panel, the downloads and the report show of a block's
auxiliary data, made from the core's results (nothing is computed here that the core does not
give): per GNSS centre its residuals v and w per axis and the 3-D test of the centre (the test
group of its three observations, F80 eq. 10-12, :attr:`baarda.stats.reliability.Reliability.groups`);
per check point its difference adjusted − known (:meth:`baarda.analysis.Analysis.check_points`)
with the RMSE per axis; per image the precision of its projection centre
(:func:`baarda.stats.pose.pose_covariance`). The residual vectors on the maps are exaggerated by a round factor so
that the largest is a few per cent of the map (:func:`vectors`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from baarda.errors import BaardaError
from baarda.stats import pose

from .geometry import display_matrix, object_unit
from .jobs import shared
from .mapgeometry import extent, round_scale
from .text import plain

#: The largest residual vector on a map, as a fraction of the map's extent.
VECTOR_FRACTION = 0.08

GNSS_COLUMNS = ["image", "strip", "x", "y", "z", "vx", "vy", "vz", "wx", "wy", "wz", "T", "critical", "rejected",
                "excluded"]
CHECK_COLUMNS = ["id", "dX", "dY", "dZ", "sX", "sY", "sZ"]


def has_gnss(problem) -> bool:
    """Whether ``problem`` has GNSS observations of projection centres (kinds ``gnss-x|y|z``)."""
    return problem is not None and any(str(k).startswith("gnss-") for k in problem.info.kind)


def has_imu(problem) -> bool:
    """Whether ``problem`` has IMU attitude observations (kinds ``imu-omega|phi|kappa``)."""
    return problem is not None and any(str(k).startswith("imu-") for k in problem.info.kind)


def gnss_centres(state) -> pd.DataFrame:
    """One row per GNSS centre of ``state``'s problem (:data:`GNSS_COLUMNS`): the image and strip,
    the observed antenna position x, y, z (m, the block's frame), the residuals vx, vy, vz (m)
    and wx, wy, wz (the core's v and w; NaN where excluded), and the 3-D test of the centre (its
    observation group): T, critical value, rejected. Empty without GNSS observations."""
    if state.results is None or not has_gnss(state.problem):
        return pd.DataFrame(columns=GNSS_COLUMNS)
    return shared(state.results, ("gnss-centres", state.reliability.policy), lambda: _centres(state))


def _centres(state) -> pd.DataFrame:
    p, adj, rel = state.problem, state.results, state.reliability
    kinds, ids = p.info.kind, p.info.ids
    rows: dict = {}
    for i, k in enumerate(kinds):
        if str(k).startswith("gnss-"):
            im = str(ids[i].get("image"))
            rows.setdefault(im, {})[str(k)[-1]] = i
    red = state.reduced_index(np.arange(p.n))
    v, w = state.expand(adj.v), state.expand(adj.w)
    g = rel.groups
    group_of = np.full(adj.n, -1, dtype=np.int64)
    if len(g):
        for k in range(len(g)):
            group_of[g.members[g.ptr[k]:g.ptr[k + 1]]] = k
    out = []
    for im, axes in rows.items():
        idx = [axes.get(a) for a in "xyz"]
        first = next(i for i in idx if i is not None)
        xyz = [float(p.l[i]) if i is not None else np.nan for i in idx]
        r = {"image": plain(im), "strip": plain(ids[first].get("strip", "")),
             "x": xyz[0], "y": xyz[1], "z": xyz[2],
             **{f"v{a}": float(v[i]) if i is not None else np.nan for a, i in zip("xyz", idx)},
             **{f"w{a}": float(w[i]) if i is not None else np.nan for a, i in zip("xyz", idx)},
             "T": np.nan, "critical": np.nan, "rejected": False,
             "excluded": any(i is None or red[i] < 0 for i in idx)}
        live = [int(red[i]) for i in idx if i is not None and red[i] >= 0]
        ks = {int(group_of[j]) for j in live}
        if len(ks) == 1 and -1 not in ks:
            d = g[ks.pop()]
            r.update(T=float(d["T"]), critical=float(d["critical"]), rejected=bool(d["rejected"]))
        out.append(r)
    df = pd.DataFrame(out, columns=GNSS_COLUMNS)
    e, n = display_matrix(p) @ np.vstack([df["x"].to_numpy(dtype=float), df["y"].to_numpy(dtype=float)])
    return df.assign(x=e, y=n)


def check_points(state) -> dict:
    """The core's check points of ``state``'s analysis (:meth:`baarda.analysis.Analysis.check_points`;
    ``n`` 0 without any)."""
    a = state.analysis
    if a is None:
        return {"points": [], "n": 0}
    return a.check_points()


def check_table(state) -> pd.DataFrame:
    """The check points as a table (:data:`CHECK_COLUMNS`, lengths in the block's object units):
    id, dX, dY, dZ = adjusted − known, sX, sY, sZ the adjusted coordinates' σ, then a last row
    ``RMSE`` (its σ columns empty). Empty without check points."""
    cp = check_points(state)
    if not cp["n"]:
        return pd.DataFrame(columns=CHECK_COLUMNS)
    rows = [{"id": plain(r["id"]), **dict(zip(("dX", "dY", "dZ"), map(float, r["diff"]))),
             **dict(zip(("sX", "sY", "sZ"), map(float, r["sigma"])))} for r in cp["points"]]
    rows.append({"id": "RMSE", **dict(zip(("dX", "dY", "dZ"), map(float, cp["rms"]))),
                 "sX": np.nan, "sY": np.nan, "sZ": np.nan})
    return pd.DataFrame(rows, columns=CHECK_COLUMNS)


def check_download(state) -> pd.DataFrame:
    """:func:`check_table` with the unit in the column names (the CSV and xlsx downloads)."""
    df = check_table(state)
    unit = object_unit(state.problem) if state.problem is not None else ""
    if unit:
        df = df.rename(columns={c: f"{c} [{unit}]" for c in CHECK_COLUMNS[1:]})
    return df


def check_vectors(state, pts: pd.DataFrame) -> pd.DataFrame:
    """The check points at their adjusted position on the map (``pts``: the map's points table,
    by id) with their difference adjusted − known (dX, dY, dZ)."""
    cp = check_points(state)
    where = {str(i): k for k, i in enumerate(pts["id"])} if len(pts) else {}
    rows = []
    M = display_matrix(state.problem)
    for r in cp["points"]:
        k = where.get(plain(r["id"]))
        if k is None:
            continue
        de, dn = M @ np.asarray(r["diff"][:2], dtype=float)
        rows.append({"id": plain(r["id"]), "x": float(pts["x"].iat[k]), "y": float(pts["y"].iat[k]),
                     "de": float(de), "dn": float(dn), "dX": float(r["diff"][0]), "dY": float(r["diff"][1]),
                     "dZ": float(r["diff"][2])})
    return pd.DataFrame(rows, columns=["id", "x", "y", "de", "dn", "dX", "dY", "dZ"])


def vector_scale(lengths, pts: pd.DataFrame) -> float:
    """The round exaggeration (:func:`round_scale`) that draws the largest of ``lengths`` at
    :data:`VECTOR_FRACTION` of the map's extent (1 without any)."""
    lengths = np.asarray(lengths, dtype=float)
    lengths = lengths[np.isfinite(lengths)]
    top = float(lengths.max()) if lengths.size else 0.0
    if top <= 0:
        return 1.0
    return round_scale(VECTOR_FRACTION * extent(pts) / top)


def vectors(df: pd.DataFrame, de: str, dn: str, scale: float) -> pd.DataFrame:
    """``df`` with segment ends x0, y0 (its x, y) and x1, y1 = x0 + scale·(de, dn)."""
    x, y = df["x"].to_numpy(dtype=float), df["y"].to_numpy(dtype=float)
    ex, ey = np.nan_to_num(df[de].to_numpy(dtype=float)), np.nan_to_num(df[dn].to_numpy(dtype=float))
    return df.assign(x0=x, y0=y, x1=x + scale * ex, y1=y + scale * ey)


def strip_rows(state) -> list[dict]:
    """The tests of the strips' GNSS shifts the model does not estimate (the core's
    :meth:`baarda.analysis.Analysis.gnss_strip_tests`); [] without GNSS."""
    a = state.analysis
    return a.gnss_strip_tests() if a is not None and has_gnss(state.problem) else []


def centre_precision(state) -> pd.DataFrame:
    """The images' projection centres and their precision (the core's
    :func:`baarda.stats.pose.pose_covariance`, 6 × 6 per image in the adjustment's datum, σ0 in
    use): per image its id, the adjusted X0, Y0 on the map (x, y), the 2 × 2 covariance of X0, Y0
    (``cov``, m², map axes as the block's) and σ of X0, Y0, Z0 in mm. Empty for a network, or where
    the core cannot give it (no images)."""
    cols = ["image", "x", "y", "sX0_mm", "sY0_mm", "sZ0_mm", "cov"]
    if state.results is None or state.problem is None or state.problem.geometry is None:
        return pd.DataFrame(columns=cols)
    return shared(state.results, ("centre-precision",), lambda: _centre_precision(state, cols))


def _centre_precision(state, cols) -> pd.DataFrame:
    adj = state.results
    try:
        ids, _, _ = pose.pose_parameters(adj.problem)
        cov = pose.pose_covariance(adj, ids)
        val = pose.pose_values(adj, ids)
    except BaardaError:
        return pd.DataFrame(columns=cols)
    sig = 1000.0 * pose.pose_sigma(cov)[:, :3]
    e, n = display_matrix(state.problem) @ val[:, :2].T
    return pd.DataFrame({"image": [plain(i) for i in ids], "x": e, "y": n, "sX0_mm": sig[:, 0], "sY0_mm": sig[:, 1],
                         "sZ0_mm": sig[:, 2], "cov": list(cov[:, :2, :2])}, columns=cols)
