import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.lookahead import LookaheadQueue, plan_path, plan_program, plan_segment

A = 10.0


def seed_limits(lengths, dirs, speeds, *, v_max, a_max, period, contour_error=None):
    """Seed 001's limits (1)-(5) at every inner junction, given the neighbours' speeds."""
    out = []
    for i in range(1, len(speeds) - 1):
        cos_a = float(np.dot(dirs[i - 1], dirs[i]))
        # The angle from atan2(|u1 x u2|, u1 . u2): accurate at every angle, unlike acos.
        u, w = dirs[i - 1], dirs[i]
        if len(u) == 2:
            sin_a = abs(float(u[0] * w[1] - u[1] * w[0]))
        else:
            sin_a = float(np.linalg.norm(np.cross(u, w))) if len(u) == 3 else 0.0
        alpha = math.atan2(sin_a, cos_a)
        limits = [
            math.sqrt(speeds[i - 1] ** 2 + 2 * a_max * lengths[i - 1]),  # (1) forward
            math.sqrt(speeds[i + 1] ** 2 + 2 * a_max * lengths[i]),  # (3) backward
            v_max,  # (4)
        ]
        if len(dirs[0]) == 1:
            limits.append(math.inf if cos_a > 0 else 0.0)
        elif alpha > 0.0:
            limits.append(a_max * period / (2 * math.sin(alpha / 2)))  # (2) corner
            if contour_error is not None:
                limits.append(2 * contour_error / (period * math.tan(alpha / 2)))  # (5)
        out.append(min(limits))
    return out


def geometry(points):
    pts = np.asarray(points, dtype=float)
    d = np.diff(pts, axis=0)
    lengths = np.linalg.norm(d, axis=1)
    return lengths, d / lengths[:, None]


def check_plan(plan, *, v_max, a_max):
    """Speed continuous at junctions, limits respected, path followed, ends at the end."""
    segs = plan.segments
    for k, seg in enumerate(segs):
        prof = seg.profile
        assert prof.case in {"1", "2", "3", "4", "5", "6", "7"}
        assert prof.v0 == pytest.approx(plan.speeds[k]) and prof.v1 == pytest.approx(
            plan.speeds[k + 1]
        )
        t = np.linspace(0.0, prof.duration, 201)
        s, ds, dds = prof.at(t)
        assert np.all(ds >= -1e-9 * v_max) and np.all(ds <= v_max * (1 + 1e-9))
        assert np.all(np.abs(dds) <= a_max * (1 + 1e-9))
        assert s[-1] == pytest.approx(seg.length, rel=1e-9, abs=1e-12)
        if k:
            assert seg.t_start == pytest.approx(segs[k - 1].t_end, rel=1e-12)
            np.testing.assert_allclose(
                seg.start,
                segs[k - 1].start + segs[k - 1].direction * segs[k - 1].length,
                atol=1e-9 * max(1.0, seg.length),
            )
    assert plan.speeds[0] == 0.0 and plan.speeds[-1] == 0.0
    p_end, v_end, _ = plan.at(plan.duration + 1.0)
    np.testing.assert_array_equal(p_end, plan.end)
    assert np.all(v_end == 0.0)


points_2d = st.lists(
    st.tuples(st.floats(-100, 100), st.floats(-100, 100)), min_size=2, max_size=12
).filter(lambda pts: all(math.dist(a, b) > 1e-6 for a, b in zip(pts, pts[1:], strict=False)))


@settings(settings.get_profile("planner"))
@given(points=points_2d, v_max=st.floats(0.5, 50.0), period=st.floats(1e-3, 0.1))
def test_property_junction_speeds_are_the_seed_minimum(points, v_max, period):
    plan = plan_path(points, v_max=v_max, a_max=A, period=period, contour_error=0.05)
    lengths, dirs = geometry(points)
    expected = seed_limits(
        lengths, dirs, plan.speeds, v_max=v_max, a_max=A, period=period, contour_error=0.05
    )
    # Each inner speed equals the minimum of the seed's limits with its neighbours final.
    np.testing.assert_allclose(plan.speeds[1:-1], expected, rtol=1e-12, atol=1e-12)
    # l >= l_i on every segment, by construction: planning never refuses a segment.
    for k, length in enumerate(lengths):
        l_i = abs(plan.speeds[k + 1] ** 2 - plan.speeds[k] ** 2) / (2 * A)
        assert length >= l_i * (1 - 1e-9) - 8 * math.ulp(max(plan.speeds) ** 2) / (2 * A)
    check_plan(plan, v_max=v_max, a_max=A)


