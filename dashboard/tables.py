"""The full tables of the app as CSV downloads (issue 15, item 5) and as one Excel workbook with a
sheet per table (issue 31, item 9): observations, points, suspects, and the check points where a
block has them (issue 28: id, adjusted − known per axis, σ, the RMSE row; :mod:`baarda.dashboard.auxdata`).

Typed columns: numbers as numbers (∇ŝ of a suspect one column per component, ``∇ŝ 1``, ``∇ŝ 2``,
…, in the file's unit of its observations), no unnamed index column, units in a column name only
where the block has them (one unit for all the rows: ``∇ŝ 1 [mm]``; several: a ``∇ŝ unit``
column; none: neither).

The files are UTF-8 with a byte-order mark, so that spreadsheets (Excel, LibreOffice) open them
with the right characters (σ, ∇, ids in any script). Every text cell that a spreadsheet would
take for a formula (starting with ``= + - @``, a tab or a carriage return: CSV injection) is
written with a leading apostrophe (:func:`baarda.io.output.csv_cell`, which the command line's
``analyze --csv`` uses too), so a hostile id stays text there too; numbers are written as
numbers. The observations and points are the core's tables (:meth:`baarda.analysis.Analysis.records`:
the columns and names of ``baarda analyze --csv`` and of the JSON document, one table of one thing),
with ``index`` the observation's index in the problem (excluded observations are not in the file);
the suspects are the app's (:func:`baarda.dashboard.suspects.suspects`).
"""

from __future__ import annotations

import io

import pandas as pd
from openpyxl import Workbook

import numpy as np

from baarda.io.output import csv_cell
from baarda.text import printable

from . import auxdata
from .state import State
from .suspects import COLUMNS, suspects


def core_table(state: State, table: str) -> pd.DataFrame:
    """The core's ``table`` ("observations" or "points") of ``state``'s analysis as a DataFrame,
    as ``baarda analyze --csv`` writes it (lists joined by ';'); observation ``index`` in the problem."""
    df = state.analysis.records(table, frame=True)
    if table == "observations" and len(df):
        df["index"] = state.kept[df["index"].to_numpy(dtype=int)]
    for col in df.columns:
        if df[col].dtype == object:
            df[col] = df[col].map(lambda v: ";".join(map(str, v)) if isinstance(v, list) else v)
    return df


#: what each download holds: its file name and how to make its table from a state
TABLES = {
    "observations": lambda st: core_table(st, "observations"),
    "points": lambda st: core_table(st, "points"),
    "suspects": lambda st: suspects_table(st),
    "check-points": lambda st: auxdata.check_download(st),
}
#: tables left out of the workbook (and their download hidden) when they have no rows
OPTIONAL = ("check-points",)


def suspects_table(state: State) -> pd.DataFrame:
    """The suspects (:func:`baarda.dashboard.suspects.suspects`) with typed columns: ∇ŝ one float
    column per component (module docstring for its unit), ``point`` the point's id (text),
    ``obs`` the observation's index in the problem."""
    df = suspects(state)
    out = df[[c for c in COLUMNS if c != "∇ŝ"]].copy()
    values = list(df["∇ŝ values"]) if len(df) else []
    q = max((len(v) for v in values), default=1)
    units = sorted({str(u) for u in df["∇ŝ unit"] if u}) if len(df) else []
    suffix = f" [{units[0]}]" if len(units) == 1 else ""
    at = out.columns.get_loc("MDB ratio") + 1
    for j in range(q):
        col = np.array([v[j] if j < len(v) else np.nan for v in values], dtype=float)
        out.insert(at + j, f"∇ŝ {j + 1}{suffix}", col)
    if len(units) > 1:
        out.insert(at + q, "∇ŝ unit", [str(u) for u in df["∇ŝ unit"]])
    if len(df):
        names = {v: str(k) for k, v in state.problem_index()["point_index"].items()}
        out["point"] = [names.get(int(p)) if p is not None and np.isfinite(p) else None for p in df["point"]]
    return out.reset_index(drop=True)


def safe_frame(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with every text cell made plain (no control characters) and formula-safe."""
    out = df.copy()
    for col in out.columns:
        if out[col].dtype == object or pd.api.types.is_string_dtype(out[col]):
            out[col] = out[col].map(csv_cell)
    out.columns = [csv_cell(str(c)) for c in out.columns]
    return out


def csv_bytes(df: pd.DataFrame) -> bytes:
    """``df`` as CSV for spreadsheets (UTF-8 with BOM, formula-safe text)."""
    buf = io.StringIO()
    safe_frame(df).to_csv(buf, lineterminator="\r\n", index=False)
    return buf.getvalue().encode("utf-8-sig")


def table_csv(state: State, name: str) -> io.BytesIO:
    """The table ``name`` (:data:`TABLES`) of ``state``'s current result as a CSV file object."""
    return io.BytesIO(csv_bytes(TABLES[name](state)))


def _cell(x):
    """An Excel cell value: text made printable (never a formula: openpyxl would take a string
    starting with "=" for one; the cell's type is set to text below), NaN, None and "" empty,
    numpy scalars as Python numbers."""
    if x is None or (isinstance(x, float) and np.isnan(x)):
        return None
    if isinstance(x, str):
        return printable(x) or None
    if isinstance(x, np.generic):
        return x.item()
    return x


def xlsx_bytes(frames: dict[str, pd.DataFrame]) -> bytes:
    """An .xlsx workbook with one sheet per frame (named by its key): a header row, then the rows;
    numbers as numbers, text as text (never a formula), the header frozen."""
    wb = Workbook()
    wb.remove(wb.active)
    for name, df in frames.items():
        ws = wb.create_sheet(title=str(name)[:31])
        ws.append([printable(str(c)) for c in df.columns])
        for row in df.itertuples(index=False, name=None):
            ws.append([_cell(x) for x in row])
        for cells in ws.iter_rows():
            for c in cells:
                if isinstance(c.value, str):
                    c.data_type = "s"
        ws.freeze_panes = "A2"
    buf = io.BytesIO()
    wb.save(buf)
    return buf.getvalue()


def tables_xlsx(state: State) -> io.BytesIO:
    """Every table of :data:`TABLES` of ``state``'s current result, one sheet each, as an .xlsx
    file object (empty when there is no result)."""
    if state.results is None:
        return io.BytesIO(b"")
    frames = {name: make(state) for name, make in TABLES.items()}
    return io.BytesIO(xlsx_bytes({k: v for k, v in frames.items() if not (k in OPTIONAL and v.empty)}))
