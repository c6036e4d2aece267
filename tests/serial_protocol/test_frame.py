"""The frame codec: round trips, counters, Malformed, and the decoder's properties."""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from serial_protocol import frame
from serial_protocol.frame import (
    MAX_FRAME_BYTES,
    MAX_PAYLOAD_BYTES,
    TELEMETRY_FRAME_BYTES,
    Decoder,
    crc8,
    crc32,
    decode_payload,
    encode,
    encode_payload,
    encode_telemetry_fields,
    frame_bytes,
    frame_raw,
    payload_bytes,
    payload_size_of_type,
)
from serial_protocol.messages import (
    NO_FIELD,
    Ack,
    BoardHeartbeat,
    ClearFault,
    Fault,
    FaultInfo,
    FaultReport,
    Gains,
    GetFault,
    GetGains,
    GetLimits,
    GetStatus,
    Heartbeat,
    Hello,
    HelloReply,
    Interp,
    Jog,
    Limits,
    Loop,
    Malformed,
    Move,
    MsgType,
    Nack,
    NackCode,
    Profile,
    QueueAction,
    QueueControl,
    QueueSegment,
    QueueState,
    QueueStatus,
    SetEnable,
    SetGains,
    SetLimits,
    SetTelemetry,
    State,
    Status,
    Stop,
    StreamAction,
    StreamControl,
    StreamPoints,
    StreamState,
    StreamStatus,
    Telemetry,
)

# ------------------------------------------------------------------ strategies

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
f32 = st.floats(width=32, allow_nan=False)
# values exactly representable on the wire: k * 1e-4 (decode divides by 1e4)
pos = st.integers(-(2**31), 2**31 - 1).map(lambda k: k / 10_000.0)
milli16 = st.integers(-(2**15), 2**15 - 1).map(lambda k: k / 1_000.0)
duty = st.integers(-10_000, 10_000).map(lambda k: k / 10_000.0)

BY_CLASS = {
    Hello: st.builds(Hello, u16, u8, u8, u16),
    Heartbeat: st.builds(Heartbeat, u16, u16),
    Move: st.builds(Move, u16, pos, f32, f32, f32, st.sampled_from(Profile), u16),
    Stop: st.builds(Stop, u16, f32, u16),
    SetGains: st.builds(SetGains, u16, st.sampled_from(Loop), f32, f32, f32, u16),
    GetGains: st.builds(GetGains, u16, st.sampled_from(Loop), u16),
    SetLimits: st.builds(SetLimits, u16, f32, f32, f32, f32, f32, u16, f32, f32, f32, f32, f32),
    GetLimits: st.builds(GetLimits, u16, u16),
    GetStatus: st.builds(GetStatus, u16, u16),
    ClearFault: st.builds(ClearFault, u16, u16),
    SetEnable: st.builds(SetEnable, u16, st.booleans(), u16),
    SetTelemetry: st.builds(SetTelemetry, u16, u16, u16),
    GetFault: st.builds(GetFault, u16, u8, u16),
    HelloReply: st.builds(
        HelloReply,
        u16,
        u16,
        u8,
        u8,
        u8,
        u8,
        u16,
        u16,
        u32,
        u8,
        u16,
        u8,
        u16,
        u16,
        u16,
        u16,
        u32,
    ),
    Telemetry: st.builds(
        Telemetry,
        u32,
        pos,
        pos,
        pos,
        pos,
        milli16,
        duty,
        st.sampled_from(State),
        st.sampled_from(Fault),
        u32,
    ),
    Ack: st.builds(Ack, u16, u8),
    Nack: st.builds(Nack, u16, u8, st.sampled_from(NackCode), u8, f32),
    FaultReport: st.builds(FaultReport, u32, st.sampled_from(Fault), f32, u32, f32),
    Gains: st.builds(Gains, u16, st.sampled_from(Loop), f32, f32, f32),
    Limits: st.builds(Limits, u16, *[f32] * 15),
    Status: st.builds(
        Status,
        u16,
        u32,
        st.sampled_from(State),
        st.sampled_from(Fault),
        pos,
        pos,
        pos,
        u32,
        u16,
    ),
    BoardHeartbeat: st.builds(
        BoardHeartbeat,
        u32,
        u16,
        st.sampled_from(State),
        u32,
        u32,
        u32,
        u32,
        u32,
        u32,
        u32,
        u32,
        u32,
        u32,
        u8,
        u8,
        st.sampled_from(StreamState),
        u32,
    ),
    FaultInfo: st.builds(FaultInfo, u16, u8, st.booleans(), u32, f32, f32),
    QueueSegment: st.builds(QueueSegment, u16, pos, f32, f32, u16),
    QueueControl: st.builds(QueueControl, u16, st.sampled_from(QueueAction), f32, u16),
    QueueStatus: st.builds(
        QueueStatus, u16, st.sampled_from(QueueState), u8, u8, u32, f32
    ),
    StreamControl: st.builds(
        StreamControl, u16, st.sampled_from(StreamAction), st.sampled_from(Interp), f32, u8, u16
    ),
    StreamPoints: st.builds(StreamPoints, u16, u32, u8, *([pos] * 5), *([f32] * 5), u16),
    Jog: st.builds(Jog, u16, f32, f32, u16, u16),
    StreamStatus: st.builds(StreamStatus, u16, st.sampled_from(StreamState), u8, u32, u32, pos),
}
MESSAGES = st.one_of(*BY_CLASS.values())


