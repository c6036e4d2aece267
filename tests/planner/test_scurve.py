import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner import plan_scurve, plan_scurve_stop, velocity_pulse

V, A, J = 50.0, 55.0, 120.0


def jerk_values(prof):
    return [value for _, _, value in prof.phases]


def test_full_seven_segments(check):
    prof = plan_scurve(0.0, 120.0, v_max=V, a_max=A, j_max=J)
    assert prof.case == "classic"
    assert jerk_values(prof) == [J, 0.0, -J, 0.0, -J, 0.0, J]
    check(prof, v_max=V, a_max=A, j_max=J)
    assert prof.at(prof.duration) == (120.0, 0.0, 0.0)


def test_no_constant_acceleration_phase(check):
    # v_max reached before a_max: a_max^2 / j_max = 25 > v_max = 20.
    prof = plan_scurve(0.0, 200.0, v_max=20.0, a_max=A, j_max=J)
    assert jerk_values(prof) == [J, -J, 0.0, -J, J]
    peak_a = prof.a[1]  # the acceleration where the jerk turns round
    assert peak_a == pytest.approx(math.sqrt(20.0 * J), rel=1e-6)
    check(prof, v_max=20.0, a_max=A, j_max=J)


def test_no_cruise_and_very_short_moves(check):
    for dist in (30.0, 1.0, 1e-3, 1e-9):
        prof = plan_scurve(5.0, 5.0 + dist, v_max=V, a_max=A, j_max=J)
        assert prof.case == "triangle"
        if dist == 30.0:  # reaches a_max, no cruise
            assert jerk_values(prof) == [J, 0.0, -J, -J, 0.0, J]
        else:  # neither a_max nor a cruise
            assert jerk_values(prof) == [J, -J, -J, J]
        check(prof, v_max=V, a_max=A, j_max=J)
        # For a tiny move only jerk limits: T = 4 (dist / (2 J))^(1/3).
        if dist <= 1.0:
            d = (5.0 + dist) - 5.0  # the distance the planner was given
            assert prof.duration == pytest.approx(4 * (d / (2 * J)) ** (1 / 3), rel=1e-9)


@pytest.mark.parametrize(
    ("target", "case"), [(10_000.0, "a"), (3_000.0, "b"), (-3_000.0, "c"), (-8_000.0, "d")]
)
def test_cases_from_a_moving_start(target, case, check):
    prof = plan_scurve(0.0, target, v_max=990.0, a_max=148.0, j_max=300.0, v0=400.0)
    assert prof.case == case
    check(prof, v_max=990.0, a_max=148.0, j_max=300.0)


def test_start_with_acceleration_is_continuous(check):
    prof = plan_scurve(0.0, 500.0, v_max=V, a_max=A, j_max=J, v0=10.0, a0=40.0)
    assert prof.at(0.0) == (0.0, 10.0, 40.0)
    check(prof, v_max=V, a_max=A, j_max=J)
    # a0 above a_max (after a replan that lowered a_max): brought back at j_max.
    prof = plan_scurve(0.0, 500.0, v_max=V, a_max=20.0, j_max=J, v0=10.0, a0=40.0)
    assert prof.phases[0][2] == -J
    check(prof, v_max=V, a_max=20.0, j_max=J)


def test_velocity_pulse_is_the_trapezoid_one_order_down():
    segs = velocity_pulse(0.0, 0.0, 50.0, 55.0, 120.0)
    assert [j for dt, j in segs if dt > 0] == [120.0, 0.0, -120.0]
    assert sum(dt for dt, _ in segs) == pytest.approx(50.0 / 55.0 + 55.0 / 120.0)


def test_stop(check):
    prof = plan_scurve_stop(3.0, a_max=A, j_max=J, v0=-40.0, a0=-10.0)
    assert prof.case == "stop"
    assert prof.at(prof.duration)[1:] == (0.0, 0.0)
    check(prof, v_max=40.0 + 10.0**2 / (2 * J), a_max=A, j_max=J)
    assert plan_scurve_stop(3.0, a_max=A, j_max=J).case == "hold"


@pytest.mark.parametrize("name", ["v_max", "a_max", "j_max"])
@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, math.nan])
def test_bad_limits(name, bad):
    kwargs = {"v_max": V, "a_max": A, "j_max": J, name: bad}
    with pytest.raises(ValueError, match=rf"^{name} = {bad!r}"):
        plan_scurve(0.0, 1.0, **kwargs)


def test_bad_state():
    with pytest.raises(ValueError, match="a0 = nan"):
        plan_scurve(0.0, 1.0, v_max=V, a_max=A, j_max=J, a0=math.nan)
    with pytest.raises(ValueError, match="p1 = inf"):
        plan_scurve(0.0, math.inf, v_max=V, a_max=A, j_max=J)


@settings(settings.get_profile("planner"))
@given(
    p0=st.floats(-1e3, 1e3),
    dist=st.floats(-1e3, 1e3),
    v_max=st.floats(0.1, 100.0),
    a_max=st.floats(0.1, 100.0),
    j_max=st.floats(0.1, 1000.0),
    v0_frac=st.floats(-2.0, 2.0),
    a0_frac=st.floats(-1.5, 1.5),
    with_a0=st.booleans(),
)
def test_property_valid_profile(p0, dist, v_max, a_max, j_max, v0_frac, a0_frac, with_a0, check):
    v0 = v0_frac * v_max
    a0 = a0_frac * a_max if with_a0 else 0.0
    prof = plan_scurve(p0, p0 + dist, v_max=v_max, a_max=a_max, j_max=j_max, v0=v0, a0=a0)
    # With a0 pushing outwards, overshooting v_max is unavoidable: the bound is where the
    # acceleration can first be brought to zero.
    v_natural = v0 + a0 * abs(a0) / (2 * j_max)
    v_start_max = max(v_max, abs(v0), abs(v_natural))
    check(prof, v_max=v_max, a_max=a_max, j_max=j_max, v_start_max=v_start_max)
    assert prof.at(0.0)[2] == pytest.approx(a0, abs=1e-12 * a_max)


