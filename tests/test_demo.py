"""The README's demo: the bundled block is reproducible from its recipe and the analysis finds
its planted errors."""

from __future__ import annotations

import json
from pathlib import Path

from baarda.cli import main

DATA = Path(__file__).resolve().parents[1] / "data"


def test_simulate_reproduces_the_demo_block(tmp_path, capsys):
    out = tmp_path / "demo.json"
    assert main(["simulate", str(out), "--recipe", str(DATA / "demo-block.truth.json"), "--quiet"]) == 0
    assert out.read_bytes() == (DATA / "demo-block.json").read_bytes()
    ours = json.loads((tmp_path / "demo.truth.json").read_text())
    theirs = json.loads((DATA / "demo-block.truth.json").read_text())
    assert ours["errors"] == theirs["errors"]


def test_analyze_demo_names_planted_errors(tmp_path, capsys):
    res = tmp_path / "r.json"
    assert main(["analyze", str(DATA / "demo-block.json"), "--json", str(res)]) == 0
    text = capsys.readouterr().out
    doc = json.loads(res.read_text())
    planted = doc["planted"]
    assert [p["kind"] for p in planted] == ["transfer", "image", "control", "image-point"]
    assert all(p["found"] for p in planted)
    assert text.count("→ FOUND") == 4
    transfer = planted[0]
    assert transfer["hypothesis"] == "point transfer" and transfer["T"] > transfer["critical"]
    assert doc["summary"]["global_test"]["passed"] is False
    image = next(o for o in doc["observations"] if o["rejected"] and abs(o["w"]) > 10)
    assert {"image", "point", "component"} <= set(image)


def test_other_demo_files_analyse(capsys):
    for name in ("demo-imodel.json", "demo-levelling.gkf"):
        assert main(["analyze", str(DATA / name), "--quiet"]) == 0, name
