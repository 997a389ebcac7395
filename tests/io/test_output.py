"""Outputs (issue 25, items 2, 3, 6, 7): never an input, atomic, interrupted cleanly, CSV cells
safe for spreadsheets (baarda.io.output)."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from baarda.cli import main
from baarda.io import output
from baarda.io.output import OutputError, atomic_write, check_outputs, csv_cell

HERE = Path(__file__).resolve().parents[1]
REPO = HERE.parent
VALID = HERE / "malformed" / "valid"


def snapshot(folder: Path) -> dict:
    """Every file under ``folder`` (links as their target's name) with its bytes."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_symlink():
            out[str(p)] = ("link", os.readlink(p))
        elif p.is_file():
            out[str(p)] = p.read_bytes()
    return out


# --------------------------------------------------------------------------------------------
# atomic_write, check_outputs
# --------------------------------------------------------------------------------------------
def test_atomic_write_replaces_only_when_complete(tmp_path):
    f = tmp_path / "out.json"
    f.write_text("old")
    f.chmod(0o640)
    with pytest.raises(KeyboardInterrupt):
        with atomic_write(f) as fh:
            fh.write("half a docu")
            assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".part")]
            raise KeyboardInterrupt
    assert f.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]        # no temporary file left
    with atomic_write(f) as fh:
        fh.write("new")
    assert f.read_text() == "new"
    assert f.stat().st_mode & 0o777 == 0o640                                  # permissions kept


def test_atomic_write_through_a_symbolic_link_keeps_the_link(tmp_path):
    (tmp_path / "real.json").write_text("old")
    (tmp_path / "link.json").symlink_to("real.json")
    output.write_text(tmp_path / "link.json", "new")
    assert (tmp_path / "link.json").is_symlink() and (tmp_path / "real.json").read_text() == "new"


def test_atomic_write_to_an_unwritable_place_is_an_output_error(tmp_path):
    with pytest.raises(OutputError, match=r"^/nonexistent/x.json:0: cannot write"):
        output.write_text("/nonexistent/x.json", "x")


