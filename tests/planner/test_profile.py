import math

import numpy as np
import pytest

from planner.profile import build_profile


def test_build_integrates_jerk_phases_exactly():
    # +J for 1 s, 0 for 1 s, -J for 1 s from rest: a = J, v = J/2 + J + J/2, p by hand.
    j = 6.0
    prof = build_profile("scurve", "x", 1.0, 0.0, 0.0, [(1.0, j), (1.0, 0.0), (1.0, -j)], 0, 0)
    assert prof.t0 == (0.0, 1.0, 2.0)
    assert prof.a == (0.0, j, j)
    assert prof.v == (0.0, j / 2, j / 2 + j)
    assert prof.p == (1.0, 1.0 + j / 6, 1.0 + j / 6 + j / 2 + j / 2)
    assert prof.phases == ((0.0, 1.0, j), (1.0, 2.0, 0.0), (2.0, 3.0, -j))
    assert prof.at(0.5) == pytest.approx((1.0 + j * 0.125 / 6, j * 0.125, j * 0.5))


def test_zero_length_phases_are_dropped_and_trapezoid_reports_acceleration():
    prof = build_profile("trapezoid", "x", 0.0, 1.0, 0.0, [(0.0, 5.0), (2.0, -0.5)], 1.0, 0.0)
    assert prof.phases == ((0.0, 2.0, -0.5),)
    assert prof.j == (0.0,)
    assert prof.duration == 2.0


def test_jerk_is_piecewise_constant_and_zero_outside():
    prof = build_profile("scurve", "x", 0.0, 0.0, 0.0, [(1.0, 2.0), (1.0, -2.0)], 2.0, 0.0)
    assert prof.jerk(-1.0) == 0.0 and prof.jerk(0.5) == 2.0 and prof.jerk(1.5) == -2.0
    assert prof.jerk(2.0) == 0.0
    np.testing.assert_array_equal(prof.jerk(np.array([-1.0, 0.5, 1.5, 3.0])), [0, 2, -2, 0])
    trap = build_profile("trapezoid", "x", 0.0, 0.0, 0.0, [(1.0, 2.0)], 1.0, 2.0)
    assert trap.jerk(0.5) == 0.0


def test_non_finite_duration_is_refused():
    with pytest.raises(ValueError, match="duration = inf"):
        build_profile("trapezoid", "x", 0.0, 0.0, 0.0, [(math.inf, 1.0)], 0.0, 0.0)


def test_start_acceleration_is_not_held_before_the_start():
    prof = build_profile("scurve", "x", 0.0, 1.0, 3.0, [(1.0, -3.0)], 2.5, 2.5)
    assert prof.at(-1.0) == (0.0, 1.0, 0.0)
    assert prof.at(0.0) == (0.0, 1.0, 3.0)
