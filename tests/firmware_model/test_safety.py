"""Issue #11 §1-2: the board never raises, answers every command once, never half-applies a
NACKed command, and never plans a trajectory beyond its travel.

The scenario tests run the real closed loop (``sim.loop.Simulation``: plant, encoder, ADC,
bridge, emulated UART) and talk to the board in wire frames. Each of the regressions below
fails on the tree before this change (the figures in the comments are what it did).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from uart_fuzz import fuzz_commands, paper_bench, travel_search

from firmware_model import safety
from firmware_model.params import FirmwareParams, LimitsParams
from planner.scurve import plan_scurve
from planner.trapezoid import plan_trapezoid
from serial_protocol import frame
from serial_protocol.messages import (
    Ack,
    BoardHeartbeat,
    Fault,
    FaultReport,
    GetStatus,
    Hello,
    HelloReply,
    Move,
    MsgType,
    Nack,
    NackCode,
    Profile,
    SetEnable,
    SetLimits,
    Status,
    Stop,
    Telemetry,
)
from sim.encoder import Encoder
from sim.loop import Simulation, run

TRAVEL_DEG = 3600.0
SESSION = 1


def _run(commands, duration_s=20.0, travel_deg=TRAVEL_DEG):
    """Run ``[(t_s, message), ...]`` on the paper bench with the travel +-``travel_deg``;
    returns the log and the board's answers (telemetry left out)."""
    bench = paper_bench(**{"limits.travel_min_deg": -travel_deg,
                           "limits.travel_max_deg": travel_deg})  # fmt: skip
    sim = Simulation(bench)
    sim.pc_write(frame.encode(Hello(0, session=SESSION), 0))  # a PC opens its session first
    tick = 0
    for seq, (t_s, msg) in enumerate(commands, start=1):
        k = round(t_s / sim.dt_s)
        sim.step(k - tick)
        tick = k
        sim.pc_write(frame.encode(dataclasses.replace(msg, session=SESSION), seq))
    sim.step(round(duration_s / sim.dt_s) - tick)
    # The board's answers (the HelloReply, telemetry and heartbeats left out).
    answers = [
        m
        for m in frame.Decoder().feed(sim.pc_read())
        if not isinstance(m, Telemetry | HelloReply | BoardHeartbeat)
    ]
    log = sim.log()
    # The board's zero is the encoder reading at boot; compare the true axis in its frame.
    true_pos = log.true_pos_deg + (log.pos_deg[0] - log.true_pos_deg[0])
    return log, true_pos, answers


def _move(cmd_id, target_deg, v=990.0, a=148.0, profile=Profile.TRAPEZOID, j=0.0):
    return Move(cmd_id, target_deg, v, a, j, profile)


# ------------------------------------------------------------------ §1 never raise


def test_a_soft_stop_then_get_status_no_longer_kills_the_board():
    # Before: the Stop was ACKed with its stop point at ~4.4e7 deg, which the Status field
    # cannot carry: servo_tick raised ValueError and `serve` exited with a traceback.
    log, true_pos, answers = _run(
        [(0.0, _move(1, 3000.0)), (2.0, Stop(2, 0.001)), (2.1, GetStatus(3))],
        duration_s=30.0,
        travel_deg=1e5,
    )
    assert [type(m) for m in answers] == [Ack, Nack, Status]
    assert answers[1].code == NackCode.TRAVEL and answers[1].msg_type == MsgType.STOP
    assert answers[1].limit == 1e5  # the travel end it would cross
    assert answers[2].target_deg == 3000.0  # the move went on, unchanged
    assert abs(true_pos[-1] - 3000.0) < 0.5 and log.fault.max() == 0


def test_status_saturates_a_position_beyond_its_wire_field():
    assert safety.wire_pos(1e12) == safety.WIRE_POS_MAX_DEG
    assert safety.wire_pos(-1e12) == -safety.WIRE_POS_MAX_DEG
    assert safety.wire_pos(12.5) == 12.5
    status = Status(1, 0, 1, 0, safety.wire_pos(-1e9), 0.0, safety.wire_pos(1e9))
    assert frame.Decoder().feed(frame.encode(status, 0))[0].pos_deg == pytest.approx(
        -safety.WIRE_POS_MAX_DEG, abs=1e-4
    )


@pytest.mark.parametrize("batch", [None, 2])
def test_uart_fuzz_no_exception_one_answer_each_no_half_applied_nack(batch):
    # Bounded here (a few s); benchmarks/fuzz_firmware.py runs 1,000,000 frames (docs/model.md).
    n_frames = 4000 if batch is None else 1500
    report = fuzz_commands(n_frames, seed=11, batch=batch)
    assert report.problems == []
    assert report.answers == report.answers_expected > 0.9 * report.frames_sent
    assert report.half_applied == 0 and report.nacks_checked > 0.15 * n_frames
    # The mix really holds every kind of frame.
    assert set(report.kinds) == {
        "message", "random_payload", "any_length", "other_type", "repeat", "motion"
    }  # fmt: skip


# ------------------------------------------------------------------ §2 travel


# The cases (with its own timing: 13,459 deg, 12,640 deg and 24,073 deg against a
# travel of +-3600 deg). Here: Move(3000 deg, 990 deg/s, 148 deg/s^2), then at 4 s (592
# deg/s) the soft command; before this change each was ACKed and the axis ended at 10,526 /
# 10,398 / 10,526 deg, still moving, with nothing tripped.
@pytest.mark.parametrize(
    "soft",
    [
        Stop(2, 1.0),
        SetLimits(2, 1000.0, 2.0, 5.0, 30.0),
        _move(2, 3000.0, a=1.0),
    ],
    ids=["stop_a1", "set_limits_a2", "interrupting_move_a1"],
)
def test_soft_commands_mid_move_are_refused_and_the_axis_stays_in_travel(soft):
    log, true_pos, answers = _run([(0.0, _move(1, 3000.0)), (4.0, soft)])
    assert [type(m) for m in answers] == [Ack, Nack]
    assert answers[1].code == NackCode.TRAVEL and answers[1].limit == TRAVEL_DEG
    assert true_pos.max() <= TRAVEL_DEG
    assert abs(true_pos[-1] - 3000.0) < 0.5 and abs(log.true_vel_dps[-1]) < 1.0


