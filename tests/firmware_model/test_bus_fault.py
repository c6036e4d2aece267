"""The firmware's bus over/under-voltage trips (issue 13 §2.1, ``[safety] bus_voltage_check``)
and the bus voltage on the wire (``BoardHeartbeat.bus_voltage_v``, ``Limits.bus_*``)."""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path

import numpy as np
import pytest

from firmware_model.firmware import Firmware
from firmware_model.params import CurrentLoopGains, FirmwareParams, SafetyParams
from serial_protocol import frame
from serial_protocol.messages import (
    BoardHeartbeat,
    Fault,
    FaultFlag,
    FaultReport,
    GetLimits,
    Limits,
    MsgType,
    StreamState,
)

V_PER_COUNT = CurrentLoopGains().v_per_bus_adc  # 8.862 mV
OVER_COUNTS = math.floor(27.0 / V_PER_COUNT)  # the last reading that does not trip
UNDER_COUNTS = math.ceil(18.0 / V_PER_COUNT)  # the last reading (up) that does not trip
NOMINAL = round(24.0 / V_PER_COUNT)


def _board(batch: int | None = None, **safety) -> Firmware:
    fw = Firmware(
        FirmwareParams(safety=SafetyParams(bus_voltage_check=True, **safety)), batch=batch
    )
    fw.servo_tick(np.zeros(batch, dtype=np.int64) if batch else 0, b"", 4096)  # boot, enable
    return fw


def _period(fw: Firmware, bus_counts, adc=0) -> list:
    """One current-loop period with the bus reading ``bus_counts``, then a servo tick (the
    trip's report is sent from there); returns the ``FaultReport``s the board sent."""
    if fw.batch is not None:
        adc = np.full(fw.batch, adc, dtype=np.int64)
    fw.current_tick(adc, bus_counts)
    out = fw.servo_tick(0 if fw.batch is None else np.zeros(fw.batch, dtype=np.int64), b"", 4096)
    return [m for m in frame.Decoder().feed(out) if isinstance(m, FaultReport)]


def test_thresholds_are_exact_in_counts():
    # The screen compares counts: floor(27 V / V_per_count) is 27 V or below, one more is above.
    assert OVER_COUNTS * V_PER_COUNT <= 27.0 < (OVER_COUNTS + 1) * V_PER_COUNT
    assert (UNDER_COUNTS - 1) * V_PER_COUNT < 18.0 <= UNDER_COUNTS * V_PER_COUNT
    fw = _board()
    for counts in (NOMINAL, OVER_COUNTS, UNDER_COUNTS):
        _period(fw, counts)
        assert fw.fault == 0
    [report] = _period(fw, OVER_COUNTS + 1)
    assert fw.fault == Fault.BUS_OVER_VOLTAGE
    assert fw.fault_flags() == FaultFlag.BUS_OVER_VOLTAGE
    assert report.value == pytest.approx((OVER_COUNTS + 1) * V_PER_COUNT)
    assert report.threshold == 27.0
    assert fw._brake_ticks[0] > 0  # the fault reaction: brake on the low sides


def test_under_voltage_trips_below_its_threshold():
    fw = _board()
    [report] = _period(fw, UNDER_COUNTS - 1)
    assert fw.fault == Fault.BUS_UNDER_VOLTAGE
    assert report.value == pytest.approx((UNDER_COUNTS - 1) * V_PER_COUNT)
    assert report.threshold == 18.0


def test_debounce_counts_readings_in_a_row():
    fw = _board(bus_voltage_samples=3)
    for counts in (OVER_COUNTS + 50, OVER_COUNTS + 50, NOMINAL, 0, 0):
        _period(fw, counts)  # 2 over, then a good reading restarts the count; 2 under
        assert fw.fault == 0
    _period(fw, 0)  # the third under-voltage reading in a row
    assert fw.fault == Fault.BUS_UNDER_VOLTAGE


