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
from ..errors import BaardaError
from ..model.bundle import check_points, has_check_points
from ..stats.ap_tests import ap_tests
from ..stats.check_points import check_point_tests
from ..stats.gnss import strip_tests
from ..stats.pose import POSE_NAMES, pose_covariance, pose_parameters, pose_sigma, pose_values
from ..stats.reliability import reliability_of
from . import columns as columns_, csv_rows
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
    millions of dicts (~1 KB each). ``fields()``, where given, makes the same table as columns
    (:class:`baarda.io.columns.Field`), which :func:`dump_json`, :func:`write_csv` and
    :func:`columns` write a chunk of rows at a time (the per-record path is their reference).
    ``add(f, fields)`` merges ``f(i)`` (a dict) into record i (the CLI's --risk columns), and
    ``fields()`` its keys as columns (without them the table is written record by record)."""

    def __init__(self, n: int, make, fields=None):
        self._n, self._make, self._extra = int(n), make, []
        self._fields = fields

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
        for f, _ in self._extra:
            d.update(f(i))
        return d

    def __iter__(self):
        for i in range(self._n):
            yield self[i]

    def __eq__(self, other):
        return isinstance(other, (list, Records)) and len(other) == self._n and all(a == b for a, b in zip(self, other))

    __hash__ = None

    def add(self, f, fields=None) -> None:
        self._extra.append((f, fields))

    def fields(self) -> list | None:
        """The table as :class:`~baarda.io.columns.Field` s, or None where some part of it has
        no columnar form (its keys not in one order over the records, an extra without fields)."""
        if self._fields is None or any(fl is None for _, fl in self._extra):
            return None
        base = self._fields()
        if base is None:
            return None
        out = list(base)
        for _, fl in self._extra:
            for f in fl():
                known = [k for k, g in enumerate(out) if g.key == f.key]
                if known:
                    return None          # an extra that replaces a key keeps its place: record by record
                out.append(f)
        return out

    def json_lines(self, fields, sl: slice) -> str:
        """The compact JSON text of records ``sl``, one per line, joined by ``",\\n  "``
        (:func:`baarda.io.columns.rows_text`)."""
        return columns_.rows_text(fields, sl, sl.stop - sl.start)


def observations(adj, reliability=None) -> Records:
    """One record per observation; ``rejected`` by the statistic of ``reliability``'s policy (w
    or τ), ``rejected_w`` and ``rejected_tau`` by each."""
    rel = reliability_of(adj) if reliability is None else reliability
    info = adj.problem.info
    sig = adj.problem.cov.sigma()
    r, w, tau, mdb, ext = adj.r, adj.w, adj.tau, rel.mdb, rel.external
    # r_i = (Q_vv P)_ii in [0, 1] (F80 §5, eq. 8: a diagonal element of an idempotent matrix); round-off beyond it
    # (-2e-14 for an observation left without redundancy) is written as the bound
    r = np.where((r < 0) & (r > -1e-9), 0.0, np.where((r > 1) & (r < 1 + 1e-9), 1.0, r))
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

    def fields():
        F = columns_.Field
        n = adj.n
        ids = _id_fields(info.ids, n)
        if ids is None:
            return None
        f = [F("index", "int", np.arange(n, dtype=np.int64)), F("kind", "str", info.kind), *ids]
        num = {"value": info.value_file, "sigma": info.sigma_file, "sigma_si": sig, "residual": v, "redundancy": r,
               "u_k": u_k, "u_t": u_t, "w": w, "tau": tau, "mdb": mdb, "external": ext,
               "lambda_bar": _squares(ext)}
        for key in ("value", "unit", "sigma", "sigma_unit", "sigma_si", "line", "residual", "redundancy", "u_k",
                    "u_t", "w", "tau", "mdb", "external", "lambda_bar"):
            if key in num:
                f.append(F(key, "num", np.asarray(num[key], dtype=float)))
            elif key == "line":
                f.append(F(key, "int", np.asarray(info.line).astype(np.int64)))
            else:
                f.append(F(key, "str", getattr(info, key)))
        for key, a in (("rejected", rej), ("rejected_w", rej_w), ("rejected_tau", rej_tau), ("uncontrolled", unc)):
            f.append(F(key, "bool", np.asarray(a, dtype=bool)))
        group = np.asarray(info.group).astype(np.int64)
        has = group >= 0
        if has.any():
            f.append(F("group", "int", group, None if has.all() else has))
        if len({g.key for g in f}) != len(f):
            return None                  # an id named as another key: record by record
        return f
    return Records(adj.n, make, fields)


def _squares(a) -> np.ndarray:
    """a[i] ** 2 as each record has it (libm's pow; the array's a ** 2 is x·x, which differs in
    the last bit), a chunk at a time (no list of millions of floats)."""
    a = np.asarray(a, dtype=float)
    out = np.empty(a.size)
    for sl in columns_.chunks(a.size):
        out[sl] = [x ** 2 for x in a[sl].tolist()]
    return out


def _id_fields(ids, n: int) -> list | None:
    """The observations' id keys as fields, or None where the records do not all have their
    keys in one order (then the table is written record by record)."""
    if getattr(ids, "roles", None) is not None:         # RecordIds: per role its values and codes
        out = []
        for k, role in enumerate(ids.roles):
            codes = np.asarray(ids.codes[:, k])
            has = codes >= 0
            vals = list(ids.values[k])
            if all(type(x) is str for x in vals):
                out.append(columns_.Field(role, "str", columns_.Codes(vals, codes), None if has.all() else has))
            else:
                out.append(columns_.Field(role, "obj", lambda sl, vals=vals, codes=codes: [
                    vals[c] if c >= 0 else None for c in codes[sl].tolist()], None if has.all() else has))
        return out
    sigs = list(dict.fromkeys(map(tuple, ids)))
    order: list = []
    for s in sigs:                       # a key new to the order goes before the next key of its record
        for j, k in enumerate(s):
            if k not in order:
                after = next((order.index(x) for x in s[j + 1:] if x in order), len(order))
                order.insert(after, k)
    pos = {k: j for j, k in enumerate(order)}
    if any(any(pos[a] > pos[b] for a, b in zip(s, s[1:])) for s in sigs):
        return None
    out = []
    for key in order:
        everywhere = all(key in s for s in sigs)
        vals = [d.get(key) for d in ids]
        present = None if everywhere else np.fromiter((key in d for d in ids), dtype=bool, count=n)
        kind = "str" if all(type(x) is str for x in vals if x is not None) else "obj"
        out.append(columns_.Field(key, kind, vals if kind == "str" else (lambda sl, vals=vals: vals[sl]), present))
    return out


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

    def fields():
        F = columns_.Field
        ids = list(pts.ids)
        f = [F("id", "str" if all(type(x) is str for x in ids) else "obj",
               ids if all(type(x) is str for x in ids) else (lambda sl: ids[sl])),
             F("status", "str", list(pts.status))]
        X, S = np.asarray(xyz, dtype=float), np.asarray(sig, dtype=float)
        for a, name in enumerate("xyz"):
            on = np.asarray(pts.index)[:, a] >= 0
            for key, col in ((name, X[:, a]), ("s" + name, S[:, a])):
                present = on & np.isfinite(col)
                f.append(F(key, "num", col, None if present.all() else present))
        return f
    return Records(len(pts.ids), make, fields)


def has_images(adj) -> bool:
    """Whether the adjustment is a bundle block's (it has images with poses)."""
    geo = adj.problem.geometry
    if geo is None or not geo.images or adj.problem.notes.imodel is not None:
        return False
    try:
        pose_parameters(adj.problem)         # every image's pose where the block's layout puts it
    except BaardaError:
        return False
    return True


