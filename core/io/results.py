"""The machine-readable results of an analysis: JSON (the contract, docs/json-schema.md) and CSV.

Non-finite numbers never reach the JSON as NaN: a statistic that does not exist (w of an
uncontrolled observation, σ̂0 with r = 0) is ``null`` and an infinite MDB is ``null`` with
``"uncontrolled": true``.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..datum import far_points
from ..stats.ap_tests import ap_tests
from ..stats.reliability import reliability_of
from ..text import number, printable
from .output import OutputError, atomic_write, csv_cell

SCHEMA_VERSION = "1.0"


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def summary(adj, reliability=None) -> dict:
    """The summary numbers of ``adj``; the tests under ``reliability`` (default ``reliability_of(adj)``,
    the policy of the adjustment's options)."""
    rel = reliability_of(adj) if reliability is None else reliability
    p = adj.problem
    g = rel.global_test
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
        "statistic": "tau" if rel.policy.sigma0 == "aposteriori" else "w",
        "n_rejected": int(rel.rejected.sum()),
        "global_test": {
            "statistic": _num(g["statistic"]), "dof": g["dof"], "test": g["test"], "alpha": g["alpha"],
            "lower": _num(g["lower"]), "upper": _num(g["upper"]), "conf_pr": g["conf_pr"],
            "passed": g["passed"], "side": g["side"], "verdict": g["verdict"],
            "sigma0_interval": sigma0_interval(g, adj.sigma0),
        },
        "timings": {k: round(float(v), 6) for k, v in adj.timings.items()},
        "far_points": far_point_ids(adj),
        "local_defects": local_defects(p),
        "dropped_observations": list(p.notes.dropped_observations),
        **duplicate_keypoints(p),
    }


def sigma0_interval(g: dict, sigma0: float) -> dict | None:
    """σ̂0's confidence interval at the global test's conf-pr (:func:`baarda.stats.distributions.sigma0_interval`,
    F80 §4.1): ``{"confidence", "lower", "upper"}`` in the units of σ0 a priori, or None when r = 0.
    σ0 a priori below it: the one-sided test fails; above it: σ0 a priori is too pessimistic."""
    iv = g.get("ratio_interval")
    if not iv:
        return None
    return {"confidence": g["conf_pr"], "lower": _num(iv[0] * sigma0), "upper": _num(iv[1] * sigma0)}


def duplicate_keypoints(problem) -> dict:
    """``{"duplicate_keypoints": {"points": …, "observations": …}}`` for a COLMAP block in which
    some 3D points are observed by several keypoints of one image (each its own observation;
    ``observations`` counts those beyond the first per image and point), else {}."""
    d = problem.notes.duplicate_keypoints
    return {"duplicate_keypoints": dict(d)} if d and d.get("observations") else {}


def local_defects(problem) -> list[dict]:
    """The local defects found before the adjustment (:class:`baarda.defects.LocalDefect`,
    kept in ``problem.notes.local_defects`` by networks and blocks alike): points, images,
    cameras or coordinates the observations do not determine, left out or partly adjusted."""
    return [d.as_dict() for d in problem.notes.local_defects]


def far_point_ids(adj) -> list[str]:
    """Points near infinity at the solution (:func:`baarda.datum.far_points`): their depth is
    hardly determined; a free block leaves them out of its default S-base."""
    ids = adj.problem.points.ids
    return [str(ids[i]) for i in np.flatnonzero(far_points(adj.problem, adj.x))]


class Records(Sequence):
    """The records of one table of the result document (observations, points, groups), each a
    dict made when it is asked for: a block of millions of image points holds its arrays, not
    millions of dicts (~1 KB each), and :func:`dump_json` and :func:`write_csv` stream them.
    ``add(f)`` merges ``f(i)`` (a dict) into record i (the CLI's --risk columns)."""

    def __init__(self, n: int, make):
        self._n, self._make, self._extra = int(n), make, []

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(self._n))]
        i = int(i)
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError(i)
        d = self._make(i)
        for f in self._extra:
            d.update(f(i))
        return d

    def __iter__(self):
        for i in range(self._n):
            yield self[i]

    def __eq__(self, other):
        return isinstance(other, (list, Records)) and len(other) == self._n and all(a == b for a, b in zip(self, other))

    __hash__ = None

    def add(self, f) -> None:
        self._extra.append(f)


