"""The images' pose precision and the check points in the JSON document and in --csv."""

from __future__ import annotations

import csv
import json
from importlib import resources

import jsonschema
import numpy as np
import pytest

from baarda.cli import main
from baarda.stats.pose import POSE_NAMES, pose_covariance, pose_values

SCHEMA = json.loads(resources.files("baarda").joinpath("schema/analysis.schema.json").read_text())


@pytest.fixture(scope="module")
def written(tmp_path_factory, demo_path):
    d = tmp_path_factory.mktemp("out")
    assert main(["analyze", str(demo_path), "-q", "--json", str(d / "o.json"), "--csv", str(d / "csv")]) == 0
    return d


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_json_images_carry_the_pose_covariance(written, demo_adjustment):
    doc = json.loads((written / "o.json").read_text())
    jsonschema.validate(doc, SCHEMA)
    imgs = doc["images"]
    cov = pose_covariance(demo_adjustment)
    x = pose_values(demo_adjustment)
    assert [d["id"] for d in imgs] == [im.id for im in demo_adjustment.problem.geometry.images]
    for k, d in enumerate(imgs):
        assert [d["s" + n] for n in POSE_NAMES] == pytest.approx(np.sqrt(np.diag(cov[k])), rel=1e-12)
        assert [d[n] for n in POSE_NAMES] == pytest.approx(x[k], rel=1e-12, abs=1e-12)
        assert np.allclose(d["centre_cov"], cov[k, :3, :3], rtol=1e-12, atol=0)


def test_csv_images_and_check_points(written):
    doc = json.loads((written / "o.json").read_text())
    rows = _rows(written / "csv" / "images.csv")
    assert len(rows) == len(doc["images"])
    for row, d in zip(rows, doc["images"]):
        assert row["id"] == d["id"]
        assert float(row["sZ0"]) == pytest.approx(d["sZ0"], rel=1e-15)
        assert float(row["cov_XY"]) == pytest.approx(d["centre_cov"][0][1], rel=1e-15)
        assert float(row["cov_ZZ"]) == pytest.approx(d["sZ0"] ** 2, rel=1e-12)
    cps = _rows(written / "csv" / "check_points.csv")
    ref = doc["check_points"]
    assert ref["n"] == len(cps) > 0
    d = np.array([[float(r[k]) for k in ("dx", "dy", "dz")] for r in cps])
    known = np.array([[float(r[k]) for k in ("x_ref", "y_ref", "z_ref")] for r in cps])
    adjusted = np.array([[float(r[k]) for k in ("x", "y", "z")] for r in cps])
    assert np.allclose(d, adjusted - known, rtol=0, atol=1e-9)
    assert np.sqrt((d ** 2).mean(axis=0)) == pytest.approx(ref["rms"], rel=1e-12)


def test_networks_have_no_images(tmp_path, data_dir):
    assert main(["analyze", str(data_dir / "demo-levelling.gkf"), "-q", "--json", str(tmp_path / "o.json"),
                 "--csv", str(tmp_path / "csv")]) == 0
    assert "images" not in json.loads((tmp_path / "o.json").read_text())
    assert sorted(p.name for p in (tmp_path / "csv").iterdir()) == ["groups.csv", "observations.csv", "points.csv"]