def test_off_disabled_and_batch():
    off = Firmware(FirmwareParams())  # bus_voltage_check = false: never trips
    off.servo_tick(0, b"", 4096)
    for counts in (0, 4095):
        _period(off, counts)
    assert off.fault == 0
    fw = _board()
    fw._disable()
    _period(fw, 4095)  # a disabled bridge is not screened
    assert fw.fault == 0
    batch = _board(batch=3)
    _period(batch, np.array([NOMINAL, OVER_COUNTS + 1, UNDER_COUNTS - 1]))
    assert list(batch.fault) == [0, Fault.BUS_OVER_VOLTAGE, Fault.BUS_UNDER_VOLTAGE]


def test_limits_and_heartbeat_carry_the_bus():
    fw = _board()
    [limits] = [fw._query(GetLimits(1))]
    assert (limits.bus_over_voltage_v, limits.bus_under_voltage_v) == (27.0, 18.0)
    off = Firmware(FirmwareParams())
    lim = off._query(GetLimits(1))
    assert (lim.bus_over_voltage_v, lim.bus_under_voltage_v) == (0.0, 0.0)  # check off
    fw.current_tick(0, 2709)
    hb = fw.link_status()
    assert hb.bus_voltage_v == round(2709 * V_PER_COUNT * 1000) / 1000  # 24.007 V, 1 mV steps
    fw.current_tick(0, 4095)
    assert fw.link_status().bus_voltage_v == round(4095 * V_PER_COUNT * 1000) / 1000  # 36.29 V
    # Through the codec: the decoded heartbeat has it.
    [got] = frame.Decoder().feed(frame.encode(hb, 1))
    assert got.bus_voltage_v == hb.bus_voltage_v


# ------------------------------------------------------------------ an older client

DOC = (Path(__file__).resolve().parents[2] / "docs" / "protocol.md").read_text()
WIRE = {"u8": "B", "u16": "H", "u32": "I", "i16": "h", "i32": "i", "f32": "f"}
APPENDED = {"bus_voltage_v", "bus_over_voltage_v", "bus_under_voltage_v"}


def _old_layout(name: str) -> list[tuple[str, str]]:
    """The message's fields as docs/protocol.md stated them before the bus fields."""
    text = re.search(rf"^#### 0x[0-9A-F]{{2}} `{name}` .*?(?=^#### |^### |^## )", DOC, re.M | re.S)
    assert text
    rows = re.findall(r"^\| \d+ \| \d+ \| `(\w+)` \| (\w+) \|", text.group(0), re.M)
    assert APPENDED & {r[0] for r in rows}  # the new field is documented ...
    return [r for r in rows if r[0] not in APPENDED]  # ... and an older client lacks it


def _old_client_decode(data: bytes, name: str) -> dict[str, float]:
    """What a v2 client written from the spec before the bus fields decodes: the fields it
    knows, the payload's extra bytes ignored (the extension rule)."""
    length = data[2]
    layout = _old_layout(name)
    fmt = "<" + "".join(WIRE[w] for _, w in layout)
    assert length >= struct.calcsize(fmt)  # not BAD_LENGTH for it
    values = struct.unpack_from(fmt, data, 6)
    return dict(zip([n for n, _ in layout], values, strict=True))


def test_a_client_from_the_spec_before_the_bus_fields_still_decodes_them():
    hb = BoardHeartbeat(
        100, 7, 1, 0x8, 5, 1, 2, 30, 1, 0, 1, 2, 0, 32, 60, StreamState.RUNNING, 1, 26.472
    )
    old = _old_client_decode(frame.encode(hb, 3), "BoardHeartbeat")
    assert old["tick"] == 100 and old["session"] == 7 and old["fault_flags"] == 0x8
    assert old["stream_underruns"] == 1 and old["queue_free"] == 32
    lim = Limits(1, 990.0, 148.0, 5.0, 10.0, 7.5, -1e5, 1e5, 1100.0, 7.5, 27.0, 18.0)
    old = _old_client_decode(frame.encode(lim, 4), "Limits")
    assert old["over_current_max_a"] == 7.5 and old["over_speed_dps"] == 1100.0
    # and the reference decoder of this version reads all of it
    [got] = frame.Decoder().feed(frame.encode(hb, 3))
    assert got == hb and got.MSG_TYPE == MsgType.BOARD_HEARTBEAT