def observations(adj, reliability=None) -> Records:
    """One record per observation; ``rejected`` by the statistic of ``reliability``'s policy (w
    or τ), ``rejected_w`` and ``rejected_tau`` by each."""
    rel = reliability_of(adj) if reliability is None else reliability
    info = adj.problem.info
    sig = adj.problem.cov.sigma()
    r, w, tau, mdb, ext = adj.r, adj.w, adj.tau, rel.mdb, rel.external
    v, rej, unc = adj.v, rel.rejected, adj.uncontrolled
    rej_w = np.nan_to_num(np.abs(w)) > rel.critical_w
    rej_tau = np.nan_to_num(np.abs(tau)) > rel.critical_tau
    u_k, u_t = adj.u_k, adj.u_t

    def make(i):
        d = {"index": i, "kind": info.kind[i]}
        d.update(info.ids[i])
        d.update({
            "value": _num(info.value_file[i]), "unit": info.unit[i],
            "sigma": _num(info.sigma_file[i]), "sigma_unit": info.sigma_unit[i],
            "sigma_si": _num(sig[i]),
            "line": int(info.line[i]),
            "residual": _num(v[i]), "redundancy": _num(r[i]), "u_k": _num(u_k[i]), "u_t": _num(u_t[i]),
            "w": _num(w[i]), "tau": _num(tau[i]),
            "mdb": _num(mdb[i]), "external": _num(ext[i]), "lambda_bar": _num(ext[i] ** 2),
            "rejected": bool(rej[i]), "rejected_w": bool(rej_w[i]), "rejected_tau": bool(rej_tau[i]),
            "uncontrolled": bool(unc[i]),
        })
        if info.group[i] >= 0:
            d["group"] = int(info.group[i])
        return d
    return Records(adj.n, make)


def points(adj) -> Records:
    pts = adj.problem.points
    xyz = adj.coordinates
    sig = adj.point_sigma

    def make(i):
        d = {"id": pts.ids[i], "status": pts.status[i]}
        for a, name in enumerate("xyz"):
            if pts.index[i, a] >= 0:
                for key, val in ((name, _num(xyz[i, a])), ("s" + name, _num(sig[i, a]))):
                    if val is not None:              # left out, never NaN (strict JSON, the schema)
                        d[key] = val
        return d
    return Records(len(pts.ids), make)


def groups(adj, reliability=None) -> Records:
    rel = reliability_of(adj) if reliability is None else reliability
    gs = rel.groups

    def make(i):
        g = gs[i]
        return {"group": g["group"], "members": [int(m) for m in g["members"]], "T": _num(g["T"]),
                "dimension": int(g["dimension"]), "redundancy": _num(g["redundancy"]),
                "critical": _num(g["critical"]), "alpha": g["alpha"], "rejected": bool(g["rejected"]),
                "R": _num(g["R"]), "critical_R": _num(g["critical_R"]),
                "nabla": [_num(x) for x in g["nabla"]], "nabla_sigma": [_num(x) for x in g["nabla_sigma"]],
                "ellipse_axes": [_num(x) for x in g["ellipse_axes"]],
                "delta0_prime_max": _num(g["delta0_prime_max"])}
    return Records(len(gs), make)


def to_dict(adj, reliability=None) -> dict:
    """The whole result document (schema version ``SCHEMA_VERSION``), the tests under
    ``reliability`` (default ``reliability_of(adj)``)."""
    rel = reliability_of(adj) if reliability is None else reliability
    doc = {"schema": f"baarda-analysis/{SCHEMA_VERSION}", "summary": summary(adj, rel),
           "observations": observations(adj, rel), "points": points(adj), "groups": groups(adj, rel)}
    if adj.problem.notes.ap_groups:
        doc["ap_tests"] = finite(ap_tests(adj, rel.policy))
    return doc


