"""The reviewer's ranked list of suspects: 1D tests, group tests and point-transfer scans in one table.

Every row is a hypothesis the core has tested on the current adjustment (:class:`State`'s
``results`` under its test policy, ``reliability``):

- **observation**: Baarda's w-test of one observation (H = e_i; F80 eq. 10-12, q = 1), for the
  :data:`TOP_1D` largest |w| (or |τ|);
- **group**: the multi-dimensional test of an observation group of the problem — an image point
  (x, y), a GNSS vector, a control point (F80 eq. 12; the core's ``Reliability.groups``), for
  the :data:`TOP_GROUPS` largest T / k;
- **GNSS centre**, **IMU attitude**: the 3-D test of one projection centre's GNSS position or
  of one image's IMU attitude (its observation group, F80 eq. 10-12), every one of them (up to
  :data:`TOP_AUX` of each by p-value, fewer on a large block) besides the largest groups;
- **GNSS strip**: the test of a shift common to one strip's GNSS centres (a cycle slip, F80
  §2.2; :meth:`baarda.analysis.Analysis.gnss_strip_tests`), and where the model estimates a
  strip's shift or drift the test of those additional parameters (F80 §7.2,
  :func:`baarda.stats.ap_tests.ap_test`: T ~ χ²(q), on the same scale; no H in the
  observations, so it is ranked by its p-value alone, neither tiered nor compared for twins);
- **transfer**: the point-transfer hypothesis H = (0 … I₂ … I₂ … 0)ᵀ (F80 §2.2) of a suspect
  point over consecutive images of one strip (a scan over the runs of at least two of its images
  in each strip; :data:`TRANSFER_POINTS` points at most), each tested by ``Reliability.test``.

**One scale** (issue 31, item 1): every row carries the p-value of its own test under the
test policy — the probability of a statistic at least this large if the hypothesis' observations
are free of error: χ²(q) of T for a q-dimensional hypothesis (F80 eq. 12; q = 1: Baarda's w,
two-sided normal), Pope's τ distribution (τ²/r ~ Beta(1/2, (r−1)/2), P76) for an observation
when the policy decides on τ. Twenty rejected neighbours of one large error would fill the first
screen, so the rows are ranked in two tiers: first the rejected hypotheses that the stronger ones
above them do not explain — hypothesis H is tested *given* the set C of those already listed, in
the model extended by C (F80 §2.2 with H' = [H_C H]): T(H_C, H) − T(H_C) ~ χ²(q' − q_C) under
H0, rejected at the policy's α for that dimension — then the others, each by its p-value. A
rejected row the tier-one suspects explain names the one that does ("explained by"; a twin is
explained by the hypothesis it cannot be told apart from). Ties (twins have one p-value) go to
the larger hypothesis (dimension, then observations), then the first observation in the file.

Columns: |w| and |τ| (the largest over the hypothesis' observations), T and its critical value k,
the decision in words, the estimated error ∇ŝ (F80 eq. 10, in the file's units of the
observations), and the MDB ratio √T / δ0(q): the length of ∇ŝ over the lower bound ∇0s in its
own direction (F80 eq. 13, ∇0s = s δ0 / √(sᵀ W s) with s = ∇ŝ and ∇ŝᵀ W ∇ŝ = T); for one
observation |∇ŝ| / MDB = |w| / δ0. Hypotheses whose statistics are (near-)perfectly correlated
(|ρ| ≥ :data:`baarda.stats.separability.THRESHOLD`; F80 §7.4, M84 §3.3) cannot be told apart by
the data: each row names its twins; two group or transfer hypotheses that share only one
direction (largest canonical correlation ≥ the threshold, smallest below it) are named "partly
inseparable" as ``baarda test`` names them (:func:`baarda.stats.separability.partly_inseparable`).

The dashboard computes no statistic here: every T (of a hypothesis alone or with the suspects
above it) is the core's test (:meth:`baarda.stats.reliability.Reliability.test`); the list orders,
tiers and names them (issue 15, item 2; issue 31, item 1).
"""

