"""The GNSS file (``--gnss CSV``, issue 28): columns, correlations, errors naming file, line and
field, the options of the command line, and ``baarda simulate --gnss-sigma``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import baarda
from baarda.cli import main
from baarda.io.gnss import read_gnss
from baarda.simulate import simulate_to_files


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    d = tmp_path_factory.mktemp("gnssio")
    simulate_to_files({"seed": 1, "strips": 2, "images_per_strip": 4, "control": "corners", "gnss_sigma": 0.05},
                      d / "b.json", d / "b.truth.json")
    return d


def test_columns_correlations_and_strip(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text("# antenna positions\nImage,X,Y,Z,sx,sy,sz,rxy,strip,time\n"
                 "101,1,2,3,0.05,0.04,0.1,0.5,A,12.5\n102,4,5,6,0.05,0.05,0.05,,,\n")
    c = read_gnss(p)
    assert [x.image for x in c] == ["101", "102"] and c[0].strip == "A" and c[0].time == 12.5
    np.testing.assert_allclose(c[0].cov, [[0.0025, 0.001, 0], [0.001, 0.0016, 0], [0, 0, 0.01]], atol=1e-15)
    assert c[1].strip == "" and np.isnan(c[1].time) and c[1].line == 4


@pytest.mark.parametrize("text,line,needle", [
    ("image,x,y,z,sx,sy\n101,0,0,0,1,1\n", 1, "missing: sz"),
    ("image,x,y,z,sx,sy,sz,quality\n101,0,0,0,1,1,1,a\n", 1, "unknown column(s) 'quality'"),
    ("image,x,y,z,sx,sy,sz\n101,0,0,0,1,1,1\n999,0,0,0,1,1,1\n", 3, "image 999 is not an image of the block"),
    ("image,x,y,z,sx,sy,sz\n101,0,0,zz,1,1,1\n", 2, "z = 'zz' is not a number"),
    ("image,x,y,z,sx,sy,sz\n101,0,0,0,1,0,1\n", 2, "sy = 0 must lie in"),
    ("image,x,y,z,sx,sy,sz\n101,0,0,0,1,1,1\n101,0,0,0,1,1,1\n", 3, "duplicate image 101"),
    ("image,x,y,z,sx,sy,sz,rxy,rxz,ryz\n101,0,0,0,1,1,1,0.99,0.99,-0.99\n", 2, "no positive definite"),
    ("image,x,y,z,sx,sy,sz,rxy\n101,0,0,0,1,1,1,1.5\n", 2, "rxy = 1.5 must lie in (-1, 1)"),
])
def test_bad_gnss_files_are_refused_with_file_and_line(block, tmp_path, capsys, text, line, needle):
    p = tmp_path / "g.csv"
    p.write_text(text)
    before = p.read_bytes(), (block / "b.json").read_bytes()
    assert main(["analyze", str(block / "b.json"), "--gnss", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {p}:{line}: ") and err.count("\n") == 1, err
    assert needle in err, err
    assert (p.read_bytes(), (block / "b.json").read_bytes()) == before


def test_drift_needs_times_and_options_need_gnss(block, tmp_path, capsys):
    p = tmp_path / "g.csv"
    p.write_text("image,x,y,z,sx,sy,sz\n101,0,0,1500,1,1,1\n")
    assert main(["analyze", str(block / "b.json"), "--gnss", str(p), "--gnss-drift"]) == 2
    assert "--gnss-drift needs a time in every row" in capsys.readouterr().err
    assert main(["analyze", str(block / "b.json"), "--gnss-shift"]) == 2
    assert "--gnss-shift need(s) --gnss CSV" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["analyze", str(block / "b.json"), "--gnss", str(p), "--lever-arm", "1,x,2"])
    assert exc.value.code == 2
    assert "expected DX,DY,DZ" in capsys.readouterr().err


def test_gnss_on_a_colmap_model_matched_by_file_name(tmp_path, capsys):
    """A COLMAP model is converted to a native block (intrinsics held); the GNSS file names its
    images by file name (img1.jpg) or stem (img2). Its three centres lie on a line: georeferencing
    is refused, and without control the rotation about the line is a datum defect, named."""
    from pathlib import Path

    from baarda.io import read_model
    from baarda.model.sfm import to_block
    colmap = Path(__file__).resolve().parents[1] / "malformed" / "valid" / "colmap-valid"
    blk = to_block(read_model(colmap))
    names = blk.extra["image_names"]
    C = np.array([[im.X0, im.Y0, im.Z0] for im in blk.images])
    G = C + np.random.default_rng(0).normal(0, 0.01, C.shape)
    rows = ["image,x,y,z,sx,sy,sz"]
    for k, im in enumerate(blk.images):
        name = names[im.id] if k % 2 == 0 else names[im.id].rsplit(".", 1)[0]
        rows.append(f"{name},{float(G[k, 0])!r},{float(G[k, 1])!r},{float(G[k, 2])!r},0.01,0.01,0.01")
    p = tmp_path / "g.csv"
    p.write_text("\n".join(rows) + "\n")
    from baarda.build import read_problem
    problem = read_problem(colmap, gnss=p)
    assert problem.datum.describe().startswith(f"GNSS projection centres ({len(blk.images)})")
    gx = [i for i, k in enumerate(problem.info.kind) if k == "gnss-x"]
    assert {problem.info.ids[i]["image"] for i in gx} == {im.id for im in blk.images}
    assert main(["analyze", str(colmap), "--gnss", str(p)]) == 2
    assert "rotation about x undetermined" in capsys.readouterr().err
    assert main(["analyze", str(colmap), "--gnss", str(p), "--georeference"]) == 2
    assert "--georeference: the projection centres lie on a line" in capsys.readouterr().err
    p.write_text("image,x,y,z,sx,sy,sz\nnot-an-image.jpg,0,0,0,1,1,1\n")
    assert main(["analyze", str(colmap), "--gnss", str(p)]) == 2
    assert f"{p}:2: image not-an-image.jpg is not an image of the block" in capsys.readouterr().err


def test_cli_json_and_simulate(block, tmp_path, capsys):
    out = tmp_path / "r.json"
    code = main(["analyze", str(block / "b.json"), "--gnss", str(block / "b.gnss.csv"), "--lever-arm", "0,0,0",
                 "--gnss-shift", "--json", str(out), "--top", "2"])
    assert code == 0
    text = capsys.readouterr().out
    assert "GNSS projection centres (8; per-strip shifts) and control points (4)" in text
    assert "GNSS shift of strip 1 (F80 §7.2-7.3)" in text
    doc = json.loads(out.read_text())
    kinds = {o["kind"] for o in doc["observations"]}
    assert {"gnss-x", "gnss-y", "gnss-z"} <= kinds
    gx = [o for o in doc["observations"] if o["kind"] == "gnss-x"]
    assert len(gx) == 8 and all(o["mdb"] > 0 and o["redundancy"] > 0 for o in gx)
    assert {a["camera"] for a in doc["ap_tests"] if a["group"] == "gnss-shift"} == {"1", "2"}
    # the Python door gives the same numbers
    a = baarda.analyze(block / "b.json", gnss=baarda.io.gnss.GnssOptions(block / "b.gnss.csv", shift=True))
    np.testing.assert_allclose([o["w"] for o in gx], a.records("observations")["w"][[o["index"] for o in gx]])


def test_simulate_writes_the_gnss_file(tmp_path, capsys):
    out = tmp_path / "s.json"
    assert main(["simulate", str(out), "--strips", "2", "--images", "4", "--gnss-sigma", "0.05",
                 "--error", "gnss:20:image=102:axis=z"]) == 0
    assert "GNSS centres in" in capsys.readouterr().out
    truth = json.loads((tmp_path / "s.truth.json").read_text())
    assert truth["gnss_file"] == "s.gnss.csv" and truth["recipe"]["gnss_sigma"] == 0.05
    e = [x for x in truth["errors"] if x["kind"] == "gnss"][0]
    assert e["ids"] == {"image": "102", "axis": "z"} and e["vector"] == [pytest.approx(1.0)]
    assert main(["analyze", str(out), "--gnss", str(tmp_path / "s.gnss.csv"), "--top", "1"]) == 0
    text = capsys.readouterr().out
    assert "gnss              image=102 axis=z" in text and "GNSS centre T =" in text and "FOUND" in text
    assert main(["simulate", str(tmp_path / "t.json"), "--error", "gnss:20"]) == 2
    assert "a GNSS error needs gnss_sigma" in capsys.readouterr().err


@pytest.mark.parametrize("text,line,needle", [
    ("image,omega,phi,kappa,somega,sphi\n101,0,0,0,1,1\n", 1, "missing: skappa"),
    ("image,omega,phi,kappa,somega,sphi,skappa,yaw\n101,0,0,0,1,1,1,0\n", 1, "unknown column(s) 'yaw'"),
    ("image,omega,phi,kappa,somega,sphi,skappa\n101,0,90,0,1,1,1\n", 2, "singular at |φ| = 90°"),
    ("image,omega,phi,kappa,somega,sphi,skappa\n101,0,0,0,1,0,1\n", 2, "sphi = 0 must lie in"),
    ("image,omega,phi,kappa,somega,sphi,skappa\n777,0,0,0,1,1,1\n", 2, "image 777 is not an image of the block"),
])
def test_bad_imu_files_are_refused_with_file_and_line(block, tmp_path, capsys, text, line, needle):
    p = tmp_path / "i.csv"
    p.write_text(text)
    assert main(["analyze", str(block / "b.json"), "--imu", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {p}:{line}: ") and err.count("\n") == 1, err
    assert needle in err, err


def test_imu_through_the_cli(tmp_path, capsys):
    out = tmp_path / "s.json"
    assert main(["simulate", str(out), "--strips", "2", "--images", "4", "--gnss-sigma", "0.05", "--imu-sigma",
                 "0.005", "--imu-boresight", "0.2,0.1,-0.3", "--error", "imu:25:image=203:angle=omega"]) == 0
    capsys.readouterr()
    assert main(["analyze", str(out), "--gnss", str(tmp_path / "s.gnss.csv"), "--imu", str(tmp_path / "s.imu.csv"),
                 "--top", "1", "--json", str(tmp_path / "r.json")]) == 0
    text = capsys.readouterr().out
    assert "IMU attitudes (8; boresight estimated)" in text
    assert "#" in text and "imu-omega       image=203" in text
    doc = json.loads((tmp_path / "r.json").read_text())
    imu = [o for o in doc["observations"] if o["kind"].startswith("imu-")]
    assert len(imu) == 24 and all(o["unit"] == "deg" for o in imu)
    assert main(["analyze", str(out), "--fix-boresight"]) == 2
    assert "--boresight / --fix-boresight need --imu CSV" in capsys.readouterr().err


def _pose_prior_db(path, rows, v4=False):
    """A COLMAP database.db with only a pose_priors table, as COLMAP 3.9-3.12 (or 4) writes it."""
    import sqlite3
    con = sqlite3.connect(path)
    if v4:
        con.execute("CREATE TABLE pose_priors (pose_prior_id INTEGER PRIMARY KEY NOT NULL, corr_data_id INTEGER "
                    "NOT NULL, corr_sensor_id INTEGER NOT NULL, corr_sensor_type INTEGER NOT NULL, position BLOB, "
                    "position_covariance BLOB, gravity BLOB, coordinate_system INTEGER NOT NULL)")
        con.executemany("INSERT INTO pose_priors VALUES (?, ?, 1, 0, ?, ?, NULL, ?)",
                        [(k, i, np.asarray(p, "<f8").tobytes(), np.asarray(c, "<f8").tobytes(), cs)
                         for k, (i, p, c, cs) in enumerate(rows, 1)])
    else:
        con.execute("CREATE TABLE pose_priors (image_id INTEGER PRIMARY KEY NOT NULL, position BLOB, "
                    "coordinate_system INTEGER NOT NULL, position_covariance BLOB)")
        con.executemany("INSERT INTO pose_priors VALUES (?, ?, ?, ?)",
                        [(i, np.asarray(p, "<f8").tobytes(), cs, np.asarray(c, "<f8").tobytes())
                         for i, p, c, cs in rows])
    con.commit()
    con.close()


@pytest.mark.parametrize("v4", [False, True], ids=["colmap-3", "colmap-4"])
def test_colmap_pose_priors_from_database_db(tmp_path, capsys, v4):
    from pathlib import Path

    from baarda.build import read_problem
    from baarda.io import read_model
    from baarda.model.sfm import to_block
    colmap = Path(__file__).resolve().parents[1] / "malformed" / "valid" / "colmap-valid"
    blk = to_block(read_model(colmap))
    cov = [[0.0004, 0.0001, 0.0], [0.0001, 0.0009, 0.0], [0.0, 0.0, 0.0016]]
    rows = [(int(im.id), [im.X0 + 0.01, im.Y0, im.Z0], cov, 1) for im in blk.images]
    db = tmp_path / "database.db"
    _pose_prior_db(db, rows, v4)
    centres = baarda.io.gnss.read_gnss(db)
    assert [c.image for c in centres] == [im.id for im in blk.images]
    np.testing.assert_allclose(centres[0].cov, cov)
    problem = read_problem(colmap, gnss=db)
    g = [i for i, k in enumerate(problem.info.kind) if k.startswith("gnss-")]
    assert len(g) == 3 * len(blk.images)
    np.testing.assert_allclose(problem.cov.matrix().toarray()[np.ix_(g[:3], g[:3])], cov)
    bad = tmp_path / "wgs84.db"
    _pose_prior_db(bad, [(1, [52.0, 4.3, 10.0], cov, 0)], v4)
    assert main(["analyze", str(colmap), "--gnss", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {bad}:0: pose prior 1 (image 1): WGS84") and err.count("\n") == 1
    nan = tmp_path / "nan.db"
    _pose_prior_db(nan, [(1, [1.0, 2.0, 3.0], np.full((3, 3), np.nan), 1)], v4)
    assert main(["analyze", str(colmap), "--gnss", str(nan)]) == 2
    assert "COLMAP stores NaN for an unknown covariance" in capsys.readouterr().err
