"""The telemetry CSV (``serial_protocol.telemetry_csv``): the rows written from columns
(``write_columns``, what ``reproduce`` writes) are byte for byte the rows of the per-message
writer as it was before (one ``Telemetry`` per row; kept below as the oracle)."""

from __future__ import annotations

import csv
import dataclasses
import io

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import bench_configs
from serial_protocol.messages import Fault, State, Telemetry
from serial_protocol.telemetry_csv import TELEMETRY_CSV_COLUMNS, TelemetryCsvWriter
from sim.config import load_experiment
from sim.loop import run
from sim.reproduce.experiments import trace_from_result, write_telemetry_csv


def _oracle(msgs: list[Telemetry], tick_hz: float) -> str:
    """The writer before it wrote from columns (its per-row code, verbatim)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(TELEMETRY_CSV_COLUMNS)
    for msg in msgs:
        writer.writerow(
            (
                f"{msg.tick / tick_hz:.6f}",
                msg.tick,
                repr(msg.sp_pos_deg),
                repr(msg.sp_vel_dps),
                repr(msg.pos_deg),
                repr(msg.vel_dps),
                repr(msg.current_a),
                repr(msg.duty),
                State(msg.state).name,
                Fault(msg.fault).name,
                repr(msg.bus_voltage_v),
            )
        )
    return out.getvalue()


FIELDS = ("sp_pos_deg", "sp_vel_dps", "pos_deg", "vel_dps", "current_a", "duty")

any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
telemetry = st.builds(
    Telemetry,
    tick=st.integers(0, 2**32 - 1),
    sp_pos_deg=any_float,
    sp_vel_dps=any_float,
    pos_deg=any_float,
    vel_dps=any_float,
    current_a=any_float,
    duty=st.floats(-1.0, 1.0),
    state=st.sampled_from(State),
    fault=st.sampled_from(Fault),
    fault_flags=st.integers(0, 255),
    bus_voltage_v=st.floats(0.0, 65.535),
)


def _columns(msgs: list[Telemetry], as_arrays: bool) -> list:
    cols = [[m.tick for m in msgs]] + [[getattr(m, f) for m in msgs] for f in FIELDS]
    cols += [[int(m.state) for m in msgs], [int(m.fault) for m in msgs]]
    cols += [[m.bus_voltage_v for m in msgs]]
    if as_arrays:  # as the reproduction passes them: numpy columns
        dtypes = [np.int64] + [np.float64] * len(FIELDS) + [np.int64, np.int64, np.float64]
        cols = [np.array(c, dtype=d) for c, d in zip(cols, dtypes, strict=True)]
    return cols


@settings(max_examples=60, deadline=None)
@given(msgs=st.lists(telemetry, max_size=20), tick_hz=st.sampled_from([500.0, 1000.0, 7.0]))
def test_columns_write_the_bytes_of_one_message_per_row(msgs, tick_hz):
    expected = _oracle(msgs, tick_hz)
    for as_arrays in (False, True):
        out = io.StringIO()
        writer = TelemetryCsvWriter(out, tick_hz=tick_hz)
        writer.write_columns(*_columns(msgs, as_arrays))
        assert out.getvalue() == expected
        assert writer.rows == len(msgs)
    out = io.StringIO()
    writer = TelemetryCsvWriter(out, tick_hz=tick_hz)
    for m in msgs:  # monitor --csv and decode write one message at a time
        writer.write(m)
    assert out.getvalue() == expected


def test_bad_columns_write_nothing():
    msgs = [Telemetry(k, 1.0, 2.0, 3.0, 4.0, 0.5, 0.1, State.MOVING, Fault.NONE, 0, 24.0)
            for k in range(3)]  # fmt: skip
    cols = _columns(msgs, as_arrays=True)
    out = io.StringIO()
    writer = TelemetryCsvWriter(out)
    header = out.getvalue()
    short = [c[:2] if k == 4 else c for k, c in enumerate(cols)]
    with pytest.raises(ValueError, match=r"columns of \[2, 3\] rows"):
        writer.write_columns(*short)
    bad_state = [np.array([0, 99, 0]) if k == 8 else c for k, c in enumerate(cols)]
    with pytest.raises(ValueError, match="99"):
        writer.write_columns(*bad_state)
    assert out.getvalue() == header and writer.rows == 0


def test_the_reproductions_csv_is_the_per_message_writers(tmp_path):
    """``write_telemetry_csv`` on a real run (Fig. 6, 1.5 s, decoded by the PC) writes what
    one ``Telemetry`` per tick through the old writer wrote."""
    exp = load_experiment(bench_configs.path("fig6.toml"))
    exp = dataclasses.replace(exp, duration_s=1.5)
    trace = trace_from_result("fig6", exp, run(exp))
    path = write_telemetry_csv(trace, tmp_path / "fig6.csv")
    ticks = np.round(trace.t_s / trace.dt_s).astype(np.int64)
    msgs = [
        Telemetry(int(ticks[k]), *(float(getattr(trace, f)[k]) for f in FIELDS),
                  State(int(trace.state[k])), Fault(int(trace.fault[k])), 0,
                  float(trace.bus_voltage_v[k]))
        for k in range(len(ticks))
    ]  # fmt: skip
    assert len(msgs) > 700 and len({m.pos_deg for m in msgs}) > 100
    assert path.read_text(encoding="utf-8") == _oracle(msgs, 1.0 / trace.dt_s)
