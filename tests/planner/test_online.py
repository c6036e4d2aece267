import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner import OnlinePlanner

V_MAX, A_MAX, J_MAX = 990.0, 148.0, 500.0


def test_rest_before_any_command():
    op = OnlinePlanner()
    op.reset(12.0)
    assert op.sample(3.0) == (12.0, 0.0, 0.0)
    assert op.profile is None and not op.moving


def test_fig8_table1_sequence_replans_without_jumps():
    """Seed 000 Table 1: S_1 = 3e6 at 0 s, S_2 = -8e6 at 2 s, S_3 = -6e6 at 10 s,
    S_4 = -1e6 at 16 s (mdeg; here in deg), v_max 990, a_max 148."""
    op = OnlinePlanner("trapezoid")
    op.reset(0.0)
    dt = 0.002
    commands = {0: 3000.0, 1000: -8000.0, 5000: -6000.0, 8000: -1000.0}
    states_at_replan = {}
    prev = None
    for tick in range(15_000):
        t_s = tick * dt
        if tick in commands:
            states_at_replan[tick] = op.sample(t_s)
            op.command(t_s, commands[tick], v_max=V_MAX, a_max=A_MAX)
        p, v, a = op.sample(t_s)
        if prev is not None:
            # No velocity jump: |dv| <= a_max dt, |dp| <= v_max dt.
            assert abs(v - prev[1]) <= A_MAX * dt * (1 + 1e-9)
            assert abs(p - prev[0]) <= V_MAX * dt * (1 + 1e-9)
        prev = (p, v, a)
    # At 2 s it is accelerating from rest: v = 148 * 2 = 296 (the paper's 296).
    assert states_at_replan[1000][1] == pytest.approx(296.0)
    assert states_at_replan[1000][2] == pytest.approx(A_MAX)
    # At 10 s, 8 s after reversing from 296: 296 - 148 * 8 = -888, still accelerating
    # (the paper prints -990 cruising: its Table 1 is not consistent with a_max = 148).
    assert states_at_replan[5000][1] == pytest.approx(296.0 - 8 * A_MAX)
    # At 16 s it is moving towards -6000 (negative velocity); it ends at rest at -1000.
    assert states_at_replan[8000][1] < 0.0
    assert prev[0] == pytest.approx(-1000.0) and prev[1] == 0.0 and not op.moving


@pytest.mark.parametrize("kind", ["trapezoid", "scurve"])
def test_lower_v_max_while_cruising_brakes_to_it(kind):
    op = OnlinePlanner(kind)
    op.reset(0.0)
    op.command(0.0, 1e5, v_max=V_MAX, a_max=A_MAX, j_max=J_MAX)
    t_s = 20.0
    assert op.sample(t_s)[1] == pytest.approx(V_MAX)
    prof = op.command(t_s, 1e5, v_max=500.0, a_max=A_MAX, j_max=J_MAX)
    assert prof.at(0.0)[1] == pytest.approx(V_MAX)
    t = np.linspace(0.0, prof.duration, 20001)
    _, v, _ = prof.at(t)
    assert np.all(np.diff(v[v > 500.0]) <= 1e-9)  # only slows down until at v_max
    assert np.max(v[t > prof.duration / 2]) <= 500.0 * (1 + 1e-9)


@pytest.mark.parametrize("kind", ["trapezoid", "scurve"])
def test_stop_is_shortest_and_ends_at_rest(kind):
    op = OnlinePlanner(kind)
    op.reset(0.0)
    op.command(0.0, 1e5, v_max=V_MAX, a_max=A_MAX, j_max=J_MAX)
    p, v, a = op.sample(3.0)
    prof = op.stop(3.0, a_max=A_MAX, j_max=J_MAX)
    assert prof.at(0.0)[:2] == pytest.approx((p, v))
    if kind == "trapezoid":
        assert prof.duration == pytest.approx(v / A_MAX)
    else:
        assert prof.at(0.0)[2] == pytest.approx(a)
    assert op.sample(3.0 + prof.duration + 1.0) == (prof.p1, 0.0, 0.0)
    assert not op.moving


def test_moving_flag_follows_the_last_sample():
    op = OnlinePlanner()
    op.reset(0.0)
    prof = op.command(1.0, 10.0, v_max=10.0, a_max=10.0)
    op.sample(1.0 + prof.duration / 2)
    assert op.moving
    op.sample(1.0 + prof.duration)
    assert not op.moving


def test_bad_arguments():
    with pytest.raises(ValueError, match="kind = 'jerky'"):
        OnlinePlanner("jerky")
    op = OnlinePlanner("scurve")
    op.reset(0.0)
    with pytest.raises(ValueError, match="j_max = None"):
        op.command(0.0, 1.0, v_max=1.0, a_max=1.0)
    op.command(5.0, 1.0, v_max=1.0, a_max=1.0, j_max=1.0)
    with pytest.raises(ValueError, match="t_s = 4.0"):
        op.command(4.0, 1.0, v_max=1.0, a_max=1.0, j_max=1.0)
    with pytest.raises(ValueError, match="v_max = -1.0"):
        op.command(6.0, 1.0, v_max=-1.0, a_max=1.0, j_max=1.0)
    with pytest.raises(ValueError, match="target = inf"):
        op.command(6.0, math.inf, v_max=1.0, a_max=1.0, j_max=1.0)
    with pytest.raises(ValueError, match="p0 = nan"):
        op.reset(math.nan)