def test_three_dimensional_path():
    pts = [[0, 0, 0], [10, 0, 0], [10, 10, 0], [10, 10, 10], [0, 0, 0]]
    plan = plan_path(pts, v_max=5.0, a_max=A, period=0.01)
    check_plan(plan, v_max=5.0, a_max=A)
    # A right angle: 2 V sin(45 deg) <= a T.
    assert plan.speeds[1] == pytest.approx(A * 0.01 / (2 * math.sin(math.pi / 4)))
    p, v, a = plan.at(np.linspace(-1.0, plan.duration + 1.0, 500))
    assert p.shape == v.shape == a.shape == (500, 3)
    np.testing.assert_array_equal(p[0], [0, 0, 0])


def test_straight_waypoints_pass_at_full_speed():
    pts = [[0.0, 0.0], [50.0, 0.0], [100.0, 0.0], [150.0, 0.0]]
    plan = plan_path(pts, v_max=5.0, a_max=A, period=0.01)
    assert plan.speeds == (0.0, 5.0, 5.0, 0.0)
    # Same duration as one trapezoid over the whole line.
    assert plan.duration == pytest.approx(150.0 / 5.0 + 5.0 / A)


def test_one_dimensional_program_stops_only_at_reversals():
    plan = plan_program([0.0, 100.0, 200.0, 50.0, 50.0, 300.0], v_max=990.0, a_max=148.0)
    # Repeated 50 dropped; reversal at 200 and at 50 -> 0; 100 passed at speed.
    assert len(plan.segments) == 4
    assert plan.speeds[1] > 100.0
    assert plan.speeds[2] == 0.0 and plan.speeds[3] == 0.0
    t = np.linspace(0.0, plan.duration, 20001)
    p, v, _ = plan.at(t)
    assert p.shape == (20001, 1)
    # The 1-D velocity is continuous: no jumps larger than a_max * dt.
    assert np.max(np.abs(np.diff(v[:, 0]))) <= 148.0 * (t[1] - t[0]) * (1 + 1e-6)
    assert p[-1, 0] == pytest.approx(300.0)


def test_seed001_seven_cases():
    v_m, a = 10.0, 2.0
    cases = {
        "1": ((8.0**2 - 2.0**2) / (2 * a), 2.0, 8.0),
        "2": ((8.0**2 - 2.0**2) / (2 * a), 8.0, 2.0),
        "3": (20.0, 2.0, 8.0),
        "4": (20.0, 8.0, 2.0),
        "5": (100.0, 2.0, v_m),
        "6": (100.0, 2.0, 3.0),
        "7": (10.0, 0.0, 0.0),
    }
    for case, (length, v_b, v_e) in cases.items():
        prof = plan_segment(length, v_b, v_e, v_m, a, optimal=False)
        assert prof.case == case
        assert prof.at(0.0)[1] == v_b and prof.at(prof.duration)[:2] == (length, v_e)
        t = np.linspace(0.0, prof.duration, 1001)
        s, ds, dds = prof.at(t)
        assert np.all(ds <= v_m * (1 + 1e-12)) and np.all(np.abs(dds) <= a * (1 + 1e-12))
    # Case 4 is "cruise, then decelerate" (so a stop is at the very end), case 3 the mirror.
    seed = {"optimal": False}
    assert [ph[2] for ph in plan_segment(20.0, 8.0, 2.0, v_m, a, **seed).phases] == [0.0, -a]
    assert [ph[2] for ph in plan_segment(20.0, 2.0, 8.0, v_m, a, **seed).phases] == [a, 0.0]
    # Equal non-zero speeds and too short to reach v_m: a cruise.
    assert plan_segment(5.0, 3.0, 3.0, v_m, a, **seed).duration == pytest.approx(5.0 / 3.0)


