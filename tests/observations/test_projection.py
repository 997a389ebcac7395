"""COLMAP's camera models with their distortion held (baarda.observations.fixed_models): the
formulas against pycolmap's own projection, their Jacobian against finite differences, the
compiled kernel against the numpy reference, and whole models (text and binary) read and
adjusted to pycolmap's Ceres optimum."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baarda.adjust import adjust
from baarda.build import read_problem
from baarda.errors import ConversionError, InputError
from baarda.io.colmap import read_colmap
from baarda.model.sfm import CAMERA_MODELS, SfmBlock, SfmCamera, SfmImage, initial_cost, to_block
from baarda.observations.fixed_models import FIXED_MODELS, MAX_COEFFICIENTS, fixed_distortion, fixed_distortion_scalar

from tests.io.test_colmap import pycolmap_cost

#: distortion coefficients of each model (FOV twice: COLMAP's small-ω series too)
COEFFICIENTS = {
    "FULL_OPENCV": [0.1, -0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.005],
    "OPENCV_FISHEYE": [0.05, -0.01, 0.003, -0.001],
    "RADIAL_FISHEYE": [0.05, -0.01],
    "SIMPLE_RADIAL_FISHEYE": [0.08],
    "FOV": [0.9],
    "FOV-small": [0.005],
    "THIN_PRISM_FISHEYE": [0.05, -0.01, 0.001, -0.002, 0.003, -0.001, 0.0005, -0.0007],
    "RAD_TAN_THIN_PRISM_FISHEYE": [0.05, -0.01, 0.003, -0.001, 0.0004, -0.0001, 0.001, -0.002, 0.0005,
                                   -0.0003, -0.0007, 0.0002],
    "SIMPLE_DIVISION": [-0.15],
    "DIVISION": [0.02],
    "EUCM": [0.6, 1.1],
    "SIMPLE_FISHEYE": [],
    "FISHEYE": [],
}


def _focal(model):
    return [1280.0] if model.startswith(("SIMPLE", "RADIAL_")) else [1280.0, 1250.0]


@pytest.mark.parametrize("case", list(COEFFICIENTS))
def test_distortion_equals_pycolmaps_projection(case):
    """x = f u_d + c against pycolmap's Camera.img_from_cam (the optical axis and a point
    within 1e-9 of it included); the scalar and the array formulas agree; J against central
    differences."""
    pycolmap = pytest.importorskip("pycolmap")
    model = case.split("-")[0]
    coef = COEFFICIENTS[case]
    code = FIXED_MODELS[model][0]
    rng = np.random.default_rng(1)
    P = rng.normal(size=(300, 3)) * [0.6, 0.5, 0.1] + [0.0, 0.0, 1.0]
    P[0], P[1] = [0.0, 0.0, 1.0], [1e-9, -2e-9, 1.0]
    focal = _focal(model)
    cam = pycolmap.Camera(model=model, width=1024, height=768, params=focal + [512.0, 384.0] + coef)
    ref = np.array([cam.img_from_cam(p) for p in P])
    d = np.zeros(MAX_COEFFICIENTS)
    d[:len(coef)] = coef
    u, v = P[:, 0] / P[:, 2], P[:, 1] / P[:, 2]
    out = np.stack(fixed_distortion(code, d, u, v), 1)
    xy = np.stack([focal[0] * out[:, 0] + 512.0, focal[-1] * out[:, 1] + 384.0], 1)
    assert np.abs(xy - ref).max() <= 1e-9
    scalar = np.array([fixed_distortion_scalar(code, d, a, b) for a, b in zip(u, v)])
    assert np.allclose(scalar, out, rtol=1e-14, atol=1e-15)
    h = 1e-7
    for k, (du, dv) in enumerate(((h, 0.0), (0.0, h))):
        plus = np.array([fixed_distortion_scalar(code, d, a + du, b + dv)[:2] for a, b in zip(u, v)])
        minus = np.array([fixed_distortion_scalar(code, d, a - du, b - dv)[:2] for a, b in zip(u, v)])
        fd = (plus - minus) / (2 * h)
        assert np.abs(out[:, [2 + k, 4 + k]] - fd).max() <= 1e-7, k


def _synthetic(tmp_path: Path, model: str, coef, kind: str):
    """A pycolmap synthetic model of ``model`` written as ``kind`` ("txt"/"bin"); (dir, rec)."""
    pycolmap = pytest.importorskip("pycolmap")
    opt = pycolmap.SyntheticDatasetOptions(num_rigs=1, num_cameras_per_rig=1, num_frames_per_rig=6,
                                           num_points3D=120)
    opt.camera_model_id = getattr(pycolmap.CameraModelId, model)
    opt.camera_params = _focal(model) + [512.0, 384.0] + list(coef)
    rec = pycolmap.synthesize_dataset(opt)
    pycolmap.synthesize_noise(pycolmap.SyntheticNoiseOptions(point2D_stddev=1.0, point3D_stddev=0.01), rec)
    d = tmp_path / kind
    d.mkdir()
    rec.write_text(str(d)) if kind == "txt" else rec.write_binary(str(d))
    for f in ("rigs", "frames"):
        for g in d.glob(f"{f}.*"):
            g.unlink()
    return d, rec


@pytest.mark.parametrize("kind", ["txt", "bin"])
@pytest.mark.parametrize("model", list(FIXED_MODELS))
def test_model_read_and_adjusted_to_ceres_optimum(tmp_path, model, kind):
    """A whole model of each camera model: read (text and binary), ½Σr² at the file's values as
    pycolmap computes it, and adjusted (intrinsics held) to the optimum of pycolmap's Ceres."""
    pycolmap = pytest.importorskip("pycolmap")
    model_dir, rec = _synthetic(tmp_path, model, COEFFICIENTS[model], kind)
    cost, n = pycolmap_cost(rec)
    problem = read_problem(model_dir)
    assert problem.n == 2 * n
    assert initial_cost(problem) == pytest.approx(cost, rel=1e-12)
    s, x = problem.sets[0], problem.params.x0
    a, b = s.evaluate(x), s.evaluate_numpy(x)                   # compiled kernel (if numba) and numpy
    assert np.allclose(a[0], b[0], rtol=1e-13, atol=0) and np.array_equal(a[2], b[2])
    assert np.allclose(a[3], b[3], rtol=1e-10, atol=1e-12 * np.abs(b[3]).max())
    adj = adjust(problem)
    assert adj.converged
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = ba.refine_extra_params = ba.refine_principal_point = False
    ba.print_summary = False
    pycolmap.bundle_adjustment(rec, ba)
    assert 0.5 * adj.vPv == pytest.approx(pycolmap_cost(rec)[0], rel=1e-9)


