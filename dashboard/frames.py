"""The dashboard's tables, built from the core's results: the observations and points tables of
the maps and the tests table, the network lines, the robust suspects, the snooping log, the
leave-one-out table, the variance components and the summary's counts.

Plain functions of the core's objects (the problem, its :class:`~baarda.result.Adjustment` and
:class:`~baarda.stats.reliability.Reliability`, ``kept``: the full index of each observation of
the reduced problem) and of the problem's index (:func:`baarda.dashboard.geometry.problem_index`).
Observation indices in the tables are those of the full problem; v and MDB are in the unit of the
observation's σ in the file.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from .geometry import display_xy, expand
from .text import plain

#: Redundancy numbers below these are flagged: uncontrolled, weak (the dashboard's colour scale).
R_UNCONTROLLED = 0.1
R_WEAK = 0.3


def frames(problem, adj, rel, kept, excluded, index: dict, robust=None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(observations, points)`` tables of an adjustment.

    observations: one row per observation of the full problem (index = full index) with the
    core's v, w, τ, r, MDB, δ̄0 (v and MDB in the unit of the observation's σ in the file),
    MDB/σ, the decision, the exclusion flag (``excluded``: full indices) and the robust weight
    factor (NaN without robust reweighting). points: one row per point with its map position,
    status, σ and the extreme values over its observations (min r, max |w|, max δ̄0, max MDB/σ).
    :func:`base_frames` (what does not depend on the test policy) and :func:`with_policy`.
    """
    return with_policy(base_frames(problem, adj, kept, excluded, index), problem, rel, kept, index, robust)


