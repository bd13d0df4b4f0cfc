"""The real test's grasp-angle difference: grasp angles are pi-periodic (a grasp turned by 180 deg
is the same grasp), so the difference is the smaller turn between them, in [0, 90] deg."""

import math

import pytest

from experiments.real_test import _angle_diff_deg


@pytest.mark.parametrize("a_deg,b_deg,want_deg", [
    (10.0, 30.0, 20.0), (30.0, 10.0, 20.0),
    (10.0, 100.0, 90.0),  # perpendicular: the largest difference there is
    (5.0, 175.0, 10.0), (-85.0, 85.0, 10.0),  # across the wrap at +-90 deg
    (20.0, 200.0, 0.0), (0.0, 360.0 + 45.0, 45.0),  # half and whole turns are no difference
    (-60.0, 50.0, 70.0),
])
def test_angle_difference_is_the_smaller_turn(a_deg, b_deg, want_deg):
    assert _angle_diff_deg(math.radians(a_deg), math.radians(b_deg)) == pytest.approx(want_deg, abs=1e-9)
