"""baarda.observations.rotation: ω-φ-κ matrices, Rodrigues vectors and quaternions against
scipy.spatial.transform.Rotation (an independent implementation) and their closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from baarda.observations import rotation as rot

angles = st.floats(-1.4, 1.4)


@settings(max_examples=30, deadline=None)
@given(angles, angles, angles)
def test_rotation_round_trips(w, p, k):
    R = rot.R_opk(w, p, k)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(rot.opk_from_R(R), (w, p, k), atol=1e-9)
    assert np.allclose(rot.R_from_rodrigues(rot.rodrigues_from_R(R)), R, atol=1e-9)
    assert np.allclose(rot.R_from_quaternion(rot.quaternion_from_R(R)), R, atol=1e-9)


def test_rotation_convention_and_derivatives():
    # R = R_ω R_φ R_κ: a pure κ turns the image x axis towards object +Y
    R = rot.R_opk(0.0, 0.0, np.pi / 2)
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    assert np.allclose(rot.R_from_rodrigues([0, 0, np.pi / 2]), R, atol=1e-12)
    assert np.allclose(rot.R_from_quaternion([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]), R, atol=1e-12)
    a = np.array([0.1, -0.2, 0.3])
    _, *D = rot.R_opk_derivatives(*a)
    for j in range(3):
        h = np.zeros(3)
        h[j] = 1e-6
        fd = (rot.R_opk(*(a + h)) - rot.R_opk(*(a - h))) / 2e-6
        assert np.abs(fd - D[j]).max() < 1e-9


def test_opk_is_scipys_intrinsic_xyz():
    """R = R_ω R_φ R_κ: about X, the once-rotated Y, the twice-rotated z: intrinsic "XYZ"."""
    a = np.random.default_rng(3).uniform(-1.4, 1.4, size=(20, 3))
    R = rot.R_opk(a[:, 0], a[:, 1], a[:, 2])
    np.testing.assert_allclose(R, Rotation.from_euler("XYZ", a).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(np.column_stack(rot.opk_from_R(R)), a, atol=1e-12)


def test_rodrigues_is_scipys_rotation_vector():
    rng = np.random.default_rng(4)
    rho = rng.normal(size=(50, 3))
    rho *= (rng.uniform(0, np.pi, 50) / np.linalg.norm(rho, axis=1))[:, None]    # |ρ| < π: unique
    rho[0] = [1e-10, -2e-10, 3e-10]                                              # the series branch
    R = rot.R_from_rodrigues(rho)
    np.testing.assert_allclose(R, Rotation.from_rotvec(rho).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(rot.rodrigues_from_R(R), rho, atol=1e-11)


def test_quaternion_is_scipys_with_the_scalar_first():
    """(w, x, y, z) with w ≥ 0 (COLMAP's qvec); scipy gives (x, y, z, w)."""
    R = Rotation.random(40, random_state=5)
    q = rot.quaternion_from_R(R.as_matrix())
    ref = R.as_quat()[:, [3, 0, 1, 2]]
    ref *= np.where(ref[:, :1] < 0, -1.0, 1.0)
    np.testing.assert_allclose(q, ref, atol=1e-13)
    np.testing.assert_allclose(rot.R_from_quaternion(-3.0 * q), R.as_matrix(), atol=1e-14)   # any scale, either sign


@pytest.mark.parametrize("theta", [np.pi - 1e-9, np.pi])
def test_half_turns(theta):
    """Near and at θ = π the trace is −1 and Shepperd's method takes a diagonal pivot."""
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    R = Rotation.from_rotvec(theta * axis).as_matrix()
    np.testing.assert_allclose(rot.R_from_rodrigues(rot.rodrigues_from_R(R)), R, atol=1e-12)
