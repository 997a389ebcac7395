"""A 3D point at (within round-off of) a projection centre (issue 26, item 1).

Synthetic reproducer: six PINHOLE images in a COLMAP model (text and binary), images 1 and 2
taken from one position (a rotation-only pair), one point 1e-12 from their common centre and
seen by all six. Its projection stays finite but its Jacobian grows like 1/depth and swamps
the pose blocks of images 1 and 2: the analysis must name the point (not the images), leave out
only its image points and adjust the rest to pycolmap's Ceres optimum of the model without it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baarda.adjust import adjust
from baarda.build import read_problem
from baarda.errors import SingularError
from baarda.io import read_model
from baarda.sfm_defects import adjust_block, find_defects

from tests.io.test_colmap import pycolmap_cost

F, CX, CY = 1000.0, 500.0, 400.0
CENTRES = np.array([[0, 0, -10], [0, 0, -10], [1, 0, -14], [-1, 0.5, -14], [0.8, -0.8, -13],
                    [-0.8, 0.8, -13]], dtype=float)
AT_CENTRE = 9999                                  # id of the point at the centre of images 1, 2


def _rot(axis, deg):
    a = np.radians(deg)
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _quat(R):
    """Unit quaternion (w, x, y, z) of a rotation matrix (w > 0 here: small rotations)."""
    w = 0.5 * np.sqrt(1.0 + np.trace(R))
    return np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])


def write_model(folder: Path, offset: float = 1e-12, with_point: bool = True, seed: int = 3,
                centres=CENTRES) -> Path:
    """The six-image COLMAP text model of the module docstring in ``folder`` (without_point:
    the same model with the point's keypoints not linked to a 3D point and the point removed;
    centres: the six projection centres)."""
    CENTRES = np.asarray(centres, dtype=float)  # noqa: N806
    rng = np.random.default_rng(seed)
    rots = [_rot([0, 1, 0], 0.0), _rot([0, 1, 0], 8.0), _rot([1, 0, 0], 2.0), _rot([0, 1, 0], -3.0),
            _rot([1, 1, 0], 2.5), _rot([1, -1, 0], -2.0)]
    X = np.column_stack([rng.uniform(-4, 4, 40), rng.uniform(-3, 3, 40), rng.uniform(-1, 1, 40)])
    ids = list(range(1, 41))
    d = np.array([0.1, 0.2, 1.0])
    X = np.vstack([X, CENTRES[0] + offset * d / np.linalg.norm(d)])
    ids.append(AT_CENTRE)
    tracks = {p: [] for p in ids}
    lines = []
    for k, (R, C) in enumerate(zip(rots, CENTRES), start=1):
        t = -R @ C
        kp = []
        for p, x in zip(ids, X):
            # the point's keypoints are where a matcher saw it (the point exactly at the
            # centre still has finite image points)
            c = R @ ((x if p != AT_CENTRE else CENTRES[0] + 1e-12 * d / np.linalg.norm(d)) - C)
            uv = F * c[:2] / c[2] + [CX, CY] + rng.normal(scale=0.5, size=2)
            tracks[p].append((k, len(kp)))
            kp.append(f"{uv[0]:.17g} {uv[1]:.17g} {p if with_point or p != AT_CENTRE else -1}")
        q = _quat(R)
        lines.append(f"{k} {' '.join(f'{v:.17g}' for v in q)} {' '.join(f'{v:.17g}' for v in t)} 1 im{k}.jpg")
        lines.append(" ".join(kp))
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cameras.txt").write_text(f"1 PINHOLE 1000 800 {F} {F} {CX} {CY}\n")
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    pts = [f"{p} {' '.join(f'{v:.17g}' for v in x)} 128 128 128 0.5 "
           + " ".join(f"{i} {j}" for i, j in tracks[p]) for p, x in zip(ids, X) if with_point or p != AT_CENTRE]
    (folder / "points3D.txt").write_text("\n".join(pts) + "\n")
    return folder


def _as(kind: str, txt: Path) -> Path:
    """The text model ``txt``, or its binary twin written by pycolmap."""
    if kind == "txt":
        return txt
    pycolmap = pytest.importorskip("pycolmap")
    out = txt.parent / (txt.name + "-bin")
    out.mkdir()
    pycolmap.Reconstruction(str(txt)).write_binary(str(out))
    for g in list(out.glob("rigs.*")) + list(out.glob("frames.*")):
        g.unlink()
    return out


def ceres_cost(model_dir: Path) -> float:
    """½Σr² at pycolmap's Ceres optimum (intrinsics held, as baarda adjusts a COLMAP model)."""
    pycolmap = pytest.importorskip("pycolmap")
    rec = pycolmap.Reconstruction(str(model_dir))
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = ba.refine_extra_params = ba.refine_principal_point = False
    ba.print_summary = False
    pycolmap.bundle_adjustment(rec, ba)
    return pycolmap_cost(rec)[0]


