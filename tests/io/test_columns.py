"""The result tables written from their columns (baarda.io.columns) are the records written one
by one, byte for byte: JSON lines, CSV files and numpy columns, on networks (keys that differ
between observations), blocks (categories, id codes, a keypoint key only some observations have,
group lists), an extra (--risk) and a table whose extra has no columnar form; with orjson (the
numbers' texts) and without it, the same bytes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import baarda
from baarda.analysis import Extras
from baarda.io import columns, results
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
    with monkeypatch.context() as m:              # the numbers' texts without orjson: the same bytes
        m.setattr(columns, "orjson", None)
        results.write_json(analysis.adjustment, tmp_path / "pure.json", doc)
    assert (tmp_path / "pure.json").read_bytes() == (tmp_path / "old.json").read_bytes()
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


@pytest.fixture(params=["orjson", "repr"])
def number_path(request, monkeypatch):
    """The numbers' texts through orjson (skipped where it is not installed) or float.__repr__."""
    if request.param == "orjson":
        pytest.importorskip("orjson", reason="orjson (the fast extra) is not installed")
        assert columns.orjson is not None
    else:
        monkeypatch.setattr(columns, "orjson", None)
    return request.param


def _awkward_numbers() -> np.ndarray:
    """Doubles whose shortest texts differ between writers: exponents (1e-07, 1e+16), the
    0.0001 / 1e-05 boundary, ±0.0, subnormals, the largest double, and random bit patterns."""
    rng = np.random.default_rng(7)
    bits = rng.integers(0, 2**63, size=20000, dtype=np.int64) * rng.choice([-1, 1], size=20000)
    random = bits.view(float)
    scaled = rng.normal(size=20000) * 10.0 ** rng.integers(-30, 30, size=20000)
    special = np.array([1e-7, 1.5e-6, 1e-5, 1.234e-5, 9.999e-5, 1e-4, 0.0001234, 1e15, 1e16, 1.5e16, 1e22, 0.0,
                        -0.0, 5e-324, 2.2250738585072014e-308, 1.7976931348623157e308, 0.1, 1 / 3, 2.0, -1e-10,
                        123456789012345680.0, np.nan, np.inf, -np.inf])
    return np.concatenate([special, random, scaled])


def test_number_texts_are_repr(number_path):
    """Each number as json writes it (float.__repr__, null where not finite), with a key in front;
    a column of one value and a column of 0.0 and -0.0."""
    a = _awkward_numbers()
    ref = ["null" if not np.isfinite(x) else repr(x) for x in a.tolist()]
    assert columns.num_texts(a) == ref
    assert columns.num_texts(a, ', "w": ') == [', "w": ' + t for t in ref]
    assert columns.num_texts(np.full(100, 1e-5)) == ["1e-05"] * 100
    assert columns.num_texts(np.array([0.0] * 99 + [-0.0])) == ["0.0"] * 99 + ["-0.0"]
    assert columns.num_texts(np.zeros(0)) == []


def test_list_texts_are_the_records_lists(number_path):
    """Lists of numbers and of integers, of one length and of several (the groups' ∇, axes, members)."""
    a = _awkward_numbers()[:3000].reshape(1000, 3)
    ref = ["[" + ", ".join("null" if not np.isfinite(x) else repr(x) for x in row) + "]" for row in a.tolist()]
    assert columns.list_texts(a) == ref
    assert columns.list_texts(np.full((1000, 2), 1.5)) == ["[1.5, 1.5]"] * 1000
    assert columns.list_texts(np.zeros((3, 0))) == ["[]"] * 3
    ptr = np.array([5, 7, 7, 8, 11, 13])
    flat = np.arange(20, dtype=np.int64) - 10
    assert columns.ragged_texts(flat, ptr, real=False) == ["[-5, -4]", "[]", "[-3]", "[-2, -1, 0]", "[1, 2]"]
    x = np.array([1e-7, 2.5, -0.0, np.nan, 1e16, 3.0])
    assert columns.ragged_texts(x, np.array([0, 2, 2, 6])) == ["[1e-07, 2.5]", "[]", "[-0.0, null, 1e+16, 3.0]"]


def test_an_orjson_that_writes_numbers_otherwise_is_not_used(monkeypatch):
    """An orjson (another version) whose texts differ from repr's (1e16 for 1e+16) is left
    aside: the numbers are written by repr."""
    orjson = pytest.importorskip("orjson", reason="orjson (the fast extra) is not installed")

    class Other:
        OPT_SERIALIZE_NUMPY = orjson.OPT_SERIALIZE_NUMPY

        @staticmethod
        def dumps(a, option=0):
            return orjson.dumps(a, option=option).replace(b"e+", b"e")

    monkeypatch.setattr(columns, "orjson", Other())
    assert columns.num_texts(np.array([1e16, 2.5])) == ["1e+16", "2.5"]
    assert columns.list_texts(np.array([[1e16, 2.5]])) == ["[1e+16, 2.5]"]
