"""The full tables of the app as CSV downloads (issue 15, item 5): observations, points, suspects.

The files are UTF-8 with a byte-order mark, so that spreadsheets (Excel, LibreOffice) open them
with the right characters (σ, ∇, ids in any script). Every text cell that a spreadsheet would
take for a formula (starting with ``= + - @``, a tab or a carriage return: CSV injection) is
written with a leading apostrophe (:func:`baarda.io.output.csv_cell`, which the command line's
``analyze --csv`` uses too), so a hostile id stays text there too; numbers are written as
numbers. The columns are those of the app's tables (:meth:`State.frames`,
:func:`baarda.dashboard.suspects.suspects`).
"""

from __future__ import annotations

import io

import pandas as pd

from baarda.io.output import csv_cell

from .state import State
from .suspects import suspects

#: what each download holds: its file name and how to make its table from a state
TABLES = {
    "observations": lambda st: st.frames()[0],
    "points": lambda st: st.frames()[1],
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
