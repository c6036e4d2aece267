"""Write ``docs/conformance/vectors.json``: the machine-readable conformance vectors of
protocol v2 (docs/protocol.md section 12).

    python docs/conformance/make_vectors.py          # rewrite vectors.json
    python docs/conformance/make_vectors.py --check  # exit 1 if vectors.json is stale

The *frames* take their hex from the reference encoder (``serial_protocol.frame``); their
decoded fields are written here by hand, and ``tests/serial_protocol/test_conformance.py``
decodes the hex a second, independent way (from the tables of docs/protocol.md). The
*streams* and *exchanges* state what docs/protocol.md requires, written here by hand; the
test runs the reference decoder and the simulated board against them. Nothing here is read
back from the board.
"""

from __future__ import annotations

import dataclasses
import json
import math
import struct
import sys
from pathlib import Path
from typing import Any

from serial_protocol import frame
from serial_protocol.messages import (
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

OUT = Path(__file__).with_name("vectors.json")
S = 0x1234  # the session of the exchanges


def _value(v: Any) -> Any:
    """A field value as JSON: enums by name, floats that JSON cannot hold as strings."""
    if isinstance(v, bool):
        return v
    if isinstance(v, MsgType):
        return int(v)  # type bytes (Ack.msg_type, Nack.msg_type) are plain numbers
    if hasattr(v, "name") and isinstance(v, int):
        return v.name
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    return v


def _on_the_wire(f: frame.WireField, v: Any) -> Any:
    """``v`` as the receiver sees it: float32 rounding, fixed-point steps (docs 4.1)."""
    if f.wire == "f32" and math.isfinite(v):
        return struct.unpack("<f", struct.pack("<f", v))[0]
    if f.scale is not None:
        return round(v * f.scale) / f.scale
    return v


def _fields(msg: Any) -> dict[str, Any]:
    return {
        f.name: _value(_on_the_wire(f, getattr(msg, f.name))) for f in frame.wire_fields(type(msg))
    }


# One frame per message type (two for some), with values that exercise the scaling.
FRAMES: list[tuple[str, Any, int]] = [
    ("hello", Hello(1, 2, 2, session=S), 0),
    ("heartbeat", Heartbeat(0, session=S), 1),
    ("move_trapezoid", Move(2, 3000.0, 990.0, 148.0, 0.0, Profile.TRAPEZOID, session=S), 2),
    ("move_scurve_negative", Move(3, -8000.5, 990.0, 148.0, 1e5, Profile.SCURVE, session=S), 3),
    ("move_nan", Move(4, 10.0, math.nan, math.inf, -math.inf, Profile.STEP, session=S), 4),
    ("stop", Stop(5, 148.0, session=S), 5),
    ("set_enable", SetEnable(6, True, session=S), 6),
    ("clear_fault", ClearFault(7, session=S), 7),
    ("set_gains", SetGains(8, Loop.VELOCITY, 0.5, 2.0, 0.0, session=S), 8),
    ("get_gains", GetGains(9, Loop.POSITION, session=S), 9),
    ("set_limits", SetLimits(10, 990.0, 148.0, 5.0, 10.0, 7.0, session=S), 10),
    (
        "set_limits_thresholds",
        SetLimits(10, 990.0, 148.0, 5.0, 10.0, 0.0, session=S, bus_over_voltage_v=26.5,
                  bus_under_voltage_v=19.0, thermal_derate_c=90.0, thermal_trip_c=110.0),
        10,
    ),  # fmt: skip
    (
        "set_limits_brake_cap",
        SetLimits(10, 990.0, 148.0, 5.0, 10.0, 0.0, session=S, brake_current_limit_a=5.0),
        10,
    ),  # fmt: skip
    ("get_limits", GetLimits(11, session=S), 11),
    ("get_status", GetStatus(12, session=S), 12),
    ("set_telemetry", SetTelemetry(13, 2, session=S), 13),
    ("get_fault", GetFault(14, 0, session=S), 14),
    ("queue_segment", QueueSegment(15, 1500.0, 300.0, 0.5, session=S), 15),
    ("queue_control", QueueControl(16, QueueAction.OVERRIDE, 80.0, session=S), 16),
    (
        "stream_control",
        StreamControl(17, StreamAction.START, Interp.CUBIC, 0.125, 4, session=S),
        17,
    ),
    (
        "stream_points",
        dataclasses.replace(
            StreamPoints.of(18, 1, [0.9375, 3.75, 8.4375, 15.0], [12.5, 25.0, 37.5, 50.0]),
            session=S,
        ),
        18,
    ),
    ("jog", Jog(19, -25.0, 500.0, 250, session=S), 19),
    (
        "hello_reply",
        HelloReply(
            1,
            S,
            2,
            0,
            1,
            0,
            500,
            16384,
            0x7FFFE,
            64,
            256,
            32,
            1,
            200,
            500,
            20,
            460800,
            32,
            64,
            2,
            1000,
        ),
        0,
    ),  # fmt: skip
    (
        "telemetry",
        Telemetry(
            123456, 3000.0, 990.0, 2999.9876, 989.5, 1.234, -0.5678, State.MOVING, Fault.NONE, 0,
            24.517,
        ),
        1,
    ),  # fmt: skip
    (
        "telemetry_fault",
        Telemetry(
            0xFFFFFFFF,
            -1.0,
            0.0,
            -1.0001,
            -0.0001,
            -32.768,
            0.0,
            State.FAULT,
            Fault.OVER_CURRENT,
            0x00000001,
            65.535,
        ),
        255,
    ),  # fmt: skip
    ("ack", Ack(0x1234, MsgType.MOVE), 9),
    ("nack", Nack(3, MsgType.MOVE, NackCode.TOO_HIGH, 5, 990.0), 10),
    ("nack_no_field", Nack(4, MsgType.MOVE, NackCode.DISABLED), 11),
    ("fault_report", FaultReport(777, Fault.FOLLOWING_ERROR, 10.5, 0x100, 10.0), 12),
    (
        "fault_report_bus",
        FaultReport(3106, Fault.BUS_OVER_VOLTAGE, 27.125, 0x8, 27.0),
        12,
    ),
    ("gains", Gains(9, Loop.CURRENT, 0.25, 180.0, 0.0), 13),
    (
        "limits",
        Limits(
            11, 990.0, 148.0, 5.0, 10.0, 7.5, -1e5, 1e5, 1100.0, 7.5, 27.0, 18.0, 120.0, 41.5,
            100.0, 5.0,
        ),  # fmt: skip
        14,
    ),
    (
        "status",
        Status(12, 5000, State.HOLDING, Fault.NONE, 3000.0, 0.0, 3000.0, 0, S, 0.4795, 0.2055),
        15,
    ),
    (
        "board_heartbeat",
        BoardHeartbeat(
            100, S, State.IDLE, 0, 5, 1, 2, 30, 1, 0, 1, 2, 0, 32, 60, StreamState.RUNNING, 1,
            24.005,
        ),
        16,
    ),
    ("fault_info", FaultInfo(14, 0, True, 40, 5.18, 4.0), 17),
    ("queue_status", QueueStatus(16, QueueState.RUNNING, 30, 2, 5, 80.0), 18),
    ("stream_status", StreamStatus(18, StreamState.RUNNING, 60, 5, 0, 12.5), 19),
]


def frames() -> list[dict[str, Any]]:
    out = []
    for name, msg, seq in FRAMES:
        out.append(
            {
                "name": name,
                "type": type(msg).__name__,
                "type_byte": int(msg.MSG_TYPE),
                "seq": seq,
                "hex": frame.encode(msg, seq).hex(),
                "fields": _fields(msg),
            }
        )
    return out


def _hex(msg: Any, seq: int) -> str:
    return frame.encode(msg, seq).hex()


def streams() -> list[dict[str, Any]]:
    """Byte streams with what a decoder must deliver and count (docs section 3)."""
    a = frame.encode(Ack(1, MsgType.MOVE), 0)
    b = frame.encode(Ack(2, MsgType.STOP), 1)
    c = frame.encode(Ack(3, MsgType.SET_ENABLE), 2)
    bad_crc = bytearray(b)
    bad_crc[7] ^= 0x01  # a payload bit: the header check passes, the CRC fails
    head = bytes((frame.MAX_PAYLOAD_BYTES, 0x03, 0))
    fake = frame.SYNC + head + bytes((frame.crc8(head),))  # a valid header claiming 64 bytes
    bad_head = b"\xa5\x5a\x10\x82\x00\x00"  # the header check fails
    short = frame.frame_raw(MsgType.GET_STATUS, b"\x07", 3)  # 1 byte: BAD_LENGTH
    ack = [{"type": "Ack", "fields": _fields(m)} for m in
           (Ack(1, MsgType.MOVE), Ack(2, MsgType.STOP), Ack(3, MsgType.SET_ENABLE))]  # fmt: skip
    zero = dict.fromkeys(vars(frame.Decoder().stats()), 0)
    # the extension rule (section 6): an older board's BoardHeartbeat, without the appended
    # bus_voltage_v (2 bytes), and one cut inside that field
    heartbeat = next(msg for name, msg, _ in FRAMES if name == "board_heartbeat")
    hb_type, hb_payload = frame.encode_payload(heartbeat)
    old_heartbeat = frame.frame_raw(hb_type, hb_payload[:-2], 16)
    inside = frame.frame_raw(hb_type, hb_payload[:-1], 16)
    # ... and an older board's Telemetry, without the appended bus_voltage_v (2 bytes)
    telemetry = next(msg for name, msg, _ in FRAMES if name == "telemetry")
    tel_type, tel_payload = frame.encode_payload(telemetry)
    old_telemetry = frame.frame_raw(tel_type, tel_payload[:-2], 1)

    def counters(**kw: int) -> dict[str, int]:
        return {**zero, **kw}

    return [
        {"name": "three_frames", "hex": (a + b + c).hex(), "flush": False,
         "messages": ack, "counters": counters(frames=3), "pending_bytes": 0},
        {"name": "garbage_before", "hex": (bytes(range(17)) + a).hex(), "flush": False,
         "messages": ack[:1], "counters": counters(frames=1, resyncs=1, bytes_dropped=17),
         "pending_bytes": 0},
        {"name": "crc_error_then_recovery", "hex": (a + bytes(bad_crc) + c).hex(),
         "flush": False, "messages": [ack[0], ack[2]],
         "counters": counters(frames=2, crc_errors=1, resyncs=1, bytes_dropped=len(bad_crc),
                              seq_gaps=1, frames_missed=1), "pending_bytes": 0},
        {"name": "header_error_one_byte_skipped", "hex": (bad_head + a).hex(), "flush": False,
         "messages": ack[:1],
         "counters": counters(frames=1, header_errors=1, resyncs=1,
                              bytes_dropped=len(bad_head)), "pending_bytes": 0},
        {"name": "truncated_frame_does_not_swallow_the_next", "hex": (a[:9] + b).hex(),
         "flush": False, "messages": ack[1:2],
         "counters": counters(frames=1, crc_errors=1, resyncs=1, bytes_dropped=9),
         "pending_bytes": 0},
        {"name": "false_header_held_until_silence", "hex": (fake + b).hex(), "flush": False,
         "messages": [], "counters": counters(), "pending_bytes": len(fake) + len(b)},
        {"name": "false_header_then_silence_flush", "hex": (fake + b).hex(), "flush": True,
         "messages": ack[1:2],
         "counters": counters(frames=1, resyncs=1, bytes_dropped=len(fake),
                              partial_discards=1), "pending_bytes": 0},
        {"name": "short_payload_is_malformed", "hex": short.hex(), "flush": False,
         "messages": [{"type": "Malformed", "fields": {"msg_type": int(MsgType.GET_STATUS),
                                                       "seq": 3, "cmd_id": 0,
                                                       "code": "BAD_LENGTH", "field": 255}}],
         "counters": counters(frames=1, malformed=1), "pending_bytes": 0},
        {"name": "older_board_heartbeat_without_bus_voltage", "hex": old_heartbeat.hex(),
         "flush": False,
         "messages": [{"type": "BoardHeartbeat",
                       "fields": {**_fields(heartbeat), "bus_voltage_v": 0.0}}],
         "counters": counters(frames=1), "pending_bytes": 0},
        {"name": "older_board_telemetry_without_bus_voltage", "hex": old_telemetry.hex(),
         "flush": False,
         "messages": [{"type": "Telemetry",
                       "fields": {**_fields(telemetry), "bus_voltage_v": 0.0}}],
         "counters": counters(frames=1), "pending_bytes": 0},
        {"name": "payload_ending_inside_an_appended_field_is_malformed",
         "hex": inside.hex(), "flush": False,
         "messages": [{"type": "Malformed",
                       "fields": {"msg_type": int(MsgType.BOARD_HEARTBEAT), "seq": 16,
                                  "cmd_id": heartbeat.tick & 0xFFFF, "code": "BAD_LENGTH",
                                  "field": 255}}],
         "counters": counters(frames=1, malformed=1), "pending_bytes": 0},
        {"name": "longer_payload_is_an_extension",
         "hex": frame.frame_raw(MsgType.ACK, bytes(a[6:9]) + b"\x01\x02\x03", 0).hex(),
         "flush": False, "messages": ack[:1], "counters": counters(frames=1),
         "pending_bytes": 0},
    ]  # fmt: skip


def _cmd(msg: Any, seq: int) -> dict[str, Any]:
    return {"type": type(msg).__name__, "fields": _fields(msg), "hex": _hex(msg, seq)}


def _expect(type_name: str, **fields: Any) -> dict[str, Any]:
    return {"type": type_name, "fields": {k: _value(v) for k, v in fields.items()}}


def exchanges() -> list[dict[str, Any]]:
    """Command sequences to a freshly booted board (default configuration: 460800 baud, the
    bridge enabled and holding where it woke up, travel +-1e5 deg, v_max 1000 deg/s, a_max
    2000 deg/s^2, over-current trip 7.5 A, no watchdog). Each step is sent at once; the
    answers expected within ``wait_ms`` follow (telemetry and board heartbeats left out)
    and must match in order, on the fields listed. ``raw_hex`` steps send bytes as they
    are."""
    t = MsgType

    def step(send: Any, *expect: dict[str, Any], seq: int, wait_ms: int = 10) -> dict:
        if isinstance(send, bytes):
            return {"raw_hex": send.hex(), "wait_ms": wait_ms, "expect": list(expect)}
        return {"send": _cmd(send, seq), "wait_ms": wait_ms, "expect": list(expect)}

    hello = step(Hello(1, 2, 2, session=S), _expect("HelloReply", cmd_id=1, session=S,
                 protocol_version=2, command_mask=0x7FFFE, max_payload_bytes=64,
                 rx_silence_ms=20, telemetry_min_decimation=1), seq=0)  # fmt: skip
    head = bytes((frame.MAX_PAYLOAD_BYTES, 0x03, 0))
    fake = frame.SYNC + head + bytes((frame.crc8(head),))
    good = GetStatus(9, session=S)
    _, payload = frame.encode_payload(good)
    _, old_limits = frame.encode_payload(SetLimits(3, 900.0, 2000.0, 5.0, 30.0, session=S))
    old_limits = old_limits[:24]  # an older PC's SetLimits (version 2.0's fields)
    return [
        {"name": "commands_need_a_session", "steps": [
            step(GetStatus(1, session=0), _expect("Nack", cmd_id=1, msg_type=t.GET_STATUS,
                 code=NackCode.NO_SESSION, field=1, limit=0.0), seq=0),
            step(Move(2, 10.0, 100.0, 100.0, session=S), _expect("Nack", cmd_id=2,
                 msg_type=t.MOVE, code=NackCode.NO_SESSION, field=1), seq=1),
        ]},
        {"name": "hello_opens_and_states_capabilities", "steps": [
            hello,
            step(GetStatus(2, session=S), _expect("Status", cmd_id=2, state=State.IDLE,
                 fault=Fault.NONE, fault_flags=0, session=S), seq=1),
        ]},
        {"name": "hello_version_and_session_checks", "steps": [
            step(Hello(1, 3, 4, session=S), _expect("Nack", cmd_id=1, msg_type=t.HELLO,
                 code=NackCode.UNSUPPORTED_VERSION, field=2, limit=2.0), seq=0),
            step(Hello(2, 2, 2, session=0), _expect("Nack", cmd_id=2, msg_type=t.HELLO,
                 code=NackCode.TOO_LOW, field=1, limit=1.0), seq=1),
            step(Hello(3, 1, 9, session=S), _expect("HelloReply", cmd_id=3, session=S,
                 protocol_version=2), seq=2),
        ]},
        {"name": "another_session_takes_over", "steps": [
            hello,
            step(Hello(1, 2, 2, session=0x2222), _expect("HelloReply", cmd_id=1,
                 session=0x2222), seq=1),
            step(GetStatus(5, session=S), _expect("Nack", cmd_id=5, msg_type=t.GET_STATUS,
                 code=NackCode.STALE_SESSION, field=1, limit=float(0x2222)), seq=2),
            step(Heartbeat(0, session=S), _expect("Nack", cmd_id=0, msg_type=t.HEARTBEAT,
                 code=NackCode.STALE_SESSION, field=1, limit=float(0x2222)), seq=3),
            step(Heartbeat(0, session=0x2222), seq=4),  # accepted: no answer
        ]},
        {"name": "retry_is_answered_not_applied_and_hello_clears_the_memory", "steps": [
            hello,
            step(SetEnable(2, False, session=S), _expect("Ack", cmd_id=2,
                 msg_type=t.SET_ENABLE), seq=1),
            step(SetEnable(3, True, session=S), _expect("Ack", cmd_id=3,
                 msg_type=t.SET_ENABLE), seq=2),
            # the retry of cmd 3 after the Ack was lost: answered again, not re-applied
            step(SetEnable(3, True, session=S), _expect("Ack", cmd_id=3,
                 msg_type=t.SET_ENABLE), seq=3),
            step(SetEnable(2, False, session=S), _expect("Ack", cmd_id=2,
                 msg_type=t.SET_ENABLE), seq=4),
            step(GetStatus(4, session=S), _expect("Status", cmd_id=4, state=State.DISABLED),
                 seq=5),
            # a new program, the same session id and the same first command as before:
            # a new session, so it is applied
            step(Hello(1, 2, 2, session=S), _expect("HelloReply", cmd_id=1, session=S),
                 seq=6),
            step(SetEnable(3, True, session=S), _expect("Ack", cmd_id=3,
                 msg_type=t.SET_ENABLE), seq=7),
            step(GetStatus(5, session=S), _expect("Status", cmd_id=5, state=State.IDLE),
                 seq=8),
        ]},
        {"name": "values_out_of_range_name_the_field_and_bound", "steps": [
            hello,
            step(Move(2, 10.0, 2000.0, 148.0, session=S), _expect("Nack", cmd_id=2,
                 msg_type=t.MOVE, code=NackCode.TOO_HIGH, field=3, limit=1000.0), seq=1),
            step(Move(3, 10.0, 100.0, math.nan, session=S), _expect("Nack", cmd_id=3,
                 msg_type=t.MOVE, code=NackCode.NOT_FINITE, field=4, limit=0.0), seq=2),
            step(Move(4, 2e5, 100.0, 100.0, session=S), _expect("Nack", cmd_id=4,
                 msg_type=t.MOVE, code=NackCode.TOO_HIGH, field=2, limit=1e5), seq=3),
            step(Move(5, 10.0, 100.0, 0.0, session=S), _expect("Nack", cmd_id=5,
                 msg_type=t.MOVE, code=NackCode.TOO_LOW, field=4, limit=0.001), seq=4),
            step(Stop(6, -1.0, session=S), _expect("Nack", cmd_id=6, msg_type=t.STOP,
                 code=NackCode.TOO_LOW, field=2, limit=0.001), seq=5),
            step(SetGains(7, Loop.POSITION, 10.0, 1.0, 0.0, session=S), _expect("Nack",
                 cmd_id=7, msg_type=t.SET_GAINS, code=NackCode.TOO_HIGH, field=4, limit=0.0),
                 seq=6),
            step(SetLimits(8, 990.0, 148.0, 9.0, 10.0, 0.0, session=S), _expect("Nack",
                 cmd_id=8, msg_type=t.SET_LIMITS, code=NackCode.TOO_HIGH, field=4,
                 limit=7.5), seq=7),
            step(SetLimits(9, 990.0, 148.0, 5.0, 10.0, 8.0, session=S), _expect("Nack",
                 cmd_id=9, msg_type=t.SET_LIMITS, code=NackCode.TOO_HIGH, field=6,
                 limit=7.5), seq=8),
            step(GetFault(10, 40, session=S), _expect("Nack", cmd_id=10, msg_type=t.GET_FAULT,
                 code=NackCode.TOO_HIGH, field=2, limit=31.0), seq=9),
            step(GetLimits(11, session=S), _expect("Limits", cmd_id=11, v_max_dps=1000.0,
                 a_max_dps2=2000.0, over_current_trip_a=7.5, travel_max_deg=1e5), seq=10),
        ]},
        {"name": "settings_and_queries", "steps": [
            hello,
            step(SetLimits(2, 900.0, 1500.0, 4.0, 8.0, 6.0, session=S), _expect("Ack",
                 cmd_id=2, msg_type=t.SET_LIMITS), seq=1),
            step(GetLimits(3, session=S), _expect("Limits", cmd_id=3, v_max_dps=900.0,
                 a_max_dps2=1500.0, current_limit_a=4.0, following_error_deg=8.0,
                 over_current_trip_a=6.0, over_current_max_a=7.5), seq=2),
            step(GetFault(4, 0, session=S), _expect("FaultInfo", cmd_id=4, bit=0,
                 latched=False, tick=0), seq=3),
            step(ClearFault(5, session=S), _expect("Ack", cmd_id=5, msg_type=t.CLEAR_FAULT),
                 seq=4),
            step(GetStatus(6, session=S), _expect("Status", cmd_id=6, state=State.IDLE),
                 seq=5),  # ClearFault without a fault changes nothing
            step(SetTelemetry(7, 0, session=S), _expect("Ack", cmd_id=7,
                 msg_type=t.SET_TELEMETRY), seq=6),
        ]},
        {"name": "thresholds_set_kept_by_an_older_pc_and_refused", "steps": [
            hello,
            # SetLimits' appended thresholds (0 = keep): the thermal protection's (on in
            # this configuration) are set and read back
            step(SetLimits(2, 1000.0, 2000.0, 5.0, 30.0, 0.0, session=S, thermal_derate_c=90.0,
                           thermal_trip_c=110.0), _expect("Ack", cmd_id=2,
                 msg_type=t.SET_LIMITS), seq=1),
            # an older PC's SetLimits: the 24 bytes of version 2.0; the thresholds are kept
            step(frame.frame_raw(MsgType.SET_LIMITS, old_limits, 2), _expect("Ack", cmd_id=3,
                 msg_type=t.SET_LIMITS), seq=2),
            step(GetLimits(4, session=S), _expect("Limits", cmd_id=4, v_max_dps=900.0,
                 thermal_derate_c=90.0, thermal_trip_c=110.0, bus_over_voltage_v=0.0,
                 bus_under_voltage_v=0.0), seq=3),
            # ended inside an appended field: BAD_LENGTH
            step(frame.frame_raw(MsgType.SET_LIMITS, old_limits + b"\x00\x00", 4),
                 _expect("Nack", cmd_id=3, msg_type=t.SET_LIMITS, code=NackCode.BAD_LENGTH,
                         field=255), seq=4),
            # the derating above the trip in force; the bus check is off in this
            # configuration, so its thresholds take only 0; nothing of either is applied
            step(SetLimits(5, 800.0, 2000.0, 5.0, 30.0, 0.0, session=S,
                           thermal_derate_c=115.0), _expect("Nack", cmd_id=5,
                 msg_type=t.SET_LIMITS, code=NackCode.TOO_HIGH, field=9, limit=110.0), seq=5),
            step(SetLimits(6, 800.0, 2000.0, 5.0, 30.0, 0.0, session=S,
                           bus_over_voltage_v=26.0), _expect("Nack", cmd_id=6,
                 msg_type=t.SET_LIMITS, code=NackCode.TOO_HIGH, field=7, limit=0.0), seq=6),
            step(GetLimits(7, session=S), _expect("Limits", cmd_id=7, v_max_dps=900.0,
                 thermal_derate_c=90.0, thermal_trip_c=110.0), seq=7),
            # the cap on the brake after a trip (none configured): set, kept by 0, refused
            # out of range with nothing applied
            step(SetLimits(8, 900.0, 2000.0, 5.0, 30.0, 0.0, session=S,
                           brake_current_limit_a=5.0), _expect("Ack", cmd_id=8,
                 msg_type=t.SET_LIMITS), seq=8),
            step(SetLimits(9, 900.0, 2000.0, 5.0, 30.0, 0.0, session=S,
                           brake_current_limit_a=150.0), _expect("Nack", cmd_id=9,
                 msg_type=t.SET_LIMITS, code=NackCode.TOO_HIGH, field=11, limit=100.0), seq=9),
            step(GetLimits(10, session=S), _expect("Limits", cmd_id=10, v_max_dps=900.0,
                 brake_current_limit_a=5.0), seq=10),
        ]},
        {"name": "bad_frames_get_one_nack_each", "steps": [
            hello,
            step(frame.frame_raw(0x7E, b"\x29\x00\x34\x12", 1), _expect("Nack", cmd_id=0x29,
                 msg_type=0x7E, code=NackCode.UNKNOWN_TYPE, field=255), seq=1),
            step(frame.frame_raw(MsgType.MOVE, b"\x2a\x00\x34\x12\x05", 2), _expect("Nack",
                 cmd_id=0x2A, msg_type=t.MOVE, code=NackCode.BAD_LENGTH, field=255), seq=2),
            step(frame.frame_raw(MsgType.GET_GAINS, b"\x2b\x00\x34\x12\x09", 3),
                 _expect("Nack", cmd_id=0x2B, msg_type=t.GET_GAINS,
                         code=NackCode.OUT_OF_RANGE, field=2), seq=3),
            step(frame.encode(Ack(0x2C, MsgType.MOVE), 4), _expect("Nack", cmd_id=0x2C,
                 msg_type=t.ACK, code=NackCode.NOT_A_COMMAND, field=255), seq=4),
            step(frame.frame_raw(MsgType.GET_STATUS, payload + b"\x01\x02\x03", 5),
                 _expect("Status", cmd_id=9, session=S), seq=5),  # an extension: ignored
            step(bytes(frame.encode(good, 6)[:-1]) + b"\x00", seq=6),  # bad CRC: nothing
        ]},
        {"name": "silence_discards_a_false_header", "steps": [
            hello,
            step(fake, seq=1, wait_ms=20),  # a killed tool's false header, then 20 ms idle
            step(good, _expect("Status", cmd_id=9, session=S), seq=2, wait_ms=2),
        ]},
    ]  # fmt: skip


def vectors() -> dict[str, Any]:
    return {
        "protocol_version": 2,
        "spec": "docs/protocol.md",
        "constants": {
            "sync_hex": frame.SYNC.hex(),
            "header_bytes": frame.HEADER_BYTES,
            "crc_bytes": frame.CRC_BYTES,
            "max_payload_bytes": frame.MAX_PAYLOAD_BYTES,
            "rx_silence_ms": round(frame.RX_SILENCE_S * 1000),
            "scales": {
                "position_deg": 1e-4,
                "velocity_dps": 1e-4,
                "current_a": 1e-3,
                "duty": 1e-4,
            },  # fmt: skip
        },
        "crc": [
            {"name": "crc8_smbus", "input_hex": b"123456789".hex(), "value": 0xF4},
            {"name": "crc32_iso_hdlc", "input_hex": b"123456789".hex(), "value": 0xCBF43926},
        ],
        "frames": frames(),
        "streams": streams(),
        "exchanges": exchanges(),
    }


def render() -> str:
    return json.dumps(vectors(), indent=1, sort_keys=False) + "\n"


if __name__ == "__main__":
    text = render()
    if "--check" in sys.argv[1:]:
        sys.exit(0 if OUT.read_text() == text else 1)
    OUT.write_text(text)
    print(f"wrote {OUT} ({len(text)} bytes)")
