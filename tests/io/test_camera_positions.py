"""Camera positions as Metashape and Pix4D export them (``--gnss FILE``, baarda.io.camera_positions):
the layouts, matching labels to images, geographic coordinates refused, bad rows with file:line."""

from __future__ import annotations

import numpy as np
import pytest

import baarda
from baarda.cli import main
from baarda.io.camera_positions import sniff
from baarda.io.gnss import read_gnss
from baarda.simulate import simulate_to_files


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """A simulated block with GNSS centres (its ``b.gnss.csv``, baarda's layout)."""
    d = tmp_path_factory.mktemp("campos")
    simulate_to_files({"seed": 2, "strips": 2, "images_per_strip": 4, "control": "corners", "gnss_sigma": 0.05},
                      d / "b.json", d / "b.truth.json")
    return d


def _centres(block):
    return read_gnss(block / "b.gnss.csv")


def _metashape(centres, label=lambda i: f"{i}.JPG") -> str:
    lines = ["# Cameras (%d)" % len(centres),
             "#Label,X/Easting,Y/Northing,Z/Altitude,Yaw,Pitch,Roll,Accuracy_X/Y_(m),Accuracy_Z_(m),"
             "X error,Y error,Z error,X est,Y est,Z est"]
    for c in centres:
        sd = [float(v) for v in np.sqrt(np.diag(c.cov))]
        lines.append(f"{label(c.image)},{c.xyz[0]!r},{c.xyz[1]!r},{c.xyz[2]!r},12.5,0.3,-0.2,{sd[0]!r},{sd[2]!r},"
                     ",,,1,2,3")
    return "\n".join(lines) + "\n"


def _pix4d(centres, label=lambda i: f"IMG_{i}.jpg", accuracy=True) -> str:
    lines = ["#imagename,X,Y,Z,omega,phi,kappa" + (",accuracy horizontal,accuracy vertical" if accuracy else "")]
    for c in centres:
        sd = [float(v) for v in np.sqrt(np.diag(c.cov))]
        lines.append(f"{label(c.image)},{c.xyz[0]!r},{c.xyz[1]!r},{c.xyz[2]!r},0.1,-0.2,90.0"
                     + (f",{sd[0]!r},{sd[2]!r}" if accuracy else ""))
    return "\n".join(lines) + "\n"


def test_metashape_layout_reads_the_reference_positions(block, tmp_path):
    ref = _centres(block)
    p = tmp_path / "cams.txt"
    p.write_text(_metashape(ref))
    assert sniff(p)[0] == "metashape"
    got = read_gnss(p)
    assert [c.image for c in got] == [f"{c.image}.JPG" for c in ref]
    np.testing.assert_array_equal([c.xyz for c in got], [c.xyz for c in ref])       # not the "est" columns
    np.testing.assert_allclose([c.cov for c in got], [c.cov for c in ref], rtol=1e-15)
    assert got[0].line == 3


def test_metashape_per_axis_accuracy_and_one_accuracy(block, tmp_path):
    ref = _centres(block)[:2]
    p = tmp_path / "cams.csv"
    p.write_text("Label,X,Y,Z,X_accuracy,Y_accuracy,Z_accuracy,Omega,Phi,Kappa\n"
                 f"{ref[0].image},1,2,3,0.01,0.02,0.03,0,0,0\n")
    assert np.sqrt(np.diag(read_gnss(p)[0].cov)).tolist() == pytest.approx([0.01, 0.02, 0.03], rel=1e-15)
    p.write_text(f"#Label,X/East,Y/North,Z/Altitude,Accuracy (m)\n{ref[0].image},1,2,3,0.04\n")
    assert np.sqrt(np.diag(read_gnss(p)[0].cov)).tolist() == pytest.approx([0.04] * 3, rel=1e-15)