def test_a_stop_that_fits_is_carried_out_where_the_planner_says():
    log, true_pos, answers = _run([(0.0, _move(1, 3000.0)), (4.0, Stop(2, 148.0))])
    assert [type(m) for m in answers] == [Ack, Ack]
    v_dps = log.sp_vel_dps[2000]
    stop_at = log.sp_pos_deg[2000] + v_dps * v_dps / (2 * 148.0)
    assert abs(log.sp_pos_deg[-1] - stop_at) < 3.0  # the stop is planned from tick 2000's state
    assert true_pos.max() < 3000.0 and abs(log.true_vel_dps[-1]) < 1.0


def test_stop_during_a_step_move_brakes_instead_of_holding():
    # Before: the setpoint jumped back to where the axis was, at 1000 deg/s: a following
    # error trip, then the axis coasted on.
    log, _, answers = _run(
        [(0.0, _move(1, 3000.0, v=1000.0, profile=Profile.STEP)), (2.0, Stop(2, 0.0))],
        duration_s=4.0,
    )
    assert [type(m) for m in answers] == [Ack, Ack]
    assert log.fault.max() == 0
    k = int(np.argmax(log.sp_vel_dps != 0.0))  # the Stop applied (one tick on the line)
    assert 1000 <= k <= 1002 and abs(log.sp_vel_dps[k] - log.vel_dps[k]) < 1.0
    assert np.all(np.diff(log.sp_vel_dps[k : k + 100]) < 0.0)
    assert abs(log.true_vel_dps[-1]) < 1.0


def test_set_enable_while_moving_leaves_the_move_alone():
    # Before: SetEnable(True) while enabled re-enabled the bridge and held the position the
    # axis had, at full speed: a following error trip, then the axis coasted ~900 deg on.
    log, true_pos, answers = _run(
        [(0.0, _move(1, 3000.0, a=2000.0)), (1.0, SetEnable(2, True))], duration_s=6.0
    )
    assert [type(m) for m in answers] == [Ack, Ack]
    assert log.fault.max() == 0 and abs(true_pos[-1] - 3000.0) < 0.5


def test_a_step_move_to_the_end_of_the_travel_slows_down_before_it():
    log, true_pos, answers = _run(
        [(0.0, _move(1, 300.0, v=1000.0, profile=Profile.STEP))], duration_s=2.0, travel_deg=300.0
    )
    assert [type(m) for m in answers] == [Ack]
    assert log.fault.max() == 0
    assert true_pos.max() <= 300.0 + 0.1


def test_a_move_from_a_step_move_starts_at_the_axis_speed():
    # Before: the planner started from rest where the axis was while the axis ran at
    # 1000 deg/s: a following error trip and ~900 deg of coasting.
    log, true_pos, answers = _run(
        [
            (0.0, _move(1, 3000.0, v=1000.0, profile=Profile.STEP)),
            (1.0, _move(2, -100.0, a=2000.0)),
        ],
        duration_s=30.0,
    )
    assert [type(m) for m in answers] == [Ack, Ack]
    assert log.fault.max() == 0
    assert abs(true_pos[-1] + 100.0) < 0.5


def test_position_limit_trip_catches_an_axis_dragged_past_the_end(make_bench):
    # A loop too weak to hold the axis (10 mA; the following-error trip out of the way) and
    # an axis dragged on at 40 deg/s from tick 50 by the load: the position trip ends it.
    limits = LimitsParams(travel_min_deg=-10.0, travel_max_deg=10.0, current_limit_a=0.01,
                          following_error_deg=1e5)  # fmt: skip
    b = make_bench(FirmwareParams(limits=limits))
    counts_per_tick = 40.0 * 0.002 * 80 * 16384 / 360

    def dragged(k, counts):
        return (counts + int(max(0, k - 50) * counts_per_tick)) % 16384

    b.encoder_override = dragged
    b.run(400)
    reports = b.replies(FaultReport)
    assert [r.fault for r in reports] == [Fault.TRAVEL]
    assert 15.0 < reports[0].value < 15.25  # 10 deg travel + 5 deg margin, ~2 ticks of motion


def test_enabled_outside_the_travel_it_may_come_back_not_go_further(make_bench):
    params = FirmwareParams(limits=LimitsParams(travel_min_deg=-1000.0, travel_max_deg=2.0))
    b = make_bench(params, theta0_rad=math.radians(80 * 30.0))  # the axis at 30 deg
    b.run(100, {10: [_move(1, 40.0, v=100.0, a=2000.0)], 20: [_move(2, 0.0, v=100.0, a=2000.0)]})
    assert [(m.cmd_id, type(m)) for m in b.received if isinstance(m, Ack | Nack)] == [
        (1, Nack),
        (2, Ack),
    ]
    assert not b.replies(FaultReport)


def test_travel_search_true_axis_never_beyond_the_travel():
    # Bounded here; benchmarks/fuzz_firmware.py runs 10,000 sequences (docs/model.md).
    report = travel_search(60, seed=5)
    assert report.sequences == 60 and report.nacks > 0
    margin = FirmwareParams().safety.position_limit_margin_deg
    assert report.worst_excess_deg <= margin, report


# ------------------------------------------------------------------ pure functions


def _dense_extent(profile):
    t = np.linspace(0.0, profile.duration, 20001)
    p, _, _ = profile.at(t)
    return float(p.min()), float(p.max())


