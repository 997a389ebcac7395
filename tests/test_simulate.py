"""The block simulator: determinism, design mode, geometry of the standard pattern, planted
errors and their truth records (R84 §6 classes), files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from baarda import adjust
from baarda.io.native import read_native
from baarda.model.bundle import build_block_problem
from baarda.observations.collinearity import project
from baarda.simulate import error_class, simulate_block, simulate_to_files

ERRORS = [{"kind": "image", "size": 20}, {"kind": "transfer", "size": 10},
          {"kind": "control", "size": 20}, {"kind": "image-point", "size": 6}]


def test_same_seed_same_block():
    a, ta = simulate_block(seed=3, errors=ERRORS)
    b, tb = simulate_block(seed=3, errors=ERRORS)
    c, _ = simulate_block(seed=4, errors=ERRORS)
    assert np.array_equal(a.obs.xy, b.obs.xy) and np.array_equal(a.obs.point, b.obs.point)
    assert [p.__dict__ for p in a.points] == [p.__dict__ for p in b.points]
    assert json.dumps(ta, default=float) == json.dumps(tb, default=float)
    assert not np.array_equal(a.obs.xy, c.obs.xy)


def test_design_mode_observations_are_exact_projections():
    blk, truth = simulate_block(seed=1, design=True)
    cam = blk.cameras[0]
    P = np.array([[p.X, p.Y, p.Z] for p in blk.points])[blk.obs.point]
    xy = project(cam, [blk.images[i] for i in blk.obs.image], P)
    assert np.abs(xy - blk.obs.xy).max() < 1e-12
    adj = adjust(build_block_problem(blk))
    assert adj.iterations == 1 and np.abs(adj.v).max() < 1e-9


@pytest.mark.parametrize("pattern", [[3, 3], [5, 3]])
def test_standard_pattern_tracks(pattern):
    blk, _ = simulate_block(seed=0, pattern=pattern, strips=3, images_per_strip=8)
    track = np.bincount(blk.obs.point)
    assert track.min() >= 2 and track.max() <= 6
    per_image = np.bincount(blk.obs.image)
    assert per_image.min() >= 6
    assert per_image.max() == pattern[0] * pattern[1]
    assert len(blk.images) == 24


@pytest.mark.parametrize("control,count", [("corners", 4), ("minimal", 3), ("none", 0)])
def test_control_configurations(control, count):
    blk, _ = simulate_block(seed=0, control=control, datum="control" if count else "free")
    ctrl = [p for p in blk.points if p.status == "control"]
    assert len(ctrl) == count
    if control == "minimal":
        assert sorted(p.axes for p in ctrl) == ["xyz", "xyz", "z"]


def test_perimeter_and_dense_control():
    per, _ = simulate_block(seed=0, control="perimeter", control_spacing=2)
    dense, _ = simulate_block(seed=0, control="dense")
    n_per = sum(p.status == "control" for p in per.points)
    n_dense = sum(p.status == "control" for p in dense.points)
    assert 8 <= n_per < n_dense


def test_planted_errors_are_where_the_truth_says():
    clean, _ = simulate_block(seed=2, design=True)
    dirty, truth = simulate_block(seed=2, design=True, errors=ERRORS)
    pc, pd = build_block_problem(clean), build_block_problem(dirty)
    diff = pd.l - pc.l
    rows = sorted(r for e in truth["errors"] for r in e["rows"])
    assert sorted(np.flatnonzero(np.abs(diff) > 0)) == rows
    for e in truth["errors"]:
        if e["kind"] == "transfer":
            d = diff[e["rows"]].reshape(-1, 2)
            assert d.shape == (3, 2) and np.allclose(d, e["vector"])
            assert np.isclose(np.linalg.norm(e["vector"]), 10 * 0.005)
        elif e["kind"] in ("image", "control"):
            assert np.isclose(diff[e["rows"][0]], e["vector"][0])
        assert e["class"] == error_class(e["size_sigma"], e["size_base"])
    assert {e["kind"] for e in truth["errors"]} == {"image", "transfer", "control", "image-point"}


def test_error_classes_follow_r84():
    assert error_class(3, 0) == "random"
    assert error_class(20, 0.001) == "small"
    assert error_class(500, 1.0) == "medium"
    assert error_class(5e4, 4.0) == "large"


def test_radial_distortion_is_planted():
    a, _ = simulate_block(seed=5, design=True)
    b, _ = simulate_block(seed=5, design=True, radial=0.01)
    d = b.obs.xy - a.obs.xy
    xy = a.obs.xy / a.cameras[0].scale
    rho2 = (xy ** 2).sum(axis=1)
    assert np.allclose(d, 0.01 * xy * rho2[:, None], atol=1e-6)


def test_gross_errors_are_detected(tmp_path):
    blk, truth = simulate_to_files({"seed": 7, "errors": [{"kind": "image", "size": 30}]},
                                   tmp_path / "b.json", tmp_path / "b.truth.json")
    back = read_native(tmp_path / "b.json")
    assert np.array_equal(back.obs.xy, blk.obs.xy)
    assert json.loads((tmp_path / "b.truth.json").read_text())["errors"][0]["rows"] == truth["errors"][0]["rows"]
    adj = adjust(build_block_problem(back))
    assert int(np.nanargmax(np.abs(adj.w))) == truth["errors"][0]["rows"][0]


def test_drone_camera_in_pixels():
    blk, _ = simulate_block(seed=1, camera="drone", flying_height=100.0, strips=2, images_per_strip=5)
    assert blk.cameras[0].unit == "px"
    adj = adjust(build_block_problem(blk))
    assert adj.converged and 0.7 < adj.sigma0_post < 1.3


def test_unknown_recipe_key():
    with pytest.raises(ValueError, match="unknown recipe keys"):
        simulate_block(strip=3)


def test_cli_error_ids_are_text(tmp_path, capsys):
    """Issue 27 item 11: ``--error image:40:point=P00005:image=104`` was an internal IndexError (the
    image id parsed as the number 104); ids are text, as the readers keep them. A point not measured
    in the image named, or an unknown id, is a one-line error (exit 2), nothing written."""
    from baarda.cli import main

    out = tmp_path / "s.json"
    args = ["simulate", str(out), "--strips", "2", "--images", "5", "--seed", "1"]
    assert main(args + ["--error", "image:40:point=P00005:image=104"]) == 0
    capsys.readouterr()
    err, = json.loads(out.with_suffix(".truth.json").read_text())["errors"]
    assert err["ids"]["image"] == "104" and err["ids"]["point"] == "P00005"
    bad = tmp_path / "b.json"
    for spec, what in (("image:40:point=P00005:image=101", "not measured in image '101'"),
                       ("image:40:point=NOPE", "no point 'NOPE'"), ("exchange:1:image=999", "no image '999'")):
        assert main(["simulate", str(bad), "--strips", "2", "--images", "5", "--error", spec]) == 2
        line = capsys.readouterr().err.strip()
        assert line.startswith("baarda: error:") and what in line and "\n" not in line
        assert not bad.exists()


def test_planted_errors_against_the_fit_without_the_robust_suspects():
    """The diverged case (issue 27): the document is the least squares without the robust
    suspects (R84 §7), a subset of the block. A planted error among the suspects is
    ``robust_suspect`` and found though none of its observations is left to test; one still in
    the fit is tested there, by the truth file's rows; with no fit, the suspects alone."""
    from baarda.model.problem import subset
    from baarda.truth import compare
    blk, truth = simulate_block(seed=7, errors=[{"kind": "image", "size": 40}, {"kind": "image", "size": 30}])
    p = build_block_problem(blk)
    gone, kept = truth["errors"][0]["rows"], truth["errors"][1]["rows"]
    cluster = p.cov.members[int(p.cov.cluster[gone[0]])]           # the image point (x, y) left out
    final = adjust(subset(p, np.setdiff1d(np.arange(p.n), cluster)))
    first, second = compare(final, truth, left_out=[cluster])
    assert first["robust_suspect"] and first["found"] and "max_w" not in first
    assert not second["robust_suspect"] and second["found"] and second["snooping_rejects"]
    assert second["max_w"] == pytest.approx(float(np.abs(final.w[np.searchsorted(final.problem.notes.kept_rows,
                                                                                   kept)]).max()))
    assert [(f["robust_suspect"], f["found"]) for f in compare(None, truth, left_out=[cluster])] == \
        [(True, True), (False, False)]
    assert "robust_suspect" not in compare(final, truth)[0]          # the converged case: as before