def images(adj) -> Records:
    """The images' adjusted poses and their precision (:mod:`baarda.stats.pose`): per image
    ``id``, ``camera``, X0, Y0, Z0 (object units), omega, phi, kappa (radians), their standard
    deviations ``sX0`` … ``skappa`` and ``centre_cov``, the 3 × 3 covariance of the projection
    centre, in the adjustment's datum, σ0 as the problem uses it. Computed when first read."""
    geo = adj.problem.geometry
    held: dict = {}

    def arrays():
        if not held:
            cov = pose_covariance(adj)
            held.update(x=pose_values(adj), cov=cov, sd=pose_sigma(cov))
        return held

    def make(i):
        a = arrays()
        im = geo.images[i]
        d = {"id": im.id, "camera": im.camera}
        for k, name in enumerate(POSE_NAMES):
            val = _num(a["x"][i, k])
            if val is not None:
                d[name] = val
        for k, name in enumerate(POSE_NAMES):
            val = _num(a["sd"][i, k])
            if val is not None:
                d["s" + name] = val
        d["centre_cov"] = [[_num(v) for v in row] for row in a["cov"][i, :3, :3].tolist()]
        return d
    return Records(len(geo.images), make)


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

    def fields():
        F = columns_.Field
        ptr = np.asarray(gs.ptr, dtype=np.int64)
        axes = np.asarray(gs.ellipse_axes, dtype=float)
        keep = np.isfinite(axes)
        kept_ptr = np.concatenate([[0], np.cumsum(keep)])[ptr]
        lists = {"members": (np.asarray(gs.members, dtype=np.int64), ptr, False),
                 "nabla": (np.asarray(gs.nabla, dtype=float), ptr, True),
                 "nabla_sigma": (np.asarray(gs.nabla_sigma, dtype=float), ptr, True),
                 "ellipse_axes": (axes[keep], kept_ptr, True)}

        def listed(key):
            flat, p, real = lists[key]

            def values(sl):
                a0, b0 = int(p[sl.start]), int(p[sl.stop])
                vals = columns_.num_values(flat[a0:b0]) if real else flat[a0:b0].tolist()
                return [vals[a - a0:b - a0] for a, b in zip(p[sl].tolist(), p[1:][sl].tolist())]

            def text(sl):
                return columns_.ragged_texts(flat, p[sl.start:sl.stop + 1], real)
            return F(key, "obj", values, text=text)
        f = [F("group", "int", np.asarray(gs.group, dtype=np.int64)), listed("members")]
        for key in ("T", "dimension", "redundancy", "critical", "alpha", "rejected", "R", "critical_R",
                    "nabla", "nabla_sigma", "ellipse_axes", "delta0_prime_max"):
            if key in lists:
                f.append(listed(key))
            elif key == "dimension":
                f.append(F(key, "int", np.asarray(gs.dimension, dtype=np.int64)))
            elif key == "rejected":
                f.append(F(key, "bool", np.asarray(gs.rejected, dtype=bool)))
            else:
                f.append(F(key, "num", np.asarray(getattr(gs, key), dtype=float)))
        return f
    return Records(len(gs), make, fields)


