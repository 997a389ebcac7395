"""COLMAP models as COLMAP writes them: one 3D point matched by several keypoints of one image,
errors at the right file and line (text) or byte (binary), the real model of extdata.

References: pycolmap (its reader, its count of observations and its own projection for the
cost), the published result of ../shared/extdata/colmap (README there).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from baarda.adjust import adjust
from baarda.build import read_problem
from baarda.cli import main
from baarda.errors import InputError
from baarda.io.colmap import read_colmap
from baarda.model.sfm import initial_cost
from baarda.stats.reliability import reliability_of

from tests.extdata import EXTDATA, require_extdata

REAL = EXTDATA / "colmap" / "test_colmap-sparse0"


def pycolmap_cost(rec) -> tuple[float, int]:
    """½ Σ r² and the number of observations, by pycolmap's own camera model."""
    cost, n = 0.0, 0
    for im in rec.images.values():
        cam = rec.cameras[im.camera_id]
        pose = im.cam_from_world()
        for p2 in im.points2D:
            if p2.has_point3D():
                r = cam.img_from_cam(pose * rec.points3D[p2.point3D_id].xyz) - p2.xy
                cost += 0.5 * float(r @ r)
                n += 1
    return cost, n


def unique_labels(problem):
    keys = [tuple(sorted(d.items())) for d in problem.info.ids]
    return len(set(keys)) == len(keys)


# --------------------------------------------------------------------------------------------
# models with duplicate keypoints, written by us and read back by pycolmap
# --------------------------------------------------------------------------------------------
def duplicate_model(tmp_path: Path, n_dup: int = 3):
    """A synthetic model (pycolmap) in which n_dup points get a second keypoint in one image
    (images.txt and points3D.txt edited as COLMAP writes them); returns (text dir, binary dir,
    pycolmap's reconstruction of the edited model, the (image, point, keypoint) added)."""
    pycolmap = pytest.importorskip("pycolmap")
    opt = pycolmap.SyntheticDatasetOptions(num_rigs=1, num_cameras_per_rig=1, num_frames_per_rig=6,
                                           num_points3D=60, num_points2D_without_point3D=4)
    opt.camera_model_id = pycolmap.CameraModelId.SIMPLE_RADIAL
    opt.camera_params = [1280.0, 512.0, 384.0, 0.05]
    rec = pycolmap.synthesize_dataset(opt)
    pycolmap.synthesize_noise(pycolmap.SyntheticNoiseOptions(point2D_stddev=1.0, point3D_stddev=0.01), rec)
    txt = tmp_path / "txt"
    txt.mkdir()
    rec.write_text(str(txt))
    images = (txt / "images.txt").read_text().splitlines()
    points = (txt / "points3D.txt").read_text().splitlines()
    data = [k for k, s in enumerate(images) if s and not s.startswith("#")]
    added = []
    for j in range(n_dup):
        head = data[2 * j]                                # image j's header line; its points follow
        iid = int(images[head].split()[0])
        trip = images[head + 1].split()
        m = len(trip) // 3
        pick = next(k for k in range(m) if trip[3 * k + 2] != "-1" and
                    all(int(trip[3 * k + 2]) != a[1] for a in added))
        x, y, pid = float(trip[3 * pick]), float(trip[3 * pick + 1]), int(trip[3 * pick + 2])
        images[head + 1] += f" {x + 0.75:.6f} {y - 0.5:.6f} {pid}"
        row = next(k for k, s in enumerate(points) if s and not s.startswith("#") and int(s.split()[0]) == pid)
        points[row] += f" {iid} {m}"
        added.append((iid, pid, m))
    (txt / "images.txt").write_text("\n".join(images) + "\n")
    (txt / "points3D.txt").write_text("\n".join(points) + "\n")
    edited = pycolmap.Reconstruction(str(txt))
    binary = tmp_path / "bin"
    binary.mkdir()
    edited.write_binary(str(binary))
    for f in ("rigs", "frames"):                          # not needed by baarda
        for d in (txt, binary):
            for g in d.glob(f"{f}.*"):
                g.unlink()
    return txt, binary, edited, added