@settings(max_examples=150, deadline=None)
@given(
    p0=st.floats(-100, 100),
    v0=st.floats(-1000, 1000),
    target=st.floats(-300, 300),
    v_max=st.floats(10, 1000),
    a_max=st.floats(10, 5000),
    j_max=st.one_of(st.none(), st.floats(1e3, 1e6)),
)
def test_profile_extent_bounds_every_sample_and_is_reached(p0, v0, target, v_max, a_max, j_max):
    if j_max is None:
        profile = plan_trapezoid(p0, target, v_max=v_max, a_max=a_max, v0=v0)
    else:
        profile = plan_scurve(p0, target, v_max=v_max, a_max=a_max, j_max=j_max, v0=v0)
    lo, hi = safety.profile_extent(profile)
    d_lo, d_hi = _dense_extent(profile)
    scale = 1e-9 * max(1.0, abs(lo), abs(hi))
    assert lo <= d_lo + scale and hi >= d_hi - scale
    # ... and is reached: the dense sampling comes within one sample's travel of it.
    step = (abs(v0) + v_max + a_max * profile.duration) * profile.duration / 20000
    assert d_lo - lo <= step + scale and hi - d_hi <= step + scale


def test_travel_refusal_names_the_end_and_allows_coming_back():
    out = plan_trapezoid(0.0, 90.0, v_max=100.0, a_max=10.0, v0=100.0)  # overshoots to 500
    reason = safety.travel_refusal(out, -100.0, 100.0)
    assert reason is not None and "travel_max_deg 100" in reason
    back = plan_trapezoid(150.0, 0.0, v_max=100.0, a_max=1000.0)
    assert safety.travel_refusal(back, -100.0, 100.0) is None
    further = plan_trapezoid(150.0, 0.0, v_max=100.0, a_max=1000.0, v0=50.0)
    assert "travel_max_deg" in safety.travel_refusal(further, -100.0, 100.0)


def test_min_stop_decel_and_edge_speed():
    assert safety.min_stop_decel_dps2(0.0, 100.0, -100.0, 100.0) == pytest.approx(50.0)
    assert safety.min_stop_decel_dps2(0.0, -100.0, -50.0, 100.0) == pytest.approx(100.0)
    assert safety.min_stop_decel_dps2(100.0, 1.0, -100.0, 100.0) == math.inf
    assert safety.min_stop_decel_dps2(0.0, 0.0, -100.0, 100.0) == 0.0
    assert safety.edge_speed_dps(0.0, 50.0, -100.0, 100.0, 2000.0) == pytest.approx(632.455532)
    assert safety.edge_speed_dps(0.0, -50.0, -25.0, 100.0, 2000.0) == pytest.approx(316.227766)
    assert safety.edge_speed_dps(120.0, 150.0, -100.0, 100.0, 2000.0) == 0.0


# ------------------------------------------------------------------ §3 sensor diagnostics


def _open_and_move(sim, v_dps):
    """Open a session and send a Move towards a far target at ``v_dps``."""
    sim.pc_write(frame.encode(Hello(0, session=SESSION), 0))
    move = dataclasses.replace(_move(1, 30000.0, v=v_dps, a=2000.0), session=SESSION)
    sim.pc_write(frame.encode(move, 1))


def _freeze_run(kind, v_dps, *, seconds_before=3.0, seconds_after=2.0, **overrides):
    """Cruise at ``v_dps`` towards a far target, inject encoder fault ``kind`` (sim's
    fault-injection switch); return the log, the tick of the injection and the reports."""
    sim = Simulation(paper_bench(**overrides), seed=3)
    _open_and_move(sim, v_dps)
    k0 = round(seconds_before / sim.dt_s)
    sim.step(k0)
    sim.encoder.inject(kind, x=sim.plant_state)
    sim.step(round(seconds_after / sim.dt_s))
    reports = [m for m in frame.Decoder().feed(sim.pc_read()) if isinstance(m, FaultReport)]
    return sim.log(), k0, reports


# The back-EMF check with a model it takes as exact (no spread of the sense gain, the IS
# offset or R, no warm restart): the check as it was before a healthy board's spreads were
# allowed for.
EXACT_MODEL = {
    "safety.sensor_mismatch_sense_spread": 0.0,
    "safety.sensor_mismatch_offset_counts": 0,
    "safety.sensor_mismatch_r_spread": 0.0,
    "safety.sensor_mismatch_restart_rise_k": 0.0,
}
# The check without the warm restart's allowance (before 2 December 08:00: the datasheet's
# spreads alone; tests/firmware_model/test_sensor_spread.py pins the allowance).
NO_RESTART = {"safety.sensor_mismatch_restart_rise_k": 0.0}


@pytest.mark.parametrize(
    ("model", "ticks", "to_trip_deg", "to_rest_deg"),
    [
        # The datasheet's spreads (k_ILIS 3k-14k, 50 uA, R +-30 %) without the warm
        # restart's allowance (with it, the default: test_sensor_spread.py). The check
        # waits until the motor's back-EMF is beyond what any healthy board could explain:
        # measured 81-99 ticks, 61-63 deg to the trip (at ~647 deg/s), 101-103 deg to rest.
        ("datasheet", 120, 70.0, 110.0),
        # The model taken as exact: measured 7-25 ticks, 1.8-3.8 deg, 7.6-11.0 deg to rest.
        ("exact", 35, 5.0, 15.0),
    ],
)
@pytest.mark.parametrize("v_dps", [30.0, 100.0, 130.0])
def test_a_frozen_encoder_with_noise_on_it_is_flagged(v_dps, model, ticks, to_trip_deg,
                                                      to_rest_deg):  # fmt: skip
    # Before: the +-1 count of noise kept the stuck check from ever firing and the jump
    # check sees nothing below ~140 deg/s: the loop pushed the axis on (the issue saw 398 deg
    # at up to 1,141 deg/s before a following-error trip; disarmed here: 859-2,088 deg to rest).
    settings = EXACT_MODEL if model == "exact" else NO_RESTART
    log, k0, reports = _freeze_run("freeze", v_dps, **settings)
    assert [r.fault for r in reports] == [Fault.SENSOR_MISMATCH]
    k = reports[0].tick
    assert k - k0 < ticks
    assert log.true_pos_deg[k] - log.true_pos_deg[k0] < to_trip_deg
    assert log.true_pos_deg[-1] - log.true_pos_deg[k0] < to_rest_deg
    assert abs(log.true_vel_dps[-1]) < 0.5


