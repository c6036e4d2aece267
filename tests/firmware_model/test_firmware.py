"""The board: commands and NACKs, trips, telemetry, determinism, fixed vs float, batch.

Every run closes the loop on the minimal plant of ``conftest.py``; the PC talks to the board
in wire frames only.
"""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
import pytest

from firmware_model.firmware import Firmware
from firmware_model.params import (
    FirmwareParams,
    LimitsParams,
    SafetyParams,
    ServoParams,
    TelemetryParams,
    VelocityLoopGains,
)
from serial_protocol import frame
from serial_protocol.messages import (
    Ack,
    ClearFault,
    Fault,
    FaultReport,
    Gains,
    GetGains,
    GetLimits,
    GetStatus,
    Hello,
    HelloReply,
    Limits,
    Loop,
    Move,
    MsgType,
    Nack,
    NackCode,
    Profile,
    QueueAction,
    QueueControl,
    QueueSegment,
    SetEnable,
    SetGains,
    SetLimits,
    SetTelemetry,
    State,
    Status,
    Stop,
    Telemetry,
)

A = 2000.0  # deg/s^2: short test moves


def move(cmd_id, target, v=200.0, a=A, profile=Profile.TRAPEZOID, j=0.0):
    return Move(cmd_id=cmd_id, target_deg=target, v_max_dps=v, a_max_dps2=a, j_max_dps3=j,
                profile=profile)  # fmt: skip


def acks(bench):
    return [(m.cmd_id, m.msg_type) for m in bench.replies(Ack)]


def nacks(bench):
    return [(m.cmd_id, m.code) for m in bench.replies(Nack)]


# ---------------------------------------------------------------------------- motion


def test_planned_move_tracks_and_settles(make_bench):
    b = make_bench()
    b.run(600, {5: [move(1, 30.0)]})
    assert acks(b) == [(1, MsgType.MOVE)]
    state = b.arr("state")
    assert state[0] == State.IDLE and State.MOVING in state and state[-1] == State.HOLDING
    fe = np.abs(b.arr("sp_pos_deg") - b.arr("pos_deg"))
    assert fe.max() < 0.2  # deg at the axis (measured ~0.05)
    assert abs(b.arr("true_axis_deg")[-1, 0] - 30.0) < 0.01
    assert np.abs(b.arr("current_meas_a")).max() <= 5.0 + 0.5


def test_interrupt_replans_without_a_velocity_jump(make_bench):
    b = make_bench()
    b.run(400, {5: [move(1, 40.0)], 60: [move(2, -20.0)], 200: [move(3, 10.0, v=100.0)]})
    assert acks(b) == [(1, MsgType.MOVE), (2, MsgType.MOVE), (3, MsgType.MOVE)]
    sp_v = b.arr("sp_vel_dps")
    assert np.abs(np.diff(sp_v)).max() <= A * 0.002 + 1e-6
    assert b.arr("sp_pos_deg")[-1] == 10.0


def test_scurve_and_step_profiles(make_bench):
    b = make_bench()
    b.run(500, {5: [move(1, 20.0, profile=Profile.SCURVE, j=40000.0)]})
    acc = b.arr("sp_acc_dps2")
    assert np.abs(np.diff(acc)).max() <= 40000.0 * 0.002 + 1e-6  # jerk limited
    assert b.arr("sp_pos_deg")[-1] == 20.0
    # STEP: no planning, the setpoint jumps; the clamps shape the motion.
    s = make_bench()
    s.run(700, {5: [move(1, 60.0, v=300.0, profile=Profile.STEP)]})
    sp = s.arr("sp_pos_deg")
    assert sp[4] == 0.0 and sp[5] == 60.0
    i_ref = s.arr("current_ref_a")
    assert np.abs(i_ref).max() == pytest.approx(5.0)  # the current limit does the work
    assert s.arr("vel_dps").max() < 300.0 * 1.1
    assert s.arr("state")[-1] == State.HOLDING
    assert abs(s.arr("pos_deg")[-1] - 60.0) < 0.5
    assert s.fw.counters["faults"] == 0