def risk_fields(r, n: int) -> list:
    """The ``risk`` key of the observations' records (``--risk``, M84 §3.3) as a field: an
    object of λtol, C, α, β, r_C and the decision per observation."""
    F = columns_.Field
    names = ("lam_tol", "C", "alpha", "beta", "r_C")
    sub = [F(k, "num", np.broadcast_to(np.asarray(getattr(r, k), dtype=float), (n,))) for k in names]
    sub.append(F("rejected", "bool", np.broadcast_to(np.asarray(r.rejected, dtype=bool), (n,))))

    def values(sl):
        cols = [f.python(sl) for f in sub]
        return [dict(zip((*names, "rejected"), row)) for row in zip(*cols)]
    return [F("risk", "obj", values, text=lambda sl: columns_.row_texts(sub, sl, sl.stop - sl.start))]


def to_dict(adj, reliability=None) -> dict:
    """The whole result document (schema version ``SCHEMA_VERSION``), the tests under
    ``reliability`` (default ``reliability_of(adj)``)."""
    rel = reliability_of(adj) if reliability is None else reliability
    doc = {"schema": f"baarda-analysis/{SCHEMA_VERSION}", "summary": summary(adj, rel),
           "observations": observations(adj, rel), "points": points(adj), "groups": groups(adj, rel)}
    if has_images(adj):
        doc["images"] = images(adj)
    if adj.problem.notes.ap_groups:
        doc["ap_tests"] = finite(ap_tests(adj, rel.policy))
    model = adj.problem.notes.local_model
    if has_check_points(model):
        doc["check_points"] = finite(check_point_tests(adj, check_points(adj, model), rel.policy))
    if getattr(model, "gnss", None) is not None and model.gnss.centres:
        strips = strip_tests(adj, rel)
        if strips:
            doc["gnss_strip_tests"] = finite(strips)
    geo = georeference_of(adj)
    if geo is not None:
        doc["georeference"] = finite(geo)
    return doc


