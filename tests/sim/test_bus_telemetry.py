"""The measured bus voltage in every ``Telemetry`` frame (issue 13, appended field): what the
board reads, decoded by the PC, written to the telemetry CSV, read back by ``plot`` (also
from a CSV written before the column existed), drawn on the current panel."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest

import bench_configs
from serial_protocol.messages import BoardHeartbeat
from sim.config import load_experiment
from sim.loop import apply_overrides, run
from sim.reproduce.experiments import trace_from_result, write_telemetry_csv
from sim.reproduce.plots import BUS_LABEL, Curve, paper_figure
from sim.runfile import load_trace


@pytest.fixture(scope="module")
def fig6_bus():
    """Fig. 6 (the unplanned step) with the bus model: braking lifts the bus to the
    BTN7971's lock-out."""
    exp = load_experiment(bench_configs.path("fig6.toml"))
    bench = apply_overrides(exp.bench, {"supply.bus_model": True})
    exp = dataclasses.replace(exp, bench=bench, duration_s=5.0)
    return exp, run(exp)


def test_every_frame_carries_the_bus_voltage_the_board_reads(fig6_bus):
    exp, result = fig6_bus
    tel = result.telemetry_arrays()
    bus = tel["bus_voltage_v"]
    assert len(bus) == len(tel["tick"]) > 2000
    # the firmware's reading: ADC counts times volts per count, in the wire's 1 mV steps
    v_per_count = exp.bench.firmware.current.v_per_bus_adc
    counts = np.round(bus / v_per_count)
    assert np.all(np.abs(counts * v_per_count - bus) <= 0.0005 + 1e-12)
    assert bus[0] == pytest.approx(24.0, abs=v_per_count)  # at rest on the 24 V supply
    assert bus.max() > 27.0  # braking returns energy: the rail climbs to the lock-out
    # the simulator's bus at the sampling instants follows (the board reads the period
    # before the frame: one tick late, within its ADC step of the truth then)
    true = result.log.bus_v[tel["tick"]]
    assert np.median(np.abs(bus[1:] - true[:-1])) < v_per_count
    # the heartbeat reports the same reading as the telemetry frame of its tick
    heartbeats = [m for m in result.replies if isinstance(m, BoardHeartbeat)]
    at = {int(t): v for t, v in zip(tel["tick"], bus, strict=True)}
    # (a frame carries the tick before; the last may not have reached the PC at the end)
    paired = [(hb.bus_voltage_v, at[hb.tick - 1]) for hb in heartbeats if hb.tick - 1 in at]
    assert len(paired) >= 20 and len(paired) >= len(heartbeats) - 1
    assert all(a == b for a, b in paired)


def test_the_csv_carries_it_and_plot_reads_it_back(fig6_bus, tmp_path):
    exp, result = fig6_bus
    trace = trace_from_result("fig6 bus", exp, result)
    path = write_telemetry_csv(trace, tmp_path / "fig6.csv")
    with open(path, newline="") as f:
        header = next(csv.reader(f))
    assert header[-1] == "bus_voltage_v"
    back = load_trace(path)
    np.testing.assert_array_equal(back.bus_voltage_v, trace.bus_voltage_v)
    # a file written before the column existed still loads, without a bus voltage
    old = tmp_path / "old.csv"
    with open(path, newline="") as f, open(old, "w", newline="") as g:
        writer = csv.writer(g, lineterminator="\n")
        for row in csv.reader(f):
            writer.writerow(row[:-1])
    before = load_trace(old)
    assert len(before.bus_voltage_v) == 0
    np.testing.assert_array_equal(before.vel_dps, back.vel_dps)

    def bus_axes(fig):
        return [ax for ax in fig.axes if ax.get_ylabel() == BUS_LABEL]

    drawn = paper_figure([Curve(back, "new", "tab:blue")], title="t", bus=True)
    [ax] = bus_axes(drawn)
    [line] = ax.get_lines()
    np.testing.assert_array_equal(line.get_ydata(), back.bus_voltage_v)
    assert bus_axes(paper_figure([Curve(before, "old", "tab:blue")], title="t", bus=True)) == []
    assert bus_axes(paper_figure([Curve(back, "new", "tab:blue")], title="t")) == []