def test_stop_brakes_to_rest(make_bench):
    b = make_bench()
    b.run(300, {5: [move(1, 500.0)], 100: [Stop(cmd_id=2, a_max_dps2=0.0)]})
    assert acks(b) == [(1, MsgType.MOVE), (2, MsgType.STOP)]
    sp_v = b.arr("sp_vel_dps")
    assert sp_v[99] > 100.0 and sp_v[-1] == 0.0
    assert np.abs(np.diff(sp_v)).max() <= A * 0.002 + 1e-6  # configured a_max 2000
    assert b.arr("state")[-1] == State.HOLDING


# ---------------------------------------------------------------------------- NACKs


def _run_with(make_bench, extra, at=50, ticks=150, params=None):
    b = make_bench(params)
    script = {5: [move(1, 100.0)]}
    script.setdefault(at, []).extend(extra)
    b.run(ticks, script)
    return b


INF = math.inf


@pytest.mark.parametrize(
    ("bad", "code", "field", "limit"),
    [
        (move(7, 10.0, a=float("nan")), NackCode.NOT_FINITE, "a_max_dps2", 0.0),
        (move(7, 10.0, v=float("inf")), NackCode.NOT_FINITE, "v_max_dps", 0.0),
        (move(7, 10.0, a=0.0), NackCode.TOO_LOW, "a_max_dps2", 1e-3),
        (move(7, 10.0, a=-5.0), NackCode.TOO_LOW, "a_max_dps2", 1e-3),
        (move(7, 10.0, a=A * 2), NackCode.TOO_HIGH, "a_max_dps2", A),  # above [limits]
        (move(7, 10.0, v=1500.0), NackCode.TOO_HIGH, "v_max_dps", 1000.0),
        (move(7, 2e5), NackCode.TOO_HIGH, "target_deg", 1e5),  # beyond the travel
        (move(7, 10.0, profile=Profile.SCURVE, j=0.0), NackCode.TOO_LOW, "j_max_dps3", 1e-3),
        # a program starts at rest: a block while a Move runs is refused
        (QueueSegment(7, 10.0, 30.0), NackCode.BUSY, None, 0.0),
        (QueueSegment(7, 2e5, 30.0), NackCode.TOO_HIGH, "target_deg", 1e5),
        (QueueSegment(7, 10.0, float("nan")), NackCode.NOT_FINITE, "v_max_dps", 0.0),
        (QueueSegment(7, 10.0, 1500.0), NackCode.TOO_HIGH, "v_max_dps", 1000.0),
        (QueueSegment(7, 10.0, 30.0, -1.0), NackCode.TOO_LOW, "dwell_s", 0.0),
        (QueueControl(7, QueueAction.OVERRIDE, 5.0), NackCode.TOO_LOW, "override_pct", 10.0),
        (QueueControl(7, QueueAction.OVERRIDE, float("inf")), NackCode.NOT_FINITE,
         "override_pct", 0.0),
        (Stop(cmd_id=7, a_max_dps2=float("nan")), NackCode.NOT_FINITE, "a_max_dps2", 0.0),
        (Stop(cmd_id=7, a_max_dps2=-1.0), NackCode.TOO_LOW, "a_max_dps2", 1e-3),
        (Stop(cmd_id=7, a_max_dps2=A * 2), NackCode.TOO_HIGH, "a_max_dps2", A),
        (SetGains(cmd_id=7, loop=Loop.VELOCITY, kp=-0.1, ki=1.0, kd=0.0), NackCode.TOO_LOW,
         "kp", 0.0),
        (SetGains(cmd_id=7, loop=Loop.VELOCITY, kp=0.1, ki=1.0, kd=0.1), NackCode.TOO_HIGH,
         "kd", 0.0),
        (SetGains(cmd_id=7, loop=Loop.POSITION, kp=10.0, ki=1.0, kd=0.0), NackCode.TOO_HIGH,
         "ki", 0.0),
        (SetGains(cmd_id=7, loop=Loop.CURRENT, kp=float("nan"), ki=1.0, kd=0.0),
         NackCode.NOT_FINITE, "kp", 0.0),
        (SetGains(cmd_id=7, loop=Loop.VELOCITY, kp=5.0, ki=1.0, kd=0.0), NackCode.UNSTABLE_GAINS,
         None, 0.0),
        (SetGains(cmd_id=7, loop=Loop.CURRENT, kp=2.0, ki=300.0, kd=0.0),
         NackCode.UNSTABLE_GAINS, None, 0.0),
        (SetLimits(cmd_id=7, v_max_dps=500.0, a_max_dps2=100.0, current_limit_a=9.0,
                   following_error_deg=5.0), NackCode.TOO_HIGH, "current_limit_a", 7.5),
        (SetLimits(cmd_id=7, v_max_dps=500.0, a_max_dps2=100.0, current_limit_a=4.0,
                   following_error_deg=5.0, over_current_trip_a=3.0),
         NackCode.TOO_HIGH, "current_limit_a", 3.0),  # the clamp above the new trip
        (SetLimits(cmd_id=7, v_max_dps=500.0, a_max_dps2=100.0, current_limit_a=4.0,
                   following_error_deg=5.0, over_current_trip_a=8.0),
         NackCode.TOO_HIGH, "over_current_trip_a", 7.5),  # above the configured trip
        (SetLimits(cmd_id=7, v_max_dps=2000.0, a_max_dps2=100.0, current_limit_a=4.0,
                   following_error_deg=5.0), NackCode.TOO_HIGH, "v_max_dps", 1100.0),
        (SetLimits(cmd_id=7, v_max_dps=500.0, a_max_dps2=-1.0, current_limit_a=4.0,
                   following_error_deg=5.0), NackCode.TOO_LOW, "a_max_dps2", 1e-3),
        (SetLimits(cmd_id=7, v_max_dps=500.0, a_max_dps2=100.0, current_limit_a=4.0,
                   following_error_deg=float("nan")), NackCode.NOT_FINITE,
         "following_error_deg", 0.0),
    ],
)  # fmt: skip
def test_bad_commands_are_nacked_and_change_nothing(make_bench, bad, code, field, limit):
    good = _run_with(make_bench, [])
    b = _run_with(make_bench, [bad])
    [nack] = b.replies(Nack)
    assert (nack.cmd_id, nack.msg_type, nack.code) == (7, bad.MSG_TYPE, code)
    # The NACK names the field and the bound, so a client can print "v_max_dps = 1500 >
    # limit 1000".
    expected_field = 255 if field is None else frame.field_index(type(bad), field)
    assert nack.field == expected_field
    assert nack.limit == pytest.approx(limit, rel=1e-6)
    assert frame.field_name(nack.msg_type, nack.field) == field
    assert b.fw.counters["nacks"] == 1 and b.fw.counters[f"nack_{code.name}"] == 1
    assert b.fw.counters["commands_applied"] == 1  # the first Move only
    # Nothing half-applied: the run is the run without the bad command, bit for bit.
    for key in ("sp_pos_deg", "pos_deg", "duty", "state"):
        np.testing.assert_array_equal(b.arr(key), good.arr(key))
    assert b.fw.law.gains == good.fw.law.gains


