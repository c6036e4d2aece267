import math
import random
import sys

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from planner import plan_stop, plan_trapezoid

# Seed 000's Fig. 7 (v0 = 400, paper units read as axis deg with positions in mdeg / 1000).
V_MAX, A_MAX = 990.0, 148.0


def seed000_times(s_b, v0, v_max, a_max):
    """Seed 000's eqs. (8)-(19) as printed (typos read as S'_b and v0), for 0 <= v0 <= v_max.

    Returns (case, t1, t2, t3) with the case chosen by the seed's conditions on S'_b.
    """
    s2 = (2 * v_max**2 - v0**2) / (2 * a_max)
    s3 = v0**2 / (2 * a_max)
    if s_b > s2:
        t1 = (v_max - v0) / a_max
        t2 = (2 * a_max * s_b + v0**2 - 2 * v_max * v0) / (2 * a_max * v_max)
        t3 = (2 * a_max * s_b + v0**2 + 2 * v_max**2 - 2 * v_max * v0) / (2 * a_max * v_max)
        return "a", t1, t2, t3
    if s3 < s_b:
        t1 = (math.sqrt(a_max * s_b + v0**2 / 2) - v0) / a_max
        t3 = (math.sqrt(4 * a_max * s_b + 2 * v0**2) - v0) / a_max
        return "b", t1, t1, t3
    if -s2 < s_b:
        t1 = (v0 + math.sqrt(v0**2 / 2 - a_max * s_b)) / a_max
        t3 = (v0 + 2 * math.sqrt(v0**2 / 2 - a_max * s_b)) / a_max
        return "c", t1, t1, t3
    t1 = (v_max + v0) / a_max
    t2 = (v0**2 + 2 * v_max * v0 - 2 * a_max * s_b) / (2 * a_max * v_max)
    t3 = (v0**2 + 2 * v_max**2 + 2 * v_max * v0 - 2 * a_max * s_b) / (2 * a_max * v_max)
    return "d", t1, t2, t3


def phase_ends(prof):
    """(t1, t2, t3) of a 2- or 3-phase profile: end of the first ramp, start of the last."""
    ph = prof.phases
    if len(ph) == 3:
        return ph[0][1], ph[1][1], ph[2][1]
    assert len(ph) == 2
    return ph[0][1], ph[0][1], ph[1][1]


@pytest.mark.parametrize(
    ("target", "case"), [(10_000.0, "a"), (3_000.0, "b"), (-3_000.0, "c"), (-8_000.0, "d")]
)
def test_fig7_targets_fall_in_the_four_strategies(target, case, check):
    prof = plan_trapezoid(0.0, target, v_max=V_MAX, a_max=A_MAX, v0=400.0)
    assert prof.case == case
    seed_case, t1, t2, t3 = seed000_times(target, 400.0, V_MAX, A_MAX)
    assert seed_case == case
    assert phase_ends(prof) == pytest.approx((t1, t2, t3), rel=1e-12)
    check(prof, v_max=V_MAX, a_max=A_MAX)
    # "all start at 400, none jumps; S_2 and S_3 have no cruise"
    assert prof.at(0.0)[1] == 400.0
    assert (len(prof.phases) == 2) == (case in "bc")


def test_seed000_formulas_agree_on_random_states_in_their_domain():
    rng = random.Random(2022)
    for _ in range(3000):
        v_max = 10 ** rng.uniform(-1, 3)
        a_max = 10 ** rng.uniform(-1, 3)
        v0 = rng.uniform(0.0, v_max)
        s2 = (2 * v_max**2 - v0**2) / (2 * a_max)
        s_b = rng.uniform(-3.0, 3.0) * s2
        case, t1, t2, t3 = seed000_times(s_b, v0, v_max, a_max)
        p0 = rng.uniform(-100.0, 100.0)
        prof = plan_trapezoid(p0, p0 + s_b, v_max=v_max, a_max=a_max, v0=v0)
        assert prof.case == case
        assert prof.duration == pytest.approx(t3, rel=1e-9)
        assert phase_ends(prof) == pytest.approx((t1, t2, t3), rel=1e-9, abs=1e-9 * t3)


