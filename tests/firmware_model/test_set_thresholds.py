"""The bus and thermal thresholds set over the wire (issue 13: ``SetLimits``' appended
fields): read back by ``GetLimits``, refused with the field named and nothing applied,
kept by an older PC's shorter ``SetLimits``, and tripped at in a run."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import bench_configs
from firmware_model.firmware import Firmware
from firmware_model.params import CurrentLoopGains, FirmwareParams, SafetyParams
from serial_protocol import frame
from serial_protocol.host import BoardClient
from serial_protocol.messages import (
    Ack,
    Fault,
    FaultReport,
    Limits,
    MsgType,
    Nack,
    NackCode,
    SetLimits,
)
from sim import loop
from sim.config import ScriptedCommand, load_bench
from sim.loop import Simulation
from sim.reproduce import experiments
from sim.simlink import SimulatedLink

MOTION = (1000.0, 2000.0, 5.0, 30.0)  # v_max, a_max, current clamp, following error
BUS_CHECK = {"safety.bus_voltage_check": True}


def _client(**overrides) -> tuple[Simulation, BoardClient]:
    nested: dict = {}
    for key, value in overrides.items():
        table, name = key.split(".")
        nested.setdefault(table, {})[name] = value
    bench = load_bench(bench_configs.path("paper_bench.toml"), overrides=nested or None)
    sim = Simulation(bench, seed=0, keep_log=False)
    return sim, BoardClient(SimulatedLink(sim, ticks_per_poll=5), ack_timeout_s=30.0)


def _index(name: str) -> int:
    return frame.field_index(SetLimits, name)


def test_set_limits_sets_the_thresholds_and_get_limits_reads_them_back():
    sim, pc = _client(**BUS_CHECK)
    before = pc.get_limits()
    assert isinstance(before, Limits)
    assert (before.bus_over_voltage_v, before.bus_under_voltage_v) == (27.0, 18.0)
    assert (before.thermal_derate_c, before.thermal_trip_c) == (100.0, 120.0)
    reply = pc.set_limits(*MOTION, 0.0, 26.5, 19.0, 90.0, 110.0)
    assert reply == Ack(pc.last_command.cmd_id, MsgType.SET_LIMITS)
    got = pc.get_limits()
    assert (got.bus_over_voltage_v, got.bus_under_voltage_v) == (26.5, 19.0)
    assert (got.thermal_derate_c, got.thermal_trip_c) == (90.0, 110.0)
    assert got.over_current_trip_a == before.over_current_trip_a  # 0 kept it
    # The firmware's screens use them: the bus thresholds in counts of its reading.
    v_per_count = CurrentLoopGains().v_per_bus_adc
    assert sim.fw._bus_over_counts == math.floor(26.5 / v_per_count)
    assert sim.fw._bus_under_counts == math.ceil(19.0 / v_per_count)
    assert sim.fw.thermal_thresholds_c == (90.0, 110.0)
    # 0 keeps each one: only the trip changes.
    assert isinstance(pc.set_limits(*MOTION, 0.0, 0.0, 0.0, 0.0, 115.0), Ack)
    got = pc.get_limits()
    assert (got.bus_over_voltage_v, got.bus_under_voltage_v) == (26.5, 19.0)
    assert (got.thermal_derate_c, got.thermal_trip_c) == (90.0, 115.0)


def test_an_older_pcs_short_set_limits_keeps_the_thresholds():
    sim, pc = _client(**BUS_CHECK)
    assert isinstance(pc.set_limits(*MOTION, 0.0, 26.0, 20.0, 80.0, 100.0), Ack)
    pc.get_limits()  # the session is open, the board idle
    # An older PC's SetLimits: the 2.0 fields only (24 bytes), a new v_max.
    msg = SetLimits(77, 800.0, 2000.0, 5.0, 30.0, 0.0, session=pc.session)
    _, payload = frame.encode_payload(msg)
    assert len(payload) == 44 and frame._BY_CLASS[SetLimits].min_size == 24
    sim.pc_write(frame.frame_raw(MsgType.SET_LIMITS, payload[:24], 200))
    replies = []
    for _ in range(20):
        replies += pc.link.poll(0.0)
    assert Ack(77, MsgType.SET_LIMITS) in replies
    got = pc.get_limits()
    assert got.v_max_dps == 800.0  # applied ...
    assert (got.bus_over_voltage_v, got.bus_under_voltage_v) == (26.0, 20.0)  # ... and kept
    assert (got.thermal_derate_c, got.thermal_trip_c) == (80.0, 100.0)
    # A PC of the thresholds' version (40 bytes, no brake cap): the cap is kept.
    assert isinstance(pc.set_limits(*MOTION, brake_current_limit_a=6.0), Ack)
    msg = SetLimits(78, 850.0, 2000.0, 5.0, 30.0, 0.0, session=pc.session, thermal_trip_c=105.0)
    sim.pc_write(frame.frame_raw(MsgType.SET_LIMITS, frame.encode_payload(msg)[1][:40], 202))
    replies = []
    for _ in range(20):
        replies += pc.link.poll(0.0)
    assert Ack(78, MsgType.SET_LIMITS) in replies
    got = pc.get_limits()
    assert (got.v_max_dps, got.thermal_trip_c, got.brake_current_limit_a) == (850.0, 105.0, 6.0)
    # Cut inside an appended field: BAD_LENGTH, nothing applied.
    sim.pc_write(frame.frame_raw(MsgType.SET_LIMITS, payload[:26], 201))
    replies = []
    for _ in range(20):
        replies += pc.link.poll(0.0)
    assert [r.code for r in replies if isinstance(r, Nack)] == [NackCode.BAD_LENGTH]
    now = pc.get_limits()  # (the thermal estimate moves with time: not a setting)
    assert now == dataclasses.replace(
        got, cmd_id=pc.last_command.cmd_id, winding_estimate_c=now.winding_estimate_c
    )


@pytest.mark.parametrize(
    ("fields", "code", "name", "limit"),
    [
        ({"bus_over_voltage_v": math.nan}, NackCode.NOT_FINITE, "bus_over_voltage_v", 0.0),
        ({"bus_under_voltage_v": math.inf}, NackCode.NOT_FINITE, "bus_under_voltage_v", 0.0),
        # over below under (18 V) and below the 24 V supply: it would trip at once
        ({"bus_over_voltage_v": 17.0}, NackCode.TOO_LOW, "bus_over_voltage_v", 24.0),
        # at or above the BTN7971B's lock-out (bus_hold_v 27.8 V) the chip is first
        ({"bus_over_voltage_v": 28.5}, NackCode.TOO_HIGH, "bus_over_voltage_v", 27.8),
        ({"bus_under_voltage_v": 25.0}, NackCode.TOO_HIGH, "bus_under_voltage_v", 24.0),
        ({"bus_under_voltage_v": -1.0}, NackCode.TOO_LOW, "bus_under_voltage_v", 1e-3),
        ({"thermal_trip_c": 300.0}, NackCode.TOO_HIGH, "thermal_trip_c", 250.0),
        ({"thermal_derate_c": -50.0}, NackCode.TOO_LOW, "thermal_derate_c", -40.0),
        ({"thermal_derate_c": math.nan}, NackCode.NOT_FINITE, "thermal_derate_c", 0.0),
        # derating above the trip in force (120), or a trip below the derating (100)
        ({"thermal_derate_c": 125.0}, NackCode.TOO_HIGH, "thermal_derate_c", 120.0),
        ({"thermal_trip_c": 95.0}, NackCode.TOO_LOW, "thermal_trip_c", 100.0),
        ({"thermal_derate_c": 130.0, "thermal_trip_c": 125.0}, NackCode.TOO_HIGH,
         "thermal_derate_c", 125.0),
        # the brake's cap: positive (0 keeps), at most 100 A
        ({"brake_current_limit_a": -1.0}, NackCode.TOO_LOW, "brake_current_limit_a", 1e-3),
        ({"brake_current_limit_a": 150.0}, NackCode.TOO_HIGH, "brake_current_limit_a", 100.0),
        ({"brake_current_limit_a": math.nan}, NackCode.NOT_FINITE, "brake_current_limit_a",
         0.0),
        # wire order: a bad cap after a bad trip reports the trip
        ({"thermal_trip_c": 300.0, "brake_current_limit_a": -1.0}, NackCode.TOO_HIGH,
         "thermal_trip_c", 250.0),
    ],
)  # fmt: skip
def test_a_bad_threshold_is_refused_naming_it_and_nothing_is_applied(fields, code, name, limit):
    fw = Firmware(FirmwareParams(safety=SafetyParams(bus_voltage_check=True)))
    fw.servo_tick(0, b"", 4096)
    before = fw._query(frame.decode_payload(MsgType.GET_LIMITS, bytes(4)))
    # A valid motion limit in the same command must not be half-applied.
    reply = fw._apply(SetLimits(5, 500.0, 900.0, 4.0, 20.0, 7.0, **fields))
    assert reply == Nack(5, MsgType.SET_LIMITS, code, _index(name), pytest.approx(limit))
    after = fw._query(frame.decode_payload(MsgType.GET_LIMITS, bytes(4)))
    assert after == before
    assert fw.bus_over_voltage_v == 27.0 and fw.thermal_thresholds_c == (100.0, 120.0)
    assert after.brake_current_limit_a == 0.0


def test_a_check_the_configuration_turned_off_takes_only_zero():
    fw = Firmware(FirmwareParams(safety=SafetyParams(thermal_protection=False)))
    fw.servo_tick(0, b"", 4096)
    for name in ("bus_over_voltage_v", "bus_under_voltage_v", "thermal_derate_c",
                 "thermal_trip_c"):  # fmt: skip
        reply = fw._apply(SetLimits(1, *MOTION, **{name: 26.0}))
        assert reply == Nack(1, MsgType.SET_LIMITS, NackCode.TOO_HIGH, _index(name), 0.0)
    assert fw._apply(SetLimits(2, *MOTION)) == Ack(2, MsgType.SET_LIMITS)


def test_the_bus_screen_trips_at_the_new_threshold():
    fw = Firmware(FirmwareParams(safety=SafetyParams(bus_voltage_check=True)))
    fw.servo_tick(0, b"", 4096)
    assert fw._apply(SetLimits(1, *MOTION, bus_over_voltage_v=25.0)) == Ack(1, MsgType.SET_LIMITS)
    v_per_count = CurrentLoopGains().v_per_bus_adc
    at = math.floor(25.0 / v_per_count)
    fw.current_tick(0, at)  # 25.0 V or just below: no trip
    fw.servo_tick(0, b"", 4096)
    assert fw.fault == 0
    fw.current_tick(0, at + 1)
    out = fw.servo_tick(0, b"", 4096)
    [report] = [m for m in frame.Decoder().feed(out) if isinstance(m, FaultReport)]
    assert fw.fault == Fault.BUS_OVER_VOLTAGE and report.threshold == 25.0


def _with_set_limits(exp, t_s: float, **thresholds):
    limits = ScriptedCommand(t_s, "set_limits", (
        ("v_max_dps", 1000.0), ("a_max_dps2", 2000.0), ("current_limit_a", 5.0),
        ("following_error_deg", 30.0), *thresholds.items(),
    ))  # fmt: skip
    return dataclasses.replace(exp, commands=(limits, *exp.commands))


def test_fig6_trips_at_a_bus_threshold_set_over_the_wire_as_at_a_configured_one():
    # The bus model, no chopper: Fig. 6's braking lifts the rail; 26 V set by SetLimits
    # before the step trips on the same reading as 26 V set in [safety].
    bus = {"supply.bus_model": True, **BUS_CHECK}
    exp = experiments.with_duration(experiments.load("fig6"), 3.3)
    wire = loop.run(_with_set_limits(exp, 0.0, bus_over_voltage_v=26.0), seed=0, overrides=bus)
    conf = loop.run(_with_set_limits(exp, 0.0), seed=0,
                    overrides={**bus, "safety.bus_over_voltage_v": 26.0})  # fmt: skip
    [report] = [m for m in wire.replies if isinstance(m, FaultReport)]
    assert report.fault == Fault.BUS_OVER_VOLTAGE and report.threshold == 26.0
    assert 26.0 < report.value < 27.0  # before the chip's 28 V lock-out
    [same] = [m for m in conf.replies if isinstance(m, FaultReport)]
    assert same == report
    assert np.array_equal(wire.log.fault, conf.log.fault)


def test_a_stall_trips_at_a_thermal_threshold_set_over_the_wire():
    # A platter that will not turn, held at the 5 A limit: derating from 41 degC and the
    # trip at 43 degC (set over the wire; the estimate starts at 40 degC) come within
    # seconds, at the same tick as with the same values in [safety].
    stall = {"platter.coulomb_nm": 1e4, "platter.stiction_nm": 0.0}
    exp = experiments.with_duration(experiments.load("fig6"), 6.0)
    wire = loop.run(_with_set_limits(exp, 0.0, thermal_derate_c=41.0, thermal_trip_c=43.0),
                    seed=0, overrides=stall)  # fmt: skip
    conf = loop.run(_with_set_limits(exp, 0.0), seed=0, overrides={
        **stall, "safety.thermal_derate_c": 41.0, "safety.thermal_trip_c": 43.0})  # fmt: skip
    [report] = [m for m in wire.replies if isinstance(m, FaultReport)]
    assert report.fault == Fault.THERMAL and report.threshold == 43.0
    [same] = [m for m in conf.replies if isinstance(m, FaultReport)]
    assert same == report
    hot = np.flatnonzero(wire.log.fault == int(Fault.THERMAL))
    assert hot.size and wire.log.t_s[hot[0]] < 6.0


def test_the_brake_cap_set_over_the_wire_is_the_configured_one():
    # [safety] brake_current_limit_a over SetLimits (appended; 0 keeps): read back, kept by a
    # later SetLimits without it, and Fig. 6's bus trip brakes exactly as with the cap in
    # the configuration (the whole log and the PC's bytes).
    sim, pc = _client()
    assert pc.get_limits().brake_current_limit_a == 0.0  # none configured: the full short
    assert isinstance(pc.set_limits(*MOTION, brake_current_limit_a=5.0), Ack)
    assert pc.get_limits().brake_current_limit_a == 5.0
    assert isinstance(pc.set_limits(*MOTION), Ack)
    assert pc.get_limits().brake_current_limit_a == 5.0
    trip = {"supply.bus_model": True, "safety.bus_voltage_check": True}
    exp = experiments.with_duration(experiments.load("fig6"), 4.5)
    wire = loop.run(_with_set_limits(exp, 0.0, brake_current_limit_a=5.0), seed=0,
                    overrides=trip)  # fmt: skip
    config = loop.run(_with_set_limits(exp, 0.0), seed=0,
                      overrides={**trip, "safety.brake_current_limit_a": 5.0})  # fmt: skip
    k = int(np.argmax(wire.log.fault != 0))
    assert wire.log.fault[k] == Fault.BUS_OVER_VOLTAGE
    assert 4.0 < np.abs(wire.log.current_a[k + 2 :]).max() <= 5.0  # the capped short
    for name, column in wire.log.items():
        assert np.array_equal(column, getattr(config.log, name)), name