def test_move_when_disabled_or_faulted(make_bench):
    params = FirmwareParams(servo=ServoParams(start_enabled=False))
    b = make_bench(params)
    b.run(50, {5: [move(1, 10.0)], 10: [SetEnable(cmd_id=2, enable=True)], 20: [move(3, 10.0)]})
    assert nacks(b) == [(1, NackCode.DISABLED)]
    assert acks(b) == [(2, MsgType.SET_ENABLE), (3, MsgType.MOVE)]
    assert b.arr("state")[0] == State.DISABLED and b.arr("duty")[0] == 0.0


def test_malformed_frames_are_nacked_with_their_code(make_bench):
    b = make_bench()
    unknown = frame.frame_raw(0x7E, struct.pack("<H", 41), 0)
    short_move = frame.frame_raw(int(MsgType.MOVE), struct.pack("<HI", 42, 5), 1)
    b.run(20, rx_raw={5: unknown, 8: short_move})
    assert nacks(b) == [(41, NackCode.UNKNOWN_TYPE), (42, NackCode.BAD_LENGTH)]
    assert b.fw.counters["rx_malformed"] == 2
    assert b.arr("state")[-1] == State.IDLE


def test_repeated_command_is_acked_not_applied(make_bench):
    # A retry is the same frame payload again (cmd_id and session included): answered
    # again, not applied again, even after the axis has moved on.
    b = make_bench()
    b.run(200, {5: [move(1, 50.0)], 30: [move(1, 50.0)], 40: [move(2, 20.0)]})
    assert acks(b) == [(1, MsgType.MOVE), (1, MsgType.MOVE), (2, MsgType.MOVE)]
    assert b.fw.counters["duplicates"] == 1 and b.fw.counters["commands_applied"] == 2
    assert b.arr("sp_pos_deg")[-1] == 20.0
    # The same cmd_id with a different payload is a new command (a client that reuses an
    # id is not silently ignored): carried out.
    r = make_bench()
    r.run(200, {5: [move(1, 50.0)], 30: [move(1, -50.0)]})
    assert r.fw.counters["duplicates"] == 0 and r.fw.counters["commands_applied"] == 2
    assert r.fw._target_deg == -50.0
    # A repeat of a NACKed command gets the same NACK again.
    n = make_bench()
    n.run(20, {5: [move(3, 1.0, v=float("nan"))], 10: [move(3, 1.0, v=float("nan"))]})
    assert nacks(n) == [(3, NackCode.NOT_FINITE), (3, NackCode.NOT_FINITE)]