def test_the_compiled_tick_catches_a_noisy_freeze(monkeypatch):
    # The checks run inside sim/tick.py's multi-tick call: the Python per-tick path
    # (Simulation._step) runs no tick, not even the boot (STOP_BOOT). Before, a run through
    # the compiled path skipped the back-EMF check, the AS5048 frames and the brake.
    python_ticks = []
    step = Simulation._step
    monkeypatch.setattr(Simulation, "_step", lambda self: python_ticks.append(1) or step(self))
    log, k0, reports = _freeze_run("freeze", 100.0)
    assert len(python_ticks) == 0
    assert [r.fault for r in reports] == [Fault.SENSOR_MISMATCH]
    k = reports[0].tick
    # The brake ran in the compiled tick too: bridge on at duty 0, the current reversed.
    assert np.all(log.voltage_v[k + 2 : k + 150] == 0.0) and log.current_a[k + 3] < -1.0
    assert abs(log.true_vel_dps[-1]) < 0.5


def _member_streams(monkeypatch):
    """Encoder noise drawn per member from its own generator (member j: seed 100 + j), so
    that member j of a batch reads what a single axis with that generator reads."""

    def refill(self, n, rows=4096):
        if getattr(self, "_streams", None) is None:
            self._streams = [np.random.default_rng(100 + j) for j in range(n)]
        self.block = np.stack([g.standard_normal(rows) for g in self._streams], axis=1)
        self.row = 0

    monkeypatch.setattr(Encoder, "refill", refill)


def _first_fault_tick(fault):
    hits = np.flatnonzero(fault)
    return int(hits[0]) if hits.size else -1


@pytest.mark.parametrize("v_dps", [60.0, 990.0])
def test_one_axis_and_a_batch_detect_a_freeze_at_the_same_tick(monkeypatch, v_dps):
    _member_streams(monkeypatch)
    ticks = {}
    for batch in (None, 3):
        sim = Simulation(paper_bench(), batch=batch, seed=3)
        _open_and_move(sim, v_dps)
        sim.step(1500)
        # Member 0 (and 2) frozen, member 1 healthy.
        sim.encoder.inject("freeze", members=[0, 2] if batch else None, x=sim.plant_state)
        sim.step(500)
        log = sim.log()
        ticks[batch] = np.atleast_2d(log.fault)
    one, many = ticks[None][0], ticks[3]
    k = _first_fault_tick(one)
    # at 60 deg/s measured 132 ticks (the datasheet's spreads and a warm restart's
    # allowance 3 s after power-up; 91 without the latter)
    assert 1500 < k < 1650
    assert _first_fault_tick(many[0]) == k and many[0][k] == one[k]
    assert 1500 < _first_fault_tick(many[2]) < 1650
    assert not many[1].any()  # the healthy member goes on


def test_a_freeze_at_full_speed_trips_at_once_and_the_brake_stops_the_axis():
    log, k0, reports = _freeze_run("freeze", 990.0)
    assert [r.fault for r in reports] == [Fault.ENCODER]  # the reading jumps off prediction
    assert reports[0].tick == k0 + 1
    # Dynamic braking: the motor's own back-EMF through its resistance (~16 A at first).
    k = reports[0].tick
    assert np.all(log.voltage_v[k + 2 : k + 150] == 0.0) and log.current_a[k + 5] < -10.0
    travel = log.true_pos_deg[-1] - log.true_pos_deg[k0]
    assert travel < 80.0  # measured 65.2 deg; coasting (brake_s = 0): 919 deg
    coast, _, _ = _freeze_run("freeze", 990.0, **{"safety.brake_s": 0.0})
    assert coast.true_pos_deg[-1] - coast.true_pos_deg[k0] > 800.0  # measured 918 deg


@pytest.mark.parametrize(
    ("kind", "error"),
    [
        ("mag_weak", "field_weak"),
        ("mag_strong", "field_strong"),
        ("cordic", "cordic_overflow"),
        ("parity", "angle_parity"),
        ("error_flag", "error_flag"),
    ],
)
def test_each_as5048_diagnostic_trips_encoder_diag_with_its_bit(kind, error):
    from firmware_model import as5048

    log, k0, reports = _freeze_run(kind, 200.0, seconds_before=1.0, seconds_after=1.0)
    assert [r.fault for r in reports] == [Fault.ENCODER_DIAG]
    assert int(reports[0].value) & (1 << as5048.ERROR_NAMES.index(error))
    assert reports[0].tick - k0 == FirmwareParams().safety.encoder_diag_ticks - 1
    # The corrupt angles were not used: the position stayed on the axis.
    k = reports[0].tick
    assert abs(log.pos_deg[k] - (log.true_pos_deg[k] + log.pos_deg[0] - log.true_pos_deg[0])) < 2


def test_one_corrupt_frame_is_bridged_by_the_prediction():
    sim = Simulation(paper_bench(), seed=3)
    _open_and_move(sim, 990.0)
    sim.step(1500)
    sim.encoder.inject("parity", x=sim.plant_state)
    sim.step(1)  # one frame with a flipped bit (the angle off by 8192 counts)
    sim.encoder.inject("none")
    sim.step(500)
    log = sim.log()
    assert np.all(log.fault == 0)
    offset = log.pos_deg[0] - log.true_pos_deg[0]
    assert np.max(np.abs(log.pos_deg[1490:] - log.true_pos_deg[1490:] - offset)) < 0.5


@pytest.mark.parametrize("supply_v", [20.0, 26.0])
def test_the_back_emf_check_holds_still_off_the_nominal_supply(supply_v):
    # The firmware assumes 24 V; the tuner spreads the supply over 20-26 V. Fig. 6's step
    # without planning (saturated duty, the hardest transients) must not trip it.
    from sim.reproduce.experiments import load, with_duration

    log = run(with_duration(load("fig6"), 4.0), overrides={"supply.voltage_v": supply_v}).log
    assert np.all(log.fault == 0)


# The back-EMF check's bus: the configured supply (the bus reading, 0 here, below the
# lock-out hold of 4096 counts, only tells it when the chip may be locked out).
CONFIGURED = (np.zeros(3, dtype=np.int64), 0.0, 4096.0)
# ... and a model it takes as exact: the current's gain and offset, R, no thermal rise.
EXACT = (0.0, 0.0, 0.0, np.zeros(3), 0.0, 0.0)


