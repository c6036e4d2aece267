"""The IS-offset calibration at enable (issue 13 §2.3): the bridge's both-high-sides state
(``sim.bridge.apply_bridge`` / ``read_adc``), the firmware's calibration
(``firmware_model.sense_calibration``, ``[controller.current] sense_calibration``), its
answers on the wire, and what it changes for the sense and the back-EMF check."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from firmware_model.laws.layout import C_CAL_LEFT, C_SENSE_OFFSET_A, C_SENSE_OFFSET_B
from firmware_model.sense_calibration import IMPLAUSIBLE, MOVED, judge
from firmware_model.tick import FS_MM_OFFSET_A
from serial_protocol import frame
from serial_protocol.host import BoardClient
from serial_protocol.messages import (
    Ack,
    Fault,
    FaultFlag,
    FaultReport,
    Hello,
    Move,
    Nack,
    NackCode,
    Profile,
    SetEnable,
    State,
)
from sim import loop
from sim.bridge import N_PW, PW_OFFSET, PW_OFFSET_NEG, apply_bridge, pwm_sense_table, read_adc
from sim.config import load_bench
from sim.loop import Simulation
from sim.params import CurrentSenseParams
from sim.plant import Plant
from sim.reproduce import experiments
from sim.simlink import SimulatedLink

BENCH = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"
CAL = {"controller.current.sense_calibration": True}
A_PER_LSB = CurrentSenseParams().a_per_lsb  # 6.85 mA of load current per count
NO_DRAW = np.empty(0)


def _counts(current_a: float) -> int:
    """The ADC's reading of a load current (A) as the chip mirrors it, rounded to nearest."""
    return math.floor(current_a / A_PER_LSB + 0.5)


def _sense(bench, offset_ua: float, n: int = 1, mismatch_ua: float = 0.0):
    sense = CurrentSenseParams(is_offset_ua=offset_ua, is_offset_mismatch_ua=mismatch_ua)
    return pwm_sense_table(sense, bench.plant.bridge, bench.plant.motor.l_h, n)


def _read(x, sign, table):
    n = x.shape[0]
    out = np.empty(n, dtype=np.int64)
    read_adc(
        x, sign, np.full(n, A_PER_LSB), np.zeros(n), NO_DRAW, 4095, out,
        (np.zeros(n), np.zeros(n), table),
    )  # fmt: skip
    return out