# ---------------------------------------------------------------------------- queries


def test_queries_and_settings_round_trip(make_bench):
    b = make_bench()
    new_limits = SetLimits(cmd_id=3, v_max_dps=400.0, a_max_dps2=900.0, current_limit_a=3.0,
                           following_error_deg=12.0)  # fmt: skip
    b.run(
        30,
        {
            2: [Hello(), GetStatus(cmd_id=1)],
            5: [SetGains(cmd_id=2, loop=Loop.VELOCITY, kp=0.05, ki=1.5, kd=0.0), new_limits],
            8: [GetGains(cmd_id=4, loop=Loop.VELOCITY), GetLimits(cmd_id=5), GetStatus(cmd_id=6)],
        },
    )
    (hello,) = b.replies(HelloReply)
    assert hello.tick_hz == 500 and hello.counts_per_rev == 16384
    (gains,) = b.replies(Gains)
    assert (gains.kp, gains.ki, gains.kd) == pytest.approx((0.05, 1.5, 0.0))
    (limits,) = b.replies(Limits)
    assert (limits.v_max_dps, limits.current_limit_a) == pytest.approx((400.0, 3.0))
    s1, s2 = b.replies(Status)
    assert s1.state == State.IDLE and s2.tick == 8  # the tick that handled it
    assert b.fw.current_limit_a == 3.0
    assert b.fw.law.gains["kp_v"] == pytest.approx(0.05)  # float32 on the wire


# ---------------------------------------------------------------------------- faults


def _check_fault_cycle(b, fault):
    """The bridge brakes (duty 0, on: [safety] brake_s; over-current: none) and is then
    off, the fault is latched and reported, motion is refused until ClearFault +
    SetEnable."""
    reports = b.replies(FaultReport)
    assert [r.fault for r in reports] == [fault]
    trip = reports[0].tick
    state, duty = b.arr("state"), b.arr("duty")
    assert state[trip] == State.FAULT and state[-1] == State.FAULT
    assert np.all(duty[trip + 1 :] == 0.0)
    s = b.fw.params.safety
    brake = 0 if fault is Fault.OVER_CURRENT else round(s.brake_s * b.fw.params.servo.tick_hz)
    m = b.fw.params.servo.current_loop_multiple
    enables = np.asarray(b.enables).reshape(len(b.enables), -1)[:, 0]
    # Current periods from the trip's tick on: braking (bridge on, duty 0), then off.
    after = enables[(trip + 1) * m :]
    assert np.all(after[: max(brake - 1, 0) * m]) and not np.any(after[brake * m :])
    assert b.fw.counters[f"fault_{fault.name}"] == 1
    t = b.fw.tick
    v = min(200.0, b.fw.v_max_dps)
    target = round(float(b.fw.signals()["pos_deg"]), 3) + 0.1
    b.run(
        40,
        {
            t + 1: [move(101, target, v=v), SetEnable(cmd_id=102, enable=True)],
            t + 3: [ClearFault(cmd_id=103)],
            t + 5: [move(104, target, v=v)],
            t + 7: [SetEnable(cmd_id=105, enable=True)],
            t + 9: [move(106, target, v=v)],
        },
    )
    assert nacks(b)[-3:] == [
        (101, NackCode.FAULT_ACTIVE),
        (102, NackCode.FAULT_ACTIVE),
        (104, NackCode.DISABLED),
    ]
    assert acks(b)[-3:] == [
        (103, MsgType.CLEAR_FAULT),
        (105, MsgType.SET_ENABLE),
        (106, MsgType.MOVE),
    ]
    state = b.arr("state")
    assert state[t + 4] == State.DISABLED and state[t + 8] == State.IDLE
    assert state[-1] in (State.MOVING, State.HOLDING)
    assert b.fw.counters["faults"] == 1


