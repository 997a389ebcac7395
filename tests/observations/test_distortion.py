"""``baarda.observations.distortion.brown``: the one distortion formula of both cameras, against
Brown's AP basis (an independent spelling: the basis columns times the coefficients), OpenCV's
model written out as COLMAP documents it, and central differences for the Jacobian."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from baarda.observations.collinearity import brown_basis
from baarda.observations.distortion import brown

COEF = st.floats(-0.5, 0.5)
UV = st.floats(-1.2, 1.2)


@settings(max_examples=60, deadline=None)
@given(UV, UV, COEF, COEF, COEF, st.floats(-0.05, 0.05), st.floats(-0.05, 0.05))
def test_equals_browns_basis_and_its_derivatives(u, v, k1, k2, k3, p1, p2):
    du, dv, j00, j01, j11 = brown(np.array([u]), np.array([v]), k1, k2, k3, p1, p2)
    Fx, Fy, Fxu, Fxv, Fyu, Fyv = brown_basis(np.array([u]), np.array([v]))
    a = np.array([k1, k2, k3, p1, p2, 0.0, 0.0])
    np.testing.assert_allclose([du[0], dv[0]], [Fx[0] @ a, Fy[0] @ a], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose([j00[0], j01[0], j01[0], j11[0]],
                               [1 + Fxu[0] @ a, Fxv[0] @ a, Fyu[0] @ a, 1 + Fyv[0] @ a], rtol=1e-12, atol=1e-13)


@settings(max_examples=60, deadline=None)
@given(UV, UV, COEF, COEF, st.floats(-0.05, 0.05), st.floats(-0.05, 0.05))
def test_opencv_is_brown_with_p1_p2_exchanged(u, v, k1, k2, p1, p2):
    """COLMAP's OPENCV: u_d = u (1 + k1 r² + k2 r⁴) + 2 p1 u v + p2 (r² + 2u²), v_d alike."""
    r2 = u * u + v * v
    rad = 1 + k1 * r2 + k2 * r2 * r2
    ud = u * rad + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
    vd = v * rad + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
    du, dv, *_ = brown(u, v, k1, k2, 0.0, p2, p1)
    np.testing.assert_allclose([u + du, v + dv], [ud, vd], rtol=1e-12, atol=1e-14)


def test_jacobian_against_central_differences():
    rng = np.random.default_rng(7)
    u, v = rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50)
    c = (0.1, -0.03, 0.01, 0.002, -0.004)
    _, _, j00, j01, j11 = brown(u, v, *c)
    h = 1e-6
    def dist(uu, vv):
        du, dv, *_ = brown(uu, vv, *c)
        return uu + du, vv + dv
    xu = (np.array(dist(u + h, v)) - np.array(dist(u - h, v))) / (2 * h)
    xv = (np.array(dist(u, v + h)) - np.array(dist(u, v - h))) / (2 * h)
    np.testing.assert_allclose(j00, xu[0], rtol=1e-7)
    np.testing.assert_allclose(j01, xv[0], rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(j01, xu[1], rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(j11, xv[1], rtol=1e-7)
