"""The IS-offset calibration at enable (issue 13 §2.3): the bridge's both-high-sides state
(``sim.bridge.apply_bridge`` / ``read_adc``), the firmware's calibration
(``firmware_model.sense_calibration``, ``[controller.current] sense_calibration``), its
answers on the wire, and what it changes for the sense and the back-EMF check."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from firmware_model.laws.layout import C_CAL_LEFT, C_SENSE_OFFSET
from firmware_model.sense_calibration import IMPLAUSIBLE, MOVED, judge
from firmware_model.tick import FS_MM_OFFSET_A
from serial_protocol import frame
from serial_protocol.host import BoardClient
from serial_protocol.messages import Ack, Hello, Move, Nack, NackCode, Profile, SetEnable, State
from sim import loop
from sim.bridge import PW_OFFSET, apply_bridge, pwm_sense_table, read_adc
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


def _sense(bench, offset_ua: float, n: int = 1):
    sense = CurrentSenseParams(is_offset_ua=offset_ua)
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
    got = _read(x, np.array([2.0, -2.0]), table if offset_ua else np.zeros((0, 5)))
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
    # 16 readings, 8 per pin: the mean rounded half up; the reasons.
    offset, reason = judge(
        np.array([8 * 62, 8 * 62, 8 * 62, -1, 8 * 300]),
        np.array([8 * 62, 8 * 62 + 4, 8 * 62 + 72, 0, 8 * 300]),
        16, 8, 248,
    )  # fmt: skip
    np.testing.assert_array_equal(offset, [62, 62, 67, 0, 300])  # (992 + 4) / 16 = 62.25
    np.testing.assert_array_equal(reason, [0, 0, MOVED, MOVED, IMPLAUSIBLE])


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
    assert sim.fw.law.C[C_SENSE_OFFSET, 0] == (62 if offset_ua else 0)
    client = BoardClient(SimulatedLink(sim, ticks_per_poll=2), ack_timeout_s=30.0)
    status = client.status()
    assert status.sense_offset_a == pytest.approx(sim.fw.law.C[C_SENSE_OFFSET, 0] * A_PER_LSB)
    # the loops hold the axis after it
    sim.step(200)
    assert abs(sim.fw.signals()["pos_deg"]) < 0.05 and sim.fw.fault == 0


def test_noisy_adc_calibrates_within_its_averaging():
    # 2 LSB rms of ADC noise on 200 members (each its own draws): the mean of 16 readings
    # is within 2 / sqrt(16) = 0.5 LSB rms of the offset (62.06 counts), then rounded.
    sim = Simulation(
        load_bench(BENCH), batch=200, seed=1,
        overrides={**CAL, "current_sense.is_offset_ua": 50.0, "current_sense.noise_rms_lsb": 2.0},
    )  # fmt: skip
    sim.step(40)
    offset = sim.fw.law.C[C_SENSE_OFFSET]
    assert abs(offset.mean() - 62.06) < 0.15
    assert 0.4 < offset.std() < 0.7
    assert np.all(np.abs(offset - 62) <= 2)  # the back-EMF check's calibrated allowance
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
    assert sim.fw.law.C[C_SENSE_OFFSET, 0] == 62
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


def test_an_implausible_offset_is_refused():
    # 300 uA: 372 counts, above the datasheet's 200 uA (248 counts)
    sim = _sim(**{"servo.start_enabled": False, "current_sense.is_offset_ua": 300.0})
    client = BoardClient(SimulatedLink(sim, ticks_per_poll=1), ack_timeout_s=30.0)
    client.hello()
    reply = client.set_enable(True)
    assert isinstance(reply, Nack) and reply.code is NackCode.SENSE_OFFSET
    assert reply.limit == pytest.approx(248 * A_PER_LSB, rel=1e-6)
    sim.step(20)
    assert sim.fw.state == State.DISABLED
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
        logs.append((sim.log(), np.array(sim.fw.law.C[C_SENSE_OFFSET]), sim.pc_read()))
    (a, off_a, bytes_a), (b, off_b, bytes_b) = logs
    np.testing.assert_array_equal(off_a, off_b)
    assert bytes_a == bytes_b
    for f in ("current_a", "voltage_v", "duty", "pos_deg", "current_meas_a", "state"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    # within a count of the offset (at 0 the ADC clips the noise's negative half: reads high)
    assert np.all(np.abs(off_a - np.array([0, 31, 62] if batch else [62])) <= 1)