@settings(settings.get_profile("planner"))
@given(
    kind=st.sampled_from(["trapezoid", "scurve"]),
    targets=st.lists(st.floats(-5e3, 5e3), min_size=1, max_size=5),
    gaps=st.lists(st.floats(0.0, 8.0), min_size=5, max_size=5),
    scales=st.lists(st.floats(0.3, 1.0), min_size=5, max_size=5),
    v_max=st.floats(10.0, 1000.0),
    a_max=st.floats(10.0, 500.0),
    j_max=st.floats(10.0, 5000.0),
)
def test_property_replan_at_random_instants_is_continuous(
    kind, targets, gaps, scales, v_max, a_max, j_max
):
    """Random targets at random instants, each with limits lowered by a random factor
    (the start may then be above the new v_max or a_max): no jump, and the move ends."""
    op = OnlinePlanner(kind)
    op.reset(0.0)
    t_s = 0.0
    for target, gap, k in zip(targets, gaps, scales, strict=False):
        before = op.sample(t_s)
        prof = op.command(t_s, target, v_max=k * v_max, a_max=k * a_max, j_max=k * j_max)
        after = op.sample(t_s)
        scale = max(1.0, abs(before[0]))
        assert after[0] == pytest.approx(before[0], abs=1e-12 * scale)
        assert after[1] == pytest.approx(before[1], abs=1e-9 * v_max)
        if kind == "scurve":
            assert after[2] == pytest.approx(before[2], abs=1e-9 * a_max)
        assert prof.p1 == target
        # Within the new profile: |a| never above max(new a_max, |a at the replan|).
        t = np.linspace(0.0, prof.duration, 501)
        _, _, acc = prof.at(t)
        assert np.max(np.abs(acc)) <= max(k * a_max, abs(before[2])) * (1 + 1e-9)
        t_s += gap
    end = op.profile
    assert op.sample(t_s + end.duration + 1.0) == (end.p1, 0.0, 0.0)


@pytest.mark.parametrize(("first", "second"), [("trapezoid", "scurve"), ("scurve", "trapezoid")])
def test_switching_kind_while_moving_keeps_position_and_velocity(first, second, check):
    """A moving axis switches trapezoid <-> S-curve at a command: no jump in position or
    velocity; to the S-curve, no jump in acceleration either (it starts from the
    trapezoid's acceleration)."""
    op = OnlinePlanner(first)
    op.reset(0.0)
    op.command(0.0, 5000.0, v_max=V_MAX, a_max=A_MAX, j_max=J_MAX)
    for t_s in (0.5, 1.0, 3.0, 6.0):  # accelerating, accelerating, cruising, braking
        before = op.sample(t_s)
        assert op.moving
        prof = op.command(t_s, -2000.0, v_max=V_MAX, a_max=A_MAX, j_max=J_MAX, kind=second)
        assert op.kind == second and prof.kind == second
        after = op.sample(t_s)
        assert after[:2] == before[:2]
        if second == "scurve":
            assert after[2] == before[2]
            check(prof, v_max=V_MAX, a_max=A_MAX, j_max=J_MAX)
        else:
            check(prof, v_max=V_MAX, a_max=A_MAX)
        assert prof.p1 == -2000.0
        # Back for the next round.
        op.command(t_s, 5000.0, v_max=V_MAX, a_max=A_MAX, j_max=J_MAX, kind=first)


def test_bad_kind_or_missing_jerk_changes_nothing():
    op = OnlinePlanner("trapezoid")
    op.reset(0.0)
    prof = op.command(0.0, 100.0, v_max=V_MAX, a_max=A_MAX)
    with pytest.raises(ValueError, match="kind = 'sine'"):
        op.command(0.1, 0.0, v_max=V_MAX, a_max=A_MAX, kind="sine")
    with pytest.raises(ValueError, match="j_max = None"):
        op.command(0.1, 0.0, v_max=V_MAX, a_max=A_MAX, kind="scurve")
    with pytest.raises(ValueError, match="j_max = None"):
        op.stop(0.1, a_max=A_MAX, kind="scurve")
    assert op.kind == "trapezoid" and op.profile is prof


def test_deceleration_limit_reaches_the_planner():
    op = OnlinePlanner("trapezoid")
    op.reset(0.0)
    prof = op.command(0.0, 1000.0, v_max=100.0, a_max=50.0, d_max=25.0)
    assert [value for _, _, value in prof.phases] == [50.0, 0.0, -25.0]
    op = OnlinePlanner("scurve")
    op.reset(0.0)
    prof = op.command(0.0, 1000.0, v_max=100.0, a_max=50.0, d_max=25.0, j_max=J_MAX)
    _, _, acc = prof.at(np.linspace(0.0, prof.duration, 2001))
    assert acc.max() == pytest.approx(50.0) and acc.min() == pytest.approx(-25.0)