def georeference_of(adj) -> dict | None:
    """The similarity a block was georeferenced by (:mod:`baarda.georeference`), or None."""
    extra = getattr(adj.problem.notes.local_model, "extra", None)
    return extra.get("georeference") if isinstance(extra, dict) else None


def columns(records) -> dict:
    """A table of records as columns: ``{key: numpy array}`` in the records' key order. Numbers
    (None where the JSON has null) become float arrays with NaN, booleans and integers keep their
    type where every record has them, anything else (strings, lists, dicts) an object array;
    a key some records lack is missing (NaN / None) there (:func:`baarda.io.columns.column`).
    :class:`Records` with fields are made from their arrays, not record by record."""
    fields = records.fields() if isinstance(records, Records) else None
    if fields is not None:
        n = len(records)
        by_key = {f.key: f for f in fields}
        return {key: columns_.field_column(by_key[key], n) for key in columns_.key_order(fields, n)}
    rows = list(records)
    keys: dict = {}
    for row in rows:
        keys.update(dict.fromkeys(row))
    return {key: columns_.column([row.get(key) for row in rows]) for key in keys}


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
    compact one per record is compiled.) :class:`Records` with fields are written from their
    columns a chunk at a time (the same text, :mod:`baarda.io.columns`)."""
    with atomic_write(path) as fh:
        for chunk in json_chunks(doc):
            fh.write(chunk)


def json_chunks(doc: dict):
    """The text of :func:`dump_json` in pieces (``"".join`` of them is the file's text: a batch
    worker sends it to the client, which writes it)."""
    compact = json.JSONEncoder(allow_nan=False, ensure_ascii=True, separators=(", ", ": "))
    yield "{"
    for k, (key, val) in enumerate(doc.items()):
        yield ("," if k else "") + "\n " + json.dumps(str(key)) + ": "
        fields = val.fields() if isinstance(val, Records) else None
        if fields is not None:           # a chunk of records at a time, from their columns
            yield "["
            for sl in columns_.chunks(len(val)):
                yield ("," if sl.start else "") + "\n  " + val.json_lines(fields, sl)
            yield "\n ]"
        elif isinstance(val, Records) or (isinstance(val, list) and val and all(isinstance(v, dict) for v in val)):
            yield "["
            for i, rec in enumerate(val):
                yield ("," if i else "") + "\n  " + compact.encode(rec)
            yield "\n ]"
        else:
            yield json.dumps(val, indent=1, allow_nan=False).replace("\n", "\n ")
    yield "\n}\n"


def write_csv(adj, directory, doc=None) -> list[Path]:
    """observations.csv, points.csv, groups.csv (images.csv for a bundle block, check_points.csv
    for one with check points: :mod:`baarda.io.csv_rows`) in ``directory`` (created if needed), each
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
    for name in ("observations", "points", "groups", "images", "check_points"):
        if name not in doc:
            continue
        rows = doc[name]                   # (records made twice, streamed: not held)
        if name == "images":
            rows = [csv_rows.image_row(r) for r in rows]
        elif name == "check_points":
            rows = [csv_rows.check_point_row(r) for r in rows["points"]]
        path = d / f"{name}.csv"
        fields = rows.fields() if isinstance(rows, Records) else None
        if fields is not None:
            _csv_from_fields(fields, len(rows), path, mark)
            written.append(path)
            continue
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


