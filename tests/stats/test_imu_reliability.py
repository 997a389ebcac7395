"""IMU attitudes in a simulated block (issue 28): r and w of the IMU angles against a dense
reference from the equations, a planted attitude error found, the boresight recovered."""

from __future__ import annotations

import numpy as np

import baarda
from baarda.adjust import adjust
from baarda.build import build
from baarda.simulate import simulate_block, simulate_to_files
from tests import oracle


def test_r_and_w_against_a_dense_reference_and_the_boresight_recovered():
    blk, _ = simulate_block(seed=7, strips=2, images_per_strip=4, control="corners", gnss_sigma=0.05,
                            imu_sigma=0.005, imu_boresight=[0.5, -0.3, 1.0],
                            errors=[{"kind": "imu", "size": 8, "image": "102", "angle": "kappa"}])
    problem = build(blk)
    adj = adjust(problem)
    free, x = problem.params.free, adj.x.copy()
    A = np.zeros((problem.n, free.size))
    for j, q in enumerate(free):
        h = 1e-6 * max(1.0, abs(x[q]))
        xp, xm = x.copy(), x.copy()
        xp[q] += h
        xm[q] -= h
        d = problem.evaluate(xp)[0] - problem.evaluate(xm)[0]
        A[:, j] = np.where(problem.angular, np.angle(np.exp(1j * d)), d) / (2 * h)
    ref = oracle.Dense.of(A, problem.cov.matrix(), adj.v)
    kinds = np.asarray(problem.info.kind).astype(str)
    g = np.flatnonzero(np.char.startswith(kinds, "imu-"))
    assert g.size == 24
    np.testing.assert_allclose(adj.r[g], ref.r[g], rtol=0, atol=1e-6)
    np.testing.assert_allclose(adj.w[g], ref.w[g], rtol=1e-5, atol=1e-5)
    worst = g[np.argmax(np.abs(adj.w[g]))]
    assert problem.info.ids[worst]["image"] == "102" and problem.info.ids[worst]["component"] == "kappa"
    labels = list(problem.params.labels)
    b = [labels.index(f"imu.boresight.{nm}") for nm in ("omega", "phi", "kappa")]
    sd = np.sqrt(np.diag(adj.solve_normal(np.eye(free.size)[:, np.searchsorted(free, b)])[np.searchsorted(free, b)]))
    est = np.degrees(adj.x[b])
    assert (np.abs(est - [0.5, -0.3, 1.0]) < 3 * np.degrees(sd) + 1e-9).all(), (est, np.degrees(sd))


def test_variance_components_recover_the_imu_sigma(tmp_path):
    simulate_to_files({"seed": 12, "strips": 3, "control": "none", "gnss_sigma": 0.05, "imu_sigma": 0.004},
                      tmp_path / "b.json")
    csv = tmp_path / "b.imu.csv"
    csv.write_text(csv.read_text().replace(",0.004,0.004,0.004", ",0.008,0.008,0.008"))
    a = baarda.analyze(tmp_path / "b.json", gnss=tmp_path / "b.gnss.csv", imu=csv)
    assert "IMU attitudes (24; boresight estimated)" in a.summary()["datum"]
    vc = {d["group"]: d for d in a.variance_components().as_dict()}
    assert abs(vc["IMU"]["factor"] - 0.25) < 3 * vc["IMU"]["std_error"]