def test_default_segments_are_time_optimal_case_7_for_any_end_speeds():
    v_m, a = 10.0, 2.0
    for length, v_b, v_e in [(20.0, 2.0, 8.0), (20.0, 8.0, 2.0), (10.0, 0.0, 0.0), (5.0, 3.0, 3.0)]:
        prof = plan_segment(length, v_b, v_e, v_m, a)
        assert prof.case == "7"
        assert [ph[2] for ph in prof.phases] == [a, -a]
        peak = math.sqrt(a * length + (v_b**2 + v_e**2) / 2)
        assert prof.duration == pytest.approx((2 * peak - v_b - v_e) / a, rel=1e-14)
        assert prof.at(prof.duration)[:2] == (length, v_e)
        # Seed's cases 3/4/7 plan the same segment, never faster.
        assert plan_segment(length, v_b, v_e, v_m, a, optimal=False).duration >= prof.duration
    # Cases 1, 2, 5 and 6 are already optimal: the same with either option.
    for length, v_b, v_e in [(15.0, 2.0, 8.0), (15.0, 8.0, 2.0), (100.0, 2.0, 10.0)]:
        fast = plan_segment(length, v_b, v_e, v_m, a)
        seed = plan_segment(length, v_b, v_e, v_m, a, optimal=False)
        assert (fast.case, fast.duration) == (seed.case, seed.duration)


def test_issue_14_lookahead_numbers():
    """The issue's figures: the default is the time-optimal plan; the seed's literal cases
    3-4 crawl along whole segments at the corner speed."""
    corner = {"v_max": 100, "a_max": 1, "period": 0.002}
    assert plan_path([[0, 0], [1, 0], [1, 1]], **corner).duration == pytest.approx(3.997, abs=1e-3)
    seed = plan_path([[0, 0], [1, 0], [1, 1]], **corner, optimal=False)
    assert seed.duration == pytest.approx(1414.2, abs=0.1)
    program = {"v_max": 990, "a_max": 148}
    assert plan_program([0, 100, 101, 0], **program).duration == pytest.approx(3.304, abs=1e-3)
    seed = plan_program([0, 100, 101, 0], **program, optimal=False)
    assert seed.duration == pytest.approx(7.639, abs=1e-3)


@pytest.mark.parametrize("alpha", [3e-7, 1e-5, 1e-3, 0.5, 2.0, math.pi - 1e-3, math.pi - 1e-7])
def test_corner_and_contour_caps_accurate_at_every_angle(alpha):
    """The caps from |u2 - u1| = 2 sin(alpha/2) and |u2 + u1| = 2 cos(alpha/2): within 1e-12
    of the exact limits, where cos(alpha) lost 0.04 % at a 3e-7 rad kink."""
    a_max, period, e = 1.0, 0.002, 0.01
    turn = [1.0 + 10.0 * math.cos(alpha), 10.0 * math.sin(alpha)]
    # The angle the stored points really make (their rounding), exactly by atan2.
    d2 = np.subtract(turn, [1.0, 0.0])
    alpha_true = math.atan2(d2[1], d2[0])
    for v_max in (1e9, 100.0):
        plan = plan_path([[0.0, 0.0], [1.0, 0.0], turn], v_max=v_max, a_max=a_max, period=period)
        corner = a_max * period / (2 * math.sin(alpha_true / 2))
        reach = math.sqrt(2 * a_max * 1.0)  # forward limit of the first segment
        assert plan.speeds[1] == pytest.approx(min(corner, reach, v_max), rel=1e-12)
        assert plan.speeds[1] <= corner * (1 + 1e-14)
    big = 1e20  # acceleration so high that only the contour limit binds
    plan = plan_path(
        [[0.0, 0.0], [1.0, 0.0], turn], v_max=big, a_max=big, period=period, contour_error=e
    )
    contour = 2 * e / (period * math.tan(alpha_true / 2))
    corner = big * period / (2 * math.sin(alpha_true / 2))
    reach = math.sqrt(2 * big * 1.0)
    assert plan.speeds[1] == pytest.approx(min(contour, corner, reach), rel=1e-12)


def test_near_hairpin_queue_equals_batch_and_does_not_crawl():
    """A near-reversal with a contour limit: the cap is tiny but exact, the segment after it
    is planned time-optimally, and streaming gives the batch plan (it gave 2.46e8 s)."""
    for eps in (0.0, 1e-12, 1e-9, 1e-6):
        pts = [[0.0, 0.0], [1.0, 0.0], [-2.0, 3.0 * eps]]
        kw = {"v_max": 10.0, "a_max": 1.0, "period": 0.002, "contour_error": 0.01}
        batch = plan_path(pts, **kw)
        q = LookaheadQueue(pts[0], **kw, window=1)
        released = []
        for p in pts[1:]:
            released += q.append(p)
        released += q.flush()
        assert sum(s.profile.duration for s in released) == pytest.approx(batch.duration)
        # Rest to rest over 1 and 3 units at a = 1, stopping (nearly) at the hairpin.
        assert batch.duration == pytest.approx(2.0 + 2.0 * math.sqrt(3.0), rel=1e-5)
        assert batch.speeds[1] <= 2 * 0.01 * eps / 0.002 * (1 + 1e-9) + 1e-300