@pytest.mark.parametrize("kind", ["txt", "bin"])
def test_point_at_a_projection_centre_is_left_out_alone(tmp_path, kind):
    """Only the point is named and left out (its six image points); both images stay; the rest
    adjusts to Ceres's optimum of the model without the point."""
    pytest.importorskip("pycolmap")
    model_dir = _as(kind, write_model(tmp_path / "m"))
    block = read_model(model_dir)
    reduced, defects = find_defects(block)
    assert [(d.entity, d.id) for d in defects] == [("point", str(AT_CENTRE))]
    assert "projection centre of image" in defects[0].reason
    assert len(reduced.images) == 6 and len(reduced.points) == 40
    assert reduced.obs_image.size == block.obs_image.size - 6
    adj, used = adjust_block(read_problem(model_dir))
    assert adj.converged
    assert [(d.entity, d.id) for d in used.notes.local_defects] == [("point", str(AT_CENTRE))]
    reference = _as(kind, write_model(tmp_path / "ref", with_point=False))
    assert 0.5 * adj.vPv == pytest.approx(ceres_cost(reference), rel=1e-9)
    # the same as baarda on the model without the point
    assert 0.5 * adj.vPv == pytest.approx(0.5 * adjust(read_problem(reference)).vPv, rel=1e-10)


@pytest.mark.parametrize("offset", [1e-9, 1e-11, 1e-13, 0.0])
def test_any_offset_within_round_off(tmp_path, offset):
    """1e-9 .. 0 of the centre (scale 10): the point, never the images."""
    block = read_model(write_model(tmp_path / "m", offset=offset))
    _, defects = find_defects(block)
    assert [(d.entity, d.id) for d in defects] == [("point", str(AT_CENTRE))]


def test_a_point_near_the_centre_that_makes_the_pose_look_singular(tmp_path):
    """1e-6 of the scale from the centre: beyond round-off, but its share makes the pose blocks
    of images 1 and 2 look singular (relative eigenvalue ~1e-12): the point is named, not the
    images."""
    block = read_model(write_model(tmp_path / "m", offset=1e-5))
    _, defects = find_defects(block)
    assert [(d.entity, d.id) for d in defects] == [("point", str(AT_CENTRE))]
    assert "makes it look singular" in defects[0].reason


def test_a_near_point_that_does_not_disturb_the_pose_is_kept(tmp_path):
    """1e-3 of the scale from the centre: close, determined, kept."""
    block = read_model(write_model(tmp_path / "m", offset=1e-2))
    _, defects = find_defects(block)
    assert defects == []


def test_cli_names_the_point(tmp_path, capsys):
    """``baarda analyze`` names the point and the image whose centre it is at, in its text and
    its JSON, and analyses the rest."""
    import json

    from baarda.cli import main

    model_dir = write_model(tmp_path / "m")
    out = tmp_path / "r.json"
    assert main(["analyze", str(model_dir), "--json", str(out), "--top", "1"]) == 0
    text = capsys.readouterr().out
    assert "1 local defect(s)" in text
    assert f"point {AT_CENTRE} (x, y, z): at the projection centre of image 1" in text
    doc = json.loads(out.read_text())
    assert [(d["entity"], d["id"]) for d in doc["summary"]["local_defects"]] == [("point", str(AT_CENTRE))]
    assert doc["summary"]["converged"]