def telemetry(tick: int) -> Telemetry:
    """A distinct, easily recognised telemetry message per tick."""
    return Telemetry(tick, tick * 0.5, 1.25, tick * 0.25, -2.5, 0.75, -0.125, State.MOVING, 0)


def stream(n: int, first_seq: int = 0) -> tuple[list[Telemetry], list[bytes]]:
    msgs = [telemetry(k) for k in range(n)]
    return msgs, [encode(m, first_seq + k) for k, m in enumerate(msgs)]


def decode_all(data: bytes) -> tuple[list, Decoder]:
    decoder = Decoder()
    out = decoder.feed(data)
    out += decoder.flush()
    return out, decoder


# ------------------------------------------------------------------ CRCs and sizes


def test_crc_check_values():
    assert crc32(b"123456789") == 0xCBF43926  # CRC-32/ISO-HDLC
    assert crc8(b"123456789") == 0xF4  # CRC-8/SMBUS
    # continuing a CRC over a split message gives the CRC of the whole
    assert crc32(b"6789", crc32(b"12345")) == 0xCBF43926


def test_every_message_type_has_a_codec_and_fits():
    for msg_type in MsgType:
        assert msg_type in frame._BY_TYPE
    for codec in frame._BY_CLASS.values():
        assert codec.payload.size <= MAX_PAYLOAD_BYTES


def test_telemetry_frame_size_matches_layout():
    # header 6 + tick 4 + 4 positions/velocities x 4 + current 2 + duty 2 + state 1 + fault 1
    # + fault flags 4 + bus voltage 2 (appended) + CRC 4
    assert TELEMETRY_FRAME_BYTES == 6 + 4 + 16 + 2 + 2 + 1 + 1 + 4 + 2 + 4
    assert len(encode(telemetry(1), 0)) == TELEMETRY_FRAME_BYTES


def test_frame_layout_by_hand():
    data = encode(Ack(0x1234, MsgType.MOVE), 9)
    assert data[:2] == b"\xa5\x5a"
    assert data[2] == 3 and data[3] == MsgType.ACK and data[4] == 9
    assert data[5] == crc8(data[2:5])
    assert data[6:9] == bytes((0x34, 0x12, MsgType.MOVE))
    assert int.from_bytes(data[9:13], "little") == crc32(data[2:9])
    assert len(data) == 13
    assert frame_raw(MsgType.ACK, data[6:9], 9) == data


# ------------------------------------------------------------------ round trips


def test_strategies_cover_every_message_class():
    assert set(BY_CLASS) == set(frame._BY_CLASS)


@pytest.mark.parametrize("cls", list(BY_CLASS), ids=lambda c: c.__name__)
@settings(max_examples=60)
@given(data=st.data(), seq=u8)
def test_round_trip_every_message(cls, data, seq):
    msg = data.draw(BY_CLASS[cls])
    encoded = encode(msg, seq)
    assert len(encoded) == frame_bytes(cls)
    decoder = Decoder()
    assert decoder.feed(encoded) == [msg]
    assert decoder.last_seq == seq
    assert decoder.pending_bytes == 0