from __future__ import annotations

import time


import numpy as np
import pandas as pd
import scipy.sparse as sp
from scipy import stats

from baarda.errors import BaardaError
from baarda.stats import gnss, separability
from baarda.stats.ap_tests import ap_test
from baarda.stats.hypotheses import common_error, selection

from . import auxdata, geometry
from .jobs import shared
from .text import plain

#: Observations listed: the largest |w| (the rejected ones first, as they have the largest).
TOP_1D = 40
#: Groups listed: the largest T / k (the rejected ones first).
TOP_GROUPS = 30
#: GNSS centres (and IMU attitudes) listed at most besides the largest groups (smallest p first):
#: TOP_AUX, fewer on a large block — each row is compared with the others for twins (a solve with
#: the block's factor) — at most max(:data:`MIN_TIERED`, :data:`TIER_BUDGET` // n) of each.
TOP_AUX = 100
#: Points whose point-transfer hypotheses are scanned (those of the largest suspects).
TRANSFER_POINTS = 8
#: Transfer hypotheses kept per point (the largest T / k first).
TRANSFER_PER_POINT = 3

#: Suspects tested given the stronger ones at most (the first screen and more); the rejected rows
#: below them are ranked by their own p-value without the conditional test.
MAX_CAUSES = 15
#: A rejected row the suspects above do not reject given them stays a suspect of its own while it
#: keeps more than this share of its statistic T given them (a marginal error — a weakly
#: controlled point — loses its rejection to any small correlation; smear from a large error loses
#: most of its T).
KEPT = 0.5
#: The tiering's budget, in rejected rows examined × observations of the block (each row costs a
#: few tests, each a solve with the block's factor: ~1 s at 10⁵ observations): at most
#: max(:data:`MIN_TIERED`, TIER_BUDGET // n) rows are tiered, the rest ranked by their own p-value.
#: A count, not seconds: the list must not depend on how busy the machine is.
TIER_BUDGET = 2_000_000
MIN_TIERED = 10
#: Causes tried one by one to name the one that explains a row (else "the suspects above").
NAME_TRIES = 3

COLUMNS = ["rank", "what", "hypothesis", "p", "decision", "explained by", "|w|", "|τ|", "T", "k", "q",
           "MDB ratio", "∇ŝ", "cannot be told apart from", "obs", "point", "image"]
#: Columns after :data:`COLUMNS` for the downloads: ∇ŝ as a tuple of numbers in the file's unit
#: of its observations, and that unit (:mod:`baarda.dashboard.tables`).
EXTRA = ["∇ŝ values", "∇ŝ unit"]


def log_p(T: float, q: int, policy=None, tau: float | None = None, dof: int = 0) -> float:
    """Natural logarithm of the p-value of a test under ``policy``: χ²(q) of T (F80 eq. 12;
    q = 1 is the two-sided normal test of w, T = w²), or, for one observation when the policy
    decides on τ (``tau`` given), Pope's P(|τ| ≥ |tau|) with τ²/r ~ Beta(1/2, (r−1)/2) (P76).
    NaN for a test that sees nothing (q = 0) or an undefined statistic."""
    if policy is not None and policy.sigma0 == "aposteriori" and tau is not None:
        if not (np.isfinite(tau) and dof > 1):
            return float("nan")
        return float(stats.beta.logsf(min(tau * tau / dof, 1.0), 0.5, (dof - 1) / 2.0))
    if not (q > 0 and np.isfinite(T)):
        return float("nan")
    return float(stats.chi2.logsf(max(T, 0.0), q))


def _max_abs(values: np.ndarray, rows) -> float:
    v = np.abs(np.asarray(values, dtype=float)[np.asarray(rows, dtype=np.int64)])
    v = v[np.isfinite(v)]
    return float(v.max()) if v.size else float("nan")


def _estimate_text(nabla, factor: float, unit: str) -> str:
    return ", ".join(f"{x * factor:+.3g}" for x in np.atleast_1d(nabla)) + f" {unit}"