def test_bench_ceres_row_when_a_projection_is_undefined(tmp_path):
    """Issue 26.6: bench_solve's Ceres run on a model with a point exactly at a centre gives a
    row saying the projection is undefined (no cost), not a crash."""
    pytest.importorskip("pycolmap")
    from bench.bench_solve import ceres_colmap

    _, cost, _, n, term = ceres_colmap(write_model(tmp_path / "m", offset=0.0))
    assert cost is None and n == 6 * 41 - 2
    assert "projection of 2 image point(s) is undefined" in term


#: issue 26.5: three images 2500-3500 from a scene 8 units wide, three more 4.6e6 away
DEGENERATE = np.vstack([CENTRES[:3] * 250, [[2.1e6, -1.3e6, -4.6e6], [-1.7e6, 2.9e6, -4.6e6], [0.4e6, 1.1e6, -4.6e6]]])


def test_degenerate_geometry_is_named_not_a_gross_error(tmp_path, capsys):
    """Images far from a small scene: baarda does not converge and Ceres does not either
    (NO_CONVERGENCE); the message names the geometry and does not suggest --robust."""
    pytest.importorskip("pycolmap")
    from baarda.cli import main
    from bench.bench_solve import ceres_colmap

    model_dir = write_model(tmp_path / "m", with_point=False, centres=DEGENERATE)
    assert ceres_colmap(model_dir)[4].startswith("NO_CONVERGENCE")
    assert main(["analyze", str(model_dir), "--quiet"]) == 4
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "NOT converged" in err
    assert "the block's geometry is degenerate" in err and "images see their points within" in err
    assert "--robust" not in err


def test_degenerate_geometry_signs():
    """Both signs on their own, and none on a sound block (the six-image model)."""
    from baarda.sfm_defects import degenerate_geometry

    with_far = read_model(write_model(Path(tmp := __import__("tempfile").mkdtemp()) / "far", with_point=False,
                                      centres=np.vstack([CENTRES[:4], [[4.6e6, 0, -10], [0, 4.6e6, -10]]])))
    text = degenerate_geometry(with_far)
    assert "projection centres spread over 6.5e+06 units" in text and "within" not in text
    narrow = read_model(write_model(Path(tmp) / "narrow", with_point=False, centres=CENTRES * 250))
    text = degenerate_geometry(narrow)
    assert "images see their points within" in text and "spread over" not in text
    assert degenerate_geometry(read_model(write_model(Path(tmp) / "sound", with_point=False))) is None
    __import__("shutil").rmtree(tmp)


def test_diverged_message_names_the_geometry(tmp_path, capsys):
    """The other not-converged message (singular at the last iterate, commands._diverged) names the
    geometry and runs no robust estimation; on a sound block R84's robust estimation is tried (here it
    ends singular too) and the line says so."""
    from types import SimpleNamespace

    from baarda import commands

    adj = SimpleNamespace(termination="not converged: the maximum number of iterations was reached", iterations=200,
                          converged=False)
    for centres, degenerate in ((DEGENERATE, True), (CENTRES, False)):
        model_dir = write_model(tmp_path / str(degenerate), with_point=False, centres=centres)
        args = SimpleNamespace(input=str(model_dir), robust=None, quiet=True)
        tried = []

        def robust(method):
            tried.append(method)
            raise SingularError("normal matrix is singular")

        analysis = SimpleNamespace(problem=read_problem(model_dir), adjustment=adj, robust=robust)
        assert commands._diverged(args, analysis, "singular") == 4
        err = capsys.readouterr().err
        assert err.count("\n") == 1
        assert ("the block's geometry is degenerate" in err) is degenerate
        assert ("robust estimation (r84) gives none either" in err) is not degenerate
        assert tried == ([] if degenerate else ["r84"])