@pytest.mark.parametrize("kind", ["txt", "bin"])
def test_duplicate_keypoints_are_separate_observations(tmp_path, kind):
    txt, binary, rec, added = duplicate_model(tmp_path)
    model = txt if kind == "txt" else binary
    block = read_colmap(model)
    cost, n = pycolmap_cost(rec)
    assert block.obs_image.size == n == rec.compute_num_observations()
    assert block.extra["duplicate_keypoints"] == {"points": 3, "observations": 3}
    p = read_problem(model)
    assert initial_cost(p) == pytest.approx(cost, rel=1e-12)
    assert unique_labels(p)
    # the added keypoint is an observation of its own, with its own coordinates and label
    for iid, pid, kp in added:
        rows = [i for i, d in enumerate(p.info.ids) if d["image"] == str(iid) and d["point"] == str(pid)]
        assert len(rows) == 4
        kps = sorted({p.info.ids[i]["keypoint"] for i in rows})
        assert kp in kps and len(kps) == 2
        row = next(i for i in rows if p.info.ids[i]["keypoint"] == kp and p.info.ids[i]["component"] == "x")
        assert np.allclose(p.l[row:row + 2], rec.images[iid].points2D[kp].xy)
    # text and binary: the same block
    other = read_colmap(binary if kind == "txt" else txt)
    assert np.array_equal(block.extra["obs_keypoint"], other.extra["obs_keypoint"])
    assert np.array_equal(block.obs_point, other.obs_point) and np.allclose(block.xy, other.xy, atol=1e-9)


