"""The result tables written from their columns (baarda.io.columns) are the records written one
by one, byte for byte: JSON lines, CSV files and numpy columns, on networks (keys that differ
between observations), blocks (categories, id codes, a keypoint key only some observations have,
group lists), an extra (--risk) and a table whose extra has no columnar form."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import baarda
from baarda.analysis import Extras
from baarda.io import results
from baarda.io.columns import Field, key_order, row_texts

from ..extdata import EXTDATA, require_extdata

DATA = Path(__file__).resolve().parents[2] / "data"


def _per_record(monkeypatch, fn):
    with monkeypatch.context() as m:
        m.setattr(results.Records, "fields", lambda self: None)
        return fn()


def _same_columns(a: dict, b: dict) -> None:
    assert list(a) == list(b)
    for key in a:
        x, y = a[key], b[key]
        assert x.dtype == y.dtype, key
        if x.dtype == float:
            np.testing.assert_array_equal(x, y, err_msg=key)
        else:
            assert [list(u) if isinstance(u, list) else u for u in x] == [list(u) if isinstance(u, list) else u for u in y]


def _compare(analysis, extras, tmp_path, monkeypatch, columnar=("observations", "points", "groups")):
    doc = analysis.to_dict(extras)
    assert [t for t in ("observations", "points", "groups") if doc[t].fields() is not None] == list(columnar)
    results.write_json(analysis.adjustment, tmp_path / "new.json", doc)
    results.write_csv(analysis.adjustment, tmp_path / "new", doc)
    old = analysis.to_dict(extras)
    _per_record(monkeypatch, lambda: results.write_json(analysis.adjustment, tmp_path / "old.json", old))
    _per_record(monkeypatch, lambda: results.write_csv(analysis.adjustment, tmp_path / "old", old))
    assert (tmp_path / "new.json").read_bytes() == (tmp_path / "old.json").read_bytes()
    for table in ("observations", "points", "groups"):
        name = f"{table}.csv"
        assert (tmp_path / "new" / name).read_bytes() == (tmp_path / "old" / name).read_bytes(), name
        _same_columns(results.columns(doc[table]), _per_record(monkeypatch, lambda t=table: results.columns(old[t])))


@pytest.mark.parametrize("name, extras", [
    ("demo-levelling.gkf", None), ("demo-block.json", None), ("demo-imodel.json", None),
    ("demo-block.json", Extras(risk=(0.01, 1.0, 10.0), risk_lambda_bar=17.0))])
def test_columns_write_the_records(name, extras, tmp_path, monkeypatch):
    _compare(baarda.analyze(DATA / name), extras, tmp_path, monkeypatch)


def test_an_extra_without_columns_is_written_record_by_record(tmp_path, monkeypatch):
    """--sbase replaces the points' σ in place (their keys keep their places): the points are
    written one by one, the rest from their columns; the document is the same."""
    analysis = baarda.analyze(DATA / "demo-levelling.gkf")
    ids = list(analysis.problem.points.ids)
    _compare(analysis, Extras(sbase=(ids[0],)), tmp_path, monkeypatch, columnar=("observations", "groups"))


@pytest.mark.parametrize("path", ["colmap/test_colmap-sparse0", "bal/dubrovnik-3-7-pre.txt",
                                  "gama/jezerka-dir.gkf", "gama/local_3d.gkf"])
def test_columns_write_the_records_of_real_files(path, tmp_path, monkeypatch):
    _compare(baarda.analyze(require_extdata(EXTDATA / path)), None, tmp_path, monkeypatch)


def test_row_texts_and_key_order_of_partial_fields():
    """A key only some rows have: left out of those rows' JSON, listed where a row first has it;
    numbers that do not exist are null, strings escaped to ASCII."""
    n = 3
    fields = [Field("i", "int", np.arange(n)), Field("a", "num", np.array([1.5, np.nan, np.inf]), np.array([False, True, True])),
              Field("s", "str", ["x", "é\"", None], np.array([True, True, False])), Field("b", "bool", np.array([True, False, True]))]
    assert row_texts(fields, slice(0, n), n) == ['{"i": 0, "s": "x", "b": true}',
                                                 '{"i": 1, "a": null, "s": "\\u00e9\\"", "b": false}',
                                                 '{"i": 2, "a": null, "b": true}']
    assert key_order(fields, n) == ["i", "s", "b", "a"]
