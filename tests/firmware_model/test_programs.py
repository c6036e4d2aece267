"""The board's motion-program queue (issue #14 §1, docs/protocol.md section 4.5): blocks
with look-ahead over the UART, flow control, underrun, feed hold/resume, abort, override,
and the queue's properties (always able to stop, never beyond travel, the batch plan's
junction speeds when the queue holds the whole program)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_model.programs import QUEUE_CAPACITY, ProgramQueue
from planner.lookahead import plan_program
from serial_protocol.messages import (
    Move,
    Nack,
    NackCode,
    Profile,
    QueueAction,
    QueueControl,
    QueueSegment,
    QueueState,
    QueueStatus,
)

A = 2000.0  # the default Limits.a_max_dps2
DT = 0.002


def blocks(*rows):
    return [QueueSegment(i + 1, *row) for i, row in enumerate(rows)]


def test_a_program_passes_same_direction_junctions_at_speed_and_stops_at_reversals(make_bench):
    b = make_bench()
    prog = [(10.0, 30.0, 0.0), (20.0, 60.0, 0.0), (40.0, 60.0, 0.2), (30.0, 20.0, 0.0),
            (0.0, 60.0, 0.0)]  # fmt: skip
    b.run(1400, {5: blocks(*prog)})
    st_ = b.replies(QueueStatus)
    assert [s.free_slots for s in st_] == [QUEUE_CAPACITY - k for k in range(1, 6)]
    assert [s.queued for s in st_] == [1, 2, 3, 4, 5]
    sp, v = b.arr("sp_pos_deg"), b.arr("sp_vel_dps")
    # junction at 10 deg (30 -> 60 deg/s, same direction): passed at 30 deg/s, not stopped
    k10 = int(np.argmax(sp >= 10.0))  # the first tick past the junction
    assert 30.0 <= v[k10] <= 30.0 + A * DT
    k20 = int(np.argmax(sp >= 20.0))
    assert abs(v[k20] - 60.0) < 1e-6
    # the dwell at 40 deg: at rest for 0.2 s (100 ticks) at the reversal
    at40 = np.flatnonzero(np.abs(sp - 40.0) < 1e-9)
    assert len(at40) >= 100 and np.all(v[at40] == 0.0)
    # 40 -> 30 -> 0: the reversal-free junction at 30 deg is passed moving (20 deg/s limit)
    k30 = len(sp) - int(np.argmax(sp[::-1] >= 30.0)) - 1
    assert v[k30] < -19.0
    assert sp.max() <= 40.0 + 1e-9 and sp.min() >= -1e-9  # never beyond a target
    assert sp[-1] == 0.0 and v[-1] == 0.0
    done = b.fw.queue_status()
    assert (done.state, done.queued, done.done) == (QueueState.EMPTY, 0, 5)
    assert abs(b.arr("pos_deg")[-1]) < 0.05  # the axis followed


def test_junction_speeds_equal_the_batch_plan_when_the_queue_holds_the_whole_program(make_bench):
    b = make_bench()
    waypoints = [0.0, 5.0, 12.0, 30.0, 31.0, 20.0, 8.0, 9.0, 15.0]
    prog = [(w, 90.0, 0.0) for w in waypoints[1:]]
    b.run(10, {5: blocks(*prog)})
    fw = b.fw
    planner = fw._planners["trapezoid"]
    profile, t0 = planner.profile, planner.t_start_s
    plan = plan_program(waypoints, v_max=90.0, a_max=A)
    assert math.isclose(profile.duration, plan.duration, rel_tol=1e-12)
    t = np.linspace(0.0, plan.duration, 2001)
    p_b, v_b, _ = profile.at(t)
    p_ref, v_ref, _ = plan.at(t)
    assert np.allclose(p_b, p_ref[:, 0], atol=1e-9) and np.allclose(v_b, v_ref[:, 0], atol=1e-9)
    # the junction speeds, planned and executed (the setpoint the board followed)
    starts = [seg.t_start for seg in plan.segments[1:]]
    _, v_j, _ = profile.at(np.array(starts))
    assert np.allclose(np.abs(v_j), plan.speeds[1:-1], atol=1e-9)
    assert t0 == 5 * DT
    b.run(int(plan.duration / DT) + 20)
    v_run = b.arr("sp_vel_dps")
    for ts, vj in zip(starts, plan.speeds[1:-1], strict=True):
        k = round(ts / DT) + 5
        assert abs(abs(v_run[k]) - vj) <= A * DT + 1e-9  # within one tick's acceleration


def test_an_underrun_decelerates_to_rest_at_the_last_block_never_beyond(make_bench):
    b = make_bench()
    # blocks trickle in slower than they run: each time the queue runs dry the axis stops
    # at the last target, then goes on when the next block comes
    script = {5 + 150 * k: [QueueSegment(k + 1, 5.0 * (k + 1), 200.0)] for k in range(4)}
    b.run(900, script)
    sp, v = b.arr("sp_pos_deg"), b.arr("sp_vel_dps")
    for k in range(4):
        before_next = 5 + 150 * (k + 1) - 1
        seg = sp[5 + 150 * k : before_next + 1]
        assert seg.max() <= 5.0 * (k + 1) + 1e-9  # never beyond what it held
        if k < 3:
            assert sp[before_next] == 5.0 * (k + 1) and v[before_next] == 0.0
    assert not b.replies(Nack)


def test_appending_to_a_running_program_raises_a_junction_without_a_jump(make_bench):
    b = make_bench()
    b.run(120, {5: [QueueSegment(1, 20.0, 100.0)], 60: [QueueSegment(2, 40.0, 100.0)]})
    sp, v = b.arr("sp_pos_deg"), b.arr("sp_vel_dps")
    assert np.max(np.abs(np.diff(sp))) <= 100.0 * DT + 1e-9  # no position jump
    assert np.max(np.abs(np.diff(v))) <= A * DT + 1e-9  # no velocity jump
    b.run(400)
    sp, v = b.arr("sp_pos_deg"), b.arr("sp_vel_dps")
    k20 = int(np.argmax(sp >= 20.0))
    assert v[k20] > 50.0  # the second block came in time: 20 deg passed moving
    assert sp[-1] == 40.0


def test_the_queue_holds_its_capacity_and_refuses_one_more_changing_nothing(make_bench):
    b = make_bench()
    prog = blocks(*[(float(k + 1), 10.0, 0.0) for k in range(QUEUE_CAPACITY + 1)])
    # 8 frames a tick (the receive ring holds 256 bytes a tick)
    b.run(20, {5 + k: prog[8 * k : 8 * k + 8] for k in range(5)})
    st_ = b.replies(QueueStatus)
    assert len(st_) == QUEUE_CAPACITY and st_[-1].free_slots == 0
    [nack] = b.replies(Nack)
    assert (nack.code, nack.limit) == (NackCode.QUEUE_FULL, float(QUEUE_CAPACITY))
    assert b.fw._target_deg == float(QUEUE_CAPACITY)


def test_feed_hold_stops_on_the_path_and_resume_finishes_the_program(make_bench):
    b = make_bench()
    prog = [(10.0, 100.0, 0.0), (20.0, 100.0, 0.0), (30.0, 100.0, 0.0)]
    b.run(300, {5: blocks(*prog), 60: [QueueControl(9, QueueAction.HOLD)]})
    sp, v = b.arr("sp_pos_deg"), b.arr("sp_vel_dps")
    assert v[-1] == 0.0 and 0.0 < sp[-1] < 30.0
    held = b.replies(QueueStatus)[-1]
    assert held.state == QueueState.HELD and held.queued >= 1
    stop_at = sp[-1]
    b.run(400, {300: [QueueControl(10, QueueAction.RESUME)]})
    sp = b.arr("sp_pos_deg")
    assert np.all(sp[:300] <= stop_at + 1e-9)
    assert sp[-1] == 30.0
    assert b.fw.queue_status().done == 3


def test_resume_while_braking_is_busy_and_abort_empties_the_queue(make_bench):
    b = make_bench()
    prog = [(50.0, 200.0, 0.0), (80.0, 200.0, 0.0)]
    b.run(200, {5: blocks(*prog), 60: [QueueControl(9, QueueAction.HOLD),
                                        QueueControl(10, QueueAction.RESUME)],
                100: [QueueControl(11, QueueAction.ABORT)]})  # fmt: skip
    [nack] = b.replies(Nack)
    assert (nack.cmd_id, nack.code) == (10, NackCode.BUSY)
    last = b.replies(QueueStatus)[-1]
    assert (last.cmd_id, last.state, last.queued) == (11, QueueState.EMPTY, 0)
    assert b.arr("sp_vel_dps")[-1] == 0.0 and b.arr("sp_pos_deg")[-1] < 50.0


def test_a_move_ends_a_program_and_abort_stops_a_running_one(make_bench):
    b = make_bench()
    b.run(150, {5: blocks((40.0, 100.0, 0.0)), 40: [Move(9, -5.0, 100.0, A)]})
    assert b.fw.queue_status().state == QueueState.EMPTY
    assert b.arr("sp_pos_deg")[-1] < 40.0


def test_the_speed_override_scales_the_blocks_not_yet_entered(make_bench):
    b = make_bench()
    b.run(400, {5: [QueueControl(9, QueueAction.OVERRIDE, 50.0), *blocks((20.0, 100.0, 0.0))]})
    assert abs(b.arr("sp_vel_dps").max() - 50.0) < 1e-9  # 50 % of 100 deg/s
    assert b.replies(QueueStatus)[-1].override_pct == 50.0
    # while running: the block in progress is replanned from the commanded state, the
    # blocks after it too
    b = make_bench()
    prog = [(5.0, 100.0, 0.0), (30.0, 100.0, 0.0), (60.0, 100.0, 0.0)]
    b.run(900, {5: blocks(*prog), 8: [QueueControl(9, QueueAction.OVERRIDE, 50.0)]})
    sp, v = b.arr("sp_pos_deg"), b.arr("sp_vel_dps")
    assert v[8] < 50.0 and v.max() <= 50.0 + 1e-9 and sp[-1] == 60.0


def test_switching_the_profile_kind_while_moving_replans_without_a_jump(make_bench):
    # OnlinePlanner.command(kind=...) on the board: a trapezoid move interrupted by an
    # S-curve move (and back) is accepted, from the commanded state
    b = make_bench()
    b.run(300, {
        5: [Move(1, 60.0, 200.0, A)],
        40: [Move(2, 30.0, 200.0, A, 1e5, Profile.SCURVE)],
        80: [Move(3, 50.0, 200.0, A)],
    })  # fmt: skip
    assert not b.replies(Nack)
    sp, v = b.arr("sp_pos_deg"), b.arr("sp_vel_dps")
    assert np.max(np.abs(np.diff(sp))) <= 200.0 * DT + 1e-9
    assert np.max(np.abs(np.diff(v))) <= A * DT * (1 + 1e-9)
    assert sp[-1] == 50.0


# ------------------------------------------------------------------ properties of the queue


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(-50.0, 50.0).map(lambda x: round(x, 2)),
            st.floats(5.0, 300.0),
            st.sampled_from([0.0, 0.0, 0.0, 0.05]),
            st.integers(0, 60),  # ticks until the next append
        ),
        min_size=1,
        max_size=24,
    )
)
def test_the_queue_can_always_stop_and_never_leaves_its_targets(rows):
    """Whatever arrives when: each plan ends at rest at the last target held, stays within
    the targets' span, joins the previous plan without a jump in position or velocity, and
    keeps |v| and |a| within the limits."""
    q = ProgramQueue(QUEUE_CAPACITY, DT)
    t_s = 0.0
    lo = hi = 0.0
    old = None
    for target, v_max, dwell, wait in rows:
        before = None if old is None else old[0].at(t_s - old[1])
        here = 0.0 if before is None else float(before[0])  # the board passes its setpoint
        prof = q.append(t_s, here, target, v_max, dwell, v_limit_dps=300.0, a_max_dps2=A)
        t0 = q.t_start_s
        lo, hi = min(lo, target), max(hi, target)
        assert prof.p1 == target and prof.v1 == 0.0  # always able to stop, at the last one
        ts = np.linspace(0.0, prof.duration, 400)
        p, v, a = prof.at(ts)
        assert p.min() >= lo - 1e-9 and p.max() <= hi + 1e-9
        assert np.abs(v).max() <= 300.0 * (1 + 1e-9) and np.abs(a).max() <= A * (1 + 1e-9)
        if before is not None:
            now = prof.at(t_s - t0)
            assert abs(now[0] - before[0]) < 1e-9 and abs(now[1] - before[1]) < 1e-6
        old = (prof, t0)
        t_s += wait * DT


def _distinct_steps(rows):
    """Keep the blocks that move (a block to where the path already is is a dwell)."""
    out, p = [], 0.0
    for target, v_max, dwell in rows:
        if abs(target - p) > 1e-6:
            out.append((target, v_max, dwell))
            p = target
    return out


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(-80.0, 80.0).map(lambda x: round(x, 3)),
            st.floats(2.0, 300.0),
            st.sampled_from([0.0, 0.0, 0.0, 0.1]),
        ),
        min_size=1,
        max_size=QUEUE_CAPACITY,
    )
    .map(_distinct_steps)
    .filter(bool)
)
def test_junction_speeds_equal_the_batch_plan_with_speed_limits_and_dwells(rows):
    """A whole program appended at once (the queue holds all of it): the board's profile
    has the batch look-ahead's junction speeds and duration (planner.lookahead with the
    window holding the whole path: the PC-side plan), block by block."""
    from planner.lookahead import LookaheadQueue

    q = ProgramQueue(QUEUE_CAPACITY, DT)
    for target, v_max, dwell in rows:
        prof = q.append(0.0, 0.0, target, v_max, dwell, v_limit_dps=300.0, a_max_dps2=A)
    la = LookaheadQueue(0.0, v_max=300.0, a_max=A, period=DT, window=QUEUE_CAPACITY)
    for target, v_max, dwell in rows:
        la.append(target, v_max=v_max, stop=dwell > 0.0)
    segs = la.flush()
    assert len(segs) == len(rows)
    t = 0.0
    for seg, (_, _, dwell) in zip(segs, rows, strict=True):
        _, v_board, _ = prof.at(t)  # where the block starts: the junction speed
        assert abs(abs(v_board) - abs(seg.profile.v0)) < 1e-9
        t += seg.profile.duration
        t += dwell
    assert prof.p1 == rows[-1][0] and prof.v1 == 0.0
    assert math.isclose(prof.duration, t, rel_tol=1e-12, abs_tol=1e-12)