def _values(nabla, factor: float) -> tuple[float, ...]:
    """∇ŝ as numbers in the file's unit (the downloads' typed columns)."""
    return tuple(float(x) * factor for x in np.atleast_1d(nabla))


def _point_of(state, rows) -> int | None:
    """The point an observation set is about (the last point named by its first row)."""
    pts = state.problem_index()["obs_points"][int(rows[0])] if len(rows) else []
    return int(pts[-1]) if pts else None


def group_name(state, rows) -> tuple[str, str]:
    """(what, name) of an observation group (full indices): an image point, a control point, a
    GNSS vector or a plain group, named by its ids."""
    info = state.problem.info
    ids = info.ids[int(rows[0])]
    kinds = {str(info.kind[int(i)]) for i in rows}
    if kinds and all(k.startswith("gnss-") for k in kinds) and "image" in ids:
        strip = f" (strip {ids['strip']})" if ids.get("strip") not in (None, "") else ""
        return "GNSS centre", f"image {ids['image']}{strip}"
    if kinds and all(k.startswith("imu-") for k in kinds) and "image" in ids:
        return "IMU attitude", f"image {ids['image']}"
    if "image" in ids and "point" in ids:
        kp = f" (keypoint {ids['keypoint']})" if ids.get("keypoint") is not None else ""
        return "image point", f"{ids['point']} in image {ids['image']}{kp}"
    if "id" in ids and all(k.startswith("control") for k in kinds):
        return "control point", f"{ids['id']}"
    if "from" in ids:
        rest = [str(v) for k, v in ids.items() if k not in ("from", "component", "group", "set")]
        what = "vector" if any("gnss" in k or "vector" in k for k in kinds) else "group"
        return what, f"{ids['from']}→{','.join(rest)}"
    return "group", " ".join(str(v) for v in ids.values())


def _one_dimensional(state, picked: np.ndarray) -> list[dict]:
    """Rows of the w-tests (τ-tests under σ̂0) of the reduced observations ``picked``: T = w²
    against k = w_c² (F80 eq. 12 with H = e_i, q = 1), ∇ŝ = −(Pv)_i / (P C_vv P)_ii (F80 eq. 10,
    as :mod:`baarda.stats.snooping` reports it), from the core's arrays (no solve per row)."""
    s = state
    adj, rel = s.results, s.reliability
    factor, units = s.problem_index()["factor"]
    obs, _ = s.frames()
    d0 = rel.delta0
    stat = np.asarray(rel.statistic, dtype=float)
    out = []
    for k in picked.tolist():
        i = int(s.kept[k])
        ids = s.problem.info.ids[i]
        qpp = float(adj.qvv_pp[k])
        nabla = -float(adj.Pv[k]) / qpp if qpp > 0 else float("nan")
        out.append({"what": "observation", "hypothesis": plain(f"{i} {obs['kind'].iat[i]} {obs['ids'].iat[i]}"),
                    "|w|": abs(float(adj.w[k])), "|τ|": abs(float(adj.tau[k])),
                    "T": float(stat[k]) ** 2, "k": float(rel.critical) ** 2, "rejected": bool(rel.rejected[k]),
                    "q": 1, "_logp": log_p(float(adj.w[k]) ** 2, 1, rel.policy, float(adj.tau[k]), int(adj.dof)),
                    "∇ŝ": _estimate_text(nabla, factor[i], units[i]), "_nabla": _values(nabla, factor[i]), "_unit": units[i],
                    "MDB ratio": abs(float(stat[k])) / d0,
                    "obs": i, "point": _point_of(s, [i]),
                    "image": str(ids["image"]) if "image" in ids else None,
                    "_H": selection(adj.n, [k]), "_key": ("obs", k)})
    return out