def test_sensor_mismatch_step_integrates_only_what_the_tolerance_does_not_explain():
    n = 3
    duty = np.array([0.5, 0.5, 0.5])
    current = np.zeros(n)
    emf = np.full(n, 0.02)  # V per deg/s: 0.5 * 24 V -> 600 deg/s
    vel = np.array([600.0, 0.0, 0.0])
    live = np.array([True, True, False])
    e = np.zeros(n)
    args = (24.0, np.zeros(n), emf, 0.002, 0.05, 100.0, 0.3, 1.0)
    worst = safety.sensor_mismatch_step(duty, current, vel, live, *args, e, *CONFIGURED, *EXACT)
    # member 1: |600 - 0| - (100 + 0.3 * 600) = 320 deg/s beyond, for 2 ms
    assert e[0] == 0.0 and e[1] == pytest.approx(0.64) and e[2] == 0.0 and worst == e[1]
    for _ in range(2000):
        safety.sensor_mismatch_step(duty, current, vel, live, *args, e, *CONFIGURED, *EXACT)
    assert e[1] == pytest.approx(320.0 * 0.05, rel=1e-3)  # the leaky window's steady state
    # One tick adds at most step_max_deg: a single wild sample cannot trip it.
    e[:] = 0.0
    clamped = (*args[:-1], 0.25)
    safety.sensor_mismatch_step(
        duty, np.full(n, -50.0), vel, live, *clamped, e, *CONFIGURED, *EXACT
    )
    assert e[1] == 0.25


def test_a_current_the_high_side_sense_cannot_see_spans_the_back_emf_speed():
    # Duty +0.1 (120 deg/s of drive at 24 V, 0.02 V per deg/s) and the law's model current
    # -5 A (against the duty: not a measurement): the back-EMF speed lies anywhere between
    # 120 deg/s (0 A) and 420 deg/s (-5 A through 1.2 ohm), so 200 deg/s is no mismatch,
    # 0 deg/s is 120 deg/s below it; with a measured +5 A the speed would be -180 deg/s.
    n = 3
    duty = np.full(n, 0.1)
    emf = np.full(n, 0.02)
    vel = np.array([200.0, 0.0, 200.0])
    current = np.array([-5.0, -5.0, 5.0])
    e = np.zeros(n)
    args = (24.0, np.full(n, 1.2), emf, 0.002, 0.05, 0.0, 0.0, 10.0)
    safety.sensor_mismatch_step(duty, current, vel, np.ones(n, bool), *args, e, *CONFIGURED, *EXACT)
    assert e[0] == 0.0
    assert e[1] == pytest.approx(120.0 * 0.002)
    assert e[2] == pytest.approx(380.0 * 0.002)


def _excess(vel, current, *, sense=0.0, offset_a=0.0, r_spread=0.0, winding_c=40.0,
            alpha=0.0):  # fmt: skip
    """One tick of the check, tolerance 0: duty 0.5 at 24 V and 0.02 V per deg/s (600 deg/s
    of drive), R 1 ohm; the excess of each member (deg)."""
    n = len(vel)
    e = np.zeros(n)
    est = np.full(n, winding_c)
    args = (24.0, np.ones(n), np.full(n, 0.02), 0.002, 0.05, 0.0, 0.0, 10.0)
    duty, live = np.full(n, 0.5), np.ones(n, bool)
    cur, v = np.asarray(current, float), np.asarray(vel, float)
    model = (sense, offset_a, r_spread, est, alpha, 40.0)
    safety.sensor_mismatch_step(duty, cur, v, live, *args, e, *CONFIGURED, *model)
    return e / 0.002  # deg/s beyond the interval


def test_the_back_emf_speed_is_an_interval_over_what_the_firmware_does_not_know():
    # A measured 5 A through 1 ohm: 350 deg/s with the model taken as exact.
    assert _excess([350.0, 460.0, 200.0], [5.0] * 3) == pytest.approx([0.0, 110.0, 150.0])
    # The sense gain within 1 +- 0.5: the true current 2.5-7.5 A, the speed 225-475 deg/s;
    # a runaway (the encoder faster than the interval's top) counts as a freeze does.
    got = _excess([460.0, 500.0, 200.0], [5.0] * 3, sense=0.5)
    assert got == pytest.approx([0.0, 25.0, 25.0])
    # The offset: a reading of 0.8 A that an offset of up to 1 A may be all of is perhaps a
    # current against the duty (blind): the speed is at least 600 - 1.8 * 1 / 0.02 = 510
    # deg/s, with no upper end; a reading of 3 A is 2-4 A (400-500 deg/s).
    got = _excess([2000.0, 400.0, 520.0], [0.8, 0.8, 3.0], offset_a=1.0)
    assert got == pytest.approx([0.0, 110.0, 20.0])
    # The same on the negative side (duty -0.5 mirrored: current and speeds negated).
    n = 3
    e = np.zeros(n)
    duty, cur, vel = np.full(n, -0.5), np.array([-0.8, -0.8, -3.0]), np.array([-2e3, -400, -520])
    args = (24.0, np.ones(n), np.full(n, 0.02), 0.002, 0.05, 0.0, 0.0, 10.0)
    model = (0.0, 1.0, 0.0, np.full(n, 40.0), 0.0, 40.0)
    safety.sensor_mismatch_step(duty, cur, vel, np.ones(n, bool), *args, e, *CONFIGURED, *model)
    assert e / 0.002 == pytest.approx([0.0, 110.0, 20.0])
    # R within 1 +- 0.2 ohm: 300-400 deg/s at 5 A.
    assert _excess([390.0, 410.0, 290.0], [5.0] * 3, r_spread=0.2) == pytest.approx(
        [0.0, 10.0, 10.0]
    )
    # The thermal estimate 25 K above its power-up ambient at 0.004 / K: R up to 1.1 ohm
    # (325-350 deg/s); it raises only the upper end (the winding is at least as warm).
    got = _excess([330.0, 300.0, 360.0], [5.0] * 3, winding_c=65.0, alpha=0.004)
    assert got == pytest.approx([0.0, 25.0, 10.0])
    # A current the sense cannot see (against the duty) keeps its 0 .. model interval,
    # widened by R: -5 A model, R 0.8-1.2 ohm: 600-900 deg/s.
    assert _excess([590.0, 880.0, 910.0], [-5.0] * 3, r_spread=0.2) == pytest.approx(
        [10.0, 0.0, 10.0]
    )