def test_both_high_sides_apply_no_voltage_and_pick_the_pin_by_parity():
    n = 4
    duty = np.array([0.7, -0.3, 0.5, 0.0])
    enable = np.array([True, True, False, False])
    high = np.array([0, 5, 4, 1], dtype=np.int64)  # member 0 runs the ordinary bridge
    d, en, sign, volt = np.empty(n), np.empty(n, dtype=bool), np.empty(n), np.empty(n)
    apply_bridge(duty, enable, high, np.full(n, 3600.0), np.full(n, 24.0), d, en, sign, volt)
    np.testing.assert_array_equal(d, [0.7, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(en, [True, True, True, True])  # on whatever enable says
    np.testing.assert_array_equal(sign, [1.0, -2.0, 2.0, -2.0])
    np.testing.assert_array_equal(volt, [0.7 * 24.0, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("offset_ua", [0.0, 25.0, 50.0, 200.0])
def test_at_rest_each_pin_reads_exactly_the_offset(offset_ua):
    bench = load_bench(BENCH)
    table = _sense(bench, offset_ua, 2)
    x = np.zeros((2, 5))
    got = _read(x, np.array([2.0, -2.0]), table if offset_ua else np.zeros((0, N_PW)))
    want = _counts(offset_ua * 1e-6 * 8500.0)  # I_ISH as load current: k_ILIS times it
    assert table.shape[0] == 0 or table[0, PW_OFFSET] == pytest.approx(offset_ua * 1e-6 * 8500)
    np.testing.assert_array_equal(got, [want, want])
    assert want == {0.0: 0, 25.0: 31, 50.0: 62, 200.0: 248}[offset_ua]


def test_turning_the_pins_read_the_back_emf_loop_current():
    # Both terminals at the supply: L di/dt = -R i - K_e w. After a few L/R (0.5 ms) the
    # current is the back-EMF's, -K_e w / R (quasi-steady: the motor slows with a time
    # constant of ~72 ms, 150 times L/R); the pin whose high side carries it forward reads
    # it plus the offset, the other pin the offset alone.
    bench = load_bench(BENCH)
    plant_p = bench.plant
    r = plant_p.motor.r_ohm + plant_p.bridge.r_on_path_ohm
    ke, l_h = plant_p.motor.ke_v_s_rad, plant_p.motor.l_h
    h = 1.0 / 500.0
    plant = Plant(plant_p, 2, h, bench.loop.event_levels)
    x = np.zeros((2, 5))
    x[:, 2] = [600.0, -300.0]  # rad/s at the motor (~360 and ~180 deg/s at the axis)
    d, en = np.zeros(2), np.ones(2, dtype=bool)  # the plant's view of both high sides on
    for _ in range(3):
        before = x
        x = plant.update(0.0, x, (d, en))
    w = x[:, 2]
    # 0 = R i + K_e w + L di/dt with di/dt = -(K_e / R) dw/dt to first order: the
    # quasi-steady current and its lag (~1 % here: the motor brakes at ~8,000 rad/s^2).
    w_dot = (x[:, 2] - before[:, 2]) / h
    i_quasi = -ke * w / r + l_h * ke / r**2 * w_dot
    np.testing.assert_allclose(x[:, 0], i_quasi, rtol=2e-3)
    assert np.all(np.abs(x[:, 0] + ke * w / r) < 0.02 * np.abs(x[:, 0]))
    table = _sense(bench, 50.0, 2)
    off = 50e-6 * 8500.0
    pin_a = _read(x, np.array([2.0, 2.0]), table)  # the positive half-bridge's pin
    pin_b = _read(x, np.array([-2.0, -2.0]), table)
    want_a = [_counts(max(0.0, i) + off) for i in x[:, 0]]
    want_b = [_counts(max(0.0, -i) + off) for i in x[:, 0]]
    np.testing.assert_array_equal(pin_a, want_a)
    np.testing.assert_array_equal(pin_b, want_b)
    assert pin_a[1] > 400 and pin_b[0] > 700  # the loop current, amps of it
    assert pin_a[0] == pin_b[1] == 62  # the other pin: the offset alone
    assert l_h / r < 1e-3


def test_judge():
    # 16 readings, 8 per pin: each pin's mean rounded half up; the reasons.
    offset_a, offset_b, reason = judge(
        np.array([8 * 62, 8 * 62, 8 * 62, -1, 8 * 300, 8 * 10, 8 * 62]),
        np.array([8 * 62, 8 * 62 + 4, 8 * 62 + 72, 0, 8 * 300, 8 * 250, 8 * 62 + 3]),
        16, 8, 248,
    )  # fmt: skip
    # (496 + 4) / 8 = 62.5 rounds up to 63; 499 / 8 = 62.375 to 62
    np.testing.assert_array_equal(offset_a, [62, 62, 62, 0, 300, 10, 62])
    np.testing.assert_array_equal(offset_b, [62, 63, 71, 0, 300, 250, 62])
    np.testing.assert_array_equal(reason, [0, 0, MOVED, MOVED, IMPLAUSIBLE, MOVED, 0])
    # The default pin bound (248 counts: two offsets within 0-200 uA) accepts pins apart
    # by anything two datasheet offsets can be; one pin above the ceiling is implausible.
    _, _, reason = judge(np.array([8 * 10, 8 * 10]), np.array([8 * 250, 8 * 240]), 16, 248, 248)
    np.testing.assert_array_equal(reason, [IMPLAUSIBLE, 0])


@pytest.mark.parametrize("arithmetic", ["float", "fixed"])
@pytest.mark.parametrize(
    ("offset_ua", "mismatch_ua"), [(50.0, 40.0), (50.0, -60.0), (120.0, 150.0)]
)
def test_each_pin_s_offset_is_calibrated_and_subtracted_from_its_own_readings(
    arithmetic, offset_ua, mismatch_ua
):
    # Two chips, two offsets: pin + (the half-bridge driving positive current) at
    # offset + mismatch / 2, pin - at offset - mismatch / 2 (load-current amperes: k_ILIS
    # times I_ISH). Each is recovered within one ADC count's share of its value (the ADC
    # rounds it to a count, the mean of 8 noiseless readings is that count) ...
    over = {"current_sense.is_offset_ua": offset_ua,
            "current_sense.is_offset_mismatch_ua": mismatch_ua, "servo.arithmetic": arithmetic}
    sim = _sim(**over)
    sim.step(20)
    want_a = (offset_ua + mismatch_ua / 2) * 1e-6 * 8500.0
    want_b = (offset_ua - mismatch_ua / 2) * 1e-6 * 8500.0
    got_a = sim.fw.law.C[C_SENSE_OFFSET_A, 0] * A_PER_LSB
    got_b = sim.fw.law.C[C_SENSE_OFFSET_B, 0] * A_PER_LSB
    assert abs(got_a - want_a) <= A_PER_LSB / 2 and abs(got_b - want_b) <= A_PER_LSB / 2
    assert sim.fw.law.C[C_SENSE_OFFSET_A, 0] == _counts(want_a)
    assert sim.fw.law.C[C_SENSE_OFFSET_B, 0] == _counts(want_b)
    client = BoardClient(SimulatedLink(sim, ticks_per_poll=2), ack_timeout_s=30.0)
    status = client.status()  # both on the wire (f32)
    assert status.sense_offset_a == pytest.approx(got_a, rel=1e-6)
    assert status.sense_offset_neg_a == pytest.approx(got_b, rel=1e-6)
    # ... and each reading loses its own pin's offset: the measured current of a move
    # both ways is the plant's (within the sense's count and ripple-free averaging).
    sim.pc_write(frame.encode(Hello(cmd_id=1, session=2), 0))
    sim.pc_write(frame.encode(Move(2, 20.0, 200.0, 2000.0, 0.0, Profile.TRAPEZOID, 2), 1))
    sim.step(400)
    sim.pc_write(frame.encode(Move(3, -20.0, 200.0, 2000.0, 0.0, Profile.TRAPEZOID, 2), 2))
    sim.step(400)
    log = sim.log()
    assert np.all(log.fault == 0)
    # Where the pin reads forward current (the duty's direction), the firmware's reading
    # is the true current to within two counts (the reading lags the plant by a period).
    fwd = (log.duty * log.current_a > 0) & (np.abs(log.current_a) > 0.3)
    assert fwd.sum() > 100 and (log.duty[fwd] < 0).sum() > 30
    err = np.abs(log.current_meas_a[fwd] - log.current_a[fwd])
    assert np.median(err) < 2 * A_PER_LSB


def test_one_offset_for_both_pins_misreads_the_other_direction():
    # The pre-per-pin firmware (one offset, the mean of both pins) misreads each direction
    # by half the mismatch: measured with the configured (not calibrated) mean offset.
    bench = load_bench(BENCH)
    table = _sense(bench, 50.0, 2, mismatch_ua=40.0)
    assert table[0, PW_OFFSET] == pytest.approx(70e-6 * 8500.0)
    assert table[0, PW_OFFSET_NEG] == pytest.approx(30e-6 * 8500.0)
    got = _read(np.zeros((2, 5)), np.array([2.0, -2.0]), table)
    np.testing.assert_array_equal(got, [_counts(70e-6 * 8500.0), _counts(30e-6 * 8500.0)])
    with pytest.raises(ValueError, match="is_offset_mismatch_ua"):
        CurrentSenseParams(is_offset_ua=10.0, is_offset_mismatch_ua=30.0)


def _sim(**overrides):
    return Simulation(load_bench(BENCH), seed=3, overrides={**CAL, **overrides})


@pytest.mark.parametrize("arithmetic", ["float", "fixed"])
@pytest.mark.parametrize("offset_ua", [0.0, 50.0])
def test_power_up_calibration_learns_the_offset(arithmetic, offset_ua):
    sim = _sim(**{"current_sense.is_offset_ua": offset_ua, "servo.arithmetic": arithmetic})
    samples = sim.fw.params.current.sense_calibration_samples
    sim.step(1)  # the boot: enabled, calibrating
    assert sim.fw.law.C[C_CAL_LEFT, 0] == samples + 1 - 1
    sim.step(samples - 1)
    assert sim.fw.law.C[C_CAL_LEFT, 0] == 1 and sim.fw.state == State.IDLE
    log = sim.log()
    assert np.all(log.voltage_v == 0.0) and np.all(log.duty == 0.0)
    sim.step(1)
    assert sim.fw.law.C[C_CAL_LEFT, 0] == 0
    assert sim.fw.law.C[C_SENSE_OFFSET_A, 0] == (62 if offset_ua else 0)
    assert sim.fw.law.C[C_SENSE_OFFSET_B, 0] == (62 if offset_ua else 0)
    client = BoardClient(SimulatedLink(sim, ticks_per_poll=2), ack_timeout_s=30.0)
    status = client.status()
    assert status.sense_offset_a == pytest.approx(sim.fw.law.C[C_SENSE_OFFSET_A, 0] * A_PER_LSB)
    assert status.sense_offset_neg_a == status.sense_offset_a
    # the loops hold the axis after it
    sim.step(200)
    assert abs(sim.fw.signals()["pos_deg"]) < 0.05 and sim.fw.fault == 0


def test_noisy_adc_calibrates_within_its_averaging():
    # 2 LSB rms of ADC noise on 200 members (each its own draws): each pin's mean of 8
    # readings is within 2 / sqrt(8) = 0.71 LSB rms of its offset (62.06 counts), then
    # rounded (+ 1/12 of a count squared).
    sim = Simulation(
        load_bench(BENCH), batch=200, seed=1,
        overrides={**CAL, "current_sense.is_offset_ua": 50.0, "current_sense.noise_rms_lsb": 2.0},
    )  # fmt: skip
    sim.step(40)
    for row in (C_SENSE_OFFSET_A, C_SENSE_OFFSET_B):
        offset = sim.fw.law.C[row]
        assert abs(offset.mean() - 62.06) < 0.2
        assert 0.55 < offset.std() < 0.95
        assert np.all(np.abs(offset - 62) <= 3)
    assert np.all(sim.fw.state == State.IDLE)


def test_set_enable_is_answered_when_the_calibration_ends():
    sim = _sim(**{"servo.start_enabled": False, "current_sense.is_offset_ua": 50.0})
    client = BoardClient(SimulatedLink(sim, ticks_per_poll=1), ack_timeout_s=30.0)
    client.hello()
    assert client.status().state is State.DISABLED
    sent = sim.tick
    reply = client.set_enable(True)
    assert isinstance(reply, Ack)
    # 17 current-loop periods (the one that switches, then 16 readings) after it arrived
    assert sim.tick - sent >= 17
    assert client.status().state is State.IDLE
    assert sim.fw.law.C[C_SENSE_OFFSET_A, 0] == sim.fw.law.C[C_SENSE_OFFSET_B, 0] == 62
    assert sim.fw.counters["commands_applied"] >= 1


def test_a_turning_axis_is_refused():
    sim = _sim(**{"servo.start_enabled": False})
    client = BoardClient(SimulatedLink(sim, ticks_per_poll=1), ack_timeout_s=30.0)
    client.hello()
    sim._x[0, 2] = 100.0  # the motor turns at 100 rad/s (~72 deg/s at the axis), coasting
    sim.step(5)
    reply = client.set_enable(True)
    assert isinstance(reply, Nack) and reply.code is NackCode.BUSY
    assert reply.limit == pytest.approx(1.0)
    assert sim.fw.state == State.DISABLED and sim.fw.law.C[C_CAL_LEFT, 0] == 0
    # Refused at the command (before any calibration): not a fault, a "not now".
    assert client.status().fault is Fault.NONE


def _fault_reports(sim):
    return [m for m in frame.Decoder().feed(sim.pc_read()) if isinstance(m, FaultReport)]


def test_a_failed_calibration_latches_a_fault_the_pc_can_read_later():
    # N = 1: the SetEnable is NACKed as before, and the board says why when asked later:
    # Status.fault / fault_flags, GetFault (value, threshold), a FaultReport. ClearFault
    # then SetEnable tries again.
    sim = _sim(**{"servo.start_enabled": False, "current_sense.is_offset_ua": 300.0})
    client = BoardClient(SimulatedLink(sim, ticks_per_poll=1), ack_timeout_s=30.0)
    client.hello()
    reply = client.set_enable(True)
    assert isinstance(reply, Nack) and reply.code is NackCode.SENSE_OFFSET
    sim.step(300)  # no brake: the bridge stays off
    assert np.all(sim.log().voltage_v[-300:] == 0.0) and np.all(sim.log().duty[-300:] == 0.0)
    status = client.status()
    assert status.state is State.FAULT and status.fault is Fault.SENSE_OFFSET
    assert status.fault_flags == FaultFlag.SENSE_OFFSET == 1 << 5
    info = client.get_fault(5)
    assert info.latched
    assert info.value == pytest.approx(_counts(300e-6 * 8500.0) * A_PER_LSB, rel=1e-6)
    assert info.threshold == pytest.approx(248 * A_PER_LSB, rel=1e-6)
    assert isinstance(client.set_enable(True), Nack)  # FAULT_ACTIVE until cleared
    assert isinstance(client.clear_fault(), Ack)
    assert client.status().state is State.DISABLED
    assert isinstance(client.set_enable(True), Nack)  # the pin is still bad: again
    assert client.status().fault is Fault.SENSE_OFFSET


def test_an_axis_turning_during_the_calibration_latches_calibration_motion():
    # The axis starts turning after the SetEnable was accepted (pushed: a torque on it);
    # the encoder sees it: abandoned, CALIBRATION_MOTION with the speed in deg/s.
    sim = _sim(**{"servo.start_enabled": False})
    sim.pc_write(frame.encode(Hello(cmd_id=1, session=2), 0))
    sim.step(3)
    sim.pc_write(frame.encode(SetEnable(cmd_id=2, enable=True, session=2), 1))
    sim.step(6)
    assert sim.fw.law.C[C_CAL_LEFT, 0] > 0
    sim._x[0, 2] = 100.0  # ~72 deg/s at the axis
    sim.step(20)
    assert sim.fw.state == State.FAULT
    (report,) = _fault_reports(sim)
    assert report.fault is Fault.CALIBRATION_MOTION
    assert report.fault_flags == FaultFlag.CALIBRATION_MOTION == 1 << 11
    assert report.value > 1.0 and report.threshold == pytest.approx(1.0)


def test_a_batch_member_whose_calibration_fails_has_its_fault_code():
    # Before: the member stayed DISABLED with no fault code; the others enable.
    sim = Simulation(
        load_bench(BENCH), batch=3, seed=3,
        overrides={**CAL, "current_sense.is_offset_ua": [50.0, 300.0, 0.0]},
    )  # fmt: skip
    sim.step(40)
    np.testing.assert_array_equal(sim.fw.fault, [0, Fault.SENSE_OFFSET, 0])
    np.testing.assert_array_equal(sim.fw.state, [State.IDLE, State.FAULT, State.IDLE])
    log = sim.log()
    assert log.fault[1, -1] == Fault.SENSE_OFFSET and log.fault[0, -1] == 0
    # the pins apart by more than the bound (set low): CALIBRATION_MOTION, in deg/s
    sim = Simulation(
        load_bench(BENCH), batch=2, seed=3,
        overrides={**CAL, "current_sense.is_offset_ua": 50.0,
                   "current_sense.is_offset_mismatch_ua": [0.0, 40.0],
                   "controller.current.sense_calibration_pin_counts": 8},
    )  # fmt: skip
    sim.step(40)
    np.testing.assert_array_equal(sim.fw.fault, [0, Fault.CALIBRATION_MOTION])


def test_an_implausible_offset_is_refused():
    # 300 uA: 372 counts, above the datasheet's 200 uA (248 counts)
    sim = _sim(**{"servo.start_enabled": False, "current_sense.is_offset_ua": 300.0})
    client = BoardClient(SimulatedLink(sim, ticks_per_poll=1), ack_timeout_s=30.0)
    client.hello()
    reply = client.set_enable(True)
    assert isinstance(reply, Nack) and reply.code is NackCode.SENSE_OFFSET
    assert reply.limit == pytest.approx(248 * A_PER_LSB, rel=1e-6)
    sim.step(20)
    assert sim.fw.state == State.FAULT  # SENSE_OFFSET latched (below)
    assert np.all(sim.log().voltage_v[-10:] == 0.0)


def test_a_retry_during_the_calibration_is_answered_once():
    sim = _sim(**{"servo.start_enabled": False})
    decoder = frame.Decoder()
    sim.pc_write(frame.encode(Hello(cmd_id=1, session=9), 0))
    sim.step(5)
    msg = SetEnable(cmd_id=7, enable=True, session=9)
    for k in range(3):  # the same command three times before the calibration ends
        sim.pc_write(frame.encode(msg, k + 1))
        sim.step(3)
    sim.step(30)
    replies = [m for m in decoder.feed(sim.pc_read()) if isinstance(m, Ack | Nack)]
    assert replies == [Ack(7, int(SetEnable.MSG_TYPE))]
    assert sim.fw.counters["duplicates"] == 2


def test_the_mismatch_check_takes_the_calibrated_allowance():
    on = _sim(**{"safety.sensor_mismatch_calibrated_offset_counts": 2})
    off = Simulation(load_bench(BENCH), seed=3)
    a = on.fw.params.current.a_per_adc
    assert on.fw._fs[FS_MM_OFFSET_A] == pytest.approx(2 * a)
    assert off.fw._fs[FS_MM_OFFSET_A] == pytest.approx(62 * a)


@pytest.mark.parametrize("arithmetic", ["float", "fixed"])
def test_fig6_with_a_calibrated_offset_is_fig6(arithmetic):
    # 50 uA uncalibrated trips OVER_CURRENT in Fig. 6's braking (test_current_sense); the
    # offset calibrated at power-up gives back the 5 A clamp and the overshoot, no trip.
    arith = {"servo.arithmetic": arithmetic}
    exp = experiments.with_duration(experiments.load("fig6"), 4.0)
    cal = loop.run(exp, seed=0, overrides={**arith, **CAL, "current_sense.is_offset_ua": 50.0}).log
    base = loop.run(exp, seed=0, overrides=arith).log
    w = (base.t_s > 0.1) & (base.t_s < 0.15)
    assert np.all(cal.fault == 0)
    assert cal.current_a[w].mean() == pytest.approx(5.0, abs=0.02)
    assert abs(cal.true_pos_deg.max() - base.true_pos_deg.max()) < 1.0


@pytest.mark.parametrize("batch", [None, 3])
def test_the_compiled_tick_and_the_python_step_calibrate_alike(batch):
    # One implementation: the compiled multi-tick run and the firmware's one-tick API
    # (record_inputs=True steps through Firmware.servo_tick / current_tick) give the same
    # log, bit for bit, through the calibration and a move after it.
    over = {**CAL, "current_sense.is_offset_ua": [0.0, 25.0, 50.0] if batch else 50.0,
            "current_sense.noise_rms_lsb": 1.0}  # fmt: skip
    logs = []
    for record in (False, True):
        sim = Simulation(
            load_bench(BENCH), batch=batch, seed=5, overrides=over, record_inputs=record
        )
        sim.pc_write(frame.encode(Hello(cmd_id=1, session=2), 0))
        sim.pc_write(frame.encode(Move(2, 20.0, 200.0, 2000.0, 0.0, Profile.TRAPEZOID, 2), 1))
        sim.step(150)
        logs.append((sim.log(), np.array(sim.fw.law.C[C_SENSE_OFFSET_A]), sim.pc_read()))
    (a, off_a, bytes_a), (b, off_b, bytes_b) = logs
    np.testing.assert_array_equal(off_a, off_b)
    assert bytes_a == bytes_b
    for f in ("current_a", "voltage_v", "duty", "pos_deg", "current_meas_a", "state"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    # within a count of the offset (at 0 the ADC clips the noise's negative half: reads high)
    assert np.all(np.abs(off_a - np.array([0, 31, 62] if batch else [62])) <= 1)


def test_injected_sense_faults_short_and_stuck_the_reading():
    # sim.bridge.inject_sense_fault: the averaged sense's empty table becomes the neutral
    # full one (the same readings), then a short reads 0 V and a stuck pin holds the next
    # reading; "clear" gives the reading back.
    from sim.bridge import inject_sense_fault

    x = np.zeros((3, 5))
    x[:, 0] = [2.0, -1.5, 4.0]
    sign = np.array([1.0, -1.0, 1.0])
    table = inject_sense_fault(np.zeros((0, N_PW)), 3, "clear")
    np.testing.assert_array_equal(_read(x, sign, table), _read(x, sign, np.zeros((0, N_PW))))
    short = inject_sense_fault(table, 3, "short", [0])
    np.testing.assert_array_equal(_read(x, sign, short), [0, _counts(1.5), _counts(4.0)])
    stuck = inject_sense_fault(table, 3, "stuck")
    first = _read(x, sign, stuck)
    x[:, 0] = [3.0, -0.5, 1.0]
    np.testing.assert_array_equal(_read(x, sign, stuck), first)
    cleared = inject_sense_fault(stuck, 3, "clear")
    want = [_counts(3.0), _counts(0.5), _counts(1.0)]
    np.testing.assert_array_equal(_read(x, sign, cleared), want)
    with pytest.raises(ValueError, match="open"):
        inject_sense_fault(table, 3, "open")