@pytest.mark.parametrize("cls", list(BY_CLASS), ids=lambda c: c.__name__)
@settings(max_examples=30)
@given(data=st.data(), seq=u8)
def test_unframed_payload_round_trip(cls, data, seq):
    msg = data.draw(BY_CLASS[cls])
    msg_type, payload = encode_payload(msg)
    assert msg_type == cls.MSG_TYPE
    assert len(payload) == payload_bytes(cls) == payload_size_of_type(msg_type)
    assert frame_raw(msg_type, payload, seq) == encode(msg, seq)
    assert decode_payload(msg_type, payload) == msg


def test_unframed_payload_malformed():
    assert decode_payload(0x55, b"\x01\x02") == Malformed(0x55, 0, 0x0201, NackCode.UNKNOWN_TYPE)
    assert decode_payload(MsgType.ACK, b"\x01") == Malformed(MsgType.ACK, 0, 0, NackCode.BAD_LENGTH)
    assert payload_size_of_type(0x55) is None


@pytest.mark.parametrize("cls", list(BY_CLASS), ids=lambda c: c.__name__)
@settings(max_examples=20)
@given(data=st.data(), extra=st.binary(min_size=1, max_size=8))
def test_appended_fields_are_ignored(cls, data, extra):
    # The extension rule: a newer peer appends fields; an older one decodes the fields it
    # knows and ignores the rest.
    msg = data.draw(BY_CLASS[cls])
    msg_type, payload = encode_payload(msg)
    extra = extra[: frame.MAX_PAYLOAD_BYTES - len(payload)]  # what a frame can still carry
    assert extra
    [got] = Decoder().feed(frame_raw(msg_type, payload + extra, 0))
    assert _same([got], [msg])


# The messages that gained fields after version 2.0.
_EXTENDED = [c for c in BY_CLASS if any(f.appended for f in frame.wire_fields(c))]


def test_which_fields_were_appended_after_version_2_0():
    appended = {
        c.__name__: [f.name for f in frame.wire_fields(c) if f.appended] for c in _EXTENDED
    }
    assert appended == {
        "HelloReply": ["queue_blocks", "stream_points", "stream_period_min_ms",
                       "stream_period_max_ms"],
        "SetLimits": ["bus_over_voltage_v", "bus_under_voltage_v", "thermal_derate_c",
                      "thermal_trip_c", "brake_current_limit_a"],
        "Limits": ["bus_over_voltage_v", "bus_under_voltage_v", "thermal_trip_c",
                   "winding_estimate_c", "thermal_derate_c", "brake_current_limit_a"],
        "Telemetry": ["bus_voltage_v"],
        "BoardHeartbeat": ["queue_free", "stream_free", "stream_state", "stream_underruns",
                           "bus_voltage_v"],
        "Status": ["sense_offset_a", "sense_offset_neg_a"],
    }  # fmt: skip
    # A command's appended fields are ones whose 0 (an older PC's) keeps the board's value.
    assert [c for c in _EXTENDED if int(c.MSG_TYPE) < 0x80] == [SetLimits]


@pytest.mark.parametrize("cls", _EXTENDED, ids=lambda c: c.__name__)
@settings(max_examples=20)
@given(data=st.data())
def test_an_older_peer_s_payload_reads_the_fields_it_lacks_as_zero(cls, data):
    """The extension rule, the other way round: a newer PC reading an older board's message
    (its payload ends after the version 2.0 fields, or after any appended field) gets every
    field the older board sent and 0 for each it did not; a payload that ends inside a field
    is BAD_LENGTH. (Until 2 December the codec refused every shorter payload, while the spec
    promised 'bus_voltage_v 0 from an older board'.)"""
    msg = data.draw(BY_CLASS[cls])
    msg_type, payload = encode_payload(msg)
    fields = frame.wire_fields(cls)
    at, ends = 0, []
    for f in fields:
        at += struct.calcsize("<" + f.fmt)
        ends.append((at, f))
    first_appended = next(i for i, f in enumerate(fields) if f.appended)
    zero = decode_payload(msg_type, bytes(len(payload)))
    for i in range(first_appended - 1, len(fields)):
        end = ends[i][0]
        [got] = Decoder().feed(frame_raw(msg_type, payload[:end], 3))
        expected = dataclasses.replace(
            msg, **{f.name: getattr(zero, f.name) for f in fields[i + 1 :]}
        )
        assert _same([got], [expected]), (end, got)
        if i + 1 < len(fields) and struct.calcsize("<" + fields[i + 1].fmt) > 1:
            [cut] = Decoder().feed(frame_raw(msg_type, payload[: end + 1], 3))
            assert isinstance(cut, Malformed) and cut.code is NackCode.BAD_LENGTH
    short = ends[first_appended - 1][0] - 1
    assert decode_payload(msg_type, payload[:short]).code is NackCode.BAD_LENGTH


