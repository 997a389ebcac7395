"""A GNSS shift of a whole strip ACROSS the flight line (issue 28): the design decides whether it is
found.

The images' roll ω absorbs most of a cross-strip shift of a strip's centres, so with 4 corner
control points and GNSS alone the strip test (F80 eq. 10-12, H = (… I₃ …)ᵀ over the strip's
centres) sees little of it: on the default simulated block (3 strips × 8 images, 1,500 m, GNSS σ
5 cm) a 0.5 m shift in y of strip 3 has non-centrality λ = 20 (σ of ∇ŝ_y 0.14 m), below
δ0(α0 = 0.001, β0 = 0.8, q = 3)² = 21.5: not found with the power β0. IMU attitudes (σ 0.005°)
observe the roll and control along the perimeter fixes the strips: λ rises above twice δ0² and
σ of ∇ŝ_y halves. Error-free simulated observations (``design``) make T equal λ exactly.
"""

from __future__ import annotations

import pytest

import baarda
from baarda.simulate import simulate_to_files
from baarda.stats import gnss


def _strip_test(tmp_path, control, imu_sigma=None):
    recipe = {"seed": 2, "design": True, "control": control, "gnss_sigma": 0.05,
              "errors": [{"kind": "gnss-strip", "size": 10, "strip": "3", "axis": "y"}]}
    if imu_sigma is not None:
        recipe["imu_sigma"] = imu_sigma
    tmp_path.mkdir()
    simulate_to_files(recipe, tmp_path / "b.json", tmp_path / "b.truth.json")
    a = baarda.analyze(tmp_path / "b.json", gnss=tmp_path / "b.gnss.csv",
                       imu=tmp_path / "b.imu.csv" if imu_sigma is not None else None)
    images = [im.id for im in a.problem.notes.local_model.images if im.strip == "3"]
    t = a.reliability.test(gnss.h_gnss_strip(a.adjustment.problem, images), label="strip 3")
    assert t.nabla[1] == pytest.approx(0.5, abs=1e-4)      # error-free: ∇ŝ is the planted shift
    return t, a.reliability.policy.delta0(3) ** 2


def test_cross_strip_shift_needs_imu_or_more_control(tmp_path):
    corners, lam0 = _strip_test(tmp_path / "a", "corners")
    with_imu, _ = _strip_test(tmp_path / "b", "corners", imu_sigma=0.005)
    perimeter, _ = _strip_test(tmp_path / "c", "perimeter")
    assert corners.T < lam0                                  # below δ0²: not found with power β0
    assert with_imu.T > 2 * lam0 and with_imu.rejected_T
    assert perimeter.T > 2 * lam0 and perimeter.rejected_T
    assert with_imu.nabla_sigma[1] < 0.6 * corners.nabla_sigma[1]
    assert perimeter.nabla_sigma[1] < 0.6 * corners.nabla_sigma[1]