def test_segment_shorter_than_l_i_is_refused():
    with pytest.raises(ValueError, match="look-ahead was wrong"):
        plan_segment(1.0, 0.0, 8.0, 10.0, 2.0)


def random_polyline(rng, n, dim):
    steps = rng.normal(size=(n, dim)) * rng.uniform(0.01, 20.0, size=(n, 1))
    return np.vstack([np.zeros(dim), np.cumsum(steps, axis=0)])


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_streaming_with_whole_path_window_equals_batch(dim):
    rng = np.random.default_rng(dim)
    for _ in range(20):
        pts = random_polyline(rng, 30, dim)
        batch = plan_path(pts, v_max=8.0, a_max=A, period=0.01)
        q = LookaheadQueue(pts[0], v_max=8.0, a_max=A, period=0.01, window=len(pts))
        released = []
        for p in pts[1:]:
            released += q.append(p)
            released += q.pop_ready()
        released += q.flush()
        assert len(released) == len(batch.segments)
        for mine, theirs in zip(released, batch.segments, strict=True):
            # Equal to rounding (directions are normalised one by one here, row-wise there).
            assert mine.profile.v0 == pytest.approx(theirs.profile.v0, rel=1e-12, abs=1e-15)
            assert mine.profile.v1 == pytest.approx(theirs.profile.v1, rel=1e-12, abs=1e-15)
            assert mine.profile.duration == pytest.approx(theirs.profile.duration, rel=1e-12)
            assert mine.t_start == pytest.approx(theirs.t_start, rel=1e-12)


def test_streaming_small_window_can_always_stop_and_is_never_faster():
    rng = np.random.default_rng(5)
    pts = random_polyline(rng, 200, 2) * 0.05  # many short segments: the window binds
    batch = plan_path(pts, v_max=8.0, a_max=A, period=0.01)
    q = LookaheadQueue(pts[0], v_max=8.0, a_max=A, period=0.01, window=4)
    released = []
    for p in pts[1:]:
        released += q.append(p)
        released += q.pop_ready()
        assert len(q) <= 4
        # Whatever is pending can always be planned to a stop (plan_segment refuses l < l_i).
        speeds = q._speeds()
        assert speeds[-1] == 0.0
        for k, (_, _, length, _, _) in enumerate(q._pending):
            plan_segment(length, speeds[k], speeds[k + 1], 8.0, A)
    released += q.flush()
    assert len(released) == len(batch.segments)
    for k, seg in enumerate(released):
        if k:
            assert seg.profile.v0 == released[k - 1].profile.v1  # continuous speed
        assert seg.profile.v1 <= batch.segments[k].profile.v1 * (1 + 1e-12) + 1e-12
    assert released[-1].profile.v1 == 0.0
    assert sum(s.profile.duration for s in released) >= batch.duration * (1 - 1e-12)


