"""Control points from a CSV file: ``id,X,Y,Z,sx,sy,sz`` with a header line.

Each row gives the known coordinates of a block point (the ``id`` as the block names it: a
BAL/Bundler point index, a COLMAP POINT3D_ID, a native point id) and their standard deviations,
in the block's object units (metres for native blocks; for structure-from-motion models the
model's own frame and scale — control only makes sense once the model is close to that frame,
since the adjustment linearises at the model's coordinates). The points become weighted control
(observations of X, Y, Z) and the datum is then defined by them instead of the free-block
inner constraints.

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


def _rows(path, text: str) -> list[tuple[int, list[str]]]:
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


def read_control(path) -> list[ControlPoint]:
    """The control points of a CSV file (module docstring); InputError on any bad row."""
    text = read_text(path)
    rows = [(ln, r) for ln, r in _rows(path, text)
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError(path, 1, "empty file: expected the header 'id,X,Y,Z,sx,sy,sz'")
    hline, header = rows[0]
    names = [h.strip().lower() for h in header]
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        raise InputError(path, hline, f"the header must name the columns id,X,Y,Z,sx,sy,sz "
                         f"(missing: {', '.join(missing)})")
    col = {c: names.index(c) for c in COLUMNS}
    out, seen = [], {}
    for ln, r in rows[1:]:
        if len(r) != len(names):
            raise InputError(path, ln, f"{len(r)} fields, the header has {len(names)}")
        pid = r[col["id"]].strip()
        if not pid:
            raise InputError(path, ln, "empty id")
        if pid in seen:
            raise InputError(path, ln, f"duplicate id {pid} (first at line {seen[pid]})")
        seen[pid] = ln
        vals = {}
        for c in COLUMNS[1:]:
            tok = r[col[c]].strip()
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
        out.append(ControlPoint(pid, (vals["x"], vals["y"], vals["z"]), (vals["sx"], vals["sy"], vals["sz"]), ln))
    if not out:
        raise InputError(path, hline, "no control points after the header")
    return out


def add_control(model, csv_path):
    """The model with the control points of ``csv_path`` added (a new object; the file and the
    model are not changed). Works for SfM blocks (BAL, Bundler, COLMAP) and native bundle blocks;
    a control point must be a point of the block."""
    cps = read_control(csv_path)
    if isinstance(model, SfmBlock):
        known = set(model.points)
        for cp in cps:
            if cp.id not in known:
                raise InputError(csv_path, cp.line, f"point {cp.id} is not a point of the block")
        return model.replace(control=tuple(cps))
    if isinstance(model, Block):
        by_id = {cp.id: cp for cp in cps}
        known = {p.id for p in model.points}
        for cp in cps:
            if cp.id not in known:
                raise InputError(csv_path, cp.line, f"point {cp.id} is not a point of the block")
            if cp.sigma[0] != cp.sigma[1]:
                raise InputError(csv_path, cp.line, f"point {cp.id}: a native bundle block takes one "
                                 f"horizontal σ (sx = sy), got {cp.sigma[0]:g} and {cp.sigma[1]:g}")
        pts = tuple(dataclasses.replace(p, status="control", ref=by_id[p.id].xyz, sigma_h=by_id[p.id].sigma[0],
                                        sigma_v=by_id[p.id].sigma[2], axes="xyz", line=by_id[p.id].line)
                    if p.id in by_id else p for p in model.points)
        return model.replace(points=pts, datum="control")
    raise InputError(csv_path, 0, f"control points can be added to bundle blocks only, "
                     f"not to a {type(model).__name__}")
