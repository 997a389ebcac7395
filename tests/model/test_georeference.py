"""Georeferencing a block in an arbitrary frame by its GNSS centres (issue 28): the closed-form
similarity (Umeyama 1991) recovers a known transformation, a bad centre is left out of the fit,
and the adjustment of the georeferenced block is the adjustment of the block in its own frame."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import baarda
from baarda.cli import main
from baarda.georeference import georeference, robust_similarity, similarity
from baarda.io.gnss import GnssOptions
from baarda.io.native import write_native
from baarda.observations.rotation import R_opk, opk_from_R
from baarda.simulate import simulate_to_files


def test_similarity_recovers_a_known_transformation():
    rng = np.random.default_rng(5)
    src = rng.normal(0, 100, (12, 3))
    Q = R_opk(0.3, -1.1, 2.5)
    dst = 0.037 * (Q @ src.T).T + [1000.0, -20.0, 5.0]
    s, Q2, t = similarity(src, dst)
    assert s == pytest.approx(0.037, rel=1e-12)
    np.testing.assert_allclose(Q2, Q, atol=1e-12)
    np.testing.assert_allclose(t, [1000.0, -20.0, 5.0], atol=1e-9)
    dst[4] += [0.0, 50.0, 0.0]                       # one bad target
    s, Q2, t, kept, res = robust_similarity(src, dst + rng.normal(0, 0.01, dst.shape))
    assert not kept[4] and kept.sum() == 11 and abs(s - 0.037) < 1e-4
    assert np.linalg.norm(res[4]) == pytest.approx(50.0, abs=0.2)


def _moved(block, s, Q, t):
    """The block in another frame: points and centres s Q X + t, rotations Q R."""
    def move(X):
        return s * Q @ np.asarray(X, dtype=float) + t
    images = []
    for im in block.images:
        X0 = move([im.X0, im.Y0, im.Z0])
        w, p, k = opk_from_R(Q @ R_opk(im.omega, im.phi, im.kappa))
        images.append(dataclasses.replace(im, X0=X0[0], Y0=X0[1], Z0=X0[2], omega=float(w), phi=float(p),
                                          kappa=float(k)))
    points = [dataclasses.replace(p, **dict(zip("XYZ", move([p.X, p.Y, p.Z])))) for p in block.points]
    return block.replace(images=tuple(images), points=tuple(points))


def test_a_block_in_an_arbitrary_frame_adjusts_as_in_its_own(tmp_path, capsys):
    block, _ = simulate_to_files({"seed": 9, "control": "none", "gnss_sigma": 0.05,
                                  "errors": [{"kind": "gnss", "size": 2000, "image": "204"}]},
                                 tmp_path / "b.json")
    moved = _moved(block.replace(gnss=None), 0.01, R_opk(0.4, 0.2, -2.0), np.array([3.0, -7.0, 0.5]))
    write_native(moved.replace(datum="free"), tmp_path / "m.json")
    g = georeference(block.replace(images=moved.images, points=moved.points), "x")
    note = g.extra["georeference"]
    assert note["scale"] == pytest.approx(100.0, rel=1e-3) and note["left_out"] == ["204"]
    a = baarda.analyze(tmp_path / "b.json", gnss=tmp_path / "b.gnss.csv")
    m = baarda.analyze(tmp_path / "m.json", gnss=GnssOptions(tmp_path / "b.gnss.csv", georeference=True))
    pa, pm = a.records("points"), m.records("points")
    for c in "xyz":
        np.testing.assert_allclose(pm[c], pa[c], atol=1e-6)
    np.testing.assert_allclose(m.adjustment.w, a.adjustment.w, atol=1e-6)
    assert main(["analyze", str(tmp_path / "m.json"), "--gnss", str(tmp_path / "b.gnss.csv"), "--georeference",
                 "--top", "1"]) == 0
    out = capsys.readouterr().out
    assert "georeferenced to 23 of 24 GNSS centres by a similarity" in out and "left out of the fit" in out


def test_georeference_needs_centres(tmp_path, capsys):
    simulate_to_files({"seed": 9, "strips": 1, "images_per_strip": 4, "control": "corners"}, tmp_path / "b.json")
    csv = tmp_path / "g.csv"
    csv.write_text("image,x,y,z,sx,sy,sz\n101,0,0,0,1,1,1\n102,1,0,0,1,1,1\n")
    assert main(["analyze", str(tmp_path / "b.json"), "--gnss", str(csv), "--georeference"]) == 2
    assert "--georeference needs GNSS positions of at least 3 images" in capsys.readouterr().err
