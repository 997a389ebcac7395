"""The downloads as typed columns and as one Excel workbook (issue 31, item 9), without a browser.

- the suspects' ∇ŝ is one float column per component, equal to the numbers the app shows as text;
  no unnamed index column; units in a column name only where the block has them (the demo mixes
  mm and m: a unit column; one unit: in the name; none: neither);
- the .xlsx holds one sheet per table, numbers as numbers, text as text (a hostile id is never a
  formula), and reads back to the CSV's values.
"""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("panel")

from baarda.dashboard import suspects as suspects_module  # noqa: E402
from baarda.dashboard import tables  # noqa: E402
from baarda.dashboard.state import State  # noqa: E402


@pytest.fixture(scope="module")
def st(demo_path):
    return State(demo_path)


def test_suspects_download_has_typed_columns(st):
    df = tables.suspects_table(st)
    shown = suspects_module.suspects(st)
    comps = [c for c in df.columns if c.startswith("∇ŝ ") and c != "∇ŝ unit"]
    assert comps == ["∇ŝ 1", "∇ŝ 2", "∇ŝ 3"]              # control points: 3 components
    assert "∇ŝ" not in df.columns and "∇ŝ unit" in df.columns
    for c in comps + ["p", "|w|", "T", "k", "MDB ratio"]:
        assert pd.api.types.is_float_dtype(df[c]), c
    assert df["q"].dtype == np.int64 and df["rank"].dtype == np.int64
    for k in range(len(df)):
        text = shown["∇ŝ"].iat[k]                        # "+0.0112, -0.0452 mm"
        nums, unit = text.rsplit(" ", 1)
        vals = [float(x) for x in nums.split(", ")]
        got = df.loc[k, comps].to_numpy(dtype=float)
        np.testing.assert_allclose(got[:len(vals)], vals, rtol=6e-3)     # shown to 3 digits
        assert np.isnan(got[len(vals):]).all()
        assert df["∇ŝ unit"].iat[k] == unit
    assert set(df["∇ŝ unit"]) == {"mm", "m"}
    assert df["point"].dropna().map(type).eq(str).all() and "P05003" in set(df["point"])
    raw = tables.table_csv(st, "suspects").getvalue()
    back = pd.read_csv(io.BytesIO(raw), encoding="utf-8-sig")
    assert list(back.columns) == list(df.columns)
    assert not any(c.startswith("Unnamed") for c in back.columns)
    for c in comps:
        assert pd.api.types.is_float_dtype(back[c])


def test_units_in_column_names_only_where_the_block_has_them(st, monkeypatch):
    base = suspects_module.suspects(st)
    for units, names, unit_col in ((["mm"], "∇ŝ 1 [mm]", False), ([""], "∇ŝ 1", False)):
        fake = base.copy()
        fake["∇ŝ unit"] = units[0]
        monkeypatch.setattr(tables, "suspects", lambda _st, f=fake: f)
        df = tables.suspects_table(st)
        assert names in df.columns and ("∇ŝ unit" in df.columns) == unit_col
        assert not any("[" in c for c in df.columns if c != names and c.startswith("∇ŝ")) or names.endswith("]")


def test_xlsx_one_sheet_per_table(st):
    openpyxl = pytest.importorskip("openpyxl")
    wb = openpyxl.load_workbook(tables.tables_xlsx(st))
    assert wb.sheetnames == list(tables.TABLES)
    for name, make in tables.TABLES.items():
        ref = make(st)
        ws = wb[name]
        rows = list(ws.iter_rows(values_only=True))
        assert list(rows[0]) == [str(c) for c in ref.columns] and len(rows) == len(ref) + 1
        for c in [c for c in ref.columns if pd.api.types.is_float_dtype(ref[c])]:
            j = list(ref.columns).index(c)
            got = np.array([np.nan if r[j] is None else r[j] for r in rows[1:]], dtype=float)
            np.testing.assert_allclose(got, ref[c].to_numpy(dtype=float), rtol=1e-12, equal_nan=True)
        for r in ws.iter_rows(min_row=2):
            for cell in r:
                assert cell.data_type in ("n", "s", "b")       # never a formula
    assert tables.tables_xlsx(State()).getvalue() == b""


def test_xlsx_text_is_never_a_formula():
    openpyxl = pytest.importorskip("openpyxl")
    df = pd.DataFrame({"id": ["=HYPERLINK(\"http://x\")", "@A1", "P1\x1b[2J"], "w": [1.0, np.nan, 3]})
    wb = openpyxl.load_workbook(io.BytesIO(tables.xlsx_bytes({"t": df})))
    cells = [[c for c in r] for r in wb["t"].iter_rows(min_row=2)]
    assert [r[0].value for r in cells][:2] == ["=HYPERLINK(\"http://x\")", "@A1"]
    assert all(r[0].data_type == "s" for r in cells) and "\x1b" not in cells[2][0].value
    assert [r[1].value for r in cells] == [1.0, None, 3]


def test_tests_table_view_offers_the_workbook(st):
    openpyxl = pytest.importorskip("openpyxl")
    from baarda.dashboard.views.table import TestsTable

    view = TestsTable(state=st)
    assert view.xlsx.filename == "baarda-tables.xlsx"
    wb = openpyxl.load_workbook(view.xlsx.callback())
    # the demo block has check points (issue 28): their sheet too
    assert wb.sheetnames == ["observations", "points", "suspects", "check-points"]
