"""Local defects of bundle blocks (core/sfm_defects.py): every planted defect is named, the rest
is adjusted, and its r and w equal those of the same block with the defective entities removed
by hand (an independent reference: the block built without them from the start)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from baarda.adjust import adjust
from baarda.build import build
from baarda.errors import DatumDefectError, InputError
from baarda.io import read_model
from baarda.model.sfm import SfmCamera, SfmImage, build_sfm_problem
from baarda.sfm_defects import adjust_block, find_defects

from tests.extdata import EXTDATA, require_extdata

BALBIANELLO = EXTDATA / "bal" / "Balbianello.out"


def project(block, image_idx, point_idx):
    """Pixel coordinates of points in images (the block's own camera model, via its problem)."""
    m = len(image_idx)
    trial = block.replace(obs_image=np.asarray(image_idx, dtype=np.int64),
                          obs_point=np.asarray(point_idx, dtype=np.int64),
                          xy=np.zeros((m, 2)), obs_line=np.zeros(m, dtype=np.int64), control=(), extra={})
    pr = build_sfm_problem(trial)
    f, _ = pr.evaluate(pr.params.x0)
    return f[: 2 * m].reshape(m, 2)


def add(block, images=(), cameras=(), points=(), X=None, obs=()):
    """The block with extra cameras, images, points (ids and m × 3 coordinates) and image
    points [(image id, point id)] measured without error; a new object, the input unchanged."""
    cams = block.cameras + tuple(cameras)
    imgs = block.images + tuple(images)
    pts = block.points + tuple(points)
    XX = np.vstack([block.X, np.asarray(X, dtype=float).reshape(-1, 3)]) if len(points) else block.X
    # the readers' arrays per observation, point or image (COLMAP keypoint index, offsets) grow too
    grow = {block.obs_image.size: len(obs), len(block.points): len(points), len(block.images): len(images)}
    extra = {k: (np.concatenate([v, np.arange(grow[v.shape[0]]) + 10 ** 6])
                 if isinstance(v, np.ndarray) and v.shape[0] in grow else v) for k, v in block.extra.items()}
    big = block.replace(cameras=cams, images=imgs, points=pts, X=XX, extra=extra,
                        point_line=np.concatenate([block.point_line, np.zeros(len(points), dtype=np.int64)]))
    if not obs:
        return big
    iidx = {im.id: k for k, im in enumerate(imgs)}
    pidx = {p: k for k, p in enumerate(pts)}
    oi = np.array([iidx[a] for a, _ in obs], dtype=np.int64)
    op = np.array([pidx[b] for _, b in obs], dtype=np.int64)
    xy = project(big, oi, op)
    return big.replace(obs_image=np.concatenate([block.obs_image, oi]),
                       obs_point=np.concatenate([block.obs_point, op]),
                       xy=np.vstack([block.xy, xy]),
                       obs_line=np.concatenate([block.obs_line, np.zeros(len(obs), dtype=np.int64)]))


def seen_by(block, image_idx):
    return [block.points[p] for p in np.unique(block.obs_point[block.obs_image == image_idx])]


def in_front(block, k, n, depth=1.0, spread=0.05, seed=0):
    """n points in front of image k (inside its view), in world coordinates."""
    im = block.images[k]
    s = -1.0 if block.convention in ("bal", "bundler") else 1.0
    rng = np.random.default_rng(seed)
    P = np.column_stack([rng.uniform(-spread, spread, n), rng.uniform(-spread, spread, n), np.full(n, s * depth)])
    return (P - np.asarray(im.t)) @ im.R          # X = Rᵀ (P − t)


def duplicate_image(block, k, new_id="dup"):
    """An image (and its camera) with the very pose of image k, measuring the points k measures."""
    im = block.images[k]
    cam = next(c for c in block.cameras if c.id == im.camera)
    ncam = SfmCamera(f"{cam.id}-dup", cam.model, cam.params, cam.width, cam.height)
    nim = SfmImage(new_id, ncam.id, im.rodrigues, im.t, name="duplicate")
    return add(block, images=[nim], cameras=[ncam], obs=[(new_id, p) for p in seen_by(block, k)])


@pytest.fixture(scope="module")
def balbianello():
    require_extdata(BALBIANELLO)
    return read_model(BALBIANELLO)


@pytest.fixture(scope="module")
def planted(balbianello):
    """Balbianello (real, Bundler) with a duplicated image 0 and planted defects.

    Returns (reference block, planted block, planted defects {(entity, id)}).
    """
    ref = duplicate_image(balbianello, 0)
    ids = [im.id for im in ref.images]
    k0 = 0
    # zero baseline: four points seen only by image 0 and its duplicate (the real case)
    zb = [f"zb{j}" for j in range(4)]
    b = add(ref, points=zb, X=in_front(ref, k0, 4, seed=1),
            obs=[(i, p) for p in zb for i in ("0", "dup")])
    # single rays: three points seen by image 2 only
    sr = [f"sr{j}" for j in range(3)]
    b = add(b, points=sr, X=in_front(b, 2, 3, seed=2), obs=[("2", p) for p in sr])
    # a starved image: it sees one old point and one new point that image 3 sees too; once the
    # image is left out, the new point is left on a single ray (the pre-pass must iterate)
    cam3 = next(c for c in b.cameras if c.id == b.images[3].camera)
    scam = SfmCamera("starved-cam", cam3.model, cam3.params)
    im3 = b.images[3]
    simg = SfmImage("starved", scam.id, im3.rodrigues, tuple(np.asarray(im3.t) + [0.05, 0.0, 0.0]))
    b = add(b, images=[simg], cameras=[scam], points=["casc"], X=in_front(b, 3, 1, seed=3))
    old = seen_by(b, 3)[0]
    b = add(b, obs=[("starved", old), ("starved", "casc"), ("3", "casc")])
    want = ({("point", p) for p in zb + sr + ["casc"]} | {("image", "starved")})
    assert ids[-1] == "dup"
    return ref, b, want


def test_every_planted_defect_is_named(planted):
    ref, b, want = planted
    X_before, xy_before = b.X.copy(), b.xy.copy()
    reduced, defects = find_defects(b)
    named = {(d.entity, d.id) for d in defects}
    assert want <= named, want - named
    # the camera of the starved image (refined intrinsics) goes with it; nothing else
    assert named - want <= {("camera", "starved-cam")}
    reasons = {d.id: d.reason for d in defects}
    assert "images 0, dup have the same centre" in reasons["zb0"]
    assert reasons["sr1"].startswith("single ray")
    assert "starved" in reasons["casc"]                # named after the image was left out
    # the input is not changed; the reduced block is the reference's structure
    assert np.array_equal(b.X, X_before) and np.array_equal(b.xy, xy_before)
    assert reduced is not b
    assert reduced.points == ref.points and [im.id for im in reduced.images] == [im.id for im in ref.images]
    assert np.array_equal(reduced.obs_image, ref.obs_image) and np.array_equal(reduced.obs_point, ref.obs_point)


def test_the_rest_adjusts_as_the_block_without_them(planted):
    ref, b, want = planted
    with pytest.raises(DatumDefectError):
        adjust(build_sfm_problem(b))                   # today's behaviour without the pre-pass
    problem = build(b)
    adj, used = adjust_block(problem)
    assert adj.converged
    assert {(d["entity"], d["id"]) for d in _summary(adj)["local_defects"]} >= want
    reference = adjust(build_sfm_problem(ref))
    assert reference.converged
    key = [tuple(d.values()) for d in reference.problem.info.ids]
    assert [tuple(d.values()) for d in adj.problem.info.ids] == key
    np.testing.assert_allclose(adj.r, reference.r, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(adj.w, reference.w, rtol=1e-6, atol=1e-6)
    assert adj.dof == reference.dof


def _summary(adj):
    from baarda.io import results
    return results.summary(adj)


def test_clean_block_is_untouched(balbianello):
    reduced, defects = find_defects(balbianello)
    assert reduced is balbianello and defects == []


def test_opposite_rays_fix_no_depth(balbianello):
    """A point between two centres on their baseline: its rays are opposite (angle π)."""
    b = balbianello
    C0, C1 = b.images[0].centre, b.images[1].centre
    X = 0.5 * (C0 + C1)
    b2 = add(b, points=["mid"], X=X[None, :])
    b2 = b2.replace(obs_image=np.concatenate([b2.obs_image, [0, 1]]),
                    obs_point=np.concatenate([b2.obs_point, [len(b2.points) - 1] * 2]),
                    xy=np.vstack([b2.xy, [[1.0, 2.0], [3.0, 4.0]]]),
                    obs_line=np.concatenate([b2.obs_line, [0, 0]]))
    _, defects = find_defects(b2)
    assert [(d.entity, d.id) for d in defects] == [("point", "mid")]
    assert "zero baseline" in defects[0].reason


def test_collinear_points_and_the_safety_net(balbianello, monkeypatch):
    """An image whose three points lie on one line: counting passes it, its pose block does not
    (the pose can turn about that line). The pre-pass names it; with that check switched off,
    the safety net (singular normal equations → leave out, adjust again) names it instead."""
    import baarda.sfm_defects as sd

    b = read_model(BALBIANELLO, refine_intrinsics=False)
    ref = b
    # three collinear new points in front of image 1, each also seen by images 0 and 1
    X = in_front(b, 1, 1, seed=5)[0]
    d = in_front(b, 1, 1, seed=6)[0] - X
    line = np.array([X + t * d for t in (-1.0, 0.0, 1.0)])
    cl = ["l0", "l1", "l2"]
    ref = add(b, points=cl, X=line, obs=[(i, p) for p in cl for i in ("0", "1")])
    im1 = b.images[1]
    cam1 = next(c for c in b.cameras if c.id == im1.camera)
    ncam = SfmCamera("lone-cam", cam1.model, cam1.params)
    nim = SfmImage("lone", ncam.id, im1.rodrigues, tuple(np.asarray(im1.t) + [0.1, 0.02, 0.0]))
    blk = add(ref, images=[nim], cameras=[ncam], obs=[("lone", p) for p in cl])
    _, pre = find_defects(blk)
    assert [(d.entity, d.id) for d in pre] == [("image", "lone")]
    assert "do not fix its pose" in pre[0].reason
    monkeypatch.setattr(sd, "POSE_TOL", -1.0)          # counting alone cannot see it
    assert find_defects(blk)[1] == []
    adj, used = adjust_block(build(blk))
    named = {(d.entity, d.id) for d in used.notes.local_defects}
    assert ("image", "lone") in named
    assert not any(e == "point" for e, _ in named)
    reference = adjust(build_sfm_problem(ref))
    np.testing.assert_allclose(adj.r, reference.r, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(adj.w, reference.w, rtol=1e-6, atol=1e-6)


def test_strict_refuses_naming_all(planted):
    _, b, want = planted
    with pytest.raises(InputError) as err:
        build(b, strict=True)
    msg = str(err.value)
    for _, ident in want:
        assert ident in msg


def test_cli_names_zero_baseline_points_and_strict_refuses(balbianello, tmp_path, capsys):
    """The issue's case as a file: two images with identical poses and four points seen by them
    only. `baarda analyze` names all four (text and JSON) and analyses the rest; --strict exits 2."""
    import jsonschema
    from importlib import resources

    from baarda.cli import main
    from baarda.io.bal import write_bal

    b = duplicate_image(balbianello, 0)
    zb = [f"zb{j}" for j in range(4)]
    b = add(b, points=zb, X=in_front(b, 0, 4, seed=1), obs=[(i, p) for p in zb for i in ("0", "dup")])
    src = tmp_path / "zero-baseline.txt"
    write_bal(b, src)
    ids = [str(len(b.points) - 4 + j) for j in range(4)]          # BAL numbers its points
    out = tmp_path / "out.json"
    assert main(["analyze", str(src), "--json", str(out), "--top", "1"]) == 0
    text = capsys.readouterr().out
    assert "4 local defect(s)" in text
    for i in ids:
        assert f"point {i} (x, y, z): zero baseline" in text
    doc = json.loads(out.read_text())
    schema = json.loads(resources.files("baarda").joinpath("schema/analysis.schema.json").read_text())
    jsonschema.validate(doc, schema)
    named = doc["summary"]["local_defects"]
    assert [d["id"] for d in named] == ids
    assert all(d["entity"] == "point" and d["action"] == "left out" for d in named)
    assert doc["summary"]["converged"]
    assert doc["summary"]["n_observations"] == 2 * (b.obs_image.size - 8)
    assert main(["analyze", str(src), "--strict", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--strict" in err and "left out" not in err
    for i in ids:
        assert f"point {i} " in err


# --------------------------------------------------------------------------------------------
# native photogrammetric blocks (baarda.model.bundle.Block)
# --------------------------------------------------------------------------------------------
def add_native(block, images=(), cameras=(), points=(), obs=()):
    """A native Block with extra cameras, images, points and error-free image points."""
    from baarda.model.bundle import ImageObservations
    from baarda.observations.collinearity import project

    cams = block.cameras + tuple(cameras)
    imgs = block.images + tuple(images)
    pts = block.points + tuple(points)
    iidx = {im.id: k for k, im in enumerate(imgs)}
    pidx = {p.id: k for k, p in enumerate(pts)}
    camd = {c.id: c for c in cams}
    oi = np.array([iidx[a] for a, _ in obs], dtype=np.int64)
    op = np.array([pidx[b] for _, b in obs], dtype=np.int64)
    xy = np.array([project(camd[imgs[i].camera], [imgs[i]], [(pts[p].X, pts[p].Y, pts[p].Z)])[0]
                   for i, p in zip(oi, op)]).reshape(-1, 2)
    o = block.obs
    cov = np.broadcast_to(o.cov[0], (len(obs), 2, 2))
    new = ImageObservations(np.concatenate([o.image, oi]), np.concatenate([o.point, op]),
                            np.vstack([o.xy, xy]), np.concatenate([o.cov, cov]),
                            np.concatenate([o.line, np.zeros(len(obs), dtype=np.int64)]))
    return block.replace(cameras=cams, images=imgs, points=pts, obs=new)


def test_native_block(tmp_path):
    """A simulated aerial block with a duplicated image, zero-baseline and single-ray points, a
    starved image and a camera with APs on too few points; a single-ray *control* point is
    determined by its control and stays."""
    from dataclasses import replace

    from baarda.model.bundle import Camera, ObjectPoint, build_block_problem
    from baarda.simulate import simulate_block

    base, _ = simulate_block(strips=2, images_per_strip=4, control="perimeter", seed=1)
    im0, im3, im5 = base.images[0], base.images[3], base.images[5]
    seen0 = [base.points[p].id for p in np.unique(base.obs.point[base.obs.image == 0])]
    seen5 = [base.points[p].id for p in np.unique(base.obs.point[base.obs.image == 5])]
    Zg = float(np.mean([p.Z for p in base.points]))
    dup = replace(im0, id="dup")
    ctrl = ObjectPoint("ctl", im3.X0 + 20.0, im3.Y0 - 15.0, Zg, status="control",
                       ref=(im3.X0 + 20.0, im3.Y0 - 15.0, Zg), sigma_h=0.05, sigma_v=0.05)
    ref = add_native(base, images=[dup], points=[ctrl],
                     obs=[("dup", p) for p in seen0] + [(im3.id, "ctl")])
    zb = [ObjectPoint(f"zb{j}", im0.X0 + 30.0 * j, im0.Y0 + 10.0, Zg) for j in range(2)]
    sr = [ObjectPoint("sr", im3.X0 - 10.0, im3.Y0 + 5.0, Zg)]
    starved = replace(im3, id="starved", X0=im3.X0 + 40.0)
    apcam = Camera("apcam", c=base.cameras[0].c, unit=base.cameras[0].unit, width=base.cameras[0].width,
                   height=base.cameras[0].height, ap=("brown",))
    apimg = replace(im5, id="apimg", camera="apcam", X0=im5.X0 + 25.0)
    b = add_native(ref, images=[starved, apimg], cameras=[apcam], points=zb + sr,
                   obs=[(i, p.id) for p in zb for i in (im0.id, "dup")] + [(im3.id, "sr")]
                   + [("starved", seen0[0]), ("starved", "sr")] + [("apimg", p) for p in seen5[:4]])
    reduced, defects = find_defects(b)
    named = {(d.entity, d.id) for d in defects}
    assert named == {("point", "zb0"), ("point", "zb1"), ("point", "sr"), ("image", "starved"),
                     ("camera", "apcam"), ("image", "apimg")}, named
    assert all("same centre" in d.reason for d in defects if d.id.startswith("zb"))
    with pytest.raises(DatumDefectError):
        adjust(build_block_problem(b))
    adj, used = adjust_block(build(b))
    reference = adjust(build_block_problem(ref))
    assert [tuple(d.values()) for d in adj.problem.info.ids] == [tuple(d.values()) for d in reference.problem.info.ids]
    np.testing.assert_allclose(adj.r, reference.r, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(adj.w, reference.w, rtol=1e-6, atol=1e-6)
    assert "ctl" in [p.id for p in reduced.points]


def test_real_colmap_model_with_identical_poses():
    """The issue's case on the real COLMAP model: an image with the very pose of another and
    four points seen by these two only; plus a point measured twice (two keypoints) in one image
    only — one ray, not two."""
    path = require_extdata(EXTDATA / "colmap" / "test_colmap-sparse0")
    model = read_model(path)
    ref = duplicate_image(model, 0)
    zb = [f"zb{j}" for j in range(4)]
    b = add(ref, points=zb + ["dk"], X=np.vstack([in_front(ref, 0, 4, depth=5.0, seed=1), in_front(ref, 2, 1, seed=4)]),
            obs=[(i, p) for p in zb for i in (ref.images[0].id, "dup")])
    k2 = ref.images[2].id
    b = add(b, obs=[(k2, "dk"), (k2, "dk")])
    b = b.replace(xy=b.xy.copy())
    b.xy[-1] += 3.0                                     # the second keypoint elsewhere
    reduced, defects = find_defects(b)
    assert {(d.entity, d.id) for d in defects} == {("point", p) for p in zb + ["dk"]}
    assert next(d for d in defects if d.id == "dk").reason.startswith("single ray")
    adj, used = adjust_block(build(b))
    reference = adjust(build_sfm_problem(ref))
    assert adj.converged and reference.converged
    np.testing.assert_allclose(adj.r, reference.r, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(adj.w, reference.w, rtol=1e-6, atol=1e-6)


def test_arrays_in_extra_are_cut_like_the_block(balbianello):
    """Per-observation, per-point and per-image arrays the readers keep in ``extra`` (COLMAP's
    keypoint index, byte offsets) follow the reduction; the input's stay as they were."""
    b = add(balbianello, points=["one"], X=in_front(balbianello, 1, 1, seed=9), obs=[("1", "one")])
    n, m, k = b.obs_image.size, len(b.points), len(b.images)
    b = b.replace(extra={"obs_keypoint": np.arange(n) + 1000, "point_offset": np.arange(m) * 10,
                         "image_offset": np.arange(k) * 7, "note": "kept"})
    reduced, defects = find_defects(b)
    assert [(d.entity, d.id) for d in defects] == [("point", "one")]
    assert np.array_equal(reduced.extra["obs_keypoint"], np.arange(n - 1) + 1000)
    assert np.array_equal(reduced.extra["point_offset"], np.arange(m - 1) * 10)
    assert np.array_equal(reduced.extra["image_offset"], np.arange(k) * 7)
    assert reduced.extra["note"] == "kept" and b.extra["obs_keypoint"].size == n


@pytest.mark.parametrize("where", ["extdata", "corpus"])
def test_undetermined_intrinsics_are_held_and_the_rest_adjusted(where, tmp_path, capsys):
    """dubrovnik-3-7 (38 equations for 48 unknowns with f, k1, k2 of its three cameras estimated)
    and a block of its pattern: no point or image is a local defect, but the cameras' intrinsics
    are undetermined. They are named and held at the file's values and the rest is adjusted —
    the same r and w as the file read with --no-refine-intrinsics (an independent route);
    --strict gives the whole-block diagnosis as before."""
    from baarda.adjust import Options
    from baarda.cli import main

    path = (require_extdata(EXTDATA / "bal" / "dubrovnik-3-7-pre.txt") if where == "extdata"
            else Path(__file__).resolve().parent / "defects" / "bal-underdetermined.txt")
    model = read_model(path)
    assert find_defects(model)[1] == []
    adj, problem = adjust_block(build(model), Options())
    named = problem.notes.local_defects
    assert {(d.entity, d.id) for d in named} == {("camera", "0"), ("camera", "1"), ("camera", "2")}
    assert all(d.components == ("f", "k1", "k2") for d in named)
    ref = adjust(build(read_model(path, refine_intrinsics=False)), Options())
    assert adj.converged and ref.converged and adj.problem.n == ref.problem.n == 38
    np.testing.assert_allclose(adj.r, ref.r, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(adj.w, ref.w, rtol=1e-6, atol=1e-8)
    out = tmp_path / "r.json"
    assert main(["analyze", str(path), "--quiet", "--json", str(out)]) == 0
    assert len(json.loads(out.read_text())["summary"]["local_defects"]) == 3
    assert main(["analyze", str(path), "--quiet", "--strict"]) == 2
    err = capsys.readouterr().err
    assert "38 observations for 48 unknowns" in err and "do not determine" in err and err.count("\n") == 1


def test_camera_with_too_few_points_for_its_intrinsics(balbianello):
    """BAL/Bundler refine f, k1, k2 per camera: an image of its own camera that sees 4 points
    gives 2·4 − 6 = 2 equations for those 3 — the camera and its image are left out. With the
    intrinsics held fixed the same image is fine."""
    b = balbianello
    im = b.images[4]
    cam = next(c for c in b.cameras if c.id == im.camera)
    ncam = SfmCamera("four-cam", cam.model, cam.params)
    nim = SfmImage("four", ncam.id, im.rodrigues, tuple(np.asarray(im.t) + [0.05, -0.02, 0.01]))
    blk = add(b, images=[nim], cameras=[ncam], obs=[("four", p) for p in seen_by(b, 4)[:4]])
    reduced, defects = find_defects(blk)
    assert [(d.entity, d.id) for d in defects] == [("camera", "four-cam"), ("image", "four")]
    assert defects[0].components == ("f", "k1", "k2") and "2 equation(s)" in defects[0].reason
    assert [c.id for c in reduced.cameras] == [c.id for c in b.cameras]
    assert find_defects(blk.replace(refine_intrinsics=False))[1] == []
    adj, _ = adjust_block(build(blk))
    reference = adjust(build_sfm_problem(b))
    np.testing.assert_allclose(adj.r, reference.r, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(adj.w, reference.w, rtol=1e-6, atol=1e-6)


# --------------------------------------------------------------------------------------------
# files with single-ray points and starved images: read, the defects named, the rest analysed
# --------------------------------------------------------------------------------------------
DEFECT_FILES = Path(__file__).resolve().parent / "defects"
VALID_SEEDS = Path(__file__).resolve().parent / "malformed" / "valid"


@pytest.mark.parametrize("name,entity,ident", [("bal-one-view.txt", "point", "5"),
                                               ("bundler-one-view.out", "point", "15"),
                                               ("bal-camera-two-points.txt", "image", "2")])
def test_file_with_local_defect_is_analysed_and_strict_refuses_it(name, entity, ident, tmp_path, capsys):
    from baarda.cli import main

    path = DEFECT_FILES / name
    before = path.read_bytes()
    out = tmp_path / "r.json"
    code = main(["analyze", str(path), "--quiet", "--json", str(out), "--no-refine-intrinsics"])
    err = capsys.readouterr().err
    assert code == 0, err
    doc = json.loads(out.read_text())
    named = [(d["entity"], d["id"]) for d in doc["summary"]["local_defects"]]
    assert named == [(entity, ident)]
    # the rest analysed: the reduced problem has observations and a finite r for each
    r = [o["redundancy"] for o in doc["observations"]]
    assert len(r) > 0 and all(-1e-9 <= x <= 1.0 + 1e-9 for x in r)
    assert doc["summary"]["converged"] is True
    assert main(["analyze", str(path), "--quiet", "--strict"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"baarda: error: {path}:")
    assert f"{entity} {ident} " in err and "--strict" in err
    assert path.read_bytes() == before


def test_single_ray_point_from_file_equals_the_file_without_it(tmp_path):
    """The same BAL file with the single-ray point's only observation removed by hand (and the
    point itself) gives the same r and w: an independent reference for what is left out."""
    from baarda.adjust import Options

    text = (DEFECT_FILES / "bal-one-view.txt").read_text().split()
    nc, npt, nobs = (int(t) for t in text[:3])
    obs = [text[3 + 4 * k: 7 + 4 * k] for k in range(nobs)]
    params = text[3 + 4 * nobs:]
    cams, pts = params[: 9 * nc], params[9 * nc:]
    keep = [o for o in obs if int(o[1]) != 5]
    renum = {p: (p if p < 5 else p - 1) for p in range(npt) if p != 5}
    lines = [f"{nc} {npt - 1} {len(keep)}"] + [f"{o[0]} {renum[int(o[1])]} {o[2]} {o[3]}" for o in keep]
    lines += cams + [v for p in range(npt) if p != 5 for v in pts[3 * p: 3 * p + 3]]
    by_hand = tmp_path / "by-hand.txt"
    by_hand.write_text("\n".join(lines) + "\n")
    a, _ = adjust_block(build(read_model(DEFECT_FILES / "bal-one-view.txt")), Options())
    b = adjust(build(read_model(by_hand)), Options())
    assert a.problem.n == b.problem.n
    np.testing.assert_allclose(a.r, b.r, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(a.w, b.w, rtol=1e-6, atol=1e-8)