def test_classic_trapezoid_and_triangle_eqs_1_to_7():
    # Eqs. (1)-(3): t1 = v/a, t2 = S/v, t3 = (a S + v^2) / (a v).
    s_a, v, a = 100.0, 10.0, 2.0
    prof = plan_trapezoid(0.0, s_a, v_max=v, a_max=a)
    assert prof.case == "classic"
    assert phase_ends(prof) == pytest.approx((v / a, s_a / v, (a * s_a + v * v) / (a * v)))
    # Eqs. (4)-(7), condition S_a < v^2/a: the seed writes v_max for the peak; the peak of
    # the triangle is v' = sqrt(a S_a), and t1 = t2 = v'/a, t3 = 2 v'/a.
    s_a = 30.0
    assert s_a < v * v / a
    prof = plan_trapezoid(0.0, s_a, v_max=v, a_max=a)
    assert prof.case == "triangle"
    peak = math.sqrt(a * s_a)
    assert phase_ends(prof) == pytest.approx((peak / a, peak / a, 2 * peak / a))
    assert prof.at(peak / a)[1] == pytest.approx(peak)


def test_negative_start_velocity_is_the_mirror_image():
    for target in (10_000.0, 3_000.0, -3_000.0, -8_000.0, 0.0):
        fwd = plan_trapezoid(5.0, 5.0 + target, v_max=V_MAX, a_max=A_MAX, v0=400.0)
        back = plan_trapezoid(-5.0, -5.0 - target, v_max=V_MAX, a_max=A_MAX, v0=-400.0)
        assert back.case == fwd.case
        assert back.duration == pytest.approx(fwd.duration, rel=1e-14)
        t = np.linspace(-1.0, fwd.duration + 1.0, 101)
        pf, vf, af = fwd.at(t)
        pb, vb, ab = back.at(t)
        np.testing.assert_allclose(pb, -pf, atol=1e-9)
        np.testing.assert_allclose(vb, -vf, atol=1e-9)
        np.testing.assert_allclose(ab, -af, atol=1e-12)


def test_start_above_v_max_brakes_first(check):
    # After a replan that lowers v_max to 500 while moving at 990.
    prof = plan_trapezoid(0.0, 20_000.0, v_max=500.0, a_max=A_MAX, v0=990.0)
    assert prof.case == "brake+a"
    t_brake = (990.0 - 500.0) / A_MAX
    assert prof.phases[0] == pytest.approx((0.0, t_brake, -A_MAX))
    assert prof.at(t_brake)[1] == pytest.approx(500.0)
    check(prof, v_max=500.0, a_max=A_MAX)
    # ... and overshooting targets make it reverse after braking.
    prof = plan_trapezoid(0.0, 100.0, v_max=500.0, a_max=A_MAX, v0=-990.0)
    assert prof.case.startswith("brake+")
    check(prof, v_max=500.0, a_max=A_MAX)


def test_target_at_start_with_velocity_goes_out_and_back(check):
    prof = plan_trapezoid(7.0, 7.0, v_max=V_MAX, a_max=A_MAX, v0=400.0)
    assert prof.case == "c"
    # Stop (400/148 s), then come back the stop distance with a triangle.
    stop = 400.0**2 / (2 * A_MAX)
    assert prof.duration == pytest.approx(400.0 / A_MAX + 2 * math.sqrt(stop / A_MAX))
    check(prof, v_max=V_MAX, a_max=A_MAX)


def test_hold_when_already_there():
    prof = plan_trapezoid(3.0, 3.0, v_max=1.0, a_max=1.0)
    assert prof.case == "hold"
    assert prof.duration == 0.0
    assert prof.phases == ()
    assert prof.at(0.0) == (3.0, 0.0, 0.0)
    p, v, a = prof.at(np.array([-1.0, 0.0, 1.0]))
    assert p.tolist() == [3.0, 3.0, 3.0] and v.tolist() == [0.0] * 3 and a.tolist() == [0.0] * 3