def can_write_parquet() -> bool:
    """Whether pyarrow is installed (:func:`write_parquet`)."""
    return columns_.pa is not None


def write_parquet(adj, directory, doc=None) -> list[Path]:
    """observations.parquet, points.parquet and groups.parquet in ``directory`` (created if
    needed): the columns of :func:`write_csv`, typed (:func:`baarda.io.columns.arrow_array`:
    numbers float64 and int64, null where the JSON has null or a record lacks the key, booleans,
    strings, lists of numbers), each file written atomically, the summary as JSON in the schema's
    metadata (``baarda``). Needs pyarrow (the ``batch`` extra): :class:`OutputError` without it."""
    if not can_write_parquet():
        raise OutputError(directory, "cannot write Parquet: pyarrow is not installed (pip install 'baarda[batch]')")
    doc = doc if doc is not None else to_dict(adj)
    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(directory, f"cannot create the folder: {err.strerror or err}") from None
    mark = {} if doc["summary"]["converged"] else {"adjustment": "NOT converged"}
    meta = {"baarda": json.dumps(doc["summary"], allow_nan=False)}
    written = []
    for name in ("observations", "points", "groups"):
        rows, pa = doc[name], columns_.pa
        fields = rows.fields() if isinstance(rows, Records) else None
        if fields is not None:
            n = len(rows)
            by_key = {f.key: f for f in fields}
            cols = {k: columns_.arrow_array(by_key[k], n) for k in columns_.key_order(fields, n)}
        else:
            table = columns(rows)
            n = len(rows)
            cols = {k: columns_.arrow_column(a) for k, a in table.items()}
        for k, text in mark.items():
            cols.setdefault(k, pa.array([text] * n, type=pa.string()))
        table = pa.table(cols).replace_schema_metadata(meta)
        path = d / f"{name}.parquet"
        with atomic_write(path, binary=True) as fh:
            columns_.pq.write_table(table, fh)
        written.append(path)
    return written


def _csv_from_fields(fields, n: int, path, mark: dict) -> None:
    """One CSV of :func:`write_csv` from a table's columns, a chunk of rows at a time: the cells
    the per-record path writes (None and absent keys empty, lists joined by ';', text made safe)."""
    by_key = {f.key: f for f in fields}
    names = columns_.key_order(fields, n) + [k for k in mark if k not in by_key]
    safe: dict = {}

    def cell(v):
        if isinstance(v, str):
            if v not in safe:
                safe[v] = csv_cell(v)
            return safe[v]
        return csv_cell(";".join(map(str, v))) if isinstance(v, list) else v
    with atomic_write(path, newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow([csv_cell(k) for k in (names or ["empty"])])
        for sl in columns_.chunks(n):
            m = sl.stop - sl.start
            cols = []
            for k in names:
                if k not in by_key:
                    cols.append([cell(mark[k])] * m)
                    continue
                f = by_key[k]
                vals = f.python(sl)
                if f.present is not None:
                    vals = [v if p else "" for v, p in zip(vals, f.present[sl].tolist())]
                if f.kind in ("str", "obj"):
                    vals = list(map(cell, vals))
                cols.append(vals)
            wr.writerows(zip(*cols))
