"""Readers of real data: BAL, Bundler, COLMAP (text and binary), control CSV; writers: GeoJSON
and ``baarda convert``.

References: the initial costs of ../shared/extdata/README.md (BAL and Bundler, computed by other
programs) and pycolmap (COLMAP's own reader and bundle adjuster) as a peer.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from baarda import datum as datum_mod
from baarda.adjust import adjust
from baarda.build import build, read_problem
from baarda.cli import main
from baarda.errors import InputError
from baarda.io import detect_format, read_model
from baarda.io.bal import read_bal
from baarda.io.bundler import read_bundler
from baarda.io.colmap import read_colmap
from baarda.io.control import add_control
from baarda.io.native import read_native
from baarda.model.bundle import build_block_problem
from baarda.model.sfm import CAMERA_MODELS, SfmBlock, build_sfm_problem, initial_cost, to_block
from baarda.observations.projection import ProjectionSet
from baarda.observations.rotation import R_from_rodrigues
from baarda.stats.reliability import reliability_of

from tests.extdata import EXTDATA, require_extdata

BAL = EXTDATA / "bal"
VALID = Path(__file__).resolve().parents[1] / "malformed" / "valid"


def numeric_jacobian(s, x, h=1e-6):
    J = np.zeros((s.rows.size, x.size))
    for j in range(x.size):
        step = h * max(1.0, abs(x[j]))
        xp, xm = x.copy(), x.copy()
        xp[j] += step
        xm[j] -= step
        J[:, j] = (s.evaluate(xp)[0] - s.evaluate(xm)[0]) / (2 * step)
    return J


def analytic_jacobian(s, x):
    _, r, c, v = s.evaluate(x)
    return sp.csr_matrix((v, (r, c)), shape=(s.rows.size, x.size)).toarray()


# --------------------------------------------------------------------------------------------
# BAL and Bundler against the published initial costs
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,cost,check", [
    ("problem-49-7776-pre.txt", 850912.46, True),
    ("dubrovnik-3-7-pre.txt", 2764.219984, True),
    ("dubrovnik-3-7-18-pre.txt", 2753.173947, True),
    ("dubrovnik-1-1-pre.txt", 63.316421, False),       # one point in one image: not adjustable
])
def test_bal_initial_cost(name, cost, check):
    require_extdata(BAL)
    block = read_bal(BAL / name, check=check)
    got = initial_cost(build_sfm_problem(block))
    assert got == pytest.approx(cost, rel=1e-8, abs=5e-3)


def test_bal_counts_and_ids():
    require_extdata(BAL)
    block = read_model(BAL / "problem-49-7776-pre.txt")
    assert (len(block.images), len(block.points), block.obs_image.size) == (49, 7776, 31843)
    p = build(block)
    assert p.n == 2 * 31843 and p.params.free.size == 49 * 9 + 7776 * 3
    assert p.info.ids[1] == {"image": str(block.obs_image[0]), "point": str(block.obs_point[0]), "component": "y"}
    assert p.info.line[0] == 2 and p.info.kind[:2] == ("image-x", "image-y")
    assert p.datum.kind == "free" and p.datum.sbase == ()
    # minimal geometry for the dashboard: projection centres −Rᵀt
    im = p.geometry.images[3]
    rho, t = block.images[3].rodrigues, block.images[3].t
    assert np.allclose([im.X0, im.Y0, im.Z0], -R_from_rodrigues(np.array(rho)).T @ np.array(t))
    assert "footprint" not in im.details and "footprint" not in p.geometry.as_dict()["images"][3]


def test_bal_dubrovnik_1_1_is_refused_with_reason(capsys):
    """One image, one point, one image point: both are local defects (a single ray, an image on
    one point); left out, nothing remains, and that is the error, naming the file."""
    from baarda.cli import main

    require_extdata(BAL)
    block = read_bal(BAL / "dubrovnik-1-1-pre.txt")
    assert (len(block.images), len(block.points), block.obs_image.size) == (1, 1, 1)
    assert main(["analyze", str(BAL / "dubrovnik-1-1-pre.txt")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "dubrovnik-1-1-pre.txt:" in err and "nothing to adjust" in err
    from baarda.io.bal import check_block           # the readers' own check, with rays=True
    with pytest.raises(InputError, match="point 0 is seen by 1 image"):
        check_block(BAL / "dubrovnik-1-1-pre.txt", block, rays=True)


def test_bundler_balbianello():
    require_extdata(BAL)
    block = read_bundler(BAL / "Balbianello.out")
    assert (len(block.images), len(block.points), block.obs_image.size) == (5, 544, 1417)
    p = build_sfm_problem(block)
    assert initial_cost(p) == pytest.approx(126.928, abs=5e-4)
    adj = adjust(p)
    assert adj.converged and adj.defect == 7
    assert adj.dof == 2 * 1417 - (5 * 9 + 544 * 3 - 7)
    assert 0.5 * adj.vPv < 126.928
    assert 0.5 * adj.vPv == pytest.approx(125.1696, abs=1e-3)


def test_underdetermined_bal_names_what_is_undetermined(capsys):
    require_extdata(BAL)
    path = BAL / "dubrovnik-3-7-pre.txt"
    assert main(["analyze", str(path), "--strict"]) == 2       # without --strict: intrinsics held
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {path}:0: 38 observations for 48 unknowns") and err.count("\n") == 1
    assert "do not determine" in err and "camera " in err and "point " in err


@pytest.mark.slow
def test_ladybug_adjusts():
    """Ladybug (23,769 unknowns) from its initial values (cost 850,912) to the README's bound for
    a good solver (≤ 13,392.3): the first Gauss-Newton step diverges, Levenberg-Marquardt takes
    over (core/adjust.py), through the Schur-complement path; it stops on the cost (two steps
    lowering vᵀPv by < 1e-6 relative, Ceres' function tolerance).

    Then its reliability: a free block with the 7 similarity transformations as gauge, named
    one by one; a dozen points drift towards infinity (3 × 3 blocks of condition 1e12) and are
    left out of the default S-base; the square-root point elimination keeps Σ r_i = dof to 1e-6
    and every r_i in [0, 1] with finite w."""
    from baarda.adjust import Options
    from baarda.datum import far_points

    require_extdata(BAL)
    p = read_problem(BAL / "problem-49-7776-pre.txt")
    adj = adjust(p, Options(max_iter=100))
    assert adj.solver == "schur" and adj.converged
    assert 0.5 * adj.vPv <= 13392.3
    assert adj.plan.names == ("translation x", "translation y", "translation z", "rotation about x",
                              "rotation about y", "rotation about z", "scale")
    assert far_points(p, adj.x).sum() > 0
    r, w = adj.r, adj.w
    assert abs(r.sum() - adj.dof) < 1e-6
    assert r.min() >= 0.0 and r.max() <= 1.0 and np.isfinite(w).all()
    assert np.isfinite(reliability_of(adj).mdb).all() and np.isfinite(reliability_of(adj).external).all()


# --------------------------------------------------------------------------------------------
# the projection model
# --------------------------------------------------------------------------------------------
def test_jacobian_bal_matches_finite_differences():
    block = read_bal(VALID / "bal-valid.txt")
    p = build_sfm_problem(block)
    x = p.params.x0.copy()
    s = p.sets[0]
    J = analytic_jacobian(s, x)
    assert np.abs(J - numeric_jacobian(s, x)).max() < 1e-6 * np.abs(J).max()


@pytest.mark.parametrize("model", ["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"])
def test_jacobian_colmap_models(model):
    rng = np.random.default_rng(7)
    m = 6
    X = rng.uniform(-1, 1, (m, 3))
    rho = np.array([0.4, -2.2, 1.3])           # a large rotation, far from the series branch
    t = np.array([0.1, -0.2, 4.0])             # points at |X| ≤ √3 stay in front (+z)
    names, feeds = CAMERA_MODELS[model]
    values = {"f": 800.0, "fx": 800.0, "fy": 820.0, "cx": 320.0, "cy": 240.0, "k": 0.05, "k1": 0.05,
              "k2": -0.01, "p1": 0.002, "p2": -0.003}
    x = np.concatenate([rho, t, [values[n] for n in names], X.ravel()])
    where = {n: 6 + k for k, n in enumerate(names)}
    iint = np.array([where[f] if f is not None else -1 for f in feeds])
    s = ProjectionSet(rows=np.arange(2 * m), ipt=6 + len(names) + np.arange(3 * m).reshape(m, 3),
                      irot=np.tile(np.arange(3), (m, 1)), itr=np.tile(np.arange(3, 6), (m, 1)),
                      iint=np.tile(iint, (m, 1)), sign=1.0)
    P, *_ = s.camera_frame(x)
    assert (P[:, 2] > 0).all()
    J = analytic_jacobian(s, x)
    assert np.abs(J - numeric_jacobian(s, x)).max() < 1e-6 * np.abs(J).max()


def test_rodrigues_jacobian_near_zero_rotation():
    block = read_bal(VALID / "bal-valid.txt")
    p = build_sfm_problem(block)
    x = p.params.x0.copy()
    s = p.sets[0]
    x[s.irot[0]] = [1e-9, -2e-9, 0.0]
    J = analytic_jacobian(s, x)
    assert np.abs(J - numeric_jacobian(s, x)).max() < 1e-6 * np.abs(J).max()


def test_free_block_datum_defect_is_seven():
    p = read_problem(VALID / "bal-valid.txt")
    x = p.params.x0
    f, J = p.evaluate(x)
    free = p.params.free
    plan = datum_mod.plan(p, x, J[:, free].tocsr(), p.cov.weight(), free)
    assert plan.defect == 7


# --------------------------------------------------------------------------------------------
# COLMAP against pycolmap
# --------------------------------------------------------------------------------------------
def synthetic_reconstruction(model="SIMPLE_RADIAL", params=(1280.0, 512.0, 384.0, 0.05)):
    pycolmap = pytest.importorskip("pycolmap")
    opt = pycolmap.SyntheticDatasetOptions(num_rigs=1, num_cameras_per_rig=1, num_frames_per_rig=6,
                                           num_points3D=60, num_points2D_without_point3D=4)
    opt.camera_model_id = getattr(pycolmap.CameraModelId, model)
    opt.camera_params = list(params)
    rec = pycolmap.synthesize_dataset(opt)
    pycolmap.synthesize_noise(pycolmap.SyntheticNoiseOptions(point2D_stddev=1.0, point3D_stddev=0.01), rec)
    return rec


def write_model(rec, path: Path, binary: bool = False) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    (rec.write_binary if binary else rec.write_text)(str(path))
    return path


def same_block(a: SfmBlock, b: SfmBlock):
    assert [im.id for im in a.images] == [im.id for im in b.images]
    assert [im.name for im in a.images] == [im.name for im in b.images]
    assert a.points == b.points
    assert np.array_equal(a.obs_image, b.obs_image) and np.array_equal(a.obs_point, b.obs_point)
    assert np.allclose(a.xy, b.xy, rtol=0, atol=1e-9)
    assert np.allclose(a.X, b.X, rtol=0, atol=1e-12)


@pytest.mark.parametrize("model,params", [("SIMPLE_RADIAL", (1280.0, 512.0, 384.0, 0.05)),
                                          ("OPENCV", (1200.0, 1180.0, 500.0, 390.0, 0.03, -0.01, 0.001, -0.002))])
def test_colmap_text_and_binary_round_trip(tmp_path, model, params):
    rec = synthetic_reconstruction(model, params)
    write_model(rec, tmp_path / "txt")
    write_model(rec, tmp_path / "bin", binary=True)
    assert detect_format(tmp_path / "txt") == detect_format(tmp_path / "bin" / "images.bin") == "colmap"
    a = read_colmap(tmp_path / "txt")
    b = read_colmap(tmp_path / "bin")
    same_block(a, b)
    assert len(a.images) == rec.num_images() and len(a.points) == rec.num_points3D()
    assert a.obs_image.size == rec.compute_num_observations()
    # ids are COLMAP's, and each observation is the one pycolmap has
    k = 5
    im = rec.images[int(a.images[a.obs_image[k]].id)]
    p3 = rec.points3D[int(a.points[a.obs_point[k]])]
    el = next(e for e in p3.track.elements if e.image_id == im.image_id)
    assert np.allclose(im.points2D[el.point2D_idx].xy, a.xy[k])
    # the projection agrees with pycolmap's camera model
    p = build_sfm_problem(a)
    f, _ = p.evaluate(p.params.x0)
    cam = rec.cameras[im.camera_id]
    assert np.allclose(f[2 * k:2 * k + 2], cam.img_from_cam(im.cam_from_world() * p3.xyz), atol=1e-8)
    # COLMAP's reprojection errors are those residuals
    r = p.misclosure(f).reshape(-1, 2)
    assert np.sqrt((r ** 2).sum(1)).mean() == pytest.approx(rec.compute_mean_reprojection_error(), rel=1e-9)


def test_colmap_adjusted_cost_equals_pycolmap(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    rec = synthetic_reconstruction()
    write_model(rec, tmp_path / "before")
    opt = pycolmap.BundleAdjustmentOptions(refine_focal_length=False, refine_principal_point=False,
                                           refine_extra_params=False, print_summary=False)
    so = opt.ceres.solver_options
    so.function_tolerance, so.gradient_tolerance, so.parameter_tolerance = 1e-16, 1e-16, 1e-16
    so.max_num_iterations = 200
    so.num_threads = 1
    pycolmap.bundle_adjustment(rec, opt)
    write_model(rec, tmp_path / "after")
    peer = initial_cost(read_problem(tmp_path / "after"))
    adj = adjust(read_problem(tmp_path / "before"))
    print(f"baarda {0.5 * adj.vPv:.10g}, pycolmap {peer:.10g}")
    assert adj.converged and adj.defect == 7
    assert 0.5 * adj.vPv == pytest.approx(peer, rel=1e-6)


def test_colmap_refine_intrinsics_keeps_principal_point(tmp_path):
    rec = synthetic_reconstruction()
    write_model(rec, tmp_path)
    fixed = read_problem(tmp_path)
    assert not any(lab.startswith("camera ") for lab in np.asarray(fixed.params.labels)[fixed.params.free])
    p = read_problem(tmp_path, refine_intrinsics=True, sigma_px=0.5)
    free = {lab for lab in np.asarray(p.params.labels)[p.params.free] if lab.startswith("camera ")}
    assert free == {"camera 1.f", "camera 1.k"}
    assert np.allclose(p.cov.sigma(), 0.5)
    assert p.notes.image_names["1"].endswith(".png")


# --------------------------------------------------------------------------------------------
# control points, GeoJSON, convert
# --------------------------------------------------------------------------------------------
def test_control_points_make_a_weighted_datum():
    block = add_control(read_model(VALID / "bal-valid.txt"), VALID / "control-valid.csv")
    p = build(block)
    assert p.datum.kind == "fixed"
    rows = [i for i, k in enumerate(p.info.kind) if k.startswith("control-")]
    assert len(rows) == 12 and p.info.ids[rows[0]] == {"id": "0"} and p.info.line[rows[0]] == 2
    assert np.allclose(p.cov.sigma()[rows[:3]], [0.01, 0.01, 0.02])
    assert p.points.status[:5] == ("control",) * 4 + ("tie",)
    adj = adjust(p)
    assert adj.converged and adj.defect == 0


def test_control_points_on_a_native_block(tmp_path):
    nat = tmp_path / "b.json"
    assert main(["convert", str(VALID / "bal-valid.txt"), str(nat), "-q"]) == 0
    block = add_control(read_native(nat), VALID / "control-valid.csv")
    assert block.datum == "control" and block.points[0].status == "control"
    assert block.points[0].ref == pytest.approx(tuple(float(v) for v in
                                                      (VALID / "control-valid.csv").read_text().splitlines()[1]
                                                      .split(",")[1:4]))


def test_geojson(tmp_path):
    out = tmp_path / "pts.geojson"
    assert main(["analyze", str(VALID / "bal-valid.txt"), "-q", "--geojson", str(out),
                 "--json", str(tmp_path / "r.json")]) == 0
    doc = json.loads(out.read_text())
    res = json.loads((tmp_path / "r.json").read_text())
    assert doc["type"] == "FeatureCollection" and len(doc["features"]) == 16
    f = doc["features"][3]
    obs = [o for o in res["observations"] if o["point"] == f["id"]]
    assert f["properties"]["n_obs"] == len(obs)
    assert f["properties"]["r_min"] == pytest.approx(min(o["redundancy"] for o in obs))
    assert f["properties"]["mdb_max"] == pytest.approx(max(o["mdb"] for o in obs))
    assert f["properties"]["delta0bar_max"] == pytest.approx(max(o["external"] for o in obs))
    pt = next(q for q in res["points"] if q["id"] == f["id"])
    assert f["geometry"]["coordinates"] == pytest.approx([pt["x"], pt["y"], pt["z"]])


def test_geojson_network_east_north(tmp_path):
    out = tmp_path / "lev.geojson"
    assert main(["analyze", str(VALID / "levelling-valid.gkf"), "-q", "--geojson", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert [f["id"] for f in doc["features"]] == ["A", "B", "C"]
    assert doc["features"][1]["properties"]["n_obs"] == 2


@pytest.mark.parametrize("src", ["bal-valid.txt", "bundler-valid.out", "colmap-valid"])
def test_convert_to_native_keeps_the_residuals(tmp_path, src):
    path = VALID / src
    before = {f: f.read_bytes() for f in ([path] if path.is_file() else sorted(path.iterdir()))}
    out = tmp_path / "native.json"
    assert main(["convert", str(path), str(out), "-q"]) == 0
    native = build_block_problem(read_native(out))
    sfm = read_problem(path, refine_intrinsics=False)
    assert initial_cost(native) == pytest.approx(initial_cost(sfm), rel=1e-9)
    assert {f: f.read_bytes() for f in before} == before
    assert initial_cost(native) > 1.0


def test_convert_colmap_opencv_with_distortion(tmp_path):
    rec = synthetic_reconstruction("OPENCV", (1200.0, 1200.0, 500.0, 390.0, 0.03, -0.01, 0.001, -0.002))
    write_model(rec, tmp_path / "m", binary=True)
    out = tmp_path / "n.json"
    assert main(["convert", str(tmp_path / "m"), str(out), "-q"]) == 0
    assert initial_cost(build_block_problem(read_native(out))) == pytest.approx(
        initial_cost(read_problem(tmp_path / "m")), rel=1e-9)
    cam = to_block(read_model(tmp_path / "m")).cameras[0]
    assert (cam.p1, cam.p2) == pytest.approx((-0.002 / 1200.0, -0.001 / 1200.0))


def test_convert_refuses_fx_ne_fy(tmp_path, capsys):
    rec = synthetic_reconstruction("PINHOLE", (1200.0, 1100.0, 500.0, 390.0))
    write_model(rec, tmp_path / "m")
    assert main(["convert", str(tmp_path / "m"), str(tmp_path / "n.json")]) == 2
    assert "f_x ≠ f_y" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# memory discipline: numbers held once, lying headers and malformed files refused early
# --------------------------------------------------------------------------------------------
def big_bal(path: Path, nobs: int, seed: int = 3) -> Path:
    """A valid BAL file of nobs image points (3 per point, 20 cameras)."""
    rng = np.random.default_rng(seed)
    npt, ncam = nobs // 3, 20
    cam = np.repeat(np.arange(npt) % ncam, 3) + np.tile([0, 7, 13], npt)
    obs = np.c_[cam % ncam, np.repeat(np.arange(npt), 3), rng.normal(scale=300, size=(3 * npt, 2))]
    with open(path, "w") as f:
        f.write(f"{ncam} {npt} {3 * npt}\n")
        np.savetxt(f, obs, fmt=["%d", "%d", "%.6e", "%.6e"])
        np.savetxt(f, np.c_[rng.normal(scale=0.1, size=(ncam, 6)), np.full(ncam, 500.0),
                            np.zeros((ncam, 2))].reshape(-1, 1), fmt="%.16e")
        np.savetxt(f, rng.normal(scale=10, size=(3 * npt, 1)), fmt="%.16e")
    return path


def peak_bytes(fn):
    """(result or exception, peak of the memory allocated through Python and numpy), after a
    first small read (imports, the compiled parser) outside the measurement."""
    import tracemalloc
    read_bal(VALID / "bal-valid.txt")
    tracemalloc.start()
    try:
        try:
            out = fn()
        except InputError as err:
            out = err
        return out, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_bal_numbers_are_held_once(tmp_path):
    path = big_bal(tmp_path / "big.txt", 300_000)
    size = path.stat().st_size
    block, peak = peak_bytes(lambda: read_bal(path, check=False))
    assert block.obs_image.size == 300_000
    # the values as Python parses them, token by token (an independent reading)
    toks = path.read_bytes().split()
    ref = np.array(toks[3:3 + 4 * 300_000], dtype=float).reshape(-1, 4)
    assert np.array_equal(block.xy, ref[:, 2:]) and np.array_equal(block.obs_point, ref[:, 1])
    assert np.array_equal(block.X.ravel(), np.array(toks[3 + 4 * 300_000 + 9 * 20:], dtype=float))
    # the text is never held whole, and its numbers once (a token list alone took ~10× the file)
    print(f"file {size / 1e6:.1f} MB, peak {peak / 1e6:.1f} MB")
    assert peak < 3.5 * size                               # the reader before: 10.9 × (192 MB here)


def test_bal_header_that_lies_is_refused_before_its_numbers_are_held(tmp_path):
    lines = (VALID / "bal-valid.txt").read_text().splitlines()
    lies = tmp_path / "lies.txt"
    lies.write_text("\n".join(["3 16 100000000"] + lines[1:]) + "\n")
    err, peak = peak_bytes(lambda: read_bal(lies))
    assert isinstance(err, InputError) and err.line == 1
    assert "(400000075 numbers) but the file of" in err.message and "cannot hold them" in err.message
    assert peak < 8e6                                    # not the 3.2 GB the header asks for
    # one number fewer, one more than announced: the counts at the end of the file
    short = tmp_path / "short.txt"
    short.write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(InputError, match=r"^.*:1: the header announces .* \(267 numbers\) but the file holds 266"):
        read_bal(short)
    extra = tmp_path / "extra.txt"
    extra.write_text("\n".join(lines + ["0.5"]) + "\n")
    with pytest.raises(InputError, match=rf":{len(lines) + 1}: unexpected '0.5' after the last point"):
        read_bal(extra)


def test_malformed_big_bal_is_refused_early(tmp_path):
    """A broken number near the start: refused with the memory of a few chunks, the same for a
    file twice as long (the reader before held the whole file's tokens first: 10× its size)."""
    peaks = []
    for nobs in (150_000, 300_000):
        path = big_bal(tmp_path / f"big{nobs}.txt", nobs)
        data = path.read_bytes().split(b"\n")
        data[1000] = data[1000][:-3] + b"x12"
        path.write_bytes(b"\n".join(data))
        del data
        err, peak = peak_bytes(lambda: read_bal(path))
        assert isinstance(err, InputError) and err.line == 1001 and "x12' is not a number" in err.message
        print(f"file {path.stat().st_size / 1e6:.1f} MB, peak {peak / 1e6:.1f} MB")
        peaks.append(peak)
    assert peaks[1] < 1.25 * peaks[0] and peaks[1] < 48e6


@pytest.mark.parametrize("path", ["compiled", "numpy"])
@pytest.mark.parametrize("fmt", ["%.6e", "%.17g", "%.16e", "%.3f", "%.12g", "%r"])
def test_chunk_parser_gives_pythons_numbers(fmt, path):
    """The chunk parser (the exact fast path compiled by numba when installed; numpy's
    fromstring otherwise) against Python's float, token by token: the same double, sign of zero
    included."""
    from baarda.io.source import parse_chunk

    if path == "compiled":
        pytest.importorskip("numba", reason="numba is not installed")

    rng = np.random.default_rng(11)
    x = rng.normal(size=20000) * 10.0 ** rng.integers(-40, 40, size=20000)
    edge = ["-0", "0.0", "1e22", "1e23", "9007199254740993", "123456789012345678", ".5", "5.", "+3",
            "1e-22", "4.9e-324", "1.7976931348623157e308", "2.2250738585072014e-308", "0.1", "-7e-5"]
    toks = [fmt % float(v) for v in x] + edge
    buf = ("\n".join(" ".join(toks[k:k + 4]) for k in range(0, len(toks), 4)) + "\n").encode()
    vals, lines, starts, _ = parse_chunk(buf, 1, None, compiled=(path == "compiled"))
    ref = np.array([float(t) for t in toks])
    assert np.array_equal(vals, ref) and np.array_equal(np.signbit(vals), np.signbit(ref))
    assert lines.tolist() == [1 + k // 4 for k in range(len(toks))]


def test_bundler_header_that_lies_is_refused_before_its_numbers_are_held(tmp_path):
    lines = (VALID / "bundler-valid.out").read_text().splitlines()
    assert lines[1].split() == ["3", "16"]
    lies = tmp_path / "lies.out"
    lies.write_text("\n".join([lines[0], "3 90000000"] + lines[2:]) + "\n")
    err, peak = peak_bytes(lambda: read_bundler(lies))
    assert isinstance(err, InputError) and err.line == 2
    assert "(at least 630000045 numbers) but the file of" in err.message and "cannot hold them" in err.message
    assert peak < 8e6