def test_an_older_board_s_heartbeat_has_no_bus_voltage():
    """The spec's own example: a BoardHeartbeat without ``bus_voltage_v`` (2 bytes shorter)
    reads 0 V, 'unknown'."""
    msg = BoardHeartbeat(**{f.name: 0 for f in frame.wire_fields(BoardHeartbeat)})
    msg = dataclasses.replace(msg, tick=1234, rx_frames=7, bus_voltage_v=24.0)
    msg_type, payload = encode_payload(msg)
    got = decode_payload(msg_type, payload[:-2])
    assert got == dataclasses.replace(msg, bus_voltage_v=0.0)


def test_nan_and_infinity_travel_in_float_fields():
    decoder = Decoder()
    [move] = decoder.feed(encode(Move(1, 10.0, math.nan, math.inf, -math.inf), 0))
    assert math.isnan(move.v_max_dps)
    assert move.a_max_dps2 == math.inf and move.j_max_dps3 == -math.inf


@settings(max_examples=200)
@given(
    u32,
    st.lists(st.floats(allow_nan=False, min_value=-1e12, max_value=1e12), min_size=6, max_size=6),
    st.sampled_from(State),
    st.sampled_from(Fault),
    u8,
)
def test_encode_telemetry_fields_matches_encode(tick, values, state, fault, seq):
    msg = Telemetry(tick, *values, state, fault)
    assert encode_telemetry_fields(seq, tick, *values, state, fault) == encode(msg, seq)


def test_telemetry_saturates_and_rejects_nan():
    huge = Telemetry(2**32 + 5, 1e9, -math.inf, 0.0, 0.0, 100.0, -7.0, State.FAULT, 1)
    [out] = Decoder().feed(encode(huge, 0))
    assert out.tick == 5  # the tick counter wraps modulo 2**32
    assert out.sp_pos_deg == (2**31 - 1) / 10_000.0
    assert out.sp_vel_dps == -(2**31) / 10_000.0
    assert out.current_a == (2**15 - 1) / 1000.0
    assert out.duty == -(2**15) / 10_000.0
    with pytest.raises(ValueError, match="pos_deg"):
        encode(dataclasses.replace(huge, pos_deg=math.nan), 0)


@pytest.mark.parametrize(
    ("msg", "match"),
    [
        (Move(70_000, 1.0, 1.0, 1.0), r"Move.cmd_id = 70000: must be an integer in 0 .. 65535"),
        (Move(1, math.nan, 1.0, 1.0), r"Move.target_deg = nan deg: beyond the wire range"),
        (Move(1, 1e9, 1.0, 1.0), r"Move.target_deg = 1000000000.0 deg: beyond the wire range "
                                 r"-214748.3648 .. 214748.3647 deg"),
        (Stop(-1), r"Stop.cmd_id = -1"),
        (SetTelemetry(1, 70_000), r"SetTelemetry.decimation = 70000"),
        (Stop(1, 1e300), r"Stop.a_max_dps2 = 1e\+300: beyond the float32 range"),
        (Move(1, 1.0, "fast", 1.0), r"Move.v_max_dps = 'fast': must be a number"),
        (SetEnable(1, 2), r"SetEnable.enable = 2: must be true or false"),
        (Move(1, 1.0, 1.0, 1.0, session=-3), r"Move.session = -3"),
        (GetGains(1, 7), r"GetGains.loop = 7: must be one of"),
    ],
)  # fmt: skip
def test_command_values_that_do_not_fit_raise_naming_the_field(msg, match):
    # The host library refuses what the wire cannot carry: a ValueError naming the field,
    # never a struct.error.
    with pytest.raises(ValueError, match=match):
        encode(msg, 0)
    with pytest.raises(ValueError, match=match):
        encode_payload(msg)


