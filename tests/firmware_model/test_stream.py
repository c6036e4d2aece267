"""Fixed-period streaming (issue #14 §1, seed 002; docs/protocol.md section 4.6) and jog, on
the board: seed 002's Tables 1 and 2 from streamed points (LINEAR and CUBIC), underrun,
END, field-level refusals; a jog's acceleration, Stop, timeout and travel end."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_model.params import FirmwareParams, LimitsParams
from firmware_model.safety import profile_extent
from firmware_model.stream import STREAM_CAPACITY, PointStream
from planner import sample_fixed_period, scurve_from_periods, trapezoid_from_periods
from serial_protocol.messages import (
    STREAM_POINTS_PER_FRAME,
    Ack,
    BoardHeartbeat,
    Interp,
    Jog,
    Nack,
    NackCode,
    Stop,
    StreamAction,
    StreamControl,
    StreamPoints,
    StreamState,
    StreamStatus,
)

DT = 0.002
PER = STREAM_POINTS_PER_FRAME
H = 0.15  # seed 002's period
TICKS_PER_ROW = 75


def stream_script(points, *, interp, period_s=H, prefill=4, end=True, start_tick=5):
    """One frame per tick from ``start_tick``: START, the points 5 to a frame, END."""
    msgs = [StreamControl(1, StreamAction.START, interp, period_s, prefill)]
    for k in range(0, len(points), PER):
        chunk = points[k : k + PER]
        msgs.append(StreamPoints.of(10 + k, k + 1, [p for p, _ in chunk], [v for _, v in chunk]))
    if end:
        msgs.append(StreamControl(2, StreamAction.END))
    return {start_tick + i: [m] for i, m in enumerate(msgs)}


def table_samples(table: int):
    if table == 1:
        prof = trapezoid_from_periods(120.0, 50.0, H, n_acc=4)
    else:
        prof = scurve_from_periods(120.0, 50.0, H, n_jerk=3, n_const=3)
    return sample_fixed_period(prof, H)


def rows_of(b, n_rows):
    """The setpoint and the position at the stream's point times (from the board's t0)."""
    k0 = round(b.fw.stream.t0_s / DT)
    idx = k0 + TICKS_PER_ROW * np.arange(n_rows)
    return b.arr("sp_pos_deg")[idx], b.arr("sp_vel_dps")[idx], b.arr("pos_deg")[idx]


@pytest.mark.parametrize("table", [1, 2])
def test_seed002_tables_from_streamed_pvt_points(make_bench, table):
    """CUBIC (PVT) points every 150 ms: the board's setpoint at every row is the table's
    position and velocity (the cubic through two samples of a profile that is at most cubic
    within each period is that profile); the axis follows."""
    s = table_samples(table)
    b = make_bench()
    pts = list(zip(s.p[1:], s.v[1:], strict=True))
    b.run(len(s.p) * TICKS_PER_ROW + 400, stream_script(pts, interp=Interp.CUBIC))
    assert not b.replies(Nack)
    sp, v, pos = rows_of(b, len(s.p))
    assert np.max(np.abs(sp - s.p)) < 1e-4  # the wire's position step
    assert np.max(np.abs(v - s.v)) < 1e-4
    assert np.max(np.abs(pos - s.p)) < 0.1
    # between the rows too: the setpoint is the profile sampled every tick
    t = np.arange(len(s.p) * TICKS_PER_ROW - TICKS_PER_ROW) * DT
    k0 = round(b.fw.stream.t0_s / DT)
    prof = trapezoid_from_periods(120.0, 50.0, H, n_acc=4) if table == 1 else (
        scurve_from_periods(120.0, 50.0, H, n_jerk=3, n_const=3))  # fmt: skip
    p_ref, _, _ = prof.at(t)
    assert np.max(np.abs(b.arr("sp_pos_deg")[k0 : k0 + len(t)] - p_ref)) < 1e-4
    assert b.fw.stream_status().state is StreamState.IDLE  # ended and at rest
    assert b.arr("sp_vel_dps")[-1] == 0.0


def test_seed002_table1_from_streamed_linear_points(make_bench):
    """LINEAR: positions hit the rows; the velocity between two rows is their mean."""
    s = table_samples(1)
    b = make_bench()
    pts = [(p, 0.0) for p in s.p[1:]]
    b.run(len(s.p) * TICKS_PER_ROW + 400, stream_script(pts, interp=Interp.LINEAR))
    assert not b.replies(Nack)
    sp, _, _ = rows_of(b, len(s.p))
    assert np.max(np.abs(sp - s.p)) < 1e-4
    k0 = round(b.fw.stream.t0_s / DT)
    mid = k0 + TICKS_PER_ROW * np.arange(len(s.p) - 1) + TICKS_PER_ROW // 2
    assert np.max(np.abs(b.arr("sp_vel_dps")[mid] - np.diff(s.p) / H)) < 1e-3
    assert b.arr("sp_vel_dps")[-1] == 0.0


def test_an_underrun_decelerates_to_rest_at_a_max_and_is_flagged(make_bench):
    b = make_bench()
    a_max = b.fw.a_max_dps2
    # 0, 1, 2, 3 deg every 0.1 s (10 deg/s) and then nothing: no END
    pts = [(float(k), 0.0) for k in range(1, 4)]
    script = stream_script(pts, interp=Interp.LINEAR, period_s=0.1, prefill=3, end=False)
    script[400] = [StreamPoints.of(50, 4, [4.0])]  # too late: the stream ran dry
    b.run(600, script)
    sp, v = b.arr("sp_pos_deg"), b.arr("sp_vel_dps")
    k0 = round(b.fw.stream.t0_s / DT)
    k_last = k0 + 150  # point 3 at 0.3 s
    assert abs(sp[k_last] - 3.0) < 1e-6 and v[k_last - 1] == pytest.approx(10.0)
    # the stop: 10 deg/s at a_max, 5 ms, 0.025 deg past the last point
    assert sp.max() == pytest.approx(3.0 + 10.0**2 / (2 * a_max), abs=1e-9)
    assert np.all(np.abs(np.diff(v[k_last:])) <= a_max * DT + 1e-9)
    assert v[-1] == 0.0
    late = [r for r in b.replies(Nack) if r.cmd_id == 50]
    assert late and late[0].code is NackCode.NO_STREAM
    st = b.fw.stream_status()
    assert (st.state, st.underruns, st.free_slots) == (StreamState.UNDERRUN, 1, 0)
    hb = b.replies(BoardHeartbeat)[-1]
    assert (hb.stream_state, hb.stream_underruns) == (StreamState.UNDERRUN, 1)
    # a new stream may start once at rest; the counter stays
    b.run(5, {b.fw.tick: [StreamControl(60, StreamAction.START, Interp.LINEAR, 0.01, 1)]})
    assert b.fw.stream_status().state is StreamState.FILLING
    assert b.fw.stream_status().underruns == 1


def test_stream_refusals_name_the_field_and_take_nothing(make_bench):
    b = make_bench()
    v_max, a_max = b.fw.v_max_dps, b.fw.a_max_dps2
    h = 0.01
    script = {
        5: [StreamControl(1, StreamAction.START, Interp.LINEAR, 0.001, 1)],  # period too short
        6: [StreamControl(2, StreamAction.START, Interp.LINEAR, h, 0)],  # prefill 0
        7: [StreamPoints.of(3, 1, [1.0])],  # no stream
        8: [StreamControl(4, StreamAction.START, Interp.LINEAR, h, 2)],
        9: [StreamPoints.of(5, 2, [1.0])],  # skips point 1
        10: [StreamPoints.of(6, 1, [0.01, 0.02, v_max * h * 2])],  # point 3 too fast
        11: [StreamPoints.of(7, 1, [0.0, a_max * h * h * 2])],  # velocity step > a_max h
    }
    b.run(20, script)
    nacks = {n.cmd_id: n for n in b.replies(Nack)}
    from serial_protocol.frame import field_name

    def said(cmd_id):
        n = nacks[cmd_id]
        return n.code, field_name(n.msg_type, n.field), n.limit

    assert said(1) == (NackCode.TOO_LOW, "period_s", pytest.approx(0.002))
    assert said(2)[:2] == (NackCode.TOO_LOW, "prefill")
    assert said(3)[:2] == (NackCode.NO_STREAM, None)
    assert said(5) == (NackCode.TOO_HIGH, "first_index", 1.0)
    code, field, limit = said(6)
    assert (code, field) == (NackCode.TOO_HIGH, "pos2_deg")
    assert limit == pytest.approx(0.02 + min(v_max, 1.0 + a_max * h) * h, rel=1e-3)
    assert said(7)[:2] == (NackCode.TOO_HIGH, "pos1_deg")
    st = b.fw.stream_status()
    assert (st.state, st.next_index, st.free_slots) == (StreamState.FILLING, 1, STREAM_CAPACITY)
    assert b.fw.sp_vel_dps == 0.0


def test_points_and_their_stop_stay_within_the_travel(make_bench):
    params = FirmwareParams(limits=LimitsParams(travel_min_deg=-1.0, travel_max_deg=1.0))
    b = make_bench(params)
    script = {
        5: [StreamControl(1, StreamAction.START, Interp.LINEAR, 1.0, 8)],
        6: [StreamPoints.of(2, 1, [0.5, 1.5])],  # a point beyond the travel
        # 0.9999 deg/s at the last point: its stop at a_max would end past 1.0 deg
        7: [StreamPoints.of(3, 1, [0.9999])],
        8: [StreamPoints.of(4, 1, [0.9999, 0.9999])],  # at rest there: accepted
    }
    b.run(10, script)
    nacks = {n.cmd_id: n for n in b.replies(Nack)}
    from serial_protocol.frame import field_name

    assert (nacks[2].code, field_name(nacks[2].msg_type, nacks[2].field), nacks[2].limit) == (
        NackCode.TOO_HIGH, "pos1_deg", 1.0)  # fmt: skip
    assert (nacks[3].code, field_name(nacks[3].msg_type, nacks[3].field), nacks[3].limit) == (
        NackCode.TRAVEL, "pos0_deg", 1.0)  # fmt: skip
    assert 4 not in nacks and b.fw.stream_status().next_index == 3


def test_cubic_refusals_and_a_full_buffer(make_bench):
    b = make_bench()
    v_max = b.fw.v_max_dps
    h = 0.002
    full = [StreamPoints.of(100 + k, 1 + PER * k, [0.0] * PER)
            for k in range(STREAM_CAPACITY // PER)]  # fmt: skip
    script = {
        5: [StreamControl(1, StreamAction.START, Interp.CUBIC, h, STREAM_CAPACITY)],
        6: [StreamPoints.of(2, 1, [0.0], [v_max * 1.01])],  # too fast a point
        7: [StreamPoints.of(3, 1, [0.0], [float("nan")])],
        8: [StreamPoints.of(4, 1, [0.1], [0.0])],  # 0.1 deg in 2 ms from rest: a > a_max
    }
    for k, m in enumerate(full):
        script[9 + k] = [m]
    n = len(full) * PER
    script[30] = [StreamPoints.of(5, n + 1, [0.0] * PER)]  # more than the free slots
    b.run(40, script)
    nacks = {x.cmd_id: x for x in b.replies(Nack)}
    from serial_protocol.frame import field_name

    assert (nacks[2].code, field_name(nacks[2].msg_type, nacks[2].field)) == (
        NackCode.TOO_HIGH, "vel0_dps")  # fmt: skip
    assert (nacks[3].code, field_name(nacks[3].msg_type, nacks[3].field)) == (
        NackCode.NOT_FINITE, "vel0_dps")  # fmt: skip
    assert (nacks[4].code, field_name(nacks[4].msg_type, nacks[4].field)) == (
        NackCode.TOO_HIGH, "pos0_deg")  # fmt: skip
    assert nacks[5].code is NackCode.QUEUE_FULL and nacks[5].limit == STREAM_CAPACITY
    assert all(k not in nacks for k in range(100, 100 + len(full)))
    st = b.fw.stream_status()
    assert st.free_slots == STREAM_CAPACITY - n and st.next_index == n + 1


def test_a_stop_aborts_a_stream(make_bench):
    b = make_bench()
    pts = [(0.5 * k, 0.0) for k in range(1, 13)]
    script = stream_script(pts, interp=Interp.LINEAR, period_s=0.05, prefill=12, end=False)
    script[40] = [Stop(90)]
    b.run(300, script)
    assert isinstance(next(r for r in b.received if getattr(r, "cmd_id", None) == 90), Ack)
    assert b.fw.stream_status().state is StreamState.IDLE
    assert b.fw.stream_status().underruns == 0
    assert b.arr("sp_vel_dps")[-1] == 0.0 and b.arr("sp_pos_deg")[-1] < 6.0


# ------------------------------------------------------------------ jog


def test_a_jog_ramps_at_its_acceleration_and_a_stop_ends_it(make_bench):
    b = make_bench()
    b.run(450, {5: [Jog(1, 100.0, 500.0)], 300: [Stop(2, 500.0)]})
    v = b.arr("sp_vel_dps")
    assert v[5] == 0.0 and v[6] == pytest.approx(500.0 * DT, rel=1e-6)
    assert v[200] == pytest.approx(100.0)
    assert np.all(np.abs(np.diff(v)) <= 500.0 * DT + 1e-9)
    assert v[-1] == 0.0
    assert abs(b.arr("pos_deg")[-1] - b.arr("sp_pos_deg")[-1]) < 0.05
    # 0.2 s to 100 deg/s, cruise, 0.2 s to rest
    assert isinstance(b.replies(Ack)[0], Ack)


def test_a_jog_stops_when_the_pc_falls_silent(make_bench):
    b = make_bench()
    b.run(300, {5: [Jog(1, -50.0, 1000.0, 100)]})  # 100 ms dead-man; the bench sends no more
    v = b.arr("sp_vel_dps")
    assert v.min() == pytest.approx(-50.0)
    k_full = int(np.argmin(v))  # at -50 deg/s after 50 ms
    k_stop = k_full + int(np.argmax(v[k_full:] > -50.0 + 1e-9))  # the first tick braking
    assert k_stop == pytest.approx(5 + 50, abs=2)  # 100 ms = 50 ticks after the Jog
    assert v[-1] == 0.0
    assert b.fw.counters["jog_timeouts"] == 1
    assert b.fw.fault == 0  # a stop, not a fault


def test_the_board_watchdog_trips_during_a_jog_without_timeout(make_bench):
    """A jog with no timeout of its own is still under the board's command watchdog
    ([safety] watchdog_s): the PC silent for 0.1 s trips WATCHDOG, the bridge brakes and
    goes off, the setpoint stops where the axis is."""
    from firmware_model.params import SafetyParams
    from serial_protocol.messages import Fault, FaultReport, State

    b = make_bench(FirmwareParams(safety=SafetyParams(watchdog_s=0.1)))
    b.run(200, {5: [Jog(1, 60.0, 1000.0)]})
    (report,) = b.replies(FaultReport)
    assert report.fault is Fault.WATCHDOG and report.tick == 5 + 51
    assert b.arr("sp_vel_dps")[report.tick - 1] == pytest.approx(60.0)  # jogging until then
    assert b.arr("state")[-1] == State.FAULT and np.all(b.arr("duty")[report.tick + 1 :] == 0.0)
    assert b.fw.counters["jog_timeouts"] == 0


def test_a_jog_stops_at_the_travel_end(make_bench):
    params = FirmwareParams(limits=LimitsParams(travel_min_deg=-5.0, travel_max_deg=5.0))
    b = make_bench(params)
    b.run(1000, {5: [Jog(1, 40.0, 400.0)]})
    sp, v = b.arr("sp_pos_deg"), b.arr("sp_vel_dps")
    assert sp.max() == pytest.approx(5.0, abs=2e-6) and sp.max() <= 5.0 and v[-1] == 0.0
    assert b.arr("pos_deg").max() < 5.0 + 0.1
    # jogging on towards the end plans no motion beyond it
    b.run(50, {b.fw.tick: [Jog(2, 40.0, 400.0)]})
    assert b.arr("sp_pos_deg").max() <= 5.0 + 1e-9


def test_jog_refusals(make_bench):
    b = make_bench()
    v_max = b.fw.v_max_dps
    b.run(20, {5: [Jog(1, v_max * 2, 100.0)], 6: [Jog(2, 10.0, 0.0)],
               7: [Jog(3, float("inf"), 100.0)]})  # fmt: skip
    from serial_protocol.frame import field_name

    said = {n.cmd_id: (n.code, field_name(n.msg_type, n.field)) for n in b.replies(Nack)}
    assert said == {
        1: (NackCode.TOO_HIGH, "vel_dps"),
        2: (NackCode.TOO_LOW, "a_max_dps2"),
        3: (NackCode.NOT_FINITE, "vel_dps"),
    }
    assert b.arr("sp_vel_dps")[-1] == 0.0


def test_stream_status_answers_and_hello_announces_the_sizes(make_bench):
    from serial_protocol.messages import HelloReply

    b = make_bench()
    b.run(10, {5: [StreamControl(1, StreamAction.STATUS)]})
    (st,) = b.replies(StreamStatus)
    assert (st.state, st.free_slots, st.next_index) == (StreamState.IDLE, 0, 0)
    (hello,) = b.replies(HelloReply)
    assert (hello.queue_blocks, hello.stream_points) == (32, STREAM_CAPACITY)
    assert (hello.stream_period_min_ms, hello.stream_period_max_ms) == (2, 1000)


def test_a_jog_from_a_running_program_towards_a_far_travel_end(make_bench):
    """Jogs from a running program (dwell included) towards an end 1e5 deg away: the
    plan's rounding at that scale stays inside the travel (before the margin, 4 of these 65
    were refused as TRAVEL)."""
    from serial_protocol.messages import QueueSegment

    for k in range(6, 200, 3):
        b = make_bench()
        b.run(k + 3, {5: [QueueSegment(1, 5.0, 50.0, 0.1)], k: [Jog(2, 10.0, 100.0, 50)]})
        assert not b.replies(Nack), k
        assert b.fw._target_deg <= b.fw.params.limits.travel_max_deg


# ------------------------------------------------------------------ properties of the stream


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from([Interp.LINEAR, Interp.CUBIC]),
    st.sampled_from([0.002, 0.01, 0.15]),
    st.lists(
        # per point: the acceleration over the period as a fraction of a_max (a little
        # beyond it sometimes), per frame: how late the PC is, as a fraction of the frame
        st.tuples(
            st.lists(st.floats(-1.1, 1.1), min_size=1, max_size=PER), st.floats(0.0, 1.3)
        ),  # fmt: skip
        min_size=1,
        max_size=25,
    ),
)
def test_a_stream_can_always_stop_within_the_travel_and_limits(interp, h, frames):
    """A PC streaming a random smooth trajectory, sometimes beyond the limits or the travel,
    sometimes too late (underrun): a refused frame takes nothing; every accepted one leaves
    a profile that ends at rest within the travel, within v_max at the points (and the
    wire's step), joined to the previous one without a jump in position (nor in velocity,
    for PVT)."""
    v_max, a_max, travel = 50.0, 400.0, (-3.0, 3.0)
    s = PointStream()
    s.start(0.0, h, interp, 3, v_max_dps=v_max, a_max_dps2=a_max, travel_deg=travel)
    t_s, old, p, v = 0.0, None, 0.0, 0.0
    for accels, late in frames:
        pts, p_try, v_try = [], p, v
        for acc in accels:
            v_new = max(-v_max, min(v_max, v_try + acc * a_max * h))
            p_try = round(p_try + 0.5 * (v_try + v_new) * h, 4)
            v_try = v_new
            pts.append((p_try, v_try))
        pts = tuple(pts)
        before = s.next_index
        if s.check(t_s, before, pts) is not None:
            assert s.next_index == before
        else:
            followed = s.add(t_s, pts)
            p, v = p_try, v_try
            assert s.next_index == before + len(pts)
            if followed is not None:
                prof, t0 = followed
                assert prof.v1 == 0.0
                lo, hi = profile_extent(prof)
                assert travel[0] - 1e-9 <= lo and hi <= travel[1] + 1e-9
                assert max(abs(x) for x in prof.v) <= v_max + 0.5e-4 / h + 1e-6
                if old is not None:
                    p_new, v_new, _ = prof.at(t_s - t0)
                    p_old, v_old, _ = old[0].at(t_s - old[1])
                    assert abs(p_new - p_old) < 1e-9
                    # LINEAR steps its velocity at the points (at most what a_max gives in a
                    # period); a frame arriving at a point's instant may show that step
                    dv = 1e-6 if interp is Interp.CUBIC else a_max * h + 1e-4 / h
                    assert abs(v_new - v_old) <= dv
                old = (prof, t0)
        t_s += round(late * len(pts) * h / DT) * DT