def test_check_outputs_refuses_inputs_by_path_link_and_folder(tmp_path):
    a = tmp_path / "a.gkf"
    a.write_text("x")
    (tmp_path / "hard.json").hardlink_to(a)
    (tmp_path / "sym.json").symlink_to(a)
    model = tmp_path / "model"
    model.mkdir()
    (model / "points3D.txt").write_text("p")
    (tmp_path / "elsewhere.txt").hardlink_to(model / "points3D.txt")
    for out, why in [(a, "overwrite the input"), (tmp_path / "hard.json", "through a link"),
                     (tmp_path / "sym.json", "overwrite the input"), (tmp_path / "." / "a.gkf", "overwrite"),
                     (model / "points3D.txt", "input folder"), (model / "new.json", "input folder"),
                     (tmp_path / "elsewhere.txt", "through a link")]:
        with pytest.raises(OutputError, match=why):
            check_outputs([a, model], [out])
    with pytest.raises(OutputError, match="named twice"):
        check_outputs([a], [tmp_path / "o.json", tmp_path / "x" / ".." / "o.json"])
    with pytest.raises(OutputError, match="is a folder"):
        check_outputs([a], [tmp_path])
    with pytest.raises(OutputError, match="no such folder"):
        check_outputs([a], [tmp_path / "missing" / "o.json"])
    with pytest.raises(OutputError, match="not a folder"):
        check_outputs([a], [], folders=[a])
    with pytest.raises(OutputError, match="not a regular file"):
        check_outputs([a], ["/dev/null"])
    check_outputs([a, None], [tmp_path / "o.json", None], folders=[tmp_path / "new" / "csv"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gkf", "elsewhere.txt", "hard.json", "model",
                                                          "sym.json"]   # checking writes nothing


# --------------------------------------------------------------------------------------------
# the commands: an output that names an input is refused before anything is read or written
# --------------------------------------------------------------------------------------------
@pytest.fixture
def inputs(tmp_path):
    """A folder with a levelling network (Gama and native), a BAL block with control, a COLMAP
    model, a simulated block with its truth file beside it and a hypothesis file."""
    (tmp_path / "a.gkf").write_bytes((REPO / "data" / "demo-levelling.gkf").read_bytes())
    (tmp_path / "a.json").write_bytes((VALID / "levelling-valid.json").read_bytes())
    (tmp_path / "bal.txt").write_bytes((VALID / "bal-valid.txt").read_bytes())
    (tmp_path / "c.csv").write_bytes((VALID / "control-valid.csv").read_bytes())
    (tmp_path / "model").mkdir()
    for f in (VALID / "colmap-valid").iterdir():
        (tmp_path / "model" / f.name).write_bytes(f.read_bytes())
    (tmp_path / "block.json").write_bytes((REPO / "data" / "demo-block.json").read_bytes())
    (tmp_path / "block.truth.json").write_bytes((REPO / "data" / "demo-block.truth.json").read_bytes())
    (tmp_path / "h.txt").write_text("0 0 1\n")
    (tmp_path / "hard.json").hardlink_to(tmp_path / "a.gkf")
    (tmp_path / "sym.json").symlink_to("a.json")
    (tmp_path / "a.html").write_text("an older report")
    return tmp_path


OUTPUT_IS_INPUT = [
    ["analyze", "a.json", "--json", "a.json"],
    ["analyze", "a.json", "--geojson", "a.json"],
    ["analyze", "a.json", "--json", "sym.json"],
    ["analyze", "a.gkf", "--json", "hard.json"],
    ["analyze", "a.gkf", "--json", "./sub/../a.gkf"],
    ["analyze", "model", "--json", "model/points3D.txt"],
    ["analyze", "model", "--csv", "model"],
    ["analyze", "bal.txt", "--control", "c.csv", "--json", "c.csv"],
    ["analyze", "block.json", "--json", "block.truth.json"],           # the truth file read beside it
    ["analyze", "a.json", "--truth", "block.truth.json", "--geojson", "block.truth.json"],
    ["test", "a.json", "-H", "observation:0", "--json", "a.json"],
    ["test", "a.json", "-H", "file:h.txt", "--json", "h.txt"],
    ["test", "bal.txt", "--control", "c.csv", "-H", "observation:0", "--json", "c.csv"],
    ["convert", "a.gkf", "hard.json"],
    ["convert", "bal.txt", "--control", "c.csv", "c.csv"],
    ["report", "a.json", "--out", "sym.json"],
    ["report", "a.json"],                                              # a.html exists: not replaced silently
    ["simulate", "block.json", "--recipe", "block.json"],
    ["simulate", "new.json", "--recipe", "block.truth.json", "--truth", "block.truth.json"],
    ["simulate", "new.json", "--truth", "new.json"],
    ["analyze", "a.json", "--json", "o.json", "--geojson", "o.json"],
]


@pytest.mark.parametrize("argv", OUTPUT_IS_INPUT, ids=[" ".join(a) for a in OUTPUT_IS_INPUT])
def test_an_output_naming_an_input_is_refused(argv, inputs, capsys, monkeypatch):
    monkeypatch.chdir(inputs)
    (inputs / "sub").mkdir()
    before = snapshot(inputs)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("baarda: error: ") and err.count("\n") == 1, err
    assert "refusing" in err or "named twice" in err or "exists" in err, err
    assert snapshot(inputs) == before                 # byte-identical, nothing written


UNWRITABLE = [["--json", "/nonexistent/x.json"], ["--json", "."], ["--json", "/proc/x.json"],
              ["--geojson", "/dev/null"], ["--csv", "a.gkf"], ["--csv", "/proc/x"]]


@pytest.mark.parametrize("option", UNWRITABLE, ids=[" ".join(o) for o in UNWRITABLE])
def test_an_unwritable_output_is_a_usage_error(option, inputs, capsys, monkeypatch):
    monkeypatch.chdir(inputs)
    before = snapshot(inputs)
    assert main(["analyze", "a.json", *option]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {option[1]}:0: ") and err.count("\n") == 1, err
    assert snapshot(inputs) == before


def test_report_replaces_an_existing_default_only_with_force(inputs, capsys, monkeypatch):
    monkeypatch.chdir(inputs)
    assert main(["report", "a.json", "-q"]) == 2
    assert "a.html:0: exists: name the report with --out, or give --force" in capsys.readouterr().err
    assert (inputs / "a.html").read_text() == "an older report"
    assert main(["report", "a.json", "-q", "--force"]) == 0
    assert (inputs / "a.html").read_text().lstrip().lower().startswith("<!doctype html")


def test_outputs_are_written_with_their_folder(inputs, monkeypatch):
    monkeypatch.chdir(inputs)
    assert main(["analyze", "a.json", "-q", "--json", "o.json", "--csv", "new/csv", "--geojson", "o.geojson"]) == 0
    assert json.loads((inputs / "o.json").read_text())["schema"].startswith("baarda-analysis/")
    assert sorted(p.name for p in (inputs / "new" / "csv").iterdir()) == ["groups.csv", "observations.csv",
                                                                         "points.csv"]
    assert not list(inputs.rglob("*.part"))


# --------------------------------------------------------------------------------------------
# interrupted writes, broken pipes
# --------------------------------------------------------------------------------------------
#: the child writes each JSON record slowly (one at a time, or a chunk of them from their
#: columns), so that it is surely interrupted while writing
SLOW_CHILD = """
import sys, time
from baarda.io import results
make = results.Records.__getitem__
def slow(self, i):
    time.sleep(0.002)
    return make(self, i)
results.Records.__getitem__ = slow
lines = results.Records.json_lines
def slow_lines(self, fields, sl):
    time.sleep(0.01 * (sl.stop - sl.start))
    return lines(self, fields, sl)
results.Records.json_lines = slow_lines
from baarda.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _wait_for(condition, proc, timeout=120.0):
    """Poll ``condition`` until true; fails if ``proc`` ends first or ``timeout`` passes."""
    end = time.monotonic() + timeout
    while not condition():
        assert proc.poll() is None, f"the child ended (status {proc.returncode}) before the condition held"
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


@pytest.mark.parametrize("sig, status, line", [(signal.SIGTERM, 143, "baarda: terminated\n"),
                                               (signal.SIGINT, 130, "baarda: interrupted\n")])
def test_an_interrupted_json_leaves_the_previous_file(sig, status, line, tmp_path):
    block = tmp_path / "block.json"
    block.write_bytes((REPO / "data" / "demo-block.json").read_bytes())
    out = tmp_path / "out.json"
    out.write_text('{"previous": true}\n')
    proc = subprocess.Popen([sys.executable, "-c", SLOW_CHILD, "analyze", str(block), "--json", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    try:
        _wait_for(lambda: any(p.name.startswith(".out.json.") for p in tmp_path.iterdir()), proc)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == status, err
    assert err == line
    assert out.read_text() == '{"previous": true}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["block.json", "out.json"]


def test_a_broken_pipe_ends_quietly_with_status_141(tmp_path):
    """``baarda analyze ... | head -1``: the reader goes away; no message, the status of SIGPIPE."""
    proc = subprocess.Popen([sys.executable, "-m", "baarda.cli", "analyze", str(REPO / "data" / "demo-block.json"),
                             "--top", "100000"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    try:
        assert proc.stdout.readline()
        proc.stdout.close()
        err = proc.stderr.read()
        proc.wait(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 141 and err == b""


# --------------------------------------------------------------------------------------------
# CSV cells (item 7)
# --------------------------------------------------------------------------------------------
HOSTILE_IDS = ['=HYPERLINK("http://x.example","click")', "+cmd|' /C calc'!A0", "@SUM(1+1)", "\t=1+1", "\r=1+1",
               "-2+3", "a\u202eb", "a\u200bb"]


def test_csv_cell():
    assert [csv_cell(s) for s in HOSTILE_IDS] == [
        '\'=HYPERLINK("http://x.example","click")', "'+cmd|' /C calc'!A0", "'@SUM(1+1)", "\\t=1+1", "\\r=1+1",
        "'-2+3", "a\\u202eb", "a\\u200bb"]
    assert csv_cell(-2.5) == -2.5 and csv_cell(None) is None and csv_cell("P1") == "P1"


def test_the_dashboard_and_the_command_line_share_the_csv_cell():
    from baarda.dashboard import tables

    assert tables.csv_cell is csv_cell


def test_analyze_csv_neutralises_formulas_and_escapes_controls(tmp_path):
    doc = json.loads((VALID / "levelling-valid.json").read_text())
    ids = {"A": HOSTILE_IDS[0], "B": HOSTILE_IDS[1], "C": HOSTILE_IDS[6]}
    doc["points"].append({"id": HOSTILE_IDS[2], "H": 103.0, "status": "adjusted"})
    doc["observations"].append({"from": "C", "to": HOSTILE_IDS[2], "dh": 1.0, "sigma": 0.001})
    doc["observations"].append({"from": "A", "to": HOSTILE_IDS[2], "dh": 3.0, "sigma": 0.001})
    for p in doc["points"]:
        p["id"] = ids.get(p["id"], p["id"])
    for o in doc["observations"]:
        o["from"], o["to"] = ids.get(o["from"], o["from"]), ids.get(o["to"], o["to"])
    f = tmp_path / "hostile.json"
    f.write_text(json.dumps(doc))
    assert main(["analyze", str(f), "-q", "--csv", str(tmp_path / "csv")]) == 0
    for name in ("points", "observations"):
        with open(tmp_path / "csv" / f"{name}.csv", newline="", encoding="utf-8") as fh:
            cells = [c for row in csv.reader(fh) for c in row]
        text = [c for c in cells if c and not _is_number(c)]
        assert not [c for c in text if c.startswith(("=", "+", "-", "@", "\t", "\r"))], name
        assert not [c for c in cells if not c.isprintable()], name
        assert "'" + HOSTILE_IDS[0] in cells and "a\\u202eb" in cells


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


WRITERS = [["analyze", "a.json", "--json", "old.out"], ["analyze", "a.json", "--geojson", "old.out"],
           ["analyze", "a.json", "--csv", "csv"], ["test", "a.json", "-H", "observation:0", "--json", "old.out"],
           ["convert", "a.gkf", "old.out"], ["convert", "bal.txt", "old.out"], ["report", "a.json", "-o", "old.out"],
           ["simulate", "old.out", "--strips", "1", "--images", "3"]]


@pytest.mark.parametrize("argv", WRITERS, ids=[" ".join(a) for a in WRITERS])
def test_every_writer_interrupted_leaves_the_previous_files(argv, inputs, capsys, monkeypatch):
    """Ctrl-C at the last moment of a write (the file complete, not yet renamed) in each writer:
    exit 130 with one line, the previous output unchanged, no temporary file left."""
    monkeypatch.chdir(inputs)
    (inputs / "old.out").write_text("previous")
    (inputs / "csv").mkdir()
    (inputs / "csv" / "points.csv").write_text("previous")
    before = snapshot(inputs)

    def interrupted(fd):
        raise KeyboardInterrupt
    monkeypatch.setattr(output.os, "fsync", interrupted)
    assert main([*argv, "-q"]) == 130
    assert capsys.readouterr().err == "baarda: interrupted\n"
    assert snapshot(inputs) == before