def _groups(state) -> list[dict]:
    s = state
    adj, rel = s.results, s.reliability
    g = rel.groups
    if len(g) == 0:
        return []
    factor, units = s.problem_index()["factor"]
    q = np.asarray(g.dimension, dtype=np.int64)
    logp = np.where(q > 0, stats.chi2.logsf(np.maximum(np.nan_to_num(np.asarray(g.T, dtype=float), nan=0.0), 0.0),
                                            np.maximum(q, 1)), np.inf)
    order = np.argsort(logp, kind="stable")
    chosen = [int(k) for k in order[:TOP_GROUPS] if np.isfinite(logp[k])]
    # every GNSS centre and IMU attitude (up to TOP_AUX of each) besides the largest groups
    kind = s.problem.info.kind
    first = np.asarray(s.kept)[np.asarray(g.members)[np.asarray(g.ptr)[:-1]]] if len(g) else np.zeros(0, dtype=np.int64)
    taken = set(chosen)
    top_aux = min(TOP_AUX, max(MIN_TIERED, TIER_BUDGET // max(int(adj.n), 1)))
    for prefix in ("gnss-", "imu-"):
        aux = [int(k) for k in order if str(kind[int(first[k])]).startswith(prefix) and np.isfinite(logp[k])]
        for k in aux[:top_aux]:
            if k not in taken:
                chosen.append(k)
                taken.add(k)
    out = []
    for k in chosen:
        d = g[k]
        members = np.asarray(d["members"], dtype=np.int64)
        rows = s.kept[members]
        what, name = group_name(s, rows)
        i0 = int(rows[0])
        q = int(d["dimension"])
        ids = s.problem.info.ids[i0]
        out.append({"what": what, "hypothesis": plain(name),
                    "|w|": _max_abs(adj.w, members), "|τ|": _max_abs(adj.tau, members),
                    "T": float(d["T"]), "k": float(d["critical"]), "rejected": bool(d["rejected"]),
                    "q": q, "_logp": log_p(float(d["T"]), q),
                    "∇ŝ": _estimate_text(d["nabla"], factor[i0], units[i0]),
                    "_nabla": _values(d["nabla"], factor[i0]), "_unit": units[i0],
                    "MDB ratio": float(np.sqrt(max(d["T"], 0.0)) / rel.policy.delta0(q)) if q else float("nan"),
                    "obs": i0, "point": _point_of(s, rows),
                    "image": str(ids["image"]) if "image" in ids else None,
                    "_H": selection(adj.n, members), "_key": ("group", int(d["group"]))})
    return out


def _strips(state) -> list[dict]:
    """Rows of the GNSS strip tests: a shift the model does not estimate (H = (0 … I₃ … I₃ … 0)ᵀ,
    F80 §2.2; the core's :meth:`baarda.analysis.Analysis.gnss_strip_tests`), and the AP-group
    test (F80 §7.2) of each strip's estimated shift and drift (no ``_H``: not tiered)."""
    s = state
    adj, rel = s.results, s.reliability
    problem = adj.problem
    if not any(str(k).startswith("gnss-") for k in problem.info.kind):
        return []
    out = []
    for t in auxdata.strip_rows(s):
        try:
            H = gnss.h_gnss_strip(problem, t["images"])
        except (BaardaError, ValueError):
            continue                       # a centre partly excluded: the core tested the others
        rows = np.unique(H.indices)
        i0 = int(s.kept[rows[0]])
        q = int(t["q"])
        out.append({"what": "GNSS strip", "hypothesis": plain(f"shift of strip {t['strip']} ({len(t['images'])} centres)"),
                    "|w|": _max_abs(adj.w, rows), "|τ|": _max_abs(adj.tau, rows),
                    "T": float(t["T"]), "k": float(t["critical"]), "rejected": bool(t["rejected"]),
                    "q": q, "_logp": log_p(float(t["T"]), q),
                    "∇ŝ": _estimate_text(t["nabla"], 1.0, "m"), "_nabla": _values(t["nabla"], 1.0), "_unit": "m",
                    "MDB ratio": float(np.sqrt(max(t["T"], 0.0)) / rel.policy.delta0(q)) if q else float("nan"),
                    "obs": i0, "point": None, "image": None, "_H": H, "_key": ("strip", str(t["strip"]))})
    for key in problem.notes.ap_groups:
        strip, _, group = key.rpartition(":")
        if group not in ("gnss-shift", "gnss-drift"):
            continue
        try:
            t = ap_test(adj, strip, group, policy=rel.policy)
        except (BaardaError, np.linalg.LinAlgError, ValueError):
            continue
        q = int(t.q)
        unit = "m" if group == "gnss-shift" else "m per time unit"
        rows = [k for k, ids in enumerate(problem.info.ids)
                if str(problem.info.kind[k]).startswith("gnss-") and str(ids.get("strip", "")) == strip]
        out.append({"what": "GNSS strip", "hypothesis": plain(f"{group[5:]} of strip {strip} (estimated)"),
                    "|w|": float("nan"), "|τ|": float("nan"),
                    "T": float(t.T), "k": float(t.critical), "rejected": bool(t.T > t.critical),
                    "q": q, "_logp": log_p(float(t.T), q),
                    "∇ŝ": _estimate_text(t.estimate, 1.0, unit), "_nabla": _values(t.estimate, 1.0), "_unit": unit,
                    "MDB ratio": float(np.sqrt(max(t.T, 0.0)) / rel.policy.delta0(q)) if q else float("nan"),
                    "obs": int(s.kept[rows[0]]) if rows else -1, "point": None, "image": None,
                    "_H": None, "_key": ("ap", key)})
    return out


def transfer_candidates(state, point: str) -> list[list[str]]:
    """The image sets of the point-transfer scan of ``point``: every run of at least two
    consecutive images (in the order of the block's images) of one strip in which the point is
    measured, leaving at least one of its images outside (else the error is absorbed by the
    point's coordinates and cannot be tested)."""
    order = {str(im["id"]): k for k, im in enumerate(geometry.images(state.problem))}
    strip = {str(im["id"]): str(im.get("strip", "")) for im in geometry.images(state.problem)}
    seen = [im for im in geometry.images_of_point(state.problem_index(), point) if im in order]
    if len(seen) < 3:
        return []
    by_strip: dict = {}
    for im in sorted(seen, key=order.get):
        by_strip.setdefault(strip[im], []).append(im)
    out = []
    for ims in by_strip.values():
        for a in range(len(ims)):
            for b in range(a + 2, len(ims) + 1):
                run = ims[a:b]
                if len(run) < len(seen) and all(order[y] - order[x] == 1 for x, y in zip(run, run[1:])):
                    out.append(run)
    return out


def _transfers(state, seeds: list[dict]) -> list[dict]:
    """Point-transfer scans of the points of the largest image suspects (``seeds`` sorted)."""
    s = state
    if not geometry.images(s.problem) or not any(str(k).startswith("image") for k in set(s.problem.info.kind)):
        return []
    adj, rel = s.results, s.reliability
    factor, units = s.problem_index()["factor"]
    points = []
    for row in seeds:
        ids = s.problem.info.ids[int(row["obs"])]
        pid = str(ids.get("point")) if "image" in ids and "point" in ids else None
        if pid is not None and pid not in points:
            points.append(pid)
        if len(points) >= TRANSFER_POINTS:
            break
    out = []
    for pid in points:
        found = []
        for ims in transfer_candidates(s, pid):
            rows = [s.reduced_index(geometry.point_rows_in_image(s.problem_index(), j, pid)) for j in ims]
            rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
            rows = rows[rows >= 0]
            comps: dict = {}
            for k in rows.tolist():
                i = int(s.kept[k])
                c = s.problem.info.ids[i].get("component") or s.problem.info.kind[i].rsplit("-", 1)[-1]
                comps.setdefault(str(c), []).append(k)
            if not comps:
                continue
            H = common_error(adj.n, [np.array(comps[c], dtype=np.int64) for c in sorted(comps)])
            try:
                h = rel.test(H, label=f"transfer of {pid} in images {', '.join(ims)}")
            except (BaardaError, np.linalg.LinAlgError, ValueError):
                continue
            if h.q == 0:
                continue
            i0 = int(s.kept[rows[0]])
            found.append({"what": "transfer", "hypothesis": plain(f"{pid} in images {', '.join(ims)}"),
                          "|w|": _max_abs(adj.w, rows), "|τ|": _max_abs(adj.tau, rows),
                          "T": float(h.T), "k": float(h.critical_T), "rejected": bool(h.rejected_T),
                          "q": int(h.q), "_logp": log_p(float(h.T), int(h.q)),
                          "∇ŝ": _estimate_text(h.nabla, factor[i0], units[i0]),
                          "_nabla": _values(h.nabla, factor[i0]), "_unit": units[i0],
                          "MDB ratio": float(np.sqrt(max(h.T, 0.0)) / h.delta0),
                          "obs": i0, "point": s.problem_index()["point_index"].get(pid), "image": ims[0],
                          "_H": H, "_key": ("transfer", pid, tuple(ims))})
        found.sort(key=_order)
        out += found[:TRANSFER_PER_POINT]
    return out


def _order(row: dict) -> tuple:
    """Sort key of one scale: the p-value (smallest first), then the larger hypothesis (its
    dimension, then its observations: an image point before its coordinates), then the first
    observation in the file (twins have one p-value)."""
    lp = row["_logp"]
    cols = row["_H"].shape[1] if row.get("_H") is not None else 0
    return (round(lp, 6) if np.isfinite(lp) else np.inf, -int(row.get("q") or 0), -int(cols), int(row["obs"]))


def _rank_key(row: dict) -> tuple:
    """The suspects of their own by p-value, each followed by its alternatives; then the rest."""
    alt = row.get("_alt")
    if alt is not None:
        return (0,) + _order(alt) + (1,) + _order(row)
    return (row["_tier"],) + _order(row) + (0,)


def _stack(a, b):
    return sp.hstack([sp.csc_matrix(a), sp.csc_matrix(b)]).tocsc()


def _explain(state, rows: list[dict]) -> None:
    """Tier each row (module docstring): a rejected row is a suspect of its own (``_tier`` 0) when
    its test given the suspects above it, T(H_C, H) − T(H_C) against χ²_{1−α}(q' − q_C) (F80 §2.2,
    eq. 12 in the model extended by C), still rejects; else (``_tier`` 1) ``explained by`` names
    the suspect above that explains it alone (of the first :data:`NAME_TRIES` sharing its point or
    image, then the strongest), or "the suspects above". Rows are visited by p-value; past
    :data:`MAX_CAUSES` suspects, or past the rows :data:`TIER_BUDGET` allows (a block of 10⁵
    observations solves for a second per test), the rejected rows stay in the first tier untested."""
    rel = state.reliability
    policy = rel.policy
    causes: list[dict] = []
    HC, TC, qC = None, 0.0, 0
    budget = max(MIN_TIERED, TIER_BUDGET // max(int(state.results.n), 1))
    seen = 0
    for r in sorted(rows, key=_order):
        r["_tier"], r["explained by"], r["_alt"] = 1, "", None
        if not r["rejected"]:
            continue
        if len(causes) >= MAX_CAUSES or seen >= budget:
            r["_tier"] = 0
            continue
        seen += 1
        own = HC is None
        if not own:
            try:
                h = rel.test(_stack(HC, r["_H"]))
                dq, dT = int(h.q) - qC, float(h.T) - TC
                own = dq > 0 and (dT > policy.critical_T(dq) or dT > KEPT * _own(rel, r)[0])
            except (BaardaError, np.linalg.LinAlgError, ValueError):
                own = True
        if own:
            r["_tier"] = 0
            HC = r["_H"] if HC is None else _stack(HC, r["_H"])
            if len(causes) == 0:
                TC, qC = _own(rel, r)
            else:
                hc = rel.test(HC)
                TC, qC = float(hc.T), int(hc.q)
            causes.append(r)
            continue
        c, alternative = _explainer(state, r, causes)
        r["explained by"] = "the suspects above" if c is None else f"{c['what']} {c['hypothesis']}"
        if alternative:
            r["_tier"], r["_alt"] = 0, c
            r["explained by"] = f"or {r['explained by']}"


def _own(rel, row: dict) -> tuple[float, int]:
    """(T, q) of ``row``'s hypothesis alone under σ0 a priori (cached on the row)."""
    if "_Tq" not in row:
        h = rel.test(row["_H"])
        row["_Tq"] = (float(h.T), int(h.q))
    return row["_Tq"]


def _related(state, row: dict, c: dict) -> bool:
    """Whether suspect ``c`` shares ``row``'s point or image, or both are observations of one
    kind outside the images (control points, GNSS vectors: the datum ties them together)."""
    if (row["point"] is not None and c["point"] == row["point"]) or (row["image"] is not None and c["image"] == row["image"]):
        return True
    kind = state.problem.info.kind
    return (row["image"] is None and c["image"] is None
            and str(kind[int(row["obs"])]) == str(kind[int(c["obs"])]))


def _explainer(state, row: dict, causes: list[dict]) -> tuple[dict | None, bool]:
    """The suspect that alone explains ``row`` best (its test given that one does not reject, the
    smallest conditional T), tried among the first :data:`NAME_TRIES` of ``causes`` related to it
    (:func:`_related`) and the strongest; None if none does. Second: whether ``row`` is an
    *alternative* to it — a hypothesis of the same dimension that explains it in turn (their tests
    nearly perfectly correlated but below the twins' threshold: the data hardly prefer one),
    listed with it."""
    rel, policy = state.reliability, state.reliability.policy
    near = [c for c in causes if _related(state, row, c)][:NAME_TRIES]
    tried = near + [c for c in causes[:1] if c not in near]
    best = None
    for c in tried:
        try:
            Tc, qc = _own(rel, c)
            h = rel.test(_stack(c["_H"], row["_H"]))
        except (BaardaError, np.linalg.LinAlgError, ValueError):
            continue
        dq, dT = int(h.q) - qc, float(h.T) - Tc
        explains = dq <= 0 or (dT <= policy.critical_T(dq) and dT <= KEPT * _own(rel, row)[0])
        if explains and (best is None or dT < best[1]):
            best = (c, dT, dq, float(h.T))
    if best is None:
        return None, False
    c, dT, dq, Tcr = best
    alt = False
    if dq > 0 and int(c["q"]) == int(row["q"]):
        Tr, _ = _own(rel, row)
        back = Tcr - Tr
        alt = back <= policy.critical_T(dq) and back <= KEPT * _own(rel, c)[0]
    return c, alt


def _mark_twins(state, rows: list[dict]) -> None:
    """Each row's "cannot be told apart from": its twins among the other rows (F80 §7.4), from
    the core's :func:`baarda.stats.separability.twins` (w-tests) and
    :func:`~baarda.stats.separability.inseparable_pairs` (the group and transfer hypotheses)."""
    adj = state.results
    for r in rows:
        r["_twins"] = []
    one = {r["_key"][1]: r for r in rows if r["_key"][0] == "obs"}
    for k, r in one.items():
        for j, rho in separability.twins(adj, k):
            name = plain(f"obs {int(state.kept[j])} {state.frames()[0]['ids'].iat[int(state.kept[j])]}")
            r["_twins"].append(f"{name} (ρ = {rho:+.2f})")
    multi = [r for r in rows if r["_key"][0] != "obs"]
    if len(multi) >= 2:
        labels = [str(n) for n in range(len(multi))]
        groups = separability.inseparable_pairs(adj, [(lab, r["_H"]) for lab, r in zip(labels, multi)])
        for grp in groups:
            members = [multi[int(m)] for m in grp.members]
            for r in members:
                r["_twins"] += [f"{o['what']} {o['hypothesis']}" for o in members if o is not r]
        # partly inseparable (F80 §7.4), named as `baarda test` names them: one direction of
        # their test spaces shared (largest canonical correlation ≥ 0.99), the others not
        for pair in separability.partly_inseparable(adj, [(lab, r["_H"]) for lab, r in zip(labels, multi)]):
            a, b = (multi[int(m)] for m in pair.members)
            corr = f"canonical correlations {pair.largest:.2f} … {pair.smallest:.2f}"
            a["_twins"].append(f"partly inseparable from {b['what']} {b['hypothesis']} ({corr})")
            b["_twins"].append(f"partly inseparable from {a['what']} {a['hypothesis']} ({corr})")


#: Seconds the suspects may take before the tiering (:func:`_explain`) for the list to be shown
#: untiered first (``early`` of :func:`suspects`): on a real COLMAP block (5,931 image points,
#: 1,443 points) the list took 10 s and its tiering 14 s more (issue 31, item 10).
EARLY_AFTER = 2.0


def suspects(state, early=None) -> pd.DataFrame:
    """The ranked list of suspects of ``state`` (module docstring): one row per hypothesis,
    ranked on one scale — the rejected hypotheses the stronger ones do not explain first, then the
    others, each tier by p-value (smallest first) — with ``rank`` 1, 2, …; ``p`` the p-value of
    the row's own test (0 where it underflows), ``q`` its dimension; ``decision`` is "rejected" or
    "accepted"; ``obs``, ``point`` and ``image`` say what a click selects (full observation index,
    point index, image id).

    Computed once per adjustment and test policy for all the sessions of a server
    (:func:`baarda.dashboard.jobs.shared`: sessions opened on a cached file share its
    adjustment, and its kept observations with it): the frame is shared, not to be changed.

    ``early(frame)``, if given, is called with the list ranked by p-value alone (rejected first,
    nothing "explained by") when the list has taken :data:`EARLY_AFTER` seconds before its
    tiering: a view shows it while the tiering runs (not called when the list is cached)."""
    if state.results is None:
        return pd.DataFrame(columns=COLUMNS + EXTRA)
    return shared(state.results, ("suspects", state.reliability.policy), lambda: _ranked(state, early))


def _ranked(state, early=None) -> pd.DataFrame:
    t0 = time.perf_counter()
    s = state
    rel = s.reliability
    stat = np.abs(np.nan_to_num(np.asarray(rel.statistic, dtype=float), nan=-1.0))
    order = np.argsort(-stat, kind="stable")
    picked = order[:TOP_1D]
    picked = picked[stat[picked] >= 0]
    rows = _one_dimensional(s, picked)
    rows += _groups(s)
    seeds = sorted(rows, key=_order)
    rows += _transfers(s, [r for r in seeds if r["image"] is not None])
    strips = _strips(s)
    rows += [r for r in strips if r["_H"] is not None]
    _mark_twins(s, rows)
    if early is not None and time.perf_counter() - t0 >= EARLY_AFTER:
        for r in rows:
            r["_tier"], r["explained by"], r["_alt"] = (0 if r["rejected"] else 1), "", None
        early(_frame(sorted(rows, key=_rank_key)))
    _explain(s, rows)
    for r in strips:                       # AP-group tests: by their own p-value (module docstring)
        if r["_H"] is None:
            r.update(_twins=[], _alt=None, _tier=0 if r["rejected"] else 1)
            r["explained by"] = ""
            rows.append(r)
    rows.sort(key=_rank_key)
    return _frame(rows)


def _frame(rows: list[dict]) -> pd.DataFrame:
    """The ranked rows as the suspects' frame (rank 1, 2, …)."""
    df = pd.DataFrame([{**{c: r.get(c) for c in COLUMNS if c in r},
                        "p": float(np.exp(r["_logp"])),
                        "decision": "rejected" if r["rejected"] else "accepted",
                        "cannot be told apart from": "; ".join(r["_twins"])} for r in rows])
    if df.empty:
        return pd.DataFrame(columns=COLUMNS + EXTRA)
    df.insert(0, "rank", np.arange(1, len(df) + 1))
    df["q"] = df["q"].astype(np.int64)
    df[EXTRA] = pd.DataFrame([(r["_nabla"], r["_unit"]) for r in rows], columns=EXTRA)
    return df[COLUMNS + EXTRA]
