"""The GNSS observation of a projection centre, X0 + R e + a_s + b_s (t − t0) (issue 28): its
values against the equation written out here (rotations from their elementary matrices) and its
Jacobian against central differences."""

from __future__ import annotations

import numpy as np

from baarda.observations.gnss import GnssSet


def _R(om, ph, ka):
    """R = R_x(ω) R_y(φ) R_z(κ), written out."""
    c, s = np.cos, np.sin
    Rx = np.array([[1, 0, 0], [0, c(om), -s(om)], [0, s(om), c(om)]])
    Ry = np.array([[c(ph), 0, s(ph)], [0, 1, 0], [-s(ph), 0, c(ph)]])
    Rz = np.array([[c(ka), -s(ka), 0], [s(ka), c(ka), 0], [0, 0, 1]])
    return Rx @ Ry @ Rz


def _set(rng, k=5):
    """k centres of two strips: EO at 0..6k-1, lever at 6k.., shifts and drifts of two strips after;
    the last centre without shift and drift."""
    x = np.concatenate([np.column_stack([rng.normal(0, 500, (k, 3)), rng.normal(0, 0.3, (k, 3))]).ravel(),
                        rng.normal(0, 0.5, 3), rng.normal(0, 0.2, 12)])
    ieo = np.arange(6 * k).reshape(k, 6)
    lever = 6 * k + np.arange(3)
    strip = np.array([0, 0, 1, 1, -1])[:k]
    shift = np.where(strip[:, None] >= 0, 6 * k + 3 + 3 * strip[:, None] + np.arange(3), -1)
    drift = np.where(strip[:, None] >= 0, 6 * k + 9 + 3 * strip[:, None] + np.arange(3), -1)
    dt = rng.normal(0, 3, k)
    return GnssSet(rows=np.arange(3 * k), ieo=ieo, lever=lever, shift=shift, drift=drift, dt=dt), x


def test_values_are_the_equation():
    rng = np.random.default_rng(1)
    s, x = _set(rng)
    f, *_ = s.evaluate(x)
    for j in range(5):
        eo = x[s.ieo[j]]
        want = eo[:3] + _R(*eo[3:]) @ x[s.lever]
        if s.shift[j, 0] >= 0:
            want = want + x[s.shift[j]] + x[s.drift[j]] * s.dt[j]
        np.testing.assert_allclose(f[3 * j:3 * j + 3], want, rtol=0, atol=1e-9)


def test_jacobian_against_central_differences():
    rng = np.random.default_rng(2)
    s, x = _set(rng)
    f, jr, jc, jv = s.evaluate(x)
    J = np.zeros((f.size, x.size))
    np.add.at(J, (jr, jc), jv)
    Jn = np.zeros_like(J)
    for p in range(x.size):
        h = 1e-6 * max(1.0, abs(x[p]))
        xp, xm = x.copy(), x.copy()
        xp[p] += h
        xm[p] -= h
        Jn[:, p] = (s.evaluate(xp)[0] - s.evaluate(xm)[0]) / (2 * h)
    np.testing.assert_allclose(J, Jn, rtol=0, atol=1e-6)
    # every parameter of the model is reached: X0, the angles (through e ≠ 0), e, a, b
    assert (np.abs(J).sum(axis=0) > 0).all()