def test_encode_rejects_non_messages():
    with pytest.raises(TypeError):
        encode(b"hello", 0)


# ------------------------------------------------------------------ Malformed


def test_unknown_type_with_good_crc_is_malformed():
    out, decoder = decode_all(frame_raw(0x42, b"\x07\x01\xff", 3))
    assert out == [Malformed(0x42, 3, 0x0107, NackCode.UNKNOWN_TYPE)]
    assert decoder.malformed == 1 and decoder.frames == 1 and decoder.crc_errors == 0


def test_short_payload_is_malformed_with_cmd_id():
    payload = encode(Move(0x0A0B, 1.0, 2.0, 3.0), 0)[6:-4]
    out, _ = decode_all(frame_raw(MsgType.MOVE, payload[:-1], 4))
    assert out == [Malformed(MsgType.MOVE, 4, 0x0A0B, NackCode.BAD_LENGTH)]
    out, _ = decode_all(frame_raw(MsgType.GET_STATUS, b"\x01", 5))
    assert out == [Malformed(MsgType.GET_STATUS, 5, 0, NackCode.BAD_LENGTH)]


def test_undefined_enum_value_is_malformed_out_of_range_naming_the_field():
    payload = struct.pack("<HHB", 77, 1, 9)  # Loop 9 does not exist
    out, _ = decode_all(frame_raw(MsgType.GET_GAINS, payload, 0))
    assert out == [Malformed(MsgType.GET_GAINS, 0, 77, NackCode.OUT_OF_RANGE, 2)]
    out, _ = decode_all(frame_raw(MsgType.SET_ENABLE, struct.pack("<HHB", 78, 1, 2), 1))
    assert out == [Malformed(MsgType.SET_ENABLE, 1, 78, NackCode.OUT_OF_RANGE, 2)]
    assert frame.field_name(MsgType.SET_ENABLE, 2) == "enable"
    assert frame.field_name(MsgType.SET_ENABLE, NO_FIELD) is None


def test_frame_raw_rejects_oversize_payload():
    with pytest.raises(ValueError, match="exceeds"):
        frame_raw(0x01, bytes(MAX_PAYLOAD_BYTES + 1), 0)


# ------------------------------------------------------------------ counters


def test_counters_for_garbage_crc_error_and_gap():
    msgs, frames = stream(6)
    garbage = bytes(range(17))  # no 0xA5 in it
    corrupted = bytearray(frames[2])
    corrupted[10] ^= 0x01  # in the payload: the header check passes, the CRC fails
    data = garbage + frames[0] + frames[1] + bytes(corrupted) + frames[3] + frames[5]
    out, decoder = decode_all(data)
    assert out == [msgs[0], msgs[1], msgs[3], msgs[5]]
    assert decoder.frames == 4
    assert decoder.crc_errors == 1
    assert decoder.header_errors == 0
    assert decoder.bytes_dropped == len(garbage) + len(corrupted)
    assert decoder.resyncs == 2  # after the garbage and after the corrupted frame
    assert decoder.seq_gaps == 2  # 1 -> 3 and 3 -> 5
    assert decoder.frames_missed == 2


def test_header_error_is_counted_and_only_one_byte_skipped():
    msgs, frames = stream(1)
    fake = b"\xa5\x5a\x10\x82\x00\x00"  # wrong header check byte
    out, decoder = decode_all(fake + frames[0])
    assert out == msgs
    assert decoder.header_errors == 1
    assert decoder.bytes_dropped == len(fake)


def test_sequence_wraps_without_a_gap():
    msgs, frames = stream(4, first_seq=254)
    out, decoder = decode_all(b"".join(frames))
    assert out == msgs
    assert decoder.seq_gaps == 0 and decoder.last_seq == 1


