"""The network's axes (Gama's ``axes-xy``): the map's east/north and the bearings agree."""
from __future__ import annotations

import itertools
import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from baarda.io.gama import bearing_convention
from baarda.model.network import east_north_matrix

#: every pair of perpendicular axis letters Gama accepts
AXES = [a + b for a, b in itertools.permutations("nesw", 2) if {a, b} not in ({"n", "s"}, {"e", "w"})]


@given(st.sampled_from(AXES), st.floats(-1e3, 1e3), st.floats(-1e3, 1e3))
def test_map_east_north_give_gamas_bearing(axes, dx, dy):
    """The clockwise bearing from north of (Δe, Δn) = M (Δx, Δy) is the bearing Gama computes
    in the file's axes (left-handed angles, manual §2.3), for all eight axis conventions."""
    if math.hypot(dx, dy) < 1e-3:
        return
    de, dn = east_north_matrix(axes) @ np.array([dx, dy])
    sign, theta = bearing_convention(axes, "left-handed")
    diff = math.atan2(de, dn) - (sign * math.atan2(dy, dx) + theta)
    assert abs(math.remainder(diff, 2 * math.pi)) < 1e-9


def test_axes_are_a_rotation_or_reflection_and_none_is_identity():
    assert len(AXES) == 8
    for axes in AXES:
        M = east_north_matrix(axes)
        np.testing.assert_array_equal(M @ M.T, np.eye(2))
    assert np.array_equal(east_north_matrix("en"), np.eye(2))
    assert np.array_equal(east_north_matrix(None), np.eye(2))