def base_frames(problem, adj, kept, excluded, index: dict) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The columns of :func:`frames` that do not depend on the test policy (v, w, τ, r, σ, …):
    the same for every α0, β0 and B-method."""
    p, n = problem, problem.n
    factor, units = index["factor"]
    w = expand(adj.w, kept, n)
    excl = np.zeros(p.n, dtype=bool)
    excl[sorted(excluded)] = True
    obs = pd.DataFrame({
        "kind": list(p.info.kind),
        "ids": index["labels"],
        "v": expand(adj.v, kept, n) * factor,
        "w": w,
        "tau": expand(adj.tau, kept, n),
        "r": expand(adj.r, kept, n),
        "unit": list(units),
        "excluded": excl,
    })
    obs.index.name = "index"
    coords = adj.coordinates
    east, north, _, _ = display_xy(p, coords)
    m = len(p.points.ids)
    live = ~excl[index["inc_obs"]]
    io, ip = index["inc_obs"][live], index["inc_pt"][live]
    sig = adj.point_sigma * 1000.0
    pts = pd.DataFrame({
        "id": [plain(i) for i in p.points.ids], "status": list(p.points.status),
        "x": east, "y": north,
        "sx_mm": sig[:, 0], "sy_mm": sig[:, 1], "sz_mm": sig[:, 2],
        "n_obs": np.bincount(ip, minlength=m),
        "min_r": _extreme(np.fmin, m, io, ip, obs["r"].to_numpy()),
        "max_w": _extreme(np.fmax, m, io, ip, np.abs(w)),
    })
    return obs, pts


def _extreme(ufunc, m, io, ip, values) -> np.ndarray:
    out = np.full(m, np.nan)
    ufunc.at(out, ip, values[io])
    return out


OBS_COLUMNS = ["kind", "ids", "v", "w", "tau", "r", "mdb", "mdb_sigma", "ext", "unit", "rejected", "excluded",
               "robust_w"]
POINT_COLUMNS = ["id", "status", "x", "y", "sx_mm", "sy_mm", "sz_mm", "n_obs", "min_r", "max_w", "max_ext",
                 "max_mdb_sigma"]


def with_policy(base, problem, rel, kept, index: dict, robust=None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """:func:`frames` from the :func:`base_frames` ``base`` and the reliability ``rel`` under a
    test policy (decision, MDB, δ̄0) and a robust result (its weights); ``base`` unchanged."""
    obs0, pts0 = base
    n = problem.n
    factor, _ = index["factor"]
    sig_si = problem.cov.sigma()
    mdb = expand(rel.mdb, kept, n)
    cols = {c: obs0[c] for c in obs0.columns}
    cols.update({
        "mdb": mdb * factor,
        "mdb_sigma": mdb / np.where(sig_si > 0, sig_si, np.nan),
        "ext": expand(rel.external, kept, n),
        "rejected": expand(rel.rejected, kept, n, fill=False).astype(bool),
        "robust_w": expand(robust.weights, kept, n) if robust is not None else np.full(n, np.nan),
    })
    obs = pd.DataFrame({c: cols[c] for c in OBS_COLUMNS}, index=obs0.index)
    m = len(pts0)
    live = ~obs0["excluded"].to_numpy()[index["inc_obs"]]
    io, ip = index["inc_obs"][live], index["inc_pt"][live]
    pcols = {c: pts0[c] for c in pts0.columns}
    pcols["max_ext"] = _extreme(np.fmax, m, io, ip, obs["ext"].to_numpy())
    pcols["max_mdb_sigma"] = _extreme(np.fmax, m, io, ip, obs["mdb_sigma"].to_numpy())
    pts = pd.DataFrame({c: pcols[c] for c in POINT_COLUMNS}, index=pts0.index)
    return obs, pts


def segments(pts: pd.DataFrame, index: dict) -> pd.DataFrame:
    """One line per (observation, other point) of the network observations: from → to, at the
    map positions of the points table ``pts``."""
    x, y = pts["x"].to_numpy(), pts["y"].to_numpy()
    a, b = index["line_from"], index["line_to"]
    return pd.DataFrame({"obs": index["line_obs"], "x0": x[a], "y0": y[a], "x1": x[b], "y1": y[b]})


def robust_suspects(rr, kept, obs: pd.DataFrame) -> pd.DataFrame:
    """The robust suspects of the core's RobustResult ``rr`` (full indices) with R84 class,
    weight, size, and beside them the data snooping of the least-squares adjustment (its w and
    decision, from the observations table ``obs``)."""
    cols = ["obs", "ids", "kind", "robust weight", "size [σ]", "class", "w (LS)", "LS rejects"]
    if rr is None:
        return pd.DataFrame(columns=cols)
    rows = []
    for d in rr.suspects:
        i = int(kept[d["index"]])
        rows.append({"obs": i, "ids": obs["ids"].iat[i], "kind": d["kind"],
                     "robust weight": round(d["weight"], 4), "size [σ]": round(d["size_sigma"], 1),
                     "class": d["class"], "w (LS)": round(float(obs["w"].iat[i]), 2),
                     "LS rejects": bool(obs["rejected"].iat[i])})
    return pd.DataFrame(rows, columns=cols)


def suspect_observations(rr, kept) -> list[int]:
    """Full indices of every observation of the robust suspects (their clusters; all the rays of a
    point the robust step left out, R84 §7)."""
    if rr is None:
        return []
    return sorted({int(kept[j]) for d in rr.suspects for j in d.get("left_out", d["members"])})


def snoop_log(snoop, kept, obs: pd.DataFrame, factor, units) -> pd.DataFrame:
    """One row per step of the core's SnoopResult: full index, ids, |w| (or |τ|), critical
    value, ∇̂ (file units), σ̂0 before → after."""
    cols = ["step", "obs", "ids", "|w|", "critical", "∇̂", "σ̂0 before", "σ̂0 after"]
    if snoop is None:
        return pd.DataFrame(columns=cols)
    rows = []
    for k, st in enumerate(snoop.steps, 1):
        i = int(kept[st.removed])
        rows.append({"step": k, "obs": i, "ids": f"{obs['kind'].iat[i]} {obs['ids'].iat[i]}",
                     "|w|": round(st.statistic, 3), "critical": round(st.critical, 3),
                     "∇̂": f"{st.nabla * factor[i]:.4g} {units[i]}",
                     "σ̂0 before": round(st.sigma0_before, 4), "σ̂0 after": round(st.sigma0_after, 4)})
    return pd.DataFrame(rows, columns=cols)


def loo_table(loo: list, kept, obs: pd.DataFrame) -> pd.DataFrame:
    """σ̂0 with each top suspect left out (the core's ``snooping.leave_one_out``), full indices."""
    cols = ["obs", "ids", "w", "σ̂0 without", "ratio"]
    rows = [{"obs": int(kept[d["index"]]), "ids": obs["ids"].iat[int(kept[d["index"]])],
             "w": round(d["w"], 3), "σ̂0 without": round(d["sigma0_without"], 4),
             "ratio": round(d["ratio"], 4)} for d in loo]
    return pd.DataFrame(rows, columns=cols)


def variance_table(variance, components) -> pd.DataFrame:
    """The core's variance components: of the radial model (``components``, a
    ComponentEstimate) if there is one, else per family (``variance``, VarianceComponents)."""
    if components is not None:
        return pd.DataFrame([{"component": d["component"], "θ": f"{d['theta']:.4g}",
                              "± s.e.": "held at 0" if d["std_error"] is None else f"{d['std_error']:.2g}", "√θ": f"{math.sqrt(max(d['theta'], 0.0)):.4g}",
                              "redundancy": round(d["redundancy"], 2)}
                             for d in components.as_dict()],
                            columns=["component", "θ", "± s.e.", "√θ", "redundancy"])
    cols = ["family", "σ̂0j²", "± s.e.", "σ̂0j", "redundancy"]
    if variance is None:
        return pd.DataFrame(columns=cols)
    return pd.DataFrame([{"family": d["group"], "σ̂0j²": round(d["factor"], 4),
                          "± s.e.": round(d["std_error"], 4), "σ̂0j": round(d["sigma_factor"], 4),
                          "redundancy": round(d["redundancy"], 2)}
                         for d in variance.as_dict()], columns=cols)


def summary_counts(obs: pd.DataFrame, pts: pd.DataFrame, excluded, images: list) -> dict:
    """The summary header's counts beside the core's summary: excluded, rejected, uncontrolled
    (r < :data:`R_UNCONTROLLED`) and weak (r < :data:`R_WEAK`) observations, points, images, strips."""
    live = ~obs["excluded"]
    return {
        "n_excluded": int(len(excluded)),
        "n_rejected": int((obs["rejected"] & live).sum()),
        "n_uncontrolled": int(((obs["r"] < R_UNCONTROLLED) & live).sum()),
        "n_weak": int(((obs["r"] >= R_UNCONTROLLED) & (obs["r"] < R_WEAK) & live).sum()),
        "n_points": len(pts),
        "n_images": len(images),
        # images without a strip (SfM, BAL, COLMAP) are in none
        "n_strips": len({str(im.get("strip")) for im in images if im.get("strip") not in (None, "")}),
    }