def test_split_sync_pair_across_chunks():
    msgs, frames = stream(1)
    decoder = Decoder()
    assert decoder.feed(b"\x00\x00" + frames[0][:1]) == []
    assert decoder.feed(frames[0][1:]) == msgs
    assert decoder.bytes_dropped == 2


# ------------------------------------------------------------------ properties

PROPERTY = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@PROPERTY
@given(st.binary(max_size=600), st.lists(st.integers(0, 600), max_size=8))
def test_arbitrary_bytes_never_raise(data, cuts):
    decoder = Decoder()
    for start, stop in zip([0, *sorted(cuts)], [*sorted(cuts), len(data)], strict=True):
        for msg in decoder.feed(data[start:stop]):
            assert isinstance(msg, Malformed) or type(msg) in frame._BY_CLASS
    decoder.flush()
    assert decoder.pending_bytes == 0


def _with_noise(msgs: list, data: st.DataObject) -> bytes:
    """The frames of ``msgs`` with up to 40 random bytes inserted at a random place."""
    raw = b"".join(encode(m, k) for k, m in enumerate(msgs))
    noise = data.draw(st.binary(max_size=40))
    where = data.draw(st.integers(0, len(raw)))
    return raw[:where] + noise + raw[where:]


@PROPERTY
@given(
    st.lists(MESSAGES, min_size=1, max_size=12),
    st.data(),
)
def test_output_is_the_same_however_the_stream_is_chunked(msgs, data):
    raw = _with_noise(msgs, data)
    whole = Decoder()
    expected = whole.feed(raw)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(raw)), max_size=20)))
    chunked = Decoder()
    got = []
    for start, stop in zip([0, *cuts], [*cuts, len(raw)], strict=True):
        got += chunked.feed(raw[start:stop])
    assert _same(got, expected)
    assert chunked.stats() == whole.stats()
    assert chunked.pending_bytes == whole.pending_bytes


@PROPERTY
@given(st.binary(max_size=200), st.lists(MESSAGES, min_size=1, max_size=6))
def test_every_intact_frame_after_garbage_is_recovered(garbage, msgs):
    raw = b"".join(encode(m, k) for k, m in enumerate(msgs))
    out, _ = decode_all(garbage + raw)
    assert _same(out[len(out) - len(msgs) :], msgs)


@PROPERTY
@given(st.lists(MESSAGES, min_size=2, max_size=6), st.data())
def test_truncated_frame_does_not_swallow_the_next(msgs, data):
    # a frame cut short claims a length that runs into the next frames: the decoder must
    # back up one byte, not skip the claimed length
    first = encode(msgs[0], 0)
    cut = data.draw(st.integers(frame.HEADER_BYTES, len(first) - 1))
    rest = b"".join(encode(m, k + 1) for k, m in enumerate(msgs[1:]))
    stream = first[:cut] + rest
    # If the bytes that follow the cut happen to equal the ones cut off (e.g. a CRC byte of
    # 0xA5 followed by the next frame's sync byte), the stream holds the first frame intact:
    # nothing was truncated, and decoding it is right.
    assume(not stream.startswith(first))
    out, decoder = decode_all(stream)
    assert _same(out, msgs[1:])


@PROPERTY
@given(
    st.binary(max_size=100),
    st.integers(0, MAX_PAYLOAD_BYTES),
    u8,
    u8,
    MESSAGES,
)
def test_fake_header_cannot_hold_a_good_frame_back(garbage, length, msg_type, seq, msg):
    head = bytes((length, msg_type, seq))
    fake = b"\xa5\x5a" + head + bytes((crc8(head),))  # a header that passes the check
    good = encode(msg, 0)
    decoder = Decoder()
    # no flush: the bytes that follow are enough to resolve the fake
    out = decoder.feed(garbage + fake + good + bytes(MAX_FRAME_BYTES))
    assert _same(out[-1:], [msg])