def _spread_run(fig, rows, **overrides):
    """``fig`` (Fig. 6 for 6 s) as one batch, member m with the plant overrides ``rows[m]``;
    the first fault each member latched (0: none) and the check's largest excess."""
    from sim.reproduce.experiments import load, with_duration

    exp = load(fig)
    exp = with_duration(exp, 6.0) if fig == "fig6" else exp
    ov = {key: [row[key] for row in rows] for key in rows[0]}
    holder = {}

    class Keep(Simulation):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            holder["sim"] = self

    import sim.loop as loop_module

    saved, loop_module.Simulation = loop_module.Simulation, Keep
    try:
        log = run(exp, batch=len(rows), overrides={**ov, **overrides}).log
    finally:
        loop_module.Simulation = saved
    first = [int(f[np.flatnonzero(f)[0]]) if f.any() else 0 for f in np.atleast_2d(log.fault)]
    return first, holder["sim"].fw.sensor_mismatch_peak_deg


R_NOMINAL_OHM = 1.2  # the bench's motor (bench_configs/paper_bench.toml [motor] r_ohm)
K_ILIS = (3000.0, 6000.0, 8500.0, 10000.0, 12000.0, 14000.0)  # datasheet min .. typ .. max
SPREAD = [
    {"current_sense.k_ilis": k, "motor.r_ohm": R_NOMINAL_OHM * r, "current_sense.is_offset_ua": 0.0}
    for k in K_ILIS
    for r in (0.7, 1.0, 1.3)
] + [
    {"current_sense.k_ilis": 8500.0, "motor.r_ohm": R_NOMINAL_OHM * r,
     "current_sense.is_offset_ua": o}  # fmt: skip
    for o in (25.0, 50.0)
    for r in (1.0, 1.3)
] + [{"current_sense.k_ilis": 14000.0, "motor.r_ohm": R_NOMINAL_OHM * 1.3,
      "current_sense.is_offset_ua": 50.0}]  # fmt: skip


@pytest.mark.parametrize("fig", ["fig6", "fig8"])
def test_a_healthy_board_within_its_datasheet_spreads_never_trips_the_back_emf_check(fig):
    # k_ILIS 3k-14k against the firmware's 8.5k, R x0.7-x1.3, the IS offset up to the
    # 50 uA the check allows for, uncalibrated (sense_offset_counts 0).
    first, peak = _spread_run(fig, SPREAD)
    assert Fault.SENSOR_MISMATCH not in first
    for row, f, p in zip(SPREAD, first, peak, strict=True):
        if row["current_sense.k_ilis"] < 8500.0 or row["current_sense.is_offset_ua"] > 0.0:
            # A chip that reads more than the current (k_ILIS 3k: 2.8x; 6k: 1.4x) or an
            # uncalibrated offset (it defeats the current loop's blind-side test in Fig. 6's
            # braking) may trip OVER_CURRENT, a different fault: measured in Fig. 6 for 3k
            # (0.008 s), 6k with R x0.7, 25 / 50 uA with R x1.0 (3.25 s); in Fig. 8 for 3k
            # with R x0.7 / x1.0.
            assert f in (0, Fault.OVER_CURRENT), row
        else:
            assert f == 0, row
            assert p < 0.75 / 2  # at most half the threshold (measured 0.22-0.25: the start)
    if fig == "fig6":
        assert first[:3] == [Fault.OVER_CURRENT] * 3  # k_ILIS 3k
    # The check as it was (the model taken as exact) trips on the same boards.
    before, _ = _spread_run(fig, SPREAD, **EXACT_MODEL)
    assert Fault.SENSOR_MISMATCH in before


@pytest.mark.parametrize("fig", ["fig6", "fig8"])
def test_with_the_offset_calibrated_the_grid_never_trips_the_back_emf_check(fig):
    # [controller.current] sense_calibration: the offset measured at power-up (both high
    # sides on; the check's allowance sensor_mismatch_calibrated_offset_counts, 2 by
    # default, with the warm restart's allowance: below and test_sensor_spread.py). The
    # same datasheet grid: no SENSOR_MISMATCH; the offset rows, which trip OVER_CURRENT
    # uncalibrated in Fig. 6, trip nothing.
    first, peak = _spread_run(fig, SPREAD, **{"controller.current.sense_calibration": True})
    assert Fault.SENSOR_MISMATCH not in first
    for row, f, p in zip(SPREAD, first, peak, strict=True):
        if row["current_sense.k_ilis"] < 8500.0:
            assert f in (0, Fault.OVER_CURRENT), row  # the chip reads 1.4-2.8x the current
        else:
            assert f == 0, row
            assert p < 0.75 / 2


# R x1.0 / x1.3 at its reference and k_ILIS 8.5k / 14k, the motor restarted warm (winding
# +55 K, housing +30 K: the firmware cannot know it) with the heat model on.
WARM_ROWS = [
    {"current_sense.k_ilis": k, "motor.r_ohm": R_NOMINAL_OHM * r}
    for k in (8500.0, 14000.0)
    for r in (1.0, 1.3)
]
WARM = {"thermal.model": True, "thermal.initial_winding_rise_k": 55.0,
        "thermal.initial_housing_rise_k": 30.0}  # fmt: skip


