"""The Parquet companion of the result tables (``baarda analyze --parquet DIR``, issue 29, item 2):
read back with pyarrow, every cell equals the CSV's (the same columns in the same order, null
where the CSV cell is empty), typed — numbers float64 or int64, booleans bool, strings, lists of
numbers — on a network (keys that differ between observations), a block, a BAL file, and a
table written record by record (--sbase); without pyarrow a one-line error, nothing written."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

import baarda
from baarda.analysis import Extras
from baarda.cli import main
from baarda.io import columns, results
from baarda.io.output import csv_cell

from ..extdata import EXTDATA, require_extdata

pa = pytest.importorskip("pyarrow", reason="pyarrow (the batch extra) is not installed")
pq = pytest.importorskip("pyarrow.parquet", reason="pyarrow (the batch extra) is not installed")

DATA = Path(__file__).resolve().parents[2] / "data"
TABLES = ("observations", "points", "groups")


def _csv_cell(value) -> str:
    """A Parquet value as the CSV writes it (empty for null, lists joined by ';', text made safe
    for spreadsheets: a leading '-' of a list quoted)."""
    if value is None:
        return ""
    if isinstance(value, list):
        return csv_cell(";".join(map(str, value)))
    return csv_cell(value) if isinstance(value, str) else str(value)


def _same_as_csv(directory: Path) -> dict:
    """Each table's Parquet read back equals its CSV cell by cell; the tables' Arrow schemas."""
    schemas = {}
    for name in TABLES:
        table = pq.read_table(directory / f"{name}.parquet")
        with open(directory / f"{name}.csv", newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
        assert table.column_names == (rows[0] if rows[0] != ["empty"] else []), name     # (the CSV of no rows)
        assert table.num_rows == len(rows) - 1, name
        for j, key in enumerate(table.column_names):
            values = table.column(key).to_pylist()
            cells = [r[j] for r in rows[1:]]
            typ = table.schema.field(key).type
            if pa.types.is_floating(typ):        # exact: the CSV holds repr, the shortest round trip
                assert [None if c == "" else float(c) for c in cells] == values, (name, key)
            else:
                assert [_csv_cell(v) for v in values] == cells, (name, key)
        schemas[name] = table.schema
    return schemas


def _write(analysis, extras, directory: Path) -> dict:
    doc = analysis.to_dict(extras)
    results.write_csv(analysis.adjustment, directory, doc)
    written = results.write_parquet(analysis.adjustment, directory, doc)
    assert written == [directory / f"{name}.parquet" for name in TABLES]
    return _same_as_csv(directory)


@pytest.mark.parametrize("name", ["demo-levelling.gkf", "demo-block.json", "demo-imodel.json"])
def test_parquet_equals_the_csv(name, tmp_path):
    schemas = _write(baarda.analyze(DATA / name), None, tmp_path)
    obs = schemas["observations"]
    assert obs.field("index").type == pa.int64() and obs.field("line").type == pa.int64()
    for key in ("value", "residual", "redundancy", "w", "mdb", "external"):
        assert obs.field(key).type == pa.float64(), key
    assert obs.field("rejected").type == pa.bool_()
    groups = schemas["groups"]
    if groups.names:                                      # (a network of 1D observations has no groups)
        assert groups.field("members").type == pa.list_(pa.int64()) and groups.field("T").type == pa.float64()
    summary = json.loads(obs.metadata[b"baarda"])
    assert summary["n_observations"] == pq.read_table(tmp_path / "observations.parquet").num_rows


def test_parquet_of_a_bal_file_and_of_a_table_written_record_by_record(tmp_path):
    _write(baarda.analyze(require_extdata(EXTDATA / "bal" / "dubrovnik-3-7-pre.txt")), None, tmp_path / "bal")
    analysis = baarda.analyze(DATA / "demo-levelling.gkf")
    extras = Extras(sbase=(list(analysis.problem.points.ids)[0],))
    assert analysis.to_dict(extras)["points"].fields() is None       # (the points: record by record)
    schemas = _write(analysis, extras, tmp_path / "sbase")
    assert schemas["points"].field("z").type == pa.float64() and schemas["points"].field("id").type == pa.string()


def test_cli_parquet_and_its_error_without_pyarrow(tmp_path, capsys, monkeypatch):
    out = tmp_path / "pq"
    assert main(["analyze", str(DATA / "demo-block.json"), "--parquet", str(out), "--csv", str(out), "--quiet"]) == 0
    _same_as_csv(out)
    capsys.readouterr()
    monkeypatch.setattr(columns, "pa", None)
    other = tmp_path / "none"
    assert main(["analyze", str(DATA / "demo-block.json"), "--parquet", str(other), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("baarda: error: analyze: --parquet needs pyarrow"), err
    assert not other.exists()