@PROPERTY
@given(
    st.lists(st.integers(0, 10_000), min_size=1, max_size=30, unique=True),
    st.data(),
)
def test_corrupted_frames_are_never_accepted(ticks, data):
    msgs = [telemetry(t) for t in ticks]
    frames = [bytearray(encode(m, k)) for k, m in enumerate(msgs)]
    corrupted = set()
    for index in data.draw(st.sets(st.integers(0, len(frames) - 1))):
        frm = frames[index]
        # a burst of at most 32 bits: the CRC-32 detects every such burst
        first_bit = data.draw(st.integers(2 * 8, len(frm) * 8 - 1))
        span = data.draw(st.integers(1, 32))
        pattern = data.draw(st.integers(1, (1 << span) - 1)) | 1 | (1 << (span - 1))
        for bit in range(span):
            if pattern >> bit & 1 and first_bit + bit < len(frm) * 8:
                frm[(first_bit + bit) // 8] ^= 0x80 >> ((first_bit + bit) % 8)
        corrupted.add(index)
    out, decoder = decode_all(b"".join(bytes(f) for f in frames))
    intact = [m for k, m in enumerate(msgs) if k not in corrupted]
    assert out == intact
    assert decoder.frames == len(intact)


def _same(got: list, expected: list) -> bool:
    """Equality that treats NaN float fields as equal (messages are compared field-wise)."""
    if len(got) != len(expected):
        return False
    for a, b in zip(got, expected, strict=True):
        if type(a) is not type(b):
            return False
        if a == b:
            continue
        for field in dataclasses.fields(a):
            x, y = getattr(a, field.name), getattr(b, field.name)
            if x != y and not (isinstance(x, float) and math.isnan(x) and math.isnan(y)):
                return False
    return True


# ------------------------------------------------------------------ columns


def _as_columns(messages: list) -> tuple[dict[str, list], list]:
    """What ``feed_columns`` must give for what ``feed`` gave: the telemetry as columns."""
    tel = [m for m in messages if isinstance(m, Telemetry)]
    names = [f.name for f in dataclasses.fields(Telemetry)]
    return {n: [getattr(t, n) for t in tel] for n in names}, [
        m for m in messages if not isinstance(m, Telemetry)
    ]


@PROPERTY
@given(st.lists(MESSAGES, min_size=1, max_size=12), st.data())
def test_feed_columns_is_feed_with_telemetry_as_columns(msgs, data):
    raw = _with_noise(msgs, data)
    objects = Decoder()
    expected_columns, expected_others = _as_columns(objects.feed(raw))
    columns = Decoder()
    got_columns, got_others = columns.feed_columns(raw)
    assert list(got_columns) == list(expected_columns)
    for name, values in expected_columns.items():
        column = got_columns[name]
        assert column.shape == (len(values),)
        ints = ("tick", "state", "fault", "fault_flags")
        assert column.dtype == (np.int64 if name in ints else np.float64)
        # Bit for bit the values the objects carry (wire / scale).
        assert column.tolist() == [float(v) if column.dtype == float else int(v) for v in values]
    assert _same(got_others, expected_others)
    assert columns.stats() == objects.stats()
    assert columns.pending_bytes == objects.pending_bytes


def test_feed_columns_across_chunks_and_bad_codes():
    msgs, frames = stream(5)
    bad = bytearray(frames[2])
    bad[frame.HEADER_BYTES + 24] = 0xEE  # state code out of range: Malformed, as feed says
    body = bytes(bad[2:-4])
    bad[-4:] = frame.crc32(body).to_bytes(4, "little")
    raw = frames[0] + frames[1] + bytes(bad) + frames[3] + frames[4]
    decoder = Decoder()
    first, others_1 = decoder.feed_columns(raw[:50])  # a frame and a half
    second, others_2 = decoder.feed_columns(raw[50:])
    assert first["tick"].tolist() == [0]
    assert second["tick"].tolist() == [1, 3, 4]
    assert second["pos_deg"].tolist() == [0.25, 0.75, 1.0]
    assert others_1 == []
    assert [type(m) for m in others_2] == [Malformed]
    assert others_2[0].code == NackCode.OUT_OF_RANGE
    assert decoder.stats().malformed == 1 and decoder.stats().frames == 5


def test_feed_columns_of_nothing():
    columns, others = Decoder().feed_columns(b"")
    assert others == []
    assert all(c.shape == (0,) for c in columns.values()) and len(columns) == 11