def test_over_current_trip(make_bench):
    b = make_bench()
    b.adc_override = lambda k, adc: np.full_like(adc, 1500) if 60 <= k < 70 else adc  # 10.3 A
    b.run(100, {5: [move(1, 100.0)]})
    (report,) = b.replies(FaultReport)
    assert report.value == pytest.approx(1500 * b.fw.params.current.a_per_adc, rel=1e-3)
    _check_fault_cycle(b, Fault.OVER_CURRENT)


def test_following_error_trip(make_bench):
    # A jammed axis (friction beyond the 5 A torque) and a tight following-error limit.
    b = make_bench(coulomb_nm=1.0)
    limits = SetLimits(cmd_id=2, v_max_dps=1000.0, a_max_dps2=A, current_limit_a=5.0,
                       following_error_deg=0.5)  # fmt: skip
    b.run(150, {2: [limits], 5: [move(1, 100.0)]})
    (report,) = b.replies(FaultReport)
    assert report.fault == Fault.FOLLOWING_ERROR and report.value > 0.5
    _check_fault_cycle(b, Fault.FOLLOWING_ERROR)


def test_over_speed_trip(make_bench):
    params = FirmwareParams(
        safety=SafetyParams(over_speed_dps=30.0), limits=LimitsParams(v_max_dps=25.0)
    )
    b = make_bench(params)
    # The encoder says the motor runs away (a driven load): +300 counts per tick = 41 deg/s.
    b.encoder_override = lambda k, c: (c + 300 * min(max(0, k - 20), 40)) % 16384
    b.run(80)
    (report,) = b.replies(FaultReport)
    assert report.value > 30.0
    _check_fault_cycle(b, Fault.OVER_SPEED)


def test_encoder_jump_trip(make_bench):
    b = make_bench()
    b.encoder_override = lambda k, c: (c + (5000 if k >= 30 else 0)) % 16384
    b.run(60)
    (report,) = b.replies(FaultReport)
    assert report.tick == 30
    _check_fault_cycle(b, Fault.ENCODER)


def test_encoder_stuck_trip(make_bench):
    # The back-EMF check would see the frozen reading first (test_safety.py): out of the way.
    b = make_bench(FirmwareParams(safety=SafetyParams(sensor_mismatch_deg=1e5)))
    frozen = {}
    b.encoder_override = lambda k, c: frozen.setdefault("c", c) if 40 <= k < 300 else c
    b.run(300, {5: [move(1, 100.0, a=200.0)]})
    (report,) = b.replies(FaultReport)
    assert report.tick == 40 + 100  # ticks 41..140 repeat the reading of tick 40
    assert report.value == frozen["c"]
    _check_fault_cycle(b, Fault.ENCODER)


def test_watchdog_trip_and_keepalive(make_bench):
    params = FirmwareParams(safety=SafetyParams(watchdog_s=0.1))
    alive = make_bench(params)
    alive.run(300, {k: [GetStatus(cmd_id=k)] for k in range(0, 300, 40)})
    assert alive.fw.counters["faults"] == 0
    b = make_bench(params)
    b.run(100, {5: [GetStatus(cmd_id=1)]})
    (report,) = b.replies(FaultReport)
    assert report.tick == 5 + 51 and report.value == 51.0
    _check_fault_cycle(b, Fault.WATCHDOG)


# ---------------------------------------------------------------------------- telemetry


