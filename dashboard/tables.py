"""The full tables of the app as CSV downloads (issue 15, item 5): observations, points, suspects.

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

from baarda.io.output import csv_cell

from .state import State
from .suspects import suspects

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
    "suspects": suspects,
}


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
    safe_frame(df).to_csv(buf, lineterminator="\r\n")
    return buf.getvalue().encode("utf-8-sig")


def table_csv(state: State, name: str) -> io.BytesIO:
    """The table ``name`` (:data:`TABLES`) of ``state``'s current result as a CSV file object."""
    return io.BytesIO(csv_bytes(TABLES[name](state)))
