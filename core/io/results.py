"""The machine-readable results of an analysis: JSON (the contract, docs/json-schema.md) and CSV.

Non-finite numbers never reach the JSON as NaN: a statistic that does not exist (w of an
uncontrolled observation, σ̂0 with r = 0) is ``null`` and an infinite MDB is ``null`` with
``"uncontrolled": true``.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ..datum import far_points
from ..text import number, printable

SCHEMA_VERSION = "1.0"


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def summary(adj, reliability=None) -> dict:
    """The summary numbers of ``adj``; the tests under ``reliability`` (default ``adj.reliability``,
    the policy of the adjustment's options)."""
    rel = adj.reliability if reliability is None else reliability
    p = adj.problem
    g = adj.global_test
    return {
        "source": p.source,
        "title": p.title,
        "n_observations": int(adj.n),
        "n_unknowns": int(adj.n_unknowns),
        "datum_defect": int(adj.defect),
        "datum": p.datum.describe(),
        "dof": int(adj.dof),
        "sigma0_apriori": _num(adj.sigma0),
        "sigma0_aposteriori": _num(adj.sigma0_post),
        "sigma0_used": getattr(p, "sigma_act", "apriori"),
        "omega": _num(adj.omega),
        "alpha0": rel.policy.alpha0,
        "beta0": rel.policy.beta0,
        "b_method": bool(rel.policy.b_method),
        "delta0": _num(rel.delta0),
        "critical_w": _num(rel.critical_w),
        "critical_tau": _num(rel.critical_tau),
        "converged": bool(adj.converged),
        "iterations": int(adj.iterations),
        "termination": str(getattr(adj, "termination", "")),
        "n_rejected": int(rel.rejected.sum()),
        "global_test": {
            "statistic": _num(g["statistic"]), "dof": g["dof"], "lower": _num(g["lower"]),
            "upper": _num(g["upper"]), "conf_pr": g["conf_pr"], "passed": g["passed"],
        },
        "timings": {k: round(float(v), 6) for k, v in adj.timings.items()},
        "far_points": far_point_ids(adj),
        "local_defects": local_defects(p),
        "dropped_observations": list(p.extra.get("dropped_observations", ())),
        **duplicate_keypoints(p),
    }


def duplicate_keypoints(problem) -> dict:
    """``{"duplicate_keypoints": {"points": …, "observations": …}}`` for a COLMAP block in which
    some 3D points are observed by several keypoints of one image (each its own observation;
    ``observations`` counts those beyond the first per image and point), else {}."""
    d = problem.extra.get("duplicate_keypoints")
    return {"duplicate_keypoints": dict(d)} if d and d.get("observations") else {}


def local_defects(problem) -> list[dict]:
    """The local defects found before the adjustment (:class:`baarda.defects.LocalDefect`,
    kept in ``problem.extra["local_defects"]`` by networks and blocks alike): points, images,
    cameras or coordinates the observations do not determine, left out or partly adjusted."""
    return [d.as_dict() for d in problem.extra.get("local_defects", ())]


def far_point_ids(adj) -> list[str]:
    """Points near infinity at the solution (:func:`baarda.datum.far_points`): their depth is
    hardly determined; a free block leaves them out of its default S-base."""
    ids = adj.problem.points.ids
    return [str(ids[i]) for i in np.flatnonzero(far_points(adj.problem, adj.x))]


def observations(adj) -> list[dict]:
    info = adj.problem.info
    sig = adj.problem.cov.sigma()
    out = []
    r, w, tau, mdb, ext = adj.r, adj.w, adj.tau, adj.mdb, adj.external
    v, rej, unc = adj.v, adj.rejected, adj.uncontrolled
    for i in range(adj.n):
        d = {"index": i, "kind": info.kind[i]}
        d.update(info.ids[i])
        d.update({
            "value": _num(info.value_file[i]), "unit": info.unit[i],
            "sigma": _num(info.sigma_file[i]), "sigma_unit": info.sigma_unit[i],
            "sigma_si": _num(sig[i]),
            "line": int(info.line[i]),
            "residual": _num(v[i]), "redundancy": _num(r[i]), "w": _num(w[i]), "tau": _num(tau[i]),
            "mdb": _num(mdb[i]), "external": _num(ext[i]), "rejected": bool(rej[i]),
            "uncontrolled": bool(unc[i]),
        })
        if info.group[i] >= 0:
            d["group"] = int(info.group[i])
        out.append(d)
    return out


def points(adj) -> list[dict]:
    pts = adj.problem.points
    xyz = adj.coordinates
    sig = adj.point_sigma
    out = []
    for i, pid in enumerate(pts.ids):
        d = {"id": pid, "status": pts.status[i]}
        for a, name in enumerate("xyz"):
            if pts.index[i, a] >= 0:
                for key, val in ((name, _num(xyz[i, a])), ("s" + name, _num(sig[i, a]))):
                    if val is not None:              # left out, never NaN (strict JSON, the schema)
                        d[key] = val
        out.append(d)
    return out


def groups(adj) -> list[dict]:
    return [{"group": g["group"], "members": [int(m) for m in g["members"]], "T": _num(g["T"]),
             "dimension": int(g["dimension"]), "redundancy": _num(g["redundancy"]),
             "critical": _num(g["critical"]), "alpha": g["alpha"], "rejected": bool(g["rejected"])}
            for g in adj.groups]


def to_dict(adj) -> dict:
    """The whole result document (schema version ``SCHEMA_VERSION``)."""
    return {"schema": f"baarda-analysis/{SCHEMA_VERSION}", "summary": summary(adj),
            "observations": observations(adj), "points": points(adj), "groups": groups(adj)}


def write_json(adj, path, doc=None) -> None:
    doc = doc if doc is not None else to_dict(adj)
    Path(path).write_text(json.dumps(doc, indent=1, allow_nan=False))


def write_csv(adj, directory, doc=None) -> list[Path]:
    """observations.csv, points.csv and groups.csv in ``directory`` (created if needed)."""
    doc = doc if doc is not None else to_dict(adj)
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    # an adjustment that did not converge marks every row (a column, so the files stay CSV)
    mark = {} if doc["summary"]["converged"] else {"adjustment": "NOT converged"}
    written = []
    for name in ("observations", "points", "groups"):
        rows = [{**row, **mark} for row in doc[name]]
        path = d / f"{name}.csv"
        keys = []
        for row in rows:
            for k in row:
                if k not in keys:
                    keys.append(k)
        with path.open("w", newline="") as fh:
            wr = csv.DictWriter(fh, fieldnames=keys or ["empty"])
            wr.writeheader()
            for row in rows:
                wr.writerow({k: (";".join(map(str, v)) if isinstance(v, list) else v) for k, v in row.items()})
        written.append(path)
    return written


def text_summary(adj, top: int = 8, reliability=None) -> str:
    """A readable summary: global test, worst w-tests, weakest r_i, largest δ̄0 (the tests under
    ``reliability``, default ``adj.reliability``)."""
    rel = adj.reliability if reliability is None else reliability
    s = summary(adj, rel)
    g = s["global_test"]
    info = adj.problem.info
    lines = []
    title = s["title"] or Path(s["source"]).name
    lines.append(f"baarda analysis of {title}")
    lines.append(f"  observations {s['n_observations']}, unknowns {s['n_unknowns']}, datum defect "
                 f"{s['datum_defect']} ({s['datum']}), redundancy {s['dof']}")
    conv = "converged" if s["converged"] else "NOT converged"
    method = "Levenberg-Marquardt" if getattr(adj, "damped", False) else "Gauss-Newton"
    lines.append(f"  {method} {conv} in {s['iterations']} iterations"
                 + (f" ({s['termination']})" if s["termination"] else ""))
    if s.get("duplicate_keypoints"):
        dk = s["duplicate_keypoints"]
        lines.append(f"  {dk['points']} point(s) observed by two or more keypoints of one image: "
                     f"{dk['observations']} extra image point(s), each tested on its own")
    if s["far_points"]:
        far = s["far_points"]
        lines.append(f"  {len(far)} point(s) near infinity (depth hardly determined, not in the default "
                     f"S-base): {', '.join(far[:10])}{' ...' if len(far) > 10 else ''}")
    if s["local_defects"]:
        defects = adj.problem.extra["local_defects"]
        lines.append(f"  {len(defects)} local defect(s): not determined by the observations "
                     f"(--strict makes them an error):")
        for d in defects[:50]:
            lines.append(f"    {d.text()}")
        if len(defects) > 50:
            rest = ", ".join(f"{d.entity} {d.id}" for d in defects[50:])
            lines.append(f"    and {len(defects) - 50} more: {rest}")
    if g["passed"] is None:
        lines.append("  global test: not applicable (no redundancy)")
    else:
        verdict = "passed" if g["passed"] else "FAILED"
        lines.append(f"  global test: vᵀPv = {number(g['statistic'])} in [{number(g['lower'])}, "
                     f"{number(g['upper'])}] at {number(g['conf_pr'], '.3g')} → {verdict};  σ0 a priori "
                     f"{number(s['sigma0_apriori'])}, a posteriori {number(s['sigma0_aposteriori'])}")
    lines.append(f"  α0 = {s['alpha0']}, β0 = {s['beta0']}: δ0 = {number(s['delta0'], '.3f')}, critical |w| = "
                 f"{number(s['critical_w'], '.3f')}; {s['n_rejected']} observation(s) rejected")

    def label(i):
        ids = " ".join(f"{k}={v}" for k, v in info.ids[i].items())
        return f"#{i:<5d} {info.kind[i]:<15s} {ids}"

    w = np.nan_to_num(np.abs(adj.w), nan=-1.0)
    lines.append("  largest |w| (data snooping):")
    for i in np.argsort(-w)[:top]:
        flag = "  REJECTED" if rel.rejected[i] else ""
        wi = (f"{number(adj.w[i], '+8.3f'):>8s}" if np.isfinite(adj.w[i])
              else f"{'—':>8s}  ({'r = 0, ' if not adj.r[i] > 1e-12 else ''}not testable)")
        lines.append(f"    {label(i):<48s} w = {wi}  r = {number(adj.r[i], '.3f')}{flag}")
    lines.append("  weakest redundancy numbers:")
    for i in np.argsort(adj.r)[:top]:
        lines.append(f"    {label(i):<48s} r = {number(adj.r[i], '.3f')}  MDB = {_unbounded(rel.mdb[i], '.4g')}")
    ext = np.where(np.isfinite(rel.external), rel.external, np.inf)
    lines.append("  largest external reliability δ̄0:")
    for i in np.argsort(-ext)[:top]:
        lines.append(f"    {label(i):<48s} δ̄0 = {_unbounded(rel.external[i], '.3f')}  r = {number(adj.r[i], '.3f')}")
    if rel.groups:
        rej = [g for g in rel.groups if g["rejected"]]
        lines.append(f"  group tests: {len(rel.groups)} groups, {len(rej)} rejected")
    return "\n".join(printable(line) for line in lines)     # ids and titles come from the file


def _unbounded(x, spec: str) -> str:
    """An MDB or δ̄0 for printing: ∞ for an uncontrolled observation (r = 0), never inf/nan."""
    return "∞ (uncontrolled)" if x is not None and np.isposinf(x) else number(x, spec)