def test_telemetry_every_tick_decimated_at_low_baud_and_never_silently_dropped(make_bench):
    b = make_bench()
    b.run(20)
    tel = b.replies(Telemetry)
    assert [t.tick for t in tel] == list(range(20))
    assert tel[-1].pos_deg == pytest.approx(b.arr("pos_deg")[-1], abs=1e-4)
    slow = make_bench(FirmwareParams(telemetry=TelemetryParams(baud=115200)))
    slow.run(20)
    # 40-byte frames at 500 Hz need 20000 B/s; 80 % of 11520 B/s carries every third tick.
    assert slow.fw.telemetry_decimation == 3
    assert [t.tick for t in slow.replies(Telemetry)] == list(range(0, 20, 3))
    # A TX FIFO with no room: frames are dropped whole and counted, replies wait.
    full = make_bench(tx_free=0)
    full.run(10, {2: [GetStatus(cmd_id=1)]})
    assert full.received == []
    assert full.fw.counters["tx_telemetry_dropped"] == 10
    full.tx_free = 4096
    full.run(1)
    assert [type(m) for m in full.received] == [HelloReply, Status, Telemetry]
    off = make_bench()
    off.run(10, {0: [SetTelemetry(cmd_id=1, decimation=0)]})
    assert off.replies(Telemetry) == [] and acks(off) == [(1, MsgType.SET_TELEMETRY)]


# ---------------------------------------------------------------------------- runs


def test_determinism(make_bench):
    runs = []
    for _ in range(2):
        b = make_bench(theta0_rad=1.0)
        b.run(300, {5: [move(1, 40.0)], 100: [move(2, -10.0)]})
        runs.append(b)
    for key in runs[0].log:
        np.testing.assert_array_equal(runs[0].arr(key), runs[1].arr(key))
    assert [m for m in runs[0].received] == [m for m in runs[1].received]


def test_fixed_point_agrees_with_float(make_bench):
    out = {}
    for arith in ("float", "fixed"):
        b = make_bench(FirmwareParams(servo=ServoParams(arithmetic=arith)), theta0_rad=0.3)
        b.run(700, {5: [move(1, 60.0, v=300.0)], 300: [move(2, -20.0, v=300.0)]})
        out[arith] = b
        assert b.fw.counters["faults"] == 0
    f, q = out["float"], out["fixed"]
    # Same run, two arithmetics: the difference is Q16.16 rounding (1.5e-5 of a unit) and
    # Q8.24 gains (6e-8), which moves a duty by one ARR step now and then (and, once in a
    # while, an ADC reading across the blind-sense floor: a few steps for one tick); Coulomb
    # friction then lets the axis come to rest a few counts apart. Measured: position max 3
    # counts (mean 0.6), velocity 0.08 deg/s, current reference 0.006 A, duty max 2 steps
    # (mean 0.35); with an earlier observer input, up to 7 counts and 5 steps.
    count_deg = 360 / 16384 / 80
    assert np.abs(f.arr("pos_deg") - q.arr("pos_deg")).max() <= 12 * count_deg
    assert np.abs(f.arr("vel_dps") - q.arr("vel_dps")).max() < 0.5
    assert np.abs(f.arr("current_ref_a") - q.arr("current_ref_a")).max() < 0.05
    duty_steps = np.abs(f.arr("duty") - q.arr("duty")) * 3600
    assert duty_steps.max() <= 8.0 + 1e-9 and duty_steps.mean() < 1.0
    np.testing.assert_array_equal(f.arr("state"), q.arr("state"))
    # ... and the two runs are not trivially the same computation.
    assert np.any(f.arr("duty") != q.arr("duty"))


def test_batch_members_match_the_scalar_run_and_fault_independently(make_bench):
    kp = np.array([0.04, 0.0651274339106258, 0.09])
    params = FirmwareParams(velocity=VelocityLoopGains(kp_a_per_dps=kp))
    batch = make_bench(params, batch=3)
    script = {5: [move(1, 30.0)]}
    batch.run(200, script)
    for m, k in enumerate(kp):
        single = make_bench(
            dataclasses.replace(params, velocity=VelocityLoopGains(kp_a_per_dps=float(k)))
        )
        single.run(200, script)
        for key in ("pos_deg", "duty", "current_ref_a", "vel_dps"):
            np.testing.assert_array_equal(batch.arr(key)[:, m], single.arr(key))
    # One member trips, the others carry on.
    b = make_bench(params, batch=3)
    b.adc_override = lambda k, adc: np.where([False, k >= 50, False], 2000, adc)
    b.run(150, script)
    fault = b.arr("fault")[-1]
    assert list(fault) == [0, Fault.OVER_CURRENT, 0]
    assert list(b.arr("state")[-1]) == [State.HOLDING, State.FAULT, State.HOLDING]
    assert b.replies(FaultReport) == []  # replies describe member 0
    assert b.fw.counters["fault_OVER_CURRENT"] == 1