@settings(settings.get_profile("planner"))
@given(
    dist=st.floats(-100.0, 100.0),
    v_max=st.floats(0.5, 20.0),
    a_max=st.floats(0.5, 50.0),
    j_max=st.floats(0.5, 200.0),
    over=st.floats(1.01, 3.0),
    sign=st.sampled_from([-1.0, 1.0]),
    a0_frac=st.floats(-1.0, 1.0),
)
def test_property_start_above_v_max_brakes_back_first(
    dist, v_max, a_max, j_max, over, sign, a0_frac, check
):
    """From |v0| > v_max (a replan that lowered v_max) the speed never grows beyond |v0| and
    is back within v_max for good no later than the fastest settled brake to v_max."""
    v0, a0 = sign * over * v_max, a0_frac * a_max
    prof = plan_scurve(0.0, dist, v_max=v_max, a_max=a_max, j_max=j_max, v0=v0, a0=a0)
    v_nat = v0 + a0 * abs(a0) / (2 * j_max)
    check(prof, v_max=v_max, a_max=a_max, j_max=j_max, v_start_max=max(abs(v0), abs(v_nat)))
    side = 1.0 if (v0 if abs(v0) > v_max else v_nat) > 0 else -1.0
    t_brake = sum(dt for dt, _ in velocity_pulse(v0, a0, side * v_max, a_max, j_max))
    t = np.linspace(0.0, prof.duration, 20001)
    _, v, _ = prof.at(t)
    over_limit = np.nonzero(np.abs(v) > v_max * (1 + 1e-6))[0]
    if over_limit.size:
        assert t[over_limit[-1]] <= t_brake * (1 + 1e-6) + (t[1] - t[0])


def test_end_velocity_for_a_queue_segment(check):
    """A jerk-limited segment that does not stop: ends at (p1, v1, 0)."""
    for v1 in (30.0, -30.0, V, 0.0):
        prof = plan_scurve(0.0, 200.0, v_max=V, a_max=A, j_max=J, v0=10.0, v1=v1)
        assert prof.at(prof.duration) == (200.0, v1, 0.0)
        check(prof, v_max=V, a_max=A, j_max=J)
        # Beyond the end it continues at v1 (the next segment takes over from there).
        assert prof.at(prof.duration + 1.0)[:2] == (200.0 + v1, v1)
    with pytest.raises(ValueError, match="v1 = 60.0"):
        plan_scurve(0.0, 1.0, v_max=V, a_max=A, j_max=J, v1=60.0)


def test_asymmetric_acceleration_and_deceleration():
    prof = plan_scurve(0.0, 500.0, v_max=V, a_max=40.0, j_max=J, d_max=20.0)
    _, v, a = prof.at(np.linspace(0.0, prof.duration, 4001))
    assert a.max() == pytest.approx(40.0) and a.min() == pytest.approx(-20.0)
    assert prof.at(prof.duration) == (500.0, 0.0, 0.0)
    same = plan_scurve(0.0, 500.0, v_max=V, a_max=40.0, j_max=J, d_max=40.0)
    assert same.phases == plan_scurve(0.0, 500.0, v_max=V, a_max=40.0, j_max=J).phases
    with pytest.raises(ValueError, match="d_max = 0.0"):
        plan_scurve(0.0, 1.0, v_max=V, a_max=A, j_max=J, d_max=0.0)


@settings(settings.get_profile("planner"))
@given(
    dist=st.floats(-1e3, 1e3),
    v_max=st.floats(0.1, 100.0),
    a_max=st.floats(0.1, 100.0),
    d_max=st.floats(0.1, 100.0),
    j_max=st.floats(0.1, 1000.0),
    v0_frac=st.floats(-1.0, 1.0),
    a0_frac=st.floats(-1.0, 1.0),
    v1_frac=st.floats(-1.0, 1.0),
)
def test_property_asymmetric_and_moving_end_valid(
    dist, v_max, a_max, d_max, j_max, v0_frac, a0_frac, v1_frac, check
):
    """Any start within the limits, any end velocity: continuous, within v_max and j_max,
    |a| <= a_max where the speed grows and <= d_max where it falls (where v passes through
    zero both), beyond the start's own |a0| never; it ends exactly at (p1, v1, 0)."""
    v0, v1 = v0_frac * v_max, v1_frac * v_max
    a0 = a0_frac * min(a_max, d_max, math.sqrt(2 * j_max * max(v_max - abs(v0), 0.0)))
    prof = plan_scurve(
        0.0, dist, v_max=v_max, a_max=a_max, j_max=j_max, v0=v0, a0=a0, v1=v1, d_max=d_max
    )
    a_top = max(a_max, d_max)
    check(prof, v_max=v_max, a_max=a_top, j_max=j_max, v_start_max=v_max)
    t = np.linspace(0.0, prof.duration, 4001)
    _, v, a = prof.at(t)
    allowed_up = max(a_max, abs(a0)) * (1 + 1e-9) + 1e-12
    allowed_down = max(d_max, abs(a0)) * (1 + 1e-9) + 1e-12
    moving = np.abs(v) > 1e-9 * v_max  # at v = 0 to rounding its sign says nothing
    assert np.all(np.abs(a[moving & (a * v > 0.0)]) <= allowed_up)
    assert np.all(np.abs(a[moving & (a * v < 0.0)]) <= allowed_down)
    assert prof.at(prof.duration) == (dist, v1, 0.0)
