"""One file, one set of numbers, whichever door it comes in by (issue "One analysis for every
door"): ``baarda analyze --json``, ``baarda.analyze(path).to_dict()``, the dashboard's State and
the client report, on every input file of ``data/`` and ``../shared/extdata``.

A file every door refuses is refused by each with the same message. The three large BAL problems
(Dubrovnik 16, Trafalgar 21, Ladybug 49: 1-3 minutes each through three doors) are left out here;
``tests/test_real_blocks.py`` and ``bench/bench_solve.py`` analyse them through the CLI.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import baarda
from baarda import cli
from baarda.errors import BaardaError
from baarda.io import results
from tests.extdata import EXTDATA, require_extdata

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data"
#: the readers' inputs: Gama networks, native blocks, BAL, Bundler, COLMAP folders
SUFFIXES = (".gkf", ".txt", ".bz2", ".out")
#: the large BAL problems (see the module docstring)
LARGE = ("problem-16-22106-pre.txt.bz2", "problem-21-11315-pre.txt.bz2", "problem-49-7776-pre.txt")


def _inputs() -> list[Path]:
    files = sorted(p for p in DATA.iterdir() if p.suffix in (".gkf", ".json") and ".truth" not in p.name)
    if EXTDATA.exists():
        files += sorted(p for p in EXTDATA.rglob("*") if p.is_file() and p.suffix in SUFFIXES
                        and "krumm" not in p.parts and p.name not in LARGE)
        files += sorted({p.parent for p in EXTDATA.rglob("points3D.*")})
    return files


def _id(p: Path) -> str:
    try:
        return str(p.relative_to(EXTDATA))
    except ValueError:
        return str(p.relative_to(ROOT))


def _plain(doc: dict) -> dict:
    """The document as JSON holds it, without what differs between runs (timings)."""
    doc = json.loads(json.dumps(results.finite({k: list(v) if isinstance(v, results.Records) else v
                                                for k, v in doc.items()}), allow_nan=False))
    doc["summary"].pop("timings", None)
    return doc


def _cli(path: Path, tmp_path: Path, capsys):
    out = tmp_path / "cli.json"
    code = cli.main(["analyze", str(path), "--json", str(out), "--quiet"])
    err = capsys.readouterr().err
    return code, (json.loads(out.read_text()) if out.exists() else None), err


@pytest.mark.slow
@pytest.mark.parametrize("path", _inputs(), ids=_id)
def test_every_door_gives_the_same_numbers(path, tmp_path, capsys):
    if EXTDATA in path.parents:
        require_extdata()
    from baarda.dashboard.state import State

    code, doc_cli, err = _cli(path, tmp_path, capsys)
    try:
        analysis = baarda.analyze(path)
    except BaardaError as exc:
        # refused: by every door, with the same words
        assert code == 2 and doc_cli is None, f"the CLI analysed {path.name} that analyze() refuses: {exc}"
        assert str(exc) in err
        st = State(path=path)
        assert st.results is None and st.error
        assert str(exc).split(": ", 1)[-1][:60] in st.error
        return
    if doc_cli is None:                 # not converged and singular at the last iterate: nothing written
        assert code == cli.NOT_CONVERGED
        return
    assert code in (0, cli.NOT_CONVERGED)
    doc_py = _plain(analysis.to_dict())
    doc_cli.pop("planted", None)        # (the CLI compares a .truth.json beside the input; not a number of the analysis)
    doc_cli["summary"].pop("timings", None)
    assert doc_cli == doc_py

    st = State(path=path)               # the dashboard: read, adjusted, tested by its own State
    assert st.error == ""
    doc_app = _plain(results.to_dict(st.results, st.reliability))
    assert doc_app == doc_py
    assert list(st.kept) == list(analysis.kept)
    # the report renders a State made from the analysis: the same summary
    rep = State.from_analysis(analysis)
    assert _plain(results.to_dict(rep.results, rep.reliability)) == doc_py


def test_dubrovnik_pre_local_defects_named_by_every_door(tmp_path, capsys):
    """The BAL file whose local defects only the CLI set aside: the dashboard analyses the same 38
    observations and names the same defects (it said "Adjustment failed" before)."""
    path = require_extdata(EXTDATA / "bal" / "dubrovnik-3-7-pre.txt")
    from baarda.dashboard.state import State
    from baarda.dashboard.views.summary import SummaryHeader

    code, doc_cli, _ = _cli(path, tmp_path, capsys)
    assert code in (0, cli.NOT_CONVERGED)
    analysis = baarda.analyze(path)
    st = State(path=path)
    assert st.error == ""
    assert st.results.n == analysis.adjustment.n == doc_cli["summary"]["n_observations"]
    defects = doc_cli["summary"]["local_defects"]
    assert defects and [d.as_dict() for d in analysis.local_defects] == defects
    html = SummaryHeader.html(st)
    assert "Local defects" in html and f"{len(defects)} set aside" in html


def test_report_shows_the_analysis_numbers(tmp_path):
    """``baarda report`` renders the core's analysis: its σ̂0 and rejection count are in the HTML."""
    from baarda.dashboard.report import write_analysis_report

    analysis = baarda.analyze(DATA / "demo-block.json")
    out = write_analysis_report(analysis, tmp_path / "r.html")
    html = out.read_text(encoding="utf-8")
    s = analysis.summary()
    assert f"σ̂0 = {s['sigma0_aposteriori']:.4g}" in html
    assert f"{s['n_rejected']} rejected" in html
    code = cli.main(["report", str(DATA / "demo-block.json"), "-o", str(tmp_path / "cli.html"), "--quiet"])
    assert code == 0
    assert f"{s['n_rejected']} rejected" in (tmp_path / "cli.html").read_text(encoding="utf-8")


def test_records_are_the_json_tables():
    """``Analysis.records`` is the JSON document's table as columns (one table, one set of names)."""
    analysis = baarda.analyze(DATA / "demo-levelling.gkf")
    doc = _plain(analysis.to_dict())
    for table in ("observations", "points", "groups"):
        cols = analysis.records(table)
        rows = doc[table]
        assert len(next(iter(cols.values()), [])) == len(rows) if rows else True
        for key, col in cols.items():
            for i, row in enumerate(rows):
                v = row.get(key)
                if isinstance(v, float) or (v is None and col.dtype == float):
                    assert (np.isnan(col[i]) if v is None else col[i] == v)
                else:
                    assert col[i] == v or (isinstance(col[i], list) and list(col[i]) == v)
    frame = analysis.records("observations", frame=True)
    assert list(frame.columns) == list(analysis.records("observations"))