def test_bad_arguments():
    with pytest.raises(ValueError, match="period = 0.0"):
        plan_path([[0, 0], [1, 1]], v_max=1.0, a_max=1.0, period=0.0)
    with pytest.raises(ValueError, match="window = 0"):
        LookaheadQueue([0.0, 0.0], v_max=1.0, a_max=1.0, period=0.01, window=0)
    q = LookaheadQueue([0.0, 0.0], v_max=1.0, a_max=1.0, period=0.01)
    with pytest.raises(ValueError, match="point = "):
        q.append([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="points: must all be finite"):
        plan_path([[0, 0], [1, math.nan]], v_max=1.0, a_max=1.0, period=0.01)


def test_optimal_segments_are_never_slower_and_keep_the_junction_speeds():
    # Case 4 of the seed (cruise at v_b, then decelerate) is slower than rising first.
    seed = plan_segment(20.0, 8.0, 2.0, 10.0, 2.0, optimal=False)
    fast = plan_segment(20.0, 8.0, 2.0, 10.0, 2.0)
    assert seed.case == "4" and fast.duration < seed.duration
    assert fast.at(fast.duration)[:2] == (20.0, 2.0)
    rng = np.random.default_rng(9)
    for dim in (1, 2, 3):
        pts = random_polyline(rng, 25, dim)
        a = plan_path(pts, v_max=8.0, a_max=A, period=0.01, optimal=False)
        b = plan_path(pts, v_max=8.0, a_max=A, period=0.01)
        assert a.speeds == b.speeds
        for sa, sb in zip(a.segments, b.segments, strict=True):
            assert sb.profile.duration <= sa.profile.duration * (1 + 1e-12)
            t = np.linspace(0.0, sb.profile.duration, 201)
            s, ds, dds = sb.profile.at(t)
            assert np.all(ds >= -1e-9) and np.all(ds <= 8.0 * (1 + 1e-9))
            assert np.all(np.abs(dds) <= A * (1 + 1e-9))
            assert s[-1] == pytest.approx(sb.length)
        q = LookaheadQueue(pts[0], v_max=8.0, a_max=A, period=0.01, window=len(pts))
        for p in pts[1:]:
            q.append(p)
        released = q.flush()
        assert [s.profile.duration for s in released] == pytest.approx(
            [s.profile.duration for s in b.segments], rel=1e-12
        )


@settings(settings.get_profile("planner"))
@given(
    waypoints=st.lists(st.integers(-20, 20).map(float), min_size=2, max_size=15),
    v_max=st.floats(1.0, 100.0),
    a_max=st.floats(1.0, 100.0),
)
def test_property_program_stops_exactly_at_reversals(waypoints, v_max, a_max):
    plan = plan_program(waypoints, v_max=v_max, a_max=a_max)
    kept = [waypoints[0]]
    for w in waypoints[1:]:
        if w != kept[-1]:
            kept.append(w)
    assert len(plan.segments) == len(kept) - 1
    for i in range(1, len(kept) - 1):
        reverses = (kept[i] - kept[i - 1]) * (kept[i + 1] - kept[i]) < 0
        assert (plan.speeds[i] == 0.0) == reverses
    if len(kept) > 1:
        t = np.linspace(0.0, plan.duration, 4001)
        p, v, a = plan.at(t)
        assert np.all(np.abs(v) <= v_max * (1 + 1e-9)) and np.all(np.abs(a) <= a_max * (1 + 1e-9))
        # Continuous 1-D velocity: steps bounded by a_max dt.
        assert np.max(np.abs(np.diff(v[:, 0]))) <= a_max * (t[1] - t[0]) * (1 + 1e-6) + 1e-12
        assert p[-1, 0] == pytest.approx(kept[-1])


@settings(settings.get_profile("planner"))
@given(points=points_2d, window=st.integers(1, 6), v_max=st.floats(0.5, 50.0))
def test_property_streaming_window_is_valid_and_never_faster(points, window, v_max):
    batch = plan_path(points, v_max=v_max, a_max=A, period=0.01)
    q = LookaheadQueue(points[0], v_max=v_max, a_max=A, period=0.01, window=window)
    released = []
    for p in points[1:]:
        released += q.append(p)
        released += q.pop_ready()
        assert len(q) <= window
    released += q.flush()
    assert len(released) == len(batch.segments)
    speed = 0.0
    for mine, theirs in zip(released, batch.segments, strict=True):
        assert mine.profile.v0 == speed  # continuous across every release boundary
        assert mine.profile.v1 <= theirs.profile.v1 * (1 + 1e-12) + 1e-15
        speed = mine.profile.v1
    assert speed == 0.0


def test_streaming_per_segment_speed_limits_and_stops():
    """Each segment's own limit caps its cruise and both its junctions; a stop flag makes
    its end junction 0; preview() is what flush() releases, without releasing."""
    q = LookaheadQueue(0.0, v_max=100.0, a_max=1000.0, period=0.002, window=16)
    q.append(10.0, v_max=30.0)
    q.append(20.0, v_max=60.0, stop=True)
    q.append(40.0)
    preview = q.preview()
    assert len(q) == 3
    segs = q.flush()
    assert [s.profile.v1 for s in segs] == [p.v1 for p in preview]
    assert segs[0].profile.v1 == 30.0  # min(30, 60) at the first junction
    assert segs[1].profile.v1 == 0.0  # the stop
    for seg, v_lim in zip(segs, (30.0, 60.0, 100.0), strict=True):
        _, v, _ = seg.profile.at(np.linspace(0.0, seg.profile.duration, 200))
        assert v.max() <= v_lim + 1e-9
    assert segs[2].profile.p1 == 20.0
    with pytest.raises(ValueError, match="v_max"):
        q.append(50.0, v_max=float("nan"))