def test_duplicate_keypoints_tested_on_their_own_and_counted_in_the_summary(tmp_path, capsys):
    txt, _, rec, added = duplicate_model(tmp_path)
    adj = adjust(read_problem(txt))
    assert adj.converged
    p = adj.problem
    iid, pid, kp = added[0]
    rows = [i for i, d in enumerate(p.info.ids) if d["image"] == str(iid) and d["point"] == str(pid)]
    groups = {int(p.info.group[i]) for i in rows}
    assert len(groups) == 2                               # one 2-D test per image point
    assert np.isfinite(adj.r[rows]).all() and (adj.r[rows] > 0).all() and np.isfinite(adj.w[rows]).all()
    assert np.isfinite(reliability_of(adj).mdb[rows]).all()
    # the shifted keypoint (0.75, −0.5 px off) pulls its partner: both residuals differ
    assert not np.allclose(adj.v[rows[:2]], adj.v[rows[2:]])
    out = tmp_path / "r.json"
    assert main(["analyze", str(txt), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "3 point(s) observed by two or more keypoints of one image: 3 extra image point(s)" in text
    doc = json.loads(out.read_text())
    assert doc["summary"]["duplicate_keypoints"] == {"points": 3, "observations": 3}
    kp_rows = [o for o in doc["observations"] if o.get("keypoint") == kp and o["image"] == str(iid)]
    assert len(kp_rows) == 2


def test_same_keypoint_twice_in_a_track_is_refused_at_its_line(tmp_path):
    txt, _, _, added = duplicate_model(tmp_path, n_dup=1)
    iid, pid, kp = added[0]
    lines = (txt / "points3D.txt").read_text().splitlines()
    row = next(k for k, s in enumerate(lines) if s and not s.startswith("#") and int(s.split()[0]) == pid)
    lines[row] += f" {iid} {kp}"
    (txt / "points3D.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as exc:
        read_colmap(txt)
    assert exc.value.path.endswith("points3D.txt") and exc.value.line == row + 1
    assert f"its track lists image point {kp} of image {iid} twice" in exc.value.message


# --------------------------------------------------------------------------------------------
# error locations: the right text file and line, byte offsets in binary files
# --------------------------------------------------------------------------------------------
def test_text_errors_name_the_file_at_fault(tmp_path):
    txt, _, _, _ = duplicate_model(tmp_path, n_dup=0)
    images = (txt / "images.txt").read_text().splitlines()
    points = (txt / "points3D.txt").read_text().splitlines()
    # a track element naming an image that does not exist: points3D.txt, the point's line
    row = next(k for k, s in enumerate(points) if s and not s.startswith("#"))
    bad = points.copy()
    bad[row] += " 999 0"
    (txt / "points3D.txt").write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError) as exc:
        read_colmap(txt)
    assert Path(exc.value.path).name == "points3D.txt" and exc.value.line == row + 1
    assert "image 999 of its track is not in images.txt" in exc.value.message
    # an image point that names a point whose track does not list it: images.txt, the image's points line
    (txt / "points3D.txt").write_text("\n".join(points) + "\n")
    head = next(k for k, s in enumerate(images) if s and not s.startswith("#"))
    trip = images[head + 1].split()
    free = next(k for k in range(len(trip) // 3) if trip[3 * k + 2] == "-1")
    pid = next(t for t in trip[2::3] if t != "-1")
    trip[3 * free + 2] = pid
    bad = images.copy()
    bad[head + 1] = " ".join(trip)
    (txt / "images.txt").write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError) as exc:
        read_colmap(txt)
    assert Path(exc.value.path).name == "images.txt" and exc.value.line == head + 2
    assert f"image point {free} refers to point {pid}, whose track in points3D.txt does not list it" in exc.value.message
    assert str(exc.value).startswith(f"{txt / 'images.txt'}:{head + 2}: ")


def point_records(data: bytes) -> list[tuple[int, int, list]]:
    """(byte offset, POINT3D_ID, track) of each record of a points3D.bin, walked independently."""
    (n,), pos, out = struct.unpack_from("<Q", data, 0), 8, []
    for _ in range(n):
        pid = struct.unpack_from("<Q", data, pos)[0]
        m = struct.unpack_from("<Q", data, pos + 43)[0]
        track = list(struct.iter_unpack("<II", data[pos + 51:pos + 51 + 8 * m]))
        out.append((pos, pid, track))
        pos += 51 + 8 * m
    return out


def test_binary_errors_give_the_byte_offset(tmp_path, capsys):
    _, binary, _, _ = duplicate_model(tmp_path, n_dup=0)
    f = binary / "points3D.bin"
    data = bytearray(f.read_bytes())
    recs = point_records(bytes(data))
    at, pid, track = recs[5]
    struct.pack_into("<I", data, at + 51 + 4, 100000)      # POINT2D_IDX of its first track element
    f.write_bytes(bytes(data))
    with pytest.raises(InputError) as exc:
        read_colmap(binary)
    assert exc.value.offset == at and exc.value.line == 0
    assert str(exc.value) == f"{f}:byte {at}: point {pid}: image {track[0][0]} has " \
        f"{exc.value.message.split(' has ')[1].split(' image points')[0]} image points, POINT2D_IDX 100000 is out of range"
    assert main(["analyze", str(binary)]) == 2
    assert capsys.readouterr().err.startswith(f"baarda: error: {f}:byte {at}: point {pid}: ")
    # a file cut inside its last record: the byte where it ends
    f.write_bytes(bytes(data[:recs[-1][0] + 20]))
    with pytest.raises(InputError) as exc:
        read_colmap(binary)
    assert exc.value.offset == recs[-1][0] + 20 and "the file ends early" in exc.value.message
    # a count no file of this size can hold: refused at byte 0, before any record is read
    f.write_bytes(struct.pack("<Q", 10 ** 9) + bytes(data[8:]))
    with pytest.raises(InputError) as exc:
        read_colmap(binary)
    assert exc.value.offset == 0 and "cannot fit" in exc.value.message


# --------------------------------------------------------------------------------------------
# the real model (extdata): 7 points with two keypoints in one image
# --------------------------------------------------------------------------------------------
def test_real_model_reads_as_pycolmap_does():
    pycolmap = pytest.importorskip("pycolmap")
    require_extdata(REAL)
    rec = pycolmap.Reconstruction(str(REAL))
    block = read_colmap(REAL)
    cost, n = pycolmap_cost(rec)
    assert block.obs_image.size == n == rec.compute_num_observations() == 5931
    # points whose track has two elements of one image, counted by pycolmap's tracks
    dup_points = sum(1 for p in rec.points3D.values()
                     if len({e.image_id for e in p.track.elements}) < p.track.length())
    dup_obs = sum(p.track.length() - len({e.image_id for e in p.track.elements}) for p in rec.points3D.values())
    assert block.extra["duplicate_keypoints"] == {"points": dup_points, "observations": dup_obs} \
        == {"points": 7, "observations": 7}
    p = read_problem(REAL)
    assert unique_labels(p)
    assert initial_cost(p) == pytest.approx(cost, rel=1e-12)
    assert initial_cost(p) == pytest.approx(3659.560464, abs=5e-7)     # extdata README


def test_real_model_adjusts_to_pycolmaps_optimum():
    require_extdata(REAL)
    adj = adjust(read_problem(REAL))
    assert adj.converged
    assert 0.5 * adj.vPv == pytest.approx(3637.780514, rel=1e-6)       # pycolmap's Ceres, intrinsics fixed
    dup = [i for i, d in enumerate(adj.problem.info.ids) if "keypoint" in d]
    assert len(dup) == 4 * 7                                            # 7 pairs of image points, x and y
    assert np.isfinite(adj.r[dup]).all()
