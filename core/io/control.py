"""Control and check points from a CSV file: ``id,X,Y,Z,sx,sy,sz[,role]`` with a header line.

Each row gives the known coordinates of a block point (the ``id`` as the block names it: a
BAL/Bundler point index, a COLMAP POINT3D_ID, a native point id) and their standard deviations,
in the block's object units (metres for native blocks; for structure-from-motion models the
model's own frame and scale — control only makes sense once the model is close to that frame,
since the adjustment linearises at the model's coordinates). The points become weighted control
(observations of X, Y, Z) and the datum is then defined by them instead of the free-block
inner constraints.

An optional ``role`` column says what a row is: ``control`` (the default, also for an empty
cell) or ``check``. A check point never enters the adjustment: it is a point of the block
determined by its image points alone, and its adjusted coordinates are compared with the file's
afterwards (residuals and RMSE per axis, :func:`baarda.model.bundle.check_points`); its σ cells
may be empty. Any other column is refused with its name (a misspelt ``role`` would otherwise make
check points control without a word).

Separators: comma; blank lines and lines starting with ``#`` are skipped; columns are found by
the header names (case-insensitive, in any order). Files as spreadsheets write them are read: a
UTF-8 byte-order mark, CR, LF or CRLF line ends, quoted fields.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math

from ..errors import InputError
from ..model.bundle import Block
from ..model.sfm import ControlPoint, SfmBlock
from ..validate import SIGMA_MAX, SIGMA_MIN, VALUE_LIMIT
from .bal import read_text

COLUMNS = ("id", "x", "y", "z", "sx", "sy", "sz")
#: The optional columns.
OPTIONAL = ("role",)
#: The values of the ``role`` column.
ROLES = ("control", "check")


def csv_rows(path, text: str) -> list[tuple[int, list[str]]]:
    """The CSV records of ``text`` with the line each starts on, as spreadsheets write them: a
    UTF-8 byte-order mark, CR, LF or CRLF line ends, quoted fields (which may hold commas)."""
    if text.startswith("\ufeff"):
        text = text[1:]
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    rows, start = [], 1
    while True:
        try:
            r = next(reader)
        except StopIteration:
            break
        except csv.Error as err:        # an unclosed quote, a field over the csv module's limit
            msg = str(err)
            if "field larger than field limit" in msg:
                msg = f"a field longer than {csv.field_size_limit()} characters"
            raise InputError(path, start, f"not a readable CSV record: {msg}") from None
        rows.append((start, r))
        start = reader.line_num + 1
    return rows


def csv_table(path, required, optional=(), shown: str | None = None):
    """A CSV table whose first row names its columns (any order, any case): blank and ``#`` lines
    skipped; InputError naming the file and line for an empty file, a missing, unknown or repeated
    column, and (as the rows are read) a row with another number of fields than the header.
    ``shown``: the required columns as the message writes them (default as given). Returns
    (column → index, the header's line, an iterator of (line, fields) over the data rows)."""
    shown = shown or ",".join(required)
    text = read_text(path)
    rows = [(ln, r) for ln, r in csv_rows(path, text)
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError(path, 1, f"empty file: expected the header '{shown}'")
    hline, header = rows[0]
    names = [h.strip().lower() for h in header]
    missing = [c for c in required if c not in names]
    if missing:
        raise InputError(path, hline, f"the header must name the columns {shown} (missing: {', '.join(missing)})")
    unknown = [h.strip() for h in header if h.strip().lower() not in (*required, *optional)]
    if unknown:
        known = shown + (f" and the optional {','.join(optional)}" if optional else "")
        raise InputError(path, hline, f"unknown column(s) {', '.join(repr(u[:40]) for u in unknown)} (known: {known})")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(path, hline, f"column(s) {', '.join(dup)} named twice")

    def data():
        for ln, r in rows[1:]:
            if len(r) != len(names):
                raise InputError(path, ln, f"{len(r)} fields, the header has {len(names)}")
            yield ln, r

    return {c: names.index(c) for c in (*required, *optional) if c in names}, hline, data()


def read_control(path) -> list[ControlPoint]:
    """The control points of a CSV file (module docstring); InputError on any bad row."""
    col, hline, rows = csv_table(path, COLUMNS, OPTIONAL, shown="id,X,Y,Z,sx,sy,sz")
    out, seen = [], {}
    for ln, r in rows:
        pid = r[col["id"]].strip()
        if not pid:
            raise InputError(path, ln, "empty id")
        if pid in seen:
            raise InputError(path, ln, f"duplicate id {pid} (first at line {seen[pid]})")
        seen[pid] = ln
        role = r[col["role"]].strip().lower() if "role" in col else ""
        role = role or "control"
        if role not in ROLES:
            raise InputError(path, ln, f"point {pid}: role = '{r[col['role']].strip()[:40]}' is not one of "
                             f"{', '.join(ROLES)}", field="role")
        vals = {}
        for c in COLUMNS[1:]:
            tok = r[col[c]].strip()
            if role == "check" and c.startswith("s") and not tok:
                vals[c] = float("nan")          # a check point's σ is not used
                continue
            try:
                v = float(tok)
            except ValueError:
                raise InputError(path, ln, f"point {pid}: {c} = '{tok[:40]}' is not a number", field=c) from None
            if not math.isfinite(v):
                raise InputError(path, ln, f"point {pid}: {c} = {tok} is not finite", field=c)
            if c.startswith("s") and v <= 0:
                raise InputError(path, ln, f"point {pid}: {c} = {v:g} must be > 0", field=c)
            if c.startswith("s") and not SIGMA_MIN <= v <= SIGMA_MAX:
                raise InputError(path, ln, f"point {pid}: {c} = {v:g} is outside [{SIGMA_MIN:g}, {SIGMA_MAX:g}]: "
                                 f"its weight 1/σ² cannot be formed in double precision", field=c)
            if abs(v) > VALUE_LIMIT:
                raise InputError(path, ln, f"point {pid}: {c} = {v:g} is outside ±{VALUE_LIMIT:g}: too large "
                                 f"to adjust in double precision", field=c)
            vals[c] = v
        out.append(ControlPoint(pid, (vals["x"], vals["y"], vals["z"]), (vals["sx"], vals["sy"], vals["sz"]), ln,
                                role=role))
    if not out:
        raise InputError(path, hline, "no control points after the header")
    return out


def add_control(model, csv_path):
    """The model with the control and check points of ``csv_path`` added (a new object; the file
    and the model are not changed). Works for SfM blocks (BAL, Bundler, COLMAP) and native bundle
    blocks; a control or check point must be a point of the block. Check points (``role`` check)
    stay tie points of the adjustment, their known coordinates kept for the comparison."""
    cps = read_control(csv_path)
    ctrl = tuple(cp for cp in cps if cp.role == "control")
    chk = tuple(cp for cp in cps if cp.role == "check")
    if isinstance(model, SfmBlock):
        known = set(model.points)
        for cp in cps:
            if cp.id not in known:
                raise InputError(csv_path, cp.line, f"point {cp.id} is not a point of the block")
        return model.replace(control=ctrl, check=chk)
    if isinstance(model, Block):
        by_id = {cp.id: cp for cp in cps}
        known = {p.id for p in model.points}
        for cp in cps:
            if cp.id not in known:
                raise InputError(csv_path, cp.line, f"point {cp.id} is not a point of the block")
            if cp.role == "control" and cp.sigma[0] != cp.sigma[1]:
                raise InputError(csv_path, cp.line, f"point {cp.id}: a native bundle block takes one "
                                 f"horizontal σ (sx = sy), got {cp.sigma[0]:g} and {cp.sigma[1]:g}")

        def point(p):
            cp = by_id.get(p.id)
            if cp is None:
                return p
            if cp.role == "check":
                return dataclasses.replace(p, status="check", ref=cp.xyz, sigma_h=0.0, sigma_v=0.0, line=cp.line)
            return dataclasses.replace(p, status="control", ref=cp.xyz, sigma_h=cp.sigma[0], sigma_v=cp.sigma[2],
                                       axes="xyz", line=cp.line)
        return model.replace(points=tuple(point(p) for p in model.points),
                             datum="control" if ctrl else model.datum)
    raise InputError(csv_path, 0, f"control points can be added to bundle blocks only, "
                     f"not to a {type(model).__name__}")