def test_the_calibrated_residual_alone_trips_a_warm_board_beyond_the_r_spread():
    # Why a warm restart needs its own allowance (docs/model.md "Safety", the decision):
    # without it (the restart key 0), narrowed to what the calibration leaves (2 counts),
    # the check trips a board at k_ILIS 14k with R x1.3 restarted warm (+55 K: R x1.58,
    # beyond the R spread of +-30 %). With the R spread at 0.5 it does not, nor on the
    # datasheet grid (a restart at the thermal trip still does: test_sensor_spread.py).
    cal = {"controller.current.sense_calibration": True,
           "safety.sensor_mismatch_calibrated_offset_counts": 2, **NO_RESTART}  # fmt: skip
    first, _ = _spread_run("fig6", WARM_ROWS, **WARM, **cal)
    assert first == [0, 0, 0, Fault.SENSOR_MISMATCH]
    first, peak = _spread_run(
        "fig6", WARM_ROWS, **WARM, **cal, **{"safety.sensor_mismatch_r_spread": 0.5}
    )
    assert first == [0, 0, 0, 0] and np.all(peak < 0.75 / 2)
    first, peak = _spread_run("fig6", SPREAD, **cal, **{"safety.sensor_mismatch_r_spread": 0.5})
    assert Fault.SENSOR_MISMATCH not in first
    assert all(
        f == 0
        for row, f in zip(SPREAD, first, strict=True)
        if row["current_sense.k_ilis"] >= 8500.0
    )


def test_a_warm_motor_with_the_heat_model_never_trips_the_back_emf_check():
    # The heat model on, the motor restarted warm (winding +55 K, housing +30 K: the firmware
    # cannot know it), R x1.0 / x1.3 at its reference and k_ILIS 8.5k / 14k.
    first, peak = _spread_run("fig6", WARM_ROWS, **WARM)
    assert first == [0, 0, 0, 0] and np.all(peak < 0.75 / 2)
    before, _ = _spread_run("fig6", WARM_ROWS, **WARM, **EXACT_MODEL)
    assert Fault.SENSOR_MISMATCH in before


# ------------------------------------------------------------------ power-up unwrapping


@pytest.mark.parametrize("batch", [None, 3])
def test_a_noisy_first_reading_below_zero_boots_one_count_off_not_one_motor_turn(batch):
    # Before: the count started at the raw reading, so an axis at rest on the encoder's
    # zero whose first (noisy) reading was 16383 booted 4.5 deg (one motor turn) away and
    # the whole run was shifted (Fig. 8 with noise seed 4 and 5).
    from firmware_model.firmware import Firmware
    from firmware_model.units import AXIS_DEG_PER_COUNT

    fw = Firmware(FirmwareParams(), batch=batch)
    first = 16383 if batch is None else np.array([16383, 0, 2])
    fw.servo_tick(first, b"", 4096)
    want = np.array([-1, 0, 2])[: 1 if batch is None else 3] * AXIS_DEG_PER_COUNT
    assert np.allclose(np.atleast_1d(fw.law.pos_deg), want)
    assert fw.sp_pos_deg == pytest.approx(want[0])
    # Beyond half a motor turn the reading is the other side of zero.
    fw = Firmware(FirmwareParams())
    fw.servo_tick(9000, b"", 4096)
    assert fw.law.pos_deg[0] == pytest.approx((9000 - 16384) * AXIS_DEG_PER_COUNT)


def test_fig8_with_noise_seed_4_boots_where_the_axis_is():
    from sim.reproduce.experiments import load, with_duration

    log = run(with_duration(load("fig8"), 0.1), seed=4).log
    assert abs(log.pos_deg[0] - log.true_pos_deg[0]) < 0.01  # was 4.4997 deg


def test_a_refusal_naming_another_messages_field_is_a_nack_not_a_crash():
    """Found by the 1,000,000-frame UART fuzz (chunk 18): a StreamControl ABORT whose Stop
    was refused NACKed with the Stop's field name, and building that NACK raised KeyError
    ("StreamControl has no field 'a_max_dps2'") out of the board. The NACK names no field."""
    from firmware_model.firmware import Firmware
    from serial_protocol.messages import NO_FIELD, StreamAction, StreamControl

    fw = Firmware(FirmwareParams())
    nack = fw._nack(StreamControl(7, StreamAction.ABORT), NackCode.TRAVEL, "a_max_dps2", 1.5)
    assert (nack.cmd_id, nack.code, nack.field, nack.limit) == (7, NackCode.TRAVEL, NO_FIELD, 1.5)
    assert nack.msg_type == int(MsgType.STREAM_CONTROL)


def test_the_back_emf_check_on_the_measured_bus():
    # Duty 0.5 at 0.02 V per deg/s, no current: 600 deg/s of back-EMF speed at 24 V, 700 at
    # a bus lifted to 28 V. An encoder reading 700 deg/s is 100 deg/s off the configured
    # supply's model (beyond a 50 deg/s tolerance) and exactly the measured bus's.
    n = 3
    v_count = 0.01  # V per count of the bus reading
    duty, current, emf = np.full(n, 0.5), np.zeros(n), np.full(n, 0.02)
    vel = np.full(n, 700.0)
    args = (24.0, np.zeros(n), emf, 0.002, 0.05, 50.0, 0.0, 1.0)
    bus = np.array([2800, 2800, 2900], dtype=np.int64)  # 28, 28 and 29 V
    e = np.zeros(n)
    safety.sensor_mismatch_step(duty, current, vel, np.ones(n, bool), *args, e, *CONFIGURED, *EXACT)
    assert e == pytest.approx(np.full(n, 50.0 * 0.002))
    e[:] = [0.0, 0.0, 0.3]
    safety.sensor_mismatch_step(
        duty, current, vel, np.ones(n, bool), *args, e, bus, v_count, 2850, *EXACT
    )
    # members 0 and 1: 28 V explains 700 deg/s; member 2 reads 29 V, at or above the hold
    # (2850 counts): perhaps locked out, its excess is kept as it was
    assert list(e) == [0.0, 0.0, 0.3]


def test_with_the_bus_model_the_check_on_the_measured_bus_catches_a_freeze():
    # The bus model on, the check's bridge voltage from the firmware's bus reading: a noisy
    # freeze is caught as on the stiff supply.
    bus = {"supply.bus_model": True, "safety.sensor_mismatch_measured_bus": True}
    log, k0, reports = _freeze_run("freeze", 100.0, **bus)
    assert [r.fault for r in reports] == [Fault.SENSOR_MISMATCH]
    _, k_stiff, stiff = _freeze_run("freeze", 100.0)
    assert abs((reports[0].tick - k0) - (stiff[0].tick - k_stiff)) <= 3
    assert abs(log.true_vel_dps[-1]) < 0.5