def test_fixed_point_batch_runs(make_bench):
    params = FirmwareParams(servo=ServoParams(arithmetic="fixed"))
    b = make_bench(params, batch=2, theta0_rad=0.0)
    b.run(200, {5: [move(1, 20.0)]})
    assert np.abs(b.arr("pos_deg")[-1] - 20.0).max() < 0.05
    assert math.isclose(b.arr("sp_pos_deg")[-1], 20.0)


def test_array_gains_need_a_batch():
    params = FirmwareParams(velocity=VelocityLoopGains(kp_a_per_dps=[0.05, 0.06]))
    with pytest.raises(ValueError, match="batch"):
        Firmware(params)
    with pytest.raises(ValueError, match="batch"):
        Firmware(params, batch=3)


@pytest.mark.parametrize(("multiple", "delay"), [(1, 0), (4, 1), (2, 2)])
def test_current_loop_rate_and_compute_delay_variants_track(make_bench, multiple, delay):
    params = FirmwareParams(
        servo=ServoParams(current_loop_multiple=multiple, compute_delay_ticks=delay)
    )
    b = make_bench(params)
    b.run(400, {5: [move(1, 30.0)]})
    assert b.fw.counters["faults"] == 0
    assert np.abs(b.arr("sp_pos_deg") - b.arr("pos_deg")).max() < 0.3
    assert abs(b.arr("true_axis_deg")[-1, 0] - 30.0) < 0.02
    assert len(b.enables) == 400 * multiple


def test_planned_move_after_a_step_move_starts_from_the_axis(make_bench):
    b = make_bench()
    b.run(
        500,
        {5: [move(1, 200.0, v=300.0, profile=Profile.STEP)], 100: [move(2, 0.0, v=300.0)]},
    )
    assert acks(b) == [(1, MsgType.MOVE), (2, MsgType.MOVE)]
    sp, pos = b.arr("sp_pos_deg"), b.arr("pos_deg")
    # At the interrupt the setpoint leaves the step target and restarts where the axis is,
    # at the speed the axis has (the STEP move runs at ~300 deg/s there): starting from rest
    # would leave the axis running away from a standing setpoint.
    vel, sp_vel = b.arr("vel_dps"), b.arr("sp_vel_dps")
    assert sp[99] == 200.0
    assert abs(sp[100] - pos[100]) < 0.01
    assert vel[100] > 250.0 and abs(sp_vel[100] - vel[100]) < 1.0
    assert np.all(np.diff(sp_vel[100:150]) < 0.0)  # then brakes and turns back
    assert sp[-1] == 0.0


def test_lowering_the_limits_mid_move_replans_without_a_jump(make_bench):
    b = make_bench()
    lower = SetLimits(cmd_id=2, v_max_dps=100.0, a_max_dps2=1000.0, current_limit_a=5.0,
                      following_error_deg=30.0)  # fmt: skip
    b.run(400, {5: [move(1, 300.0, v=300.0)], 150: [lower]})
    assert acks(b) == [(1, MsgType.MOVE), (2, MsgType.SET_LIMITS)]
    sp_v = b.arr("sp_vel_dps")
    assert sp_v[149] == pytest.approx(300.0)
    assert np.abs(np.diff(sp_v)).max() <= A * 0.002 + 1e-6  # no jump
    assert np.abs(sp_v[300:]).max() <= 100.0 + 1e-9  # braked to the new v_max
    assert b.fw.counters["faults"] == 0


def test_a_custom_gain_check_decides_unstable_gains(make_bench):
    seen = []

    def margin_check(params, gains):
        seen.append(dict(gains))
        return "gain margin below 6 dB" if gains["kp_v"] > 0.08 else None

    b = make_bench()
    b.fw = Firmware(FirmwareParams(), gain_check=margin_check)
    b.run(
        10,
        {
            2: [SetGains(cmd_id=1, loop=Loop.VELOCITY, kp=0.07, ki=1.0, kd=0.0)],
            4: [SetGains(cmd_id=2, loop=Loop.VELOCITY, kp=0.09, ki=1.0, kd=0.0)],
        },
    )
    assert acks(b) == [(1, MsgType.SET_GAINS)]
    assert nacks(b) == [(2, NackCode.UNSTABLE_GAINS)]
    assert seen[0]["kp_v"] == pytest.approx(0.07) and seen[1]["kp_p"] > 0.0
    assert b.fw.law.gains["kp_v"] == pytest.approx(0.07)