def test_end_velocity(check):
    prof = plan_trapezoid(0.0, 50.0, v_max=10.0, a_max=2.0, v0=3.0, v1=8.0)
    assert prof.at(prof.duration) == (50.0, 8.0, 0.0)
    check(prof, v_max=10.0, a_max=2.0)
    # A single ramp when the distance is exactly the ramp's.
    d = (8.0**2 - 3.0**2) / (2 * 2.0)
    prof = plan_trapezoid(0.0, d, v_max=10.0, a_max=2.0, v0=3.0, v1=8.0)
    assert len(prof.phases) == 1 and prof.duration == pytest.approx(2.5)
    # Same for two negative velocities (the single ramp, not the slow far root).
    prof = plan_trapezoid(0.0, -d, v_max=10.0, a_max=2.0, v0=-3.0, v1=-8.0)
    assert len(prof.phases) == 1 and prof.duration == pytest.approx(2.5)


@pytest.mark.parametrize("scale", [1e-12, 1e-6, 1.0, 1e6, 1e12])
def test_tiny_and_huge_distances(scale, check):
    prof = plan_trapezoid(1.0, 1.0 + scale, v_max=2.0, a_max=3.0, v0=0.5)
    check(prof, v_max=2.0, a_max=3.0)
    assert prof.at(prof.duration)[0] == 1.0 + scale


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"v_max": 0.0}, "v_max"),
        ({"v_max": -1.0}, "v_max"),
        ({"a_max": 0.0}, "a_max"),
        ({"a_max": math.inf}, "a_max"),
        ({"v_max": math.nan}, "v_max"),
        ({"v0": math.nan}, "v0"),
        ({"v1": 2.0}, "v1"),
        ({"v1": math.inf}, "v1"),
        ({"p1": math.inf}, "p1"),
        ({"p0": math.nan}, "p0"),
    ],
)
def test_bad_arguments_name_the_argument_and_value(kwargs, name):
    args = {"p0": 0.0, "p1": 1.0, "v_max": 1.0, "a_max": 1.0} | kwargs
    p0, p1 = args.pop("p0"), args.pop("p1")
    with pytest.raises(ValueError, match=rf"^{name} = {kwargs[name]!r}"):
        plan_trapezoid(p0, p1, **args)


def test_at_scalar_and_array_agree_and_keep_shape():
    prof = plan_trapezoid(0.0, 10_000.0, v_max=V_MAX, a_max=A_MAX, v0=400.0)
    t = np.linspace(-2.0, prof.duration + 2.0, 60).reshape(3, 20)
    p, v, a = prof.at(t)
    assert p.shape == v.shape == a.shape == (3, 20)
    for idx in np.ndindex(t.shape):
        ps, vs, as_ = prof.at(float(t[idx]))
        assert isinstance(ps, float) and isinstance(vs, float) and isinstance(as_, float)
        assert (ps, vs, as_) == pytest.approx((p[idx], v[idx], a[idx]), rel=1e-15, abs=1e-12)
    assert isinstance(prof.at(np.float64(1.0))[0], float)


def test_defined_before_start_and_after_end():
    prof = plan_trapezoid(2.0, 30.0, v_max=10.0, a_max=2.0, v0=1.0, v1=4.0)
    assert prof.at(-5.0) == (2.0, 1.0, 0.0)
    big_t = prof.duration
    assert prof.at(big_t + 3.0) == (30.0 + 4.0 * 3.0, 4.0, 0.0)
    p, v, a = prof.at(np.array([-5.0, big_t + 3.0]))
    assert p.tolist() == [2.0, 42.0] and v.tolist() == [1.0, 4.0] and a.tolist() == [0.0, 0.0]


def test_profile_is_immutable():
    prof = plan_trapezoid(0.0, 1.0, v_max=1.0, a_max=1.0)
    with pytest.raises(AttributeError):
        prof.duration = 3.0  # type: ignore[misc]