def test_compiled_projection_equals_numpy_reference_on_a_mixed_block(tmp_path):
    """Cameras of a held-distortion model beside an OPENCV one in one block: the compiled
    kernel's f and Jacobian equal the numpy reference's; with --refine-intrinsics the focal
    lengths are estimated and the held coefficients stay parameters held at the file's values."""
    model_dir, _ = _synthetic(tmp_path, "THIN_PRISM_FISHEYE", COEFFICIENTS["THIN_PRISM_FISHEYE"], "txt")
    cams = (model_dir / "cameras.txt").read_text().splitlines()
    head = [s for s in cams if s.startswith("#")]
    (cid, *_rest), = [s.split() for s in cams if s and not s.startswith("#")]
    cams = head + [" ".join([cid] + _rest), f"{int(cid) + 1} OPENCV 1024 768 1200 1190 512 384 0.01 -0.002 0.001 0.0005"]
    (model_dir / "cameras.txt").write_text("\n".join(cams) + "\n")
    images = (model_dir / "images.txt").read_text().splitlines()
    data = [k for k, s in enumerate(images) if s and not s.startswith("#")]
    for k in data[0::2][::2]:                      # every other image to the OPENCV camera
        f = images[k].split()
        f[8] = str(int(cid) + 1)
        images[k] = " ".join(f)
    (model_dir / "images.txt").write_text("\n".join(images) + "\n")
    block = read_colmap(model_dir, refine_intrinsics=True)
    assert {c.model for c in block.cameras} == {"THIN_PRISM_FISHEYE", "OPENCV"}
    problem = read_problem(model_dir, refine_intrinsics=True)
    s = problem.sets[0]
    assert s.dcam is not None
    x = problem.params.x0
    a, b = s.evaluate(x), s.evaluate_numpy(x)
    assert np.allclose(a[0], b[0], rtol=1e-13, atol=0)
    assert np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
    assert np.allclose(a[3], b[3], rtol=1e-10, atol=1e-12 * np.abs(b[3]).max())
    labels = [problem.params.labels[j] for j in problem.params.free]
    assert f"camera {cid}.fx" in labels and f"camera {cid}.sx1" not in labels
    assert f"camera {int(cid) + 1}.k1" in labels              # the OPENCV camera's distortion is estimated
    adj = adjust(problem)
    assert adj.converged
    held = problem.params.labels.index(f"camera {cid}.k3")
    assert adj.x[held] == pytest.approx(COEFFICIENTS["THIN_PRISM_FISHEYE"][4], abs=0)


def test_held_distortion_models_have_no_native_camera():
    """Conversion to the photogrammetric block of baarda.model.bundle says which camera cannot go."""
    for model in FIXED_MODELS:
        assert model in CAMERA_MODELS
    block = SfmBlock(cameras=(SfmCamera("1", "OPENCV_FISHEYE", (1000.0, 1000.0, 500.0, 400.0, 0.1, 0.0, 0.0, 0.0)),),
                     images=(SfmImage("1", "1", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),), points=("1",),
                     X=np.array([[0.0, 0.0, 5.0]]), point_line=np.array([1]), obs_image=np.array([0]),
                     obs_point=np.array([0]), xy=np.array([[500.0, 400.0]]), obs_line=np.array([1]),
                     convention="colmap")
    with pytest.raises(ConversionError, match="OPENCV_FISHEYE"):
        to_block(block)


def test_undefined_projection_is_refused_naming_the_image_point(tmp_path):
    """A division camera whose k leaves no real distorted point for some image points: refused
    with the file, the line and the image point, not an internal error or NaN residuals."""
    model_dir, _ = _synthetic(tmp_path, "SIMPLE_DIVISION", [-0.1], "txt")
    cams = (model_dir / "cameras.txt").read_text()
    (model_dir / "cameras.txt").write_text(cams.replace(" -0.1", " 30"))
    with pytest.raises(InputError) as err:
        read_problem(model_dir)
    msg = str(err.value)
    assert "images.txt:" in msg and "projection through camera" in msg and "undefined" in msg
