"""Pose precision (baarda.stats.pose) against the dense normal matrix (tests/oracle.py)."""

from __future__ import annotations

import numpy as np
import pytest

from baarda import adjust
from baarda.adjust import Options
from baarda.errors import BaardaError
from baarda.model.bundle import build_block_problem
from baarda.observations.rotation import R_from_rodrigues, opk_from_R
from baarda.simulate import simulate_block
from baarda.stats.pose import pose_covariance, pose_parameters, sfm_pose_jacobian
from tests import oracle


def _dense_sigma(adj) -> np.ndarray:
    """σ0² N⁻¹ over the free parameters in the adjustment's datum: N⁻¹ (weighted control), or
    S Q Sᵀ with S = I − G (EᵀG)⁻¹Eᵀ of the free block's S-base (M84 §2) and Q the generalised
    inverse of the bordered matrix [[N, G], [Gᵀ, 0]] (N's eigenvalues span too many decades for
    a pseudo-inverse's cut-off)."""
    if adj.plan.defect == 0:
        return oracle.normal_inverse(adj.A, adj.P) * adj.variance_factor
    A = adj.A.toarray()
    N = A.T @ (adj.P @ A)
    G = adj.plan.G
    assert np.abs(N @ G).max() <= 1e-8 * np.abs(N).max() * np.abs(G).max()       # G is N's null space
    u, d = N.shape[0], G.shape[1]
    Q = np.linalg.inv(np.block([[N, G], [G.T, np.zeros((d, d))]]))[:u, :u]
    S = np.eye(u) - G @ adj.plan.K
    Q = S @ Q @ S.T
    return Q * adj.variance_factor


def _blocks(adj, index, Sigma) -> np.ndarray:
    fpos = np.full(adj.problem.params.size, -1)
    fpos[adj.problem.params.free] = np.arange(adj.problem.params.free.size)
    loc = fpos[index]
    return np.stack([Sigma[np.ix_(r, r)] for r in loc])


def _rel(a, b) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.mark.parametrize("solver", ["generic", "schur"])
def test_native_block_pose_covariance_equals_dense_inverse(demo_problem, solver):
    """The demo block (weighted control): each image's 6 × 6 block is that of N⁻¹, both solvers."""
    adj = adjust(demo_problem, Options(solver=solver))
    ids, index, sfm = pose_parameters(adj.problem)
    assert not sfm and len(ids) == len(adj.problem.geometry.images)
    C = pose_covariance(adj)
    ref = _blocks(adj, index, _dense_sigma(adj))
    assert C.shape == (len(ids), 6, 6)
    assert _rel(C, ref) < 1e-10
    assert np.allclose(C, np.swapaxes(C, 1, 2), rtol=0, atol=0)
    one = pose_covariance(adj, [ids[3]])
    assert np.array_equal(one[0], C[3])


def test_free_block_pose_covariance_in_the_s_base():
    """A free block (inner constraints over all points): S N⁺ Sᵀ (M84 §2), σ̂0 not used."""
    block, _ = simulate_block(strips=2, images_per_strip=4, datum="free", seed=3)
    adj = adjust(build_block_problem(block))
    assert adj.plan.defect == 7
    _, index, _ = pose_parameters(adj.problem)
    ref = _blocks(adj, index, _dense_sigma(adj))
    assert _rel(pose_covariance(adj), ref) < 1e-9


def test_unknown_image_is_refused(demo_adjustment):
    with pytest.raises(BaardaError, match="not an image"):
        pose_covariance(demo_adjustment, ["no-such-image"])


def _opk_centre(rho, t, convention):
    D = np.diag([1.0, -1.0, -1.0]) if convention == "colmap" else np.eye(3)
    R = R_from_rodrigues(rho)
    return np.concatenate([-(R.T @ t), opk_from_R((D @ R).T @ np.eye(3))])


@pytest.mark.parametrize("convention", ["colmap", "bal"])
def test_sfm_pose_jacobian_equals_central_differences(convention):
    rng = np.random.default_rng(5)
    rho = rng.normal(0, 0.4, (4, 3))
    t = rng.normal(0, 10, (4, 3))
    J = sfm_pose_jacobian(rho, t, convention)
    h = 1e-6
    for n in range(4):
        x = np.concatenate([rho[n], t[n]])
        fd = np.empty((6, 6))
        for j in range(6):
            e = np.zeros(6)
            e[j] = h
            fd[:, j] = (_opk_centre((x + e)[:3], (x + e)[3:], convention)
                        - _opk_centre((x - e)[:3], (x - e)[3:], convention)) / (2 * h)
        assert np.abs(J[n] - fd).max() <= 1e-7 * max(1.0, np.abs(fd).max())


def test_sfm_pose_covariance_equals_dense_propagation(tmp_path):
    """A COLMAP model (free, 7-parameter S-base): J (S N⁺ Sᵀ)_ρt Jᵀ with J by central differences."""
    pycolmap = pytest.importorskip("pycolmap")
    from baarda.build import read_problem

    opt = pycolmap.SyntheticDatasetOptions(num_rigs=1, num_cameras_per_rig=1, num_frames_per_rig=5,
                                           num_points3D=60)
    rec = pycolmap.synthesize_dataset(opt)
    pycolmap.synthesize_noise(pycolmap.SyntheticNoiseOptions(point2D_stddev=1.0, point3D_stddev=0.01), rec)
    rec.write_text(str(tmp_path))
    for g in list(tmp_path.glob("rigs.*")) + list(tmp_path.glob("frames.*")):
        g.unlink()
    adj = adjust(read_problem(tmp_path))
    ids, index, sfm = pose_parameters(adj.problem)
    assert sfm
    Srt = _blocks(adj, index, _dense_sigma(adj))
    C = pose_covariance(adj)
    h = 1e-6
    for n in range(len(ids)):
        x = adj.x[index[n]]
        J = np.empty((6, 6))
        for j in range(6):
            e = np.zeros(6)
            e[j] = h
            J[:, j] = (_opk_centre((x + e)[:3], (x + e)[3:], "colmap")
                       - _opk_centre((x - e)[:3], (x - e)[3:], "colmap")) / (2 * h)
        assert _rel(C[n], J @ Srt[n] @ J.T) < 1e-6
