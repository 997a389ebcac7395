"""IMU attitudes with a boresight, angles(R(ω, φ, κ) R_b) (issue 28): values against rotations
written out here and the Jacobian against central differences."""

from __future__ import annotations

import numpy as np

from baarda.observations.imu import ImuSet, angles_of
from tests.observations.test_gnss import _R


def _set(rng, k=6):
    x = np.concatenate([np.column_stack([rng.normal(0, 500, (k, 3)), rng.normal(0, 0.4, (k, 3))]).ravel(),
                        rng.normal(0, 0.05, 3)])
    x[6 * np.arange(k) + 5] += np.pi * (np.arange(k) % 2)         # κ near 0 and near π
    return ImuSet(rows=np.arange(3 * k), ieo=np.arange(6 * k).reshape(k, 6), boresight=6 * k + np.arange(3)), x


def test_values_are_the_angles_of_the_product():
    rng = np.random.default_rng(3)
    s, x = _set(rng)
    f, *_ = s.evaluate(x)
    for j in range(6):
        M = _R(*x[s.ieo[j, 3:]]) @ _R(*x[s.boresight])
        om, ph, ka = f[3 * j:3 * j + 3]
        np.testing.assert_allclose(_R(om, ph, ka), M, atol=1e-12)      # the angles rebuild R R_b
    # a zero boresight observes the image's own angles (wrapped)
    x0 = x.copy()
    x0[s.boresight] = 0.0
    a = s.evaluate(x0)[0].reshape(-1, 3)
    d = a - x0[s.ieo[:, 3:]]
    np.testing.assert_allclose(np.angle(np.exp(1j * d)), 0.0, atol=1e-12)
    np.testing.assert_allclose(angles_of(_R(0.1, -0.2, 3.0)), [0.1, -0.2, 3.0], atol=1e-14)


def test_jacobian_against_central_differences():
    rng = np.random.default_rng(4)
    s, x = _set(rng)
    f, jr, jc, jv = s.evaluate(x)
    J = np.zeros((f.size, x.size))
    np.add.at(J, (jr, jc), jv)
    Jn = np.zeros_like(J)
    for p in range(x.size):
        h = 1e-6
        xp, xm = x.copy(), x.copy()
        xp[p] += h
        xm[p] -= h
        d = s.evaluate(xp)[0] - s.evaluate(xm)[0]
        Jn[:, p] = np.angle(np.exp(1j * d)) / (2 * h)
    np.testing.assert_allclose(J, Jn, rtol=0, atol=1e-7)
    assert np.abs(J[:, 6 * 6:]).min(axis=0).max() > 0            # the boresight reaches every image
