"""``baarda study`` (issue 30): on the demo design, a block where the w-test's assumptions hold
(σ known, normal noise, one error at a time), the empirical size equals α0 and the empirical
power the power expected from the planted error's size and redundancy number (β0 at the MDB),
each within 3 standard errors; seeds recorded reproduce a replicate alone."""

from __future__ import annotations

import csv
import json
from xml.etree import ElementTree
import math
from pathlib import Path

from baarda import study
from baarda.cli import main

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "data" / "demo-study.json"


def test_the_demo_design_reproduces_the_w_tests_size_and_power(tmp_path):
    recipe = study.read_recipe(DEMO)
    recipe["replicates"] = 24                      # seconds, not minutes (the demo's 200: bench/bench_batch.py)
    table = study.run_study(recipe, tmp_path, serial=True)
    (t,) = table
    assert t["replicates"] == 24 and t["tests"] > 24 * 100
    # size: w ~ N(0, 1) under H0 (B68), so P(|w| > k) = α0 per observation
    assert abs(t["empirical_size"] - t["alpha0"]) < 3 * t["size_se"], t
    # power: an error at the MDB (δ0/√r σ) is found with probability β0 (F80 eq. 8)
    assert abs(t["expected_power"] - t["beta0"]) < 0.05, t
    assert abs(t["empirical_power"] - t["expected_power"]) < 3 * t["power_se"], t
    rows = list(csv.DictReader((tmp_path / "replicates.csv").open()))
    assert len(rows) == 24 and len({r["seed"] for r in rows}) == 24
    # a replicate again, alone, from its recorded seed: the same statistic of the planted observation
    designs = json.loads((tmp_path / "designs.json").read_text())
    again = study.replicate(designs["designs"][0], recipe, designs["planted"][0], int(rows[5]["seed"]))
    assert repr(again["planted_w"]) == rows[5]["planted_w"]


def test_study_command_line_serial(tmp_path, capsys):
    recipe = tmp_path / "r.json"
    doc = json.loads(DEMO.read_text())
    doc["grid"] = {"control": ["perimeter", "corners"]}
    recipe.write_text(json.dumps(doc))
    assert main(["study", str(recipe), "--replicates", "2", "--serial", "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "design 0 (control=perimeter)" in out and "design 1 (control=corners)" in out
    assert len(list(csv.DictReader((tmp_path / "o" / "study.csv").open()))) == 2
    svg = ElementTree.parse(tmp_path / "o" / "study.svg").getroot()       # well-formed, one point per design
    tips = [c.find("{http://www.w3.org/2000/svg}title").text for c in svg.iter("{http://www.w3.org/2000/svg}circle")
            if c.find("{http://www.w3.org/2000/svg}title") is not None]
    assert sum(t.startswith("empirical power") for t in tips) == 2
    page = (tmp_path / "o" / "index.html").read_text(encoding="utf-8")
    assert "<svg" in page and "control=corners" in page


def test_a_bad_study_recipe_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"replicates": 0}')
    assert main(["study", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "replicates must be an integer" in err[0] and str(bad) in err[0]