def test_pix4d_layout(block, tmp_path):
    ref = _centres(block)
    p = tmp_path / "geo.csv"
    p.write_text(_pix4d(ref))
    assert sniff(p)[0] == "pix4d"
    got = read_gnss(p)
    np.testing.assert_array_equal([c.xyz for c in got], [c.xyz for c in ref])
    np.testing.assert_allclose([c.cov for c in got], [c.cov for c in ref], rtol=1e-15)
    p.write_text(_pix4d(ref).split("\n", 1)[1])                   # without the comment line
    assert [c.image for c in read_gnss(p)] == [f"IMG_{c.image}.jpg" for c in ref]


def test_each_layout_gives_the_same_adjustment(block, tmp_path):
    """Labels with an extension and in another case are matched (exact, stem, case-insensitive)."""
    ref = _centres(block)
    base = baarda.analyze(block / "b.json", gnss=block / "b.gnss.csv")
    for name, text in (("m.txt", _metashape(ref, label=lambda i: f"{i}.jpg")),
                       ("p.csv", _pix4d(ref, label=lambda i: f"{i}.TIF"))):
        (tmp_path / name).write_text(text)
        a = baarda.analyze(block / "b.json", gnss=tmp_path / name)
        assert a.adjustment.vPv == pytest.approx(base.adjustment.vPv, rel=1e-12)
        np.testing.assert_allclose(a.adjustment.x, base.adjustment.x, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name, text, line, needle", [
    ("m.txt", "#Label,X/Longitude,Y/Latitude,Z/Altitude,Accuracy (m)\n101,6.5,46.2,500,1\n", 1,
     "project to a metric frame first"),
    ("m.txt", "#Label,X/East,Y/North,Z/Altitude,Quality\n101,6.5,46.2,500,1\n", 1, "unknown column 'Quality'"),
    ("m.txt", "#Label,X/East,Y/North,Z/Altitude,Yaw,Pitch,Roll\n101,6.5,46.2,500,1,2,3\n", 1, "no accuracy columns"),
    ("m.txt", "#Label,X/East,Y/North,Z/Altitude,Accuracy (m)\n101,0,0,1500,0.05\n102,0,x1,1500,0.05\n", 3,
     "image 102: Y/North = 'x1' is not a number"),
    ("m.txt", "#Label,X/East,Y/North,Z/Altitude,Accuracy (m)\n101,0,0,1500,0\n", 2, "Accuracy (m) = 0 must lie in"),
    ("m.txt", "#Label,X/East,Y/North,Z/Altitude,Accuracy (m)\n101,0,0,1500\n", 2, "4 fields, the header has 5"),
    ("m.txt", "#Label,X/East,Y/North,Z/Altitude,Accuracy (m)\nnope,0,0,1500,0.05\n", 2,
     "image nope is not an image of the block"),
    ("p.csv", "101,46.2345,6.5611,539.9,38.6,3.5,8.3,0.02,0.04\n102,46.2346,6.5612,539.9,38.6,3.5,8.3,0.02,0.04\n", 1,
     "look geographic"),
    ("p.csv", "#imagename,latitude,longitude,altitude,omega,phi,kappa,h,v\n101,1000,2000,539.9,0,0,0,0.02,0.04\n", 2,
     "project to a metric frame first"),
    ("p.csv", "101,1000,2000,539.9,38.6,3.5,8.3\n", 1, "without accuracy columns"),
    ("p.csv", "101,1000,2000,1500,0,0,0,0.02,0.04\n102,1100,2000,1500,0,0,0,0.02\n", 2, "8 fields, the first row has 9"),
    ("p.csv", "101,1000,2000,1500,0,0,0,0.02,0.04\n101,1100,2000,1500,0,0,0,0.02,0.04\n", 2, "duplicate image 101"),
])
def test_bad_files_are_refused_with_file_and_line(block, tmp_path, capsys, name, text, line, needle):
    p = tmp_path / name
    p.write_text(text)
    before = p.read_bytes(), (block / "b.json").read_bytes()
    assert main(["analyze", str(block / "b.json"), "--gnss", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {p}:{line}: ") and err.count("\n") == 1, err
    assert needle in err, err
    assert (p.read_bytes(), (block / "b.json").read_bytes()) == before