def test_stop():
    prof = plan_stop(1.0, a_max=2.0, v0=-4.0)
    assert prof.duration == pytest.approx(2.0)
    assert prof.p1 == pytest.approx(1.0 - 4.0)
    assert prof.at(prof.duration) == (prof.p1, 0.0, 0.0)
    assert plan_stop(1.0, a_max=2.0).case == "hold"


finite = st.floats(-1e4, 1e4, allow_nan=False)
positive = st.floats(1e-2, 1e3, allow_nan=False)


@settings(settings.get_profile("planner"))
@given(
    p0=finite,
    dist=finite,
    v_max=positive,
    a_max=positive,
    v0_frac=st.floats(-2.0, 2.0),
    v1_frac=st.floats(-1.0, 1.0),
)
def test_property_valid_profile(p0, dist, v_max, a_max, v0_frac, v1_frac, check):
    v0, v1 = v0_frac * v_max, v1_frac * v_max
    prof = plan_trapezoid(p0, p0 + dist, v_max=v_max, a_max=a_max, v0=v0, v1=v1)
    check(prof, v_max=v_max, a_max=a_max)
    # Never slower than going the long way round: a lower bound on the duration.
    dist = (p0 + dist) - p0  # what the planner was actually asked to cover
    # Rounding of the peak speed may lose up to ~ulp(v^2)/a of distance (and its time).
    slack = 4 * math.ulp(max(v_max, abs(v0)) ** 2) / a_max / max(v_max, abs(v0))
    assert prof.duration >= abs(dist) / max(v_max, abs(v0)) * (1 - 1e-12) - slack


def check_asymmetric(prof, *, v_max, a_max, d_max, v_start_max=None):
    """|a| <= a_max where the speed grows (a v > 0), <= d_max where it falls (a v < 0):
    judged on dense samples, both sides of every phase boundary."""
    big_t = prof.duration
    knots = np.array(prof.t0 + (big_t,))
    eps = 1e-9 * max(big_t, 1e-300)
    ts = np.concatenate([np.linspace(0.0, big_t, 4001), knots - eps, knots + eps])
    ts = np.clip(ts, 0.0, np.nextafter(big_t, 0.0))
    _, v, a = prof.at(ts)
    v_lim = max(v_max, abs(prof.v0) if v_start_max is None else v_start_max)
    # Where the velocity is zero to rounding (a stop, a reversal) its sign says nothing.
    moving = np.abs(v) > 1e-9 * v_lim
    assert np.all(np.abs(a[moving & (a * v > 0.0)]) <= a_max * (1 + 1e-9))
    assert np.all(np.abs(a[moving & (a * v < 0.0)]) <= d_max * (1 + 1e-9))
    assert np.all(np.abs(v) <= v_lim * (1 + 1e-9))
    assert prof.at(big_t) == (prof.p1, prof.v1, 0.0)


def test_asymmetric_limits_through_zero_velocity(check):
    # From -2 towards +10: slow down at d_max to 0, speed up at a_max, brake at d_max.
    prof = plan_trapezoid(0.0, 10.0, v_max=3.0, a_max=1.0, v0=-2.0, d_max=2.0)
    assert [value for _, _, value in prof.phases] == [2.0, 1.0, 0.0, -2.0]
    assert prof.phases[0][1] == pytest.approx(1.0)  # 2 / d_max: at rest after 1 s
    check_asymmetric(prof, v_max=3.0, a_max=1.0, d_max=2.0)
    # Symmetric limits give back the symmetric plan, bit for bit.
    same = plan_trapezoid(0.0, 10.0, v_max=3.0, a_max=1.0, v0=-2.0, d_max=1.0)
    assert same.phases == plan_trapezoid(0.0, 10.0, v_max=3.0, a_max=1.0, v0=-2.0).phases


def test_start_above_v_max_brakes_at_d_max():
    prof = plan_trapezoid(0.0, 1000.0, v_max=10.0, a_max=1.0, v0=20.0, d_max=5.0)
    assert prof.case.startswith("brake+")
    assert prof.phases[0][2] == -5.0 and prof.phases[0][1] == pytest.approx(2.0)
    check_asymmetric(prof, v_max=10.0, a_max=1.0, d_max=5.0, v_start_max=20.0)


