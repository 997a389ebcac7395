"""GNSS centres against pycolmap's pose-prior bundle adjustment (issue 28: "where pycolmap offers a
pose-prior bundle adjustment, the same optimum").

A pycolmap synthetic COLMAP model (6 images, 80 points, 1 px image noise) with position priors of
its projection centres (σ 5 cm, noise added), adjusted by pycolmap's Ceres
(``create_pose_prior_bundle_adjuster``: reprojection errors in pixels plus the covariance-weighted
centre priors, intrinsics held) and by baarda (``--gnss`` on the model converted to a native block,
σ 1 px, lever arm 0, intrinsics held). Both start at the same model: the same optimum means the
same ½ vᵀPv (pycolmap's cost, evaluated here by pycolmap's own projection) and the same centres."""

from __future__ import annotations

import numpy as np
import pytest

import baarda
from baarda.stats.pose import pose_values

SIGMA = 0.05


def _cost(pycolmap, rec, priors) -> float:
    """Σ reprojection error² (px²) + Σ (C − prior)ᵀ Σ⁻¹ (C − prior) at the state of ``rec``."""
    c = 0.0
    for iid, im in rec.images.items():
        for p2 in im.points2D:
            if p2.has_point3D():
                c += float(np.sum((im.project_point(rec.points3D[p2.point3D_id].xyz) - p2.xy) ** 2))
        d = im.projection_center() - priors[iid].position
        c += float(d @ np.linalg.solve(priors[iid].position_covariance, d))
    return c


def test_same_optimum_as_pycolmaps_pose_prior_bundle_adjustment(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    if not hasattr(pycolmap, "create_pose_prior_bundle_adjuster"):
        pytest.skip("this pycolmap has no pose-prior bundle adjustment")
    opt = pycolmap.SyntheticDatasetOptions(num_rigs=1, num_cameras_per_rig=1, num_frames_per_rig=6,
                                           num_points3D=80)
    rec = pycolmap.synthesize_dataset(opt)
    pycolmap.synthesize_noise(pycolmap.SyntheticNoiseOptions(point2D_stddev=1.0, point3D_stddev=0.01), rec)
    rng = np.random.default_rng(0)
    priors, rows = {}, ["image,x,y,z,sx,sy,sz"]
    for iid, im in rec.images.items():
        C = im.projection_center() + rng.normal(0, SIGMA, 3)
        p = pycolmap.PosePrior()
        p.corr_data_id = im.data_id
        p.position = C
        p.position_covariance = np.eye(3) * SIGMA ** 2
        p.coordinate_system = pycolmap.PosePriorCoordinateSystem.CARTESIAN
        priors[iid] = p
        rows.append(f"{iid},{float(C[0])!r},{float(C[1])!r},{float(C[2])!r},{SIGMA},{SIGMA},{SIGMA}")
    model = tmp_path / "model"
    model.mkdir()
    rec.write_text(str(model))
    for g in list(model.glob("rigs.*")) + list(model.glob("frames.*")):
        g.unlink()
    (tmp_path / "g.csv").write_text("\n".join(rows) + "\n")

    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = ba.refine_extra_params = ba.refine_principal_point = False
    ba.print_summary = False
    config = pycolmap.BundleAdjustmentConfig()
    for iid in rec.images:
        config.add_image(iid)
    summary = pycolmap.create_pose_prior_bundle_adjuster(ba, pycolmap.PosePriorBundleAdjustmentOptions(), config,
                                                         list(priors.values()), rec).solve()
    assert "CONVERGENCE" in str(summary.termination_type)

    a = baarda.analyze(model, gnss=tmp_path / "g.csv")
    adj = a.adjustment
    assert adj.converged
    assert adj.vPv == pytest.approx(_cost(pycolmap, rec, priors), rel=1e-9)
    ids = [im.id for im in a.problem.geometry.images]
    centres = np.array([rec.images[int(i)].projection_center() for i in ids])
    X0 = pose_values(adj)[:, :3]
    assert np.abs(X0 - centres).max() <= 1e-6 * np.abs(centres).max()
    pts = {str(k): p.xyz for k, p in rec.points3D.items()}
    ours = {pid: adj.coordinates[k] for k, pid in enumerate(a.problem.points.ids)}
    common = sorted(set(pts) & set(ours))
    assert len(common) > 50
    P = np.array([pts[k] for k in common])
    assert np.abs(np.array([ours[k] for k in common]) - P).max() <= 1e-6 * np.abs(P).max()