def columns(records) -> dict:
    """A table of records as columns: ``{key: numpy array}`` in the records' key order. Numbers
    (None where the JSON has null) become float arrays with NaN, booleans and integers keep their
    type where every record has them, anything else (strings, lists, dicts) an object array;
    a key some records lack is missing (NaN / None) there."""
    rows = list(records)
    keys: dict = {}
    for row in rows:
        keys.update(dict.fromkeys(row))
    out = {}
    for key in keys:
        vals = [row.get(key) for row in rows]
        present = [v for v in vals if v is not None]
        if present and all(isinstance(v, bool) for v in present) and len(present) == len(vals):
            out[key] = np.array(vals, dtype=bool)
        elif present and all(isinstance(v, int) and not isinstance(v, bool) for v in present) and len(present) == len(vals):
            out[key] = np.array(vals, dtype=np.int64)
        elif all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
            out[key] = np.array([np.nan if v is None else float(v) for v in vals], dtype=float)
        else:
            arr = np.empty(len(vals), dtype=object)
            arr[:] = vals
            out[key] = arr
    return out


def finite(x):
    """Lists and dicts of numbers with non-finite ones as None (strict JSON)."""
    if isinstance(x, dict):
        return {k: finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [finite(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return _num(x)
    return x


def write_json(adj, path, doc=None) -> None:
    """The result document as JSON (:func:`dump_json`)."""
    dump_json(doc if doc is not None else to_dict(adj), path)


def dump_json(doc: dict, path) -> None:
    """``doc`` as strict JSON (no NaN), streamed to ``path``: the lists of records (observations,
    points, groups, ...) one record per line, everything else indented. (json's indenting
    encoder is pure Python, ~6 µs per value: 40 s for BAL Dubrovnik's 167,000 observations; the
    compact one per record is compiled.)"""
    compact = json.JSONEncoder(allow_nan=False, ensure_ascii=True, separators=(", ", ": "))
    with atomic_write(path) as fh:
        fh.write("{")
        for k, (key, val) in enumerate(doc.items()):
            fh.write(("," if k else "") + "\n " + json.dumps(str(key)) + ": ")
            if isinstance(val, Records) or (isinstance(val, list) and val and all(isinstance(v, dict) for v in val)):
                fh.write("[")
                for i, rec in enumerate(val):
                    fh.write(("," if i else "") + "\n  " + compact.encode(rec))
                fh.write("\n ]")
            else:
                fh.write(json.dumps(val, indent=1, allow_nan=False).replace("\n", "\n "))
        fh.write("\n}\n")


def write_csv(adj, directory, doc=None) -> list[Path]:
    """observations.csv, points.csv and groups.csv in ``directory`` (created if needed), each
    written atomically; text cells are made safe for spreadsheets (:func:`csv_cell`: no formula,
    no raw control, bidi or zero-width character), as the dashboard's CSVs."""
    doc = doc if doc is not None else to_dict(adj)
    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(directory, f"cannot create the folder: {err.strerror or err}") from None
    # an adjustment that did not converge marks every row (a column, so the files stay CSV)
    mark = {} if doc["summary"]["converged"] else {"adjustment": "NOT converged"}
    written = []
    for name in ("observations", "points", "groups"):
        rows = doc[name]                   # (records made twice, streamed: not held)
        path = d / f"{name}.csv"
        keys = {}
        for row in rows:
            keys.update(dict.fromkeys(row))
        keys.update(dict.fromkeys(mark))
        with atomic_write(path, newline="") as fh:
            wr = csv.writer(fh)
            names = list(keys) or ["empty"]
            wr.writerow([csv_cell(k) for k in names])
            for row in rows:
                row = {**row, **mark}
                wr.writerow([csv_cell(";".join(map(str, v)) if isinstance(v, list) else v)
                             for v in (row.get(k, "") for k in names)])
        written.append(path)
    return written


def text_summary(adj, top: int = 8, reliability=None) -> str:
    """A readable summary: global test, worst w-tests, weakest r_i, largest δ̄0 (the tests under
    ``reliability``, default ``reliability_of(adj)``)."""
    rel = reliability_of(adj) if reliability is None else reliability
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
        defects = adj.problem.notes.local_defects
        lines.append(f"  {len(defects)} local defect(s): not determined by the observations "
                     f"(--strict makes them an error):")
        for d in defects[:50]:
            lines.append(f"    {d.text()}")
        if len(defects) > 50:
            rest = ", ".join(f"{d.entity} {d.id}" for d in defects[50:])
            lines.append(f"    and {len(defects) - 50} more: {rest}")
    lines.append(global_test_text(g, s))
    lines.append(f"  {sigma0_text(g, s)}")
    stat = "τ" if s["statistic"] == "tau" else "w"
    lines.append(f"  α0 = {s['alpha0']}, β0 = {s['beta0']}: δ0 = {number(s['delta0'], '.3f')}, critical |w| = "
                 f"{number(s['critical_w'], '.3f')}, |τ| = {number(s['critical_tau'], '.3f')}; "
                 f"{s['n_rejected']} observation(s) rejected by {stat}")

    def label(i):
        ids = " ".join(f"{k}={v}" for k, v in info.ids[i].items())
        return f"#{i:<5d} {info.kind[i]:<15s} {ids}"

    w = np.nan_to_num(np.abs(adj.w), nan=-1.0)
    lines.append("  largest |w| (data snooping):")
    for i in np.argsort(-w)[:top]:
        flag = "  REJECTED" if rel.rejected[i] else ""
        wi = (f"{number(adj.w[i], '+8.3f'):>8s}" if np.isfinite(adj.w[i])
              else f"{'—':>8s}  ((P C_vv P)_ii = 0: not testable)")       # the criterion of uncontrolled
        lines.append(f"    {label(i):<48s} w = {wi}  r = {number(adj.r[i], '.3f')}{flag}")
    lines.append("  weakest redundancy numbers:")
    for i in np.argsort(adj.r)[:top]:
        lines.append(f"    {label(i):<48s} r = {number(adj.r[i], '.3f')}  u_k = {number(adj.u_k[i], '.3f')}  "
                     f"u_t = {number(adj.u_t[i], '.3f')}  MDB = {_unbounded(rel.mdb[i], '.4g')}")
    ext = np.where(np.isfinite(rel.external), rel.external, np.inf)
    lines.append("  largest external reliability δ̄0:")
    for i in np.argsort(-ext)[:top]:
        lines.append(f"    {label(i):<48s} δ̄0 = {_unbounded(rel.external[i], '.3f')}  λ̄ = "
                     f"{_unbounded(rel.external[i] ** 2, '.3g')}  r = {number(adj.r[i], '.3f')}")
    for a in (ap_tests(adj, rel.policy) if adj.problem.notes.ap_groups else []):
        lines.append(f"  additional parameters {a['group']} of camera {a['camera']} (F80 §7.2-7.3): T = "
                     f"{number(a['T'], '.3f')} (crit {number(a['critical'], '.2f')}, q = {a['q']}) → "
                     f"{'SIGNIFICANT' if a['significant'] else 'not significant'};  δ0′max = "
                     f"{_unbounded(a['delta0_prime_max'], '.3g')} (determinability), δ̄0max = "
                     f"{_unbounded(a['reliability_max'], '.3g')} (reliability, F80 eq. 17)")
    groups = rel.groups
    if groups:
        lines.append(f"  group tests (F80 eq. 10-14): {len(groups)} groups, {int(groups.rejected.sum())} rejected; "
                     f"largest T/critical:")
        ratio = np.where(groups.dimension > 0, groups.T / groups.critical, -1.0)
        for k in np.argsort(-np.nan_to_num(ratio, nan=-1.0))[:top].tolist():
            g = groups[k]
            ids = " ".join(f"{a}={b}" for a, b in info.ids[int(g["members"][0])].items() if a != "component")
            nab = ", ".join(f"{number(a, '+.3g')} ± {number(b, '.2g')}" for a, b in zip(g["nabla"], g["nabla_sigma"]))
            axes = ", ".join(number(a, ".3g") for a in g["ellipse_axes"])
            lines.append(f"    group {g['group']:<6d} {ids:<34s} q = {g['dimension']}  T = "
                         f"{number(g['T'], '.3f')} (crit {number(g['critical'], '.2f')})  R = {number(g['R'], '.3f')} "
                         f"(crit {number(g['critical_R'], '.2f')}){'  REJECTED' if g['rejected'] else ''}")
            lines.append(f"    {'':13s}∇ŝ = {nab};  lower-bound semi-axes {axes};  δ0′max = "
                         f"{_unbounded(g['delta0_prime_max'], '.3g')}")
    return "\n".join(printable(line) for line in lines)     # ids and titles come from the file


def global_test_text(g: dict, s: dict) -> str:
    """The global test in one line: which test, its α, the critical value(s), the verdict (F80
    §4.1, §7.2); :func:`sigma0_text` says σ̂0 with its confidence interval."""
    if g["passed"] is None:
        return "  global test: not applicable (no redundancy)"
    T = g["statistic"]              # the relation to the bound(s) as it is: "> bound" when failed
    if g["test"] == "two-sided":
        rel = "in" if g["lower"] <= T <= g["upper"] else "not in"
        how = (f"two-sided at conf-pr {number(g['conf_pr'], '.3g')} (gama-local): vᵀPv = {number(T)} "
               f"{rel} [{number(g['lower'])}, {number(g['upper'])}] (χ², r = {g['dof']})")
    else:
        rel = "≤" if T <= g["upper"] else ">"
        what = (f"one-sided (F80 §4.1) at α = {number(100 * g['alpha'], '.3g')} %" if g["test"] == "one-sided" else
                f"one-sided at the B-method's α_{g['dof']} = {number(100 * g['alpha'], '.3g')} % (F80 §7.2)")
        how = f"{what}: vᵀPv = {number(T)} {rel} {number(g['upper'])} (χ², r = {g['dof']})"
    verdict = "passed" if g["passed"] else "FAILED"
    if g["side"] is not None:
        verdict += f": {g['verdict']}" + (", not an error in the data" if g["side"] == "low" else "")
    return f"  global test {how} → {verdict}"


def sigma0_text(g: dict, s: dict) -> str:
    """"σ0 a priori 1, a posteriori σ̂0 = 1.01, 95 % interval [0.99, 1.03]: σ0 a priori inside":
    what the global test says about the precision, in the numbers' own terms."""
    iv = (s.get("global_test") or {}).get("sigma0_interval") or sigma0_interval(g, s["sigma0_apriori"] or 1.0)
    post, pri = s["sigma0_aposteriori"], s["sigma0_apriori"]
    if not iv or iv["lower"] is None or iv["upper"] is None:
        return f"σ0 a priori {number(pri)}, a posteriori {number(post)}"
    where = ("below it (σ̂0 significantly larger)" if pri < iv["lower"] else
             "above it (σ̂0 significantly smaller)" if pri > iv["upper"] else "inside it")
    return (f"σ0 a priori {number(pri)}, a posteriori σ̂0 = {number(post, '.4g')}, "
            f"{number(100 * iv['confidence'], '.3g')} % interval [{number(iv['lower'], '.4g')}, "
            f"{number(iv['upper'], '.4g')}]: σ0 a priori {where}")


def _unbounded(x, spec: str) -> str:
    """An MDB or δ̄0 for printing: ∞ for an uncontrolled observation (r = 0), never inf/nan."""
    return "∞ (uncontrolled)" if x is not None and np.isposinf(x) else number(x, spec)


def _vector(values, spec: str = "+.4g") -> str:
    return "(" + ", ".join(number(v, spec) for v in values) + ")"


def tests_text(adj, reliability, tests: list[dict], top: int = 10) -> str:
    """The text of ``baarda test``: per hypothesis (dicts of
    :func:`baarda.stats.analyses.hypothesis_analysis`, or ``ap_test`` ones) T, R, the decision,
    ∇ŝ ± σ∇ŝ, the lower-bound ellipse, δ0′max, δ̄0max with λ̄ and the ``top`` largest point
    shifts of the deformation field (F80 eq. 10-18)."""
    s = summary(adj, reliability)
    lines = [f"baarda test of {s['title'] or Path(s['source']).name}: redundancy {s['dof']}, α0 = {s['alpha0']}, "
             f"β0 = {s['beta0']}{', B-method' if s['b_method'] else ''}, σ0 "
             f"{'a posteriori (decisions on R)' if s['statistic'] == 'tau' else 'a priori (decisions on T)'}"]
    for t in tests:
        lines.append(f"hypothesis {t['hypothesis']}")
        if "ap_test" in t:
            a = t["ap_test"]
            lines.append(f"  estimated AP group (F80 §7.2-7.3): T = {number(a['T'], '.3f')} (critical "
                         f"{number(a['critical'], '.3f')}, q = {a['q']}, α = {number(a['alpha'], '.3g')}) → "
                         f"{'SIGNIFICANT' if a['significant'] else 'not significant'}")
            lines.append(f"  ŝ = {_vector(a['estimate'])} ± {_vector(a['sigma'], '.2g')}")
            lines.append(f"  δ0′max = {_unbounded(a['delta0_prime_max'], '.4g')} (determinability, F80 eq. 14), "
                         f"δ̄0max = {_unbounded(a['reliability_max'], '.4g')} (reliability, F80 eq. 17)")
            continue
        rows = t["rows"]
        lines.append(f"  q = {t['dimension']}, observations {', '.join(f'#{i}' for i in rows[:12])}"
                     f"{' ...' if len(rows) > 12 else ''}")
        decision = "REJECTED" if t["rejected"] else "accepted"
        lines.append(f"  T = {number(t['T'], '.4f')} (critical {number(t['critical_T'], '.4f')}, α = "
                     f"{number(t['alpha'], '.3g')}), R = {number(t['R'], '.4f')} (critical "
                     f"{number(t['critical_R'], '.4f')}) → {decision} on {t['decided_on']} (F80 eq. 10-12)")
        nab = ", ".join(f"{number(a, '+.4g')} ± {number(b, '.2g')}" for a, b in zip(t["nabla"], t["nabla_sigma"]))
        lines.append(f"  ∇ŝ = {nab}")
        if t["dimension"] == 0:
            lines.append("  the test sees no error of this hypothesis (q = 0): no lower bound, no δ̄0")
            continue
        axes = "; ".join(f"{number(a, '.4g')} along {_vector(d, '+.3f')}"
                         for a, d in zip(t["ellipse_axes"], t["ellipse_directions"]))
        if t["dimension"] == 1:
            lines.append(f"  lower bound (F80 eq. 13, δ0 = {number(t['delta0'], '.3f')}): |∇0s| = {axes}")
        else:
            lines.append(f"  lower-bound {'ellipse' if t['dimension'] == 2 else 'ellipsoid'} (F80 eq. 13, δ0 = "
                         f"{number(t['delta0'], '.3f')}): semi-axes {axes}")
        q_cols = len(t["nabla"])
        if t["dimension"] < q_cols:
            lines.append(f"  δ0′max = ∞: the test sees {t['dimension']} of {q_cols} directions; an error in direction "
                         f"{_vector(t['weakest'], '+.3f')} is not detectable at all (F80 eq. 14); δ̄0 below is over "
                         f"the directions seen")
        else:
            lines.append(f"  δ0′max = {number(t['delta0_prime_max'], '.4g')} in direction {_vector(t['weakest'], '+.3f')} "
                         f"(F80 eq. 14)")
        lines.append(f"  δ̄0max = {_unbounded(t['delta_bar0_max'], '.4g')} (λ̄ = {_unbounded(t['lambda_bar_max'], '.4g')}) "
                     f"in direction {_vector(t['delta_bar0_direction'], '+.3f')} (F80 eq. 17): an undetected error "
                     f"moves no function of the coordinates by more than {_unbounded(t['delta_bar0_max'], '.3g')} σ_f "
                     f"(eq. 18)")
        d = t["deformation"]
        pts = d["points"]
        lines.append(f"  deformation by that undetectable error ∇0s = {_vector(d['nabla0_s'])} (F80 eq. 16), "
                     f"{min(top, len(pts))} largest of {len(pts)} points:")
        for p in pts[:top]:
            lines.append(f"    {p['id']:<12s} dx = {number(p['dx'], '+.3e')}  dy = {number(p['dy'], '+.3e')}  "
                         f"dz = {number(p['dz'], '+.3e')}  |d| = {number(p['norm'], '.3e')}")
    return "\n".join(printable(line) for line in lines)
