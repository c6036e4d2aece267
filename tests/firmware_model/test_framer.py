"""The firmware's compiled framers (``firmware_model/tick.py``) write what the codec
(``serial_protocol.frame``) writes: the BoardHeartbeat from any wire values and from the
firmware's own state, and the Telemetry from any field values."""

from __future__ import annotations

import dataclasses

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_model import tick as ftick
from firmware_model.firmware import Firmware
from firmware_model.laws.layout import C_BUS_ADC
from firmware_model.params import FirmwareParams
from serial_protocol import frame
from serial_protocol.messages import BoardHeartbeat, StreamState

_RANGES = {"B": (0, 0xFF), "H": (0, 0xFFFF), "I": (0, 0xFFFFFFFF), "h": (-(2**15), 2**15 - 1),
           "i": (-(2**31), 2**31 - 1)}  # fmt: skip


def _wire_values(cls: type) -> st.SearchStrategy[tuple[int, ...]]:
    fields = []
    for f in frame.wire_fields(cls):
        if f.enum is not None:
            fields.append(st.sampled_from([0, 1] if f.enum is bool else [int(m) for m in f.enum]))
        else:
            fields.append(st.integers(*_RANGES[f.fmt]))
    return st.tuples(*fields)


def test_the_framers_are_in_use():
    assert ftick.framer_ok()


@settings(max_examples=300, deadline=None)
@given(_wire_values(BoardHeartbeat), st.integers(0, 255), st.integers(0, 40))
def test_frame_wire_writes_the_codecs_heartbeat(values, seq, at):
    msg = frame.from_wire_values(BoardHeartbeat, values)
    want = frame.encode(msg, seq)
    out = np.full(at + len(want) + 8, 0x55, dtype=np.uint8)
    wire = ftick.heartbeat_wire(msg)
    assert tuple(wire.tolist()) == values
    end = ftick.frame_wire(out, at, seq, wire, ftick.HEARTBEAT_TABLES)
    assert end == at + len(want) == at + ftick.HB_FRAME_BYTES
    assert bytes(out[at:end]) == want
    assert (out[:at] == 0x55).all() and (out[end:] == 0x55).all()  # nothing else written


_U32 = st.integers(0, 2**40)  # counters beyond 2**32 wrap on the wire


@settings(max_examples=150, deadline=None)
@given(
    tick=st.integers(0, 2**34),
    session=st.integers(0, 0xFFFF),
    counters=st.lists(_U32, min_size=9, max_size=9),
    flags=st.integers(0, 0xFFFFFFFF),
    enabled=st.booleans(),
    fault=st.integers(0, 12),
    moving=st.booleans(),
    moved=st.booleans(),
    bus_adc=st.integers(0, 8000),
    stream=st.tuples(st.sampled_from([StreamState.IDLE, StreamState.UNDERRUN]), _U32),
    seq=st.integers(0, 255),
)
def test_frame_heartbeat_writes_link_status(
    tick, session, counters, flags, enabled, fault, moving, moved, bus_adc, stream, seq
):
    """The compiled heartbeat of a firmware in any state (its receiver's counters, session,
    state, faults, bus reading, stream) is ``frame.encode(fw.link_status())``."""
    fw = Firmware(FirmwareParams())
    d = fw.decoder
    (
        d.frames,
        d.crc_errors,
        d.header_errors,
        d.bytes_dropped,
        d.seq_gaps,
        fw._rx_overflow_bytes,
        d.partial_discards,
        fw._counts["nacks"],
        fw._tx_dropped,
    ) = counters
    fw.tick, fw.session = tick, session
    fw._flags[0], fw._fault[0], fw._enabled[0] = flags, fault, enabled
    fw._moving, fw._moved = moving, moved
    fw.law.C[C_BUS_ADC, 0] = bus_adc
    fw.stream.state, fw.stream.underruns = stream
    fw._pack()
    fw._pack_link()
    assert fw._fi[ftick.FI_LINK] == 1
    want = frame.encode(fw.link_status(), seq)
    out = np.zeros(2 * len(want), dtype=np.uint8)
    args = (fw._fs, fw._fi, fw._enabled, fw._fault, fw._flags, fw.law.C, ftick.HEARTBEAT_TABLES)
    assert ftick.frame_heartbeat(out, 3, len(want) - 1, seq, *args) == -1  # does not fit
    assert not out.any()
    assert ftick.frame_heartbeat(out, 3, len(want), seq, *args) == 3 + len(want)
    assert bytes(out[3 : 3 + len(want)]) == want


def test_the_heartbeat_is_pythons_while_a_program_or_a_stream_runs():
    fw = Firmware(FirmwareParams())
    fw._pack_link()
    assert fw._fi[ftick.FI_LINK] == 1
    fw.stream.state = StreamState.RUNNING
    fw._pack_link()
    assert fw._fi[ftick.FI_LINK] == 0
    p = FirmwareParams()
    off = Firmware(
        dataclasses.replace(p, telemetry=dataclasses.replace(p.telemetry, heartbeat_s=0.0))
    )
    off._pack_link()
    assert off._fi[ftick.FI_LINK] == 0


@settings(max_examples=200, deadline=None)
@given(
    values=st.lists(
        st.floats(allow_nan=False, allow_infinity=True, width=64), min_size=6, max_size=6
    ),
    tick=st.integers(0, 2**34),
    state=st.integers(0, 4),
    fault=st.integers(0, 12),
    flags=st.integers(0, 0xFFFFFFFF),
    bus_mv=st.integers(0, 0xFFFF),
    seq=st.integers(0, 255),
)
def test_frame_telemetry_writes_the_codecs_telemetry(
    values, tick, state, fault, flags, bus_mv, seq
):
    want = frame.encode_telemetry_fields(seq, tick, *values, state, fault, flags, bus_mv / 1e3)
    out = np.zeros(len(want) + 4, dtype=np.uint8)
    end = ftick.frame_telemetry(
        out, 2, seq, tick, np.array(values), state, fault, flags, bus_mv, ftick.TABLES
    )
    assert end == 2 + len(want) and bytes(out[2:end]) == want
