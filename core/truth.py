"""Planted errors of a simulated block against what the tests find.

For each error listed in a ``baarda-truth`` file (:mod:`baarda.simulate`), the observations it
touched are looked up and tested: data snooping (the largest |w| among them) and the
multi-dimensional test of the hypothesis that matches the error's kind (F80 eq. 12):
a point-transfer error across its images, a 2D image point, a control point.
"""

from __future__ import annotations

import numpy as np

from .errors import BaardaError
from .stats import gnss, hypotheses
from .stats.ap_tests import ap_test
from .stats.reliability import reliability_of


def _hypothesis(adj, e):
    ids = e.get("ids", {})
    kind = e.get("kind")
    try:
        if kind == "transfer":
            return "point transfer", hypotheses.h_point_transfer(adj.problem, ids["point"], ids["images"])
        if kind == "gnss":
            return "GNSS centre", gnss.h_gnss_centre(adj.problem, ids["image"])
        if kind == "gnss-strip":
            return "GNSS strip shift", gnss.h_gnss_strip(adj.problem, ids["images"])
        if kind == "control":
            return "control point", hypotheses.h_control_point(adj.problem, ids.get("point", ids.get("id")))
        if "image" in ids and "point" in ids:
            return "image point", hypotheses.h_image_point(adj.problem, ids["image"], ids["point"])
    except (KeyError, ValueError, IndexError, TypeError, BaardaError):
        return None, None
    return None, None


def _rows_of(clusters) -> set:
    """The observation indices of a list of clusters (arrays of indices)."""
    return {int(i) for m in (clusters or ()) for i in np.asarray(m).ravel()}


def compare(adj, truth: dict, reliability=None, left_out=None) -> list[dict]:
    """One entry per planted error: kind, ids, class, max |w| of its observations, whether data
    snooping rejects one of them, and T/critical/decision of the matching hypothesis, under
    ``reliability``'s policy (default the adjustment's own).

    ``left_out`` (the diverged case: ``adj`` is the least squares without the robust suspects,
    R84 §7): the suspects' clusters (arrays of the block's observation indices). An error any of
    whose observations is among them gets ``robust_suspect`` true and counts as found; its
    observations still in ``adj`` are tested there, the rest are not in it. ``adj`` None (that
    least squares gave no result either): the comparison with the suspects alone."""
    if adj is None:
        out_rows = _rows_of(left_out)
        found = [bool({int(r) for r in e.get("rows", [])} & out_rows) for e in truth.get("errors", [])]
        return [{"kind": e.get("kind"), "ids": e.get("ids", {}), "class": e.get("class"),
                 "size_sigma": e.get("size_sigma"), "robust_suspect": f, "found": f}
                for e, f in zip(truth.get("errors", []), found)]
    rel = reliability_of(adj) if reliability is None else reliability
    kept = adj.problem.notes.kept_rows
    out_rows = None if left_out is None else _rows_of(left_out)
    out = []
    for k, e in enumerate(truth.get("errors", [])):
        rows = np.asarray(e.get("rows", []), dtype=np.int64)
        suspect = None if out_rows is None else bool(set(rows.tolist()) & out_rows)
        if kept is None and rows.size and rows.max() >= adj.n:
            raise BaardaError(f"truth file: errors[{k}].rows: {int(rows.max())} is not an observation of this "
                              f"block ({adj.n} observations)")
        if kept is not None:
            pos = {int(r): i for i, r in enumerate(kept)}
            rows = np.array([pos[int(r)] for r in rows if int(r) in pos], dtype=np.int64)
        d = {"kind": e.get("kind"), "ids": e.get("ids", {}), "class": e.get("class"),
             "size_sigma": e.get("size_sigma")}
        if rows.size:
            w = np.abs(np.nan_to_num(adj.w[rows]))
            d["max_w"] = float(w.max())
            d["snooping_rejects"] = bool(rel.rejected[rows].any())
        name, H = _hypothesis(adj, e)
        if H is not None:
            h = rel.test(H, label=name)
            d.update({"hypothesis": name, "T": h.T, "critical": h.critical_T, "rejected": h.rejected_T,
                      "nabla": h.nabla.tolist(), "nabla_sigma": h.nabla_sigma.tolist()})
        key = f"{e.get('ids', {}).get('strip')}:gnss-shift"
        if e.get("kind") == "gnss-strip" and key in adj.problem.notes.ap_groups:
            a = ap_test(adj, key.rpartition(":")[0], "gnss-shift", policy=rel.policy)   # estimated shift, F80 §7.2
            d.update({"hypothesis": "GNSS strip shift (AP group)", "T": a.T, "critical": a.critical,
                      "rejected": a.significant, "nabla": a.estimate.tolist(), "nabla_sigma": a.sigma.tolist()})
        if suspect is not None:
            d["robust_suspect"] = suspect
        d["found"] = bool(d.get("snooping_rejects") or d.get("rejected") or suspect)
        out.append(d)
    return out


def text(findings: list[dict]) -> str:
    lines = ["  planted errors (truth file):"]
    for f in findings:
        ids = " ".join(f"{k}={v if not isinstance(v, list) else ','.join(map(str, v))}" for k, v in f["ids"].items())
        s = f"    {f['kind']:<17s} {ids:<40s} {f.get('class') or '':<7s}"
        if "max_w" in f:
            s += f" max|w| = {f['max_w']:6.2f}"
        if "T" in f:
            s += f"  {f['hypothesis']} T = {f['T']:.1f} (crit {f['critical']:.1f})"
        if f.get("robust_suspect"):
            s += "  left out as a robust suspect"
        s += "  → FOUND" if f["found"] else "  → not found"
        lines.append(s)
    return "\n".join(lines)