@pytest.mark.parametrize("batch", [None, 3])
def test_signal_row_is_signals_in_order(make_bench, batch):
    from firmware_model.firmware import SIGNAL_NAMES

    b = make_bench(batch=batch)
    b.run(300, {5: [move(1, 20.0)]})
    sig = b.fw.signals()
    assert list(sig) == list(SIGNAL_NAMES)
    row = b.fw.signal_row()
    assert len(row) == len(SIGNAL_NAMES)
    for name, value in zip(SIGNAL_NAMES, row, strict=True):
        np.testing.assert_array_equal(value, sig[name])
    assert sig["vel_dps"] != 0.0 if batch is None else np.all(sig["vel_dps"] != 0.0)


def test_batch_trip_screen_is_the_union_of_the_enabled_members_conditions():
    from firmware_model import tick as ftick
    from firmware_model.laws.layout import C_INNOV, C_STUCK, P_POS, P_VEL, P_VREF

    rng = np.random.default_rng(2)
    hits = 0
    fs, fi = np.zeros(ftick.N_FS), np.zeros(ftick.N_FI, dtype=np.int64)
    fi[ftick.FI_JUMP], fi[ftick.FI_STUCK] = 35, 10
    fs[ftick.FS_STUCK_MIN_VEL], fs[ftick.FS_OVER_SPEED] = 100.0, 150.0
    for _ in range(3000):
        n = int(rng.integers(1, 9))
        innov = rng.integers(-40, 40, n)
        stuck = rng.integers(0, 12, n)
        vel_ref, vel = rng.normal(0.0, 60.0, n), rng.normal(0.0, 60.0, n)
        pos, sp = rng.normal(0.0, 1.0, n), float(rng.normal())
        step_mode = rng.random() < 0.3  # a STEP move: no following-error check
        lo, hi = (-2.5, 2.5) if rng.random() < 0.5 else (-math.inf, math.inf)
        enabled = rng.random(n) < 0.8  # a tripped (disabled) member is not screened
        want = (
            (
                (np.abs(innov) > 35)
                | ((stuck >= 10) & (np.abs(vel_ref) > 100.0))
                | (np.abs(vel) > 150.0)
                | ((np.abs(sp - pos) > 2.0) & (not step_mode))
                | (pos < lo)
                | (pos > hi)
            )
            & enabled
        ).any()
        P, C = np.zeros((7, n)), np.zeros((8, n), dtype=np.int64)
        C[C_INNOV], C[C_STUCK] = innov, stuck
        P[P_VREF], P[P_VEL], P[P_POS] = vel_ref, vel, pos
        fs[ftick.FS_SP_POS] = sp
        fs[ftick.FS_FOLLOWING] = 2.0
        fs[ftick.FS_POS_LO], fs[ftick.FS_POS_HI] = lo, hi
        fi[ftick.FI_MODE] = ftick.MODE_STEP if step_mode else ftick.MODE_HOLD
        got = ftick.trip_screen(P, C, fs, fi, enabled)
        assert got == want
        hits += bool(want)
    assert 300 < hits < 2700


def test_batch_encoder_and_following_error_trips_hit_only_their_member(make_bench):
    params = FirmwareParams()
    b = make_bench(params, batch=3)
    # Member 1's reading jumps by 3000 counts at tick 60; member 2's stops moving at 80.
    held = {}

    def readings(k, counts):
        counts = counts.copy()
        if k >= 60:
            counts[1] = (counts[1] + 3000) % 16384
        if k >= 80:
            counts[2] = held.setdefault(2, counts[2])
        return counts

    b.encoder_override = readings
    b.run(400, {5: [move(1, 30.0)]})
    fault = b.arr("fault")[-1]
    assert fault[0] == 0 and fault[1] == Fault.ENCODER
    assert fault[2] in (Fault.ENCODER, Fault.FOLLOWING_ERROR)
    first = np.argmax(b.arr("fault")[:, 1] != 0)
    assert first == 60