@pytest.mark.parametrize("name", ["d_max"])
@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, math.nan])
def test_bad_deceleration_limit(name, bad):
    with pytest.raises(ValueError, match=rf"^{name} = {bad!r}"):
        plan_trapezoid(0.0, 1.0, v_max=1.0, a_max=1.0, d_max=bad)


@settings(settings.get_profile("planner"))
@given(
    dist=st.floats(-1e3, 1e3),
    v_max=st.floats(0.1, 100.0),
    a_max=st.floats(0.1, 100.0),
    d_max=st.floats(0.1, 100.0),
    v0_frac=st.floats(-2.0, 2.0),
    v1_frac=st.floats(-1.0, 1.0),
)
# Found by a random run: a subnormal distance, which the symmetric plan at 0.5 holds (the
# 5e-324 is below what a*t^2/2 can resolve) and the asymmetric one reaches in 6.7e-162 s.
@example(dist=5e-324, v_max=1.0, a_max=1.0, d_max=0.5, v0_frac=0.0, v1_frac=0.0)
@example(dist=0.0, v_max=3.3, a_max=1.0, d_max=0.5, v0_frac=1.0, v1_frac=1.0)
def test_property_asymmetric_valid_and_between_the_symmetric_plans(
    dist, v_max, a_max, d_max, v0_frac, v1_frac
):
    """Any start and end (reversals included): within the asymmetric limits; from within
    v_max never slower than with both limits at min(a_max, d_max) nor faster than with both
    at the max (those two plans are time-optimal, tested against ruckig). From above v_max
    the brake back to v_max is at full d_max by definition (back within the limit as soon
    as possible), which a gentler brake could beat on time: no bound there."""
    v0, v1 = v0_frac * v_max, v1_frac * v_max
    kw = {"v_max": v_max, "v0": v0, "v1": v1}
    prof = plan_trapezoid(0.0, dist, a_max=a_max, d_max=d_max, **kw)
    check_asymmetric(prof, v_max=v_max, a_max=a_max, d_max=d_max, v_start_max=abs(v0))
    slow = plan_trapezoid(0.0, dist, a_max=min(a_max, d_max), **kw).duration
    fast = plan_trapezoid(0.0, dist, a_max=max(a_max, d_max), **kw).duration
    # Durations are resolved only where a*t^2/2 is a normal float: below that (a subnormal
    # distance) a plan may hold or take ~1e-162 s, and neither is wrong. And only to a few
    # ulps of the ramp time v_max/a: a zero distance at v0 = v1 = v_max takes 0 s in one plan
    # and 5.4e-16 s (rounding of the ramp arithmetic) in another.
    a_min = min(a_max, d_max)
    t_subnormal = math.sqrt(4.0 * sys.float_info.min / a_min)
    t_res = t_subnormal + 16 * sys.float_info.epsilon * v_max / a_min
    if abs(v0) <= v_max:
        assert fast * (1 - 1e-9) - t_res <= prof.duration <= slow * (1 + 1e-9) + t_res


def test_subnormal_limits_are_refused_with_a_value_error_not_a_crash():
    """A subnormal limit beside a huge distance: the phases overflow or cancel. That is a
    ValueError naming p1 (it was a ZeroDivisionError, then a profile 4.3 s long that
    jumped to its target), as for every other plan floating point cannot hold."""
    with pytest.raises(ValueError, match=r"^p1 = 3.4e\+173: cannot be planned"):
        plan_trapezoid(0.07, 3.4e173, v_max=6e-23, a_max=5e-324, v0=0.13, d_max=0.03)
    with pytest.raises(ValueError, match=r"^p1 = -1e\+308: cannot be planned"):
        plan_trapezoid(-1.6e-45, -1e308, v_max=1e-75, a_max=5e-324, d_max=0.02)