def test_the_measured_bus_lets_the_check_be_tighter():
    # A 20 V supply the firmware takes for 24 V: with a tolerance of 10 % of the speed the
    # back-EMF check false-trips on Fig. 6 with the bus model (peak excess measured 2.9 deg
    # against 0.75); on the measured bus it does not (0.34 deg), and it never trips while
    # the bridge is locked out at 28 V (the bus model's braking, held from bus_hold_v).
    from sim.reproduce.experiments import load, with_duration

    exp = with_duration(load("fig6"), 4.0)
    # (Measured with the model taken as exact, before the sense's and R's spreads.)
    tight = {
        "supply.bus_model": True,
        "supply.voltage_v": 20.0,
        "safety.sensor_mismatch_tolerance_ratio": 0.1,
        **EXACT_MODEL,
    }
    assumed = run(exp, overrides=tight).log
    assert Fault.SENSOR_MISMATCH in set(assumed.fault.tolist())
    measured = run(exp, overrides={**tight, "safety.sensor_mismatch_measured_bus": True}).log
    assert np.all(measured.fault == 0)
    locked = run(exp, overrides={**tight, "safety.sensor_mismatch_measured_bus": True,
                                 "supply.voltage_v": 24.0}).log  # fmt: skip
    assert locked.bus_v.max() > 28.0 and np.all(locked.fault == 0)


def _mismatch_oracle(duty, i, v, bus_v, r, ke, dt, window, tol_dps, ratio, step_max, excess,
                     spread, offset, r_spread, winding_c, alpha, ambient):  # fmt: skip
    """One live member's new excess by the docstring of ``sensor_mismatch_step``, computed in
    full (no shortcut), operation for operation as the kernel's full path."""
    drive = duty * bus_v / ke
    emf = drive - r * i / ke
    open_lo = open_hi = False
    if i * duty > 0.0:
        m = abs(i)
        top = (m + offset) * (1.0 + spread)
        blind = m <= offset
        bottom = 0.0 if blind else (m - offset) * (1.0 - spread)
        if i > 0.0:
            i_lo, i_hi, open_lo = bottom, top, blind
        else:
            i_lo, i_hi, open_hi = -top, -bottom, blind
    else:
        i_lo, i_hi = min(0.0, i), max(0.0, i)
    rise = 1.0 + alpha * max(winding_c - ambient, 0.0)
    r_lo = r * (1.0 - r_spread)
    r_hi = r * (1.0 + r_spread) * rise
    ri_max = r_hi * i_hi if i_hi >= 0.0 else r_lo * i_hi
    ri_min = r_lo * i_lo if i_lo >= 0.0 else r_hi * i_lo
    if open_hi:
        diff = max(v - (drive - ri_min / ke), 0.0)
    elif open_lo:
        diff = max((drive - ri_max / ke) - v, 0.0)
    else:
        lo, hi = drive - ri_max / ke, drive - ri_min / ke
        diff = lo - v if v < lo else (v - hi if v > hi else 0.0)
    tol = tol_dps + ratio * max(abs(emf), abs(v))
    e = excess * (1.0 - dt / window) + min((diff - tol) * dt, step_max)
    return e if e > 0.0 else 0.0


_SIGNED = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(
            _SIGNED, st.floats(-8.0, 8.0), st.floats(-60.0, 60.0), st.floats(0.05, 5.0),
            st.floats(0.005, 0.05), st.sampled_from([0.0, 1e-9, 0.3, 5.0]), st.floats(0.0, 0.99),
            st.floats(0.0, 0.5), st.floats(0.0, 0.99), st.floats(0.0, 160.0),
        ),
        min_size=1, max_size=12,
    ),
    st.floats(0.0, 200.0), st.sampled_from([0.0, 1e-6, 0.25]), st.floats(0.0, 0.01),
)
def test_sensor_mismatch_steps_shortcut_is_the_full_computation_bit_for_bit(
    members, tol_dps, ratio, alpha
):
    # The kernel skips the interval for a member with no excess whose encoder speed is
    # within tolerance_dps of the back-EMF speed (its docstring says why that gives 0.0):
    # speeds drawn around that boundary, the excess 0 or carried, every sign of duty and
    # current, blind and measured currents; the model's spreads as the firmware may set them.
    # (Each member takes the shared spreads of the first: the kernel's are per call.)
    n = len(members)
    duty = np.array([m[0] for m in members])
    cur = np.array([m[1] for m in members])
    r = np.array([m[3] for m in members])
    ke = np.array([m[4] for m in members])
    excess = np.array([m[5] for m in members])
    spread, offset, r_spread = members[0][6], members[0][7], members[0][8]
    winding = np.array([m[9] for m in members])
    drive = duty * 24.0 / ke
    emf = drive - r * cur / ke
    # around |v - emf| = tol_dps (every other member: within 2 % of it, either side),
    # elsewhere anywhere within 60 deg/s
    near = np.array([m[2] for m in members]) / 3000.0  # -0.02 .. 0.02
    side = np.where(np.arange(n) % 4 < 2, 1.0, -1.0)
    v = np.where(
        np.arange(n) % 2 == 0, emf + side * tol_dps * (1.0 + near),
        emf + np.array([m[2] for m in members]),
    )  # fmt: skip
    args = (24.0, r, ke, 0.002, 0.05, tol_dps, ratio, 10.0)
    e = excess.copy()
    worst = safety.sensor_mismatch_step(
        duty, cur, v, np.ones(n, bool), *args, e, np.zeros(n, np.int64), 0.0, 4096.0,
        spread, offset, r_spread, winding, alpha, 40.0,
    )  # fmt: skip
    want = [
        _mismatch_oracle(duty[j], cur[j], v[j], 24.0, r[j], ke[j], 0.002, 0.05, tol_dps, ratio,
                         10.0, excess[j], spread, offset, r_spread, winding[j], alpha, 40.0)
        for j in range(n)
    ]  # fmt: skip
    assert e.tobytes() == np.array(want).tobytes()
    assert worst == max([0.0, *want])
