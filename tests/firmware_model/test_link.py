"""The board's side of protocol v2: sessions and duplicates, the watchdog and heartbeats, the
silence rule, version negotiation, fault reporting on the wire, and the v1 contradictions
resolved (docs/protocol.md sections 3, 5, 6, 7 and 13). Each defect of issue #10 that lives
on the board has its regression test here."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_model.params import FirmwareParams, SafetyParams, ServoParams, TelemetryParams
from serial_protocol import frame
from serial_protocol.messages import (
    FAULT_FLAG,
    Ack,
    BoardHeartbeat,
    ClearFault,
    Fault,
    FaultFlag,
    FaultInfo,
    FaultReport,
    GetFault,
    GetLimits,
    GetStatus,
    Heartbeat,
    Hello,
    HelloReply,
    Limits,
    Move,
    MsgType,
    Nack,
    NackCode,
    SetEnable,
    SetLimits,
    SetTelemetry,
    State,
    Status,
    Telemetry,
)


def move(cmd_id, target, session, v=200.0, a=2000.0):
    return Move(cmd_id, target, v, a, session=session)


def raw_bench(make_bench, params=None, **kw):
    """A bench that sends exactly what the test says (no automatic Hello or session)."""
    b = make_bench(params, **kw)
    b.auto_session = False
    return b


def answers(b, cls=(Ack, Nack)):
    return [m for m in b.received if isinstance(m, cls)]


# ---------------------------------------------------------------------------- sessions


def test_a_new_sessions_first_command_is_carried_out(make_bench):
    # Issue #10's regression: `monitor --move 30` then `monitor --move -30` (or --enable
    # then --disable). Each program opens its own session and starts at cmd_id 1; the
    # second one's first command must be applied, not swallowed as a repeat.
    b = raw_bench(make_bench, FirmwareParams(servo=ServoParams(start_enabled=False)))
    b.run(400, {
        5: [Hello(1, session=100), SetEnable(2, True, session=100)],
        200: [Hello(1, session=200), SetEnable(2, False, session=200)],
    })  # fmt: skip
    assert [(m.cmd_id, type(m).__name__) for m in answers(b, (Ack, Nack, HelloReply))] == [
        (1, "HelloReply"), (2, "Ack"), (1, "HelloReply"), (2, "Ack"),
    ]  # fmt: skip
    assert b.fw.counters["duplicates"] == 0
    assert b.arr("state")[199] == State.IDLE  # the first program's enable happened
    assert b.arr("state")[-1] == State.DISABLED  # and the second program's disable
    m = raw_bench(make_bench)
    m.run(600, {
        5: [Hello(1, session=100), move(2, 30.0, session=100)],
        300: [Hello(1, session=200), move(2, -30.0, session=200)],
    })  # fmt: skip
    assert m.fw.counters["duplicates"] == 0 and m.fw._target_deg == -30.0

    # The same program reconnecting with the same session id and the very same bytes:
    # the new Hello cleared the duplicate memory, so the command is applied again.
    r = raw_bench(make_bench)
    r.run(600, {
        5: [Hello(1, session=7), move(2, 30.0, session=7)],
        150: [move(3, 0.0, session=7)],
        300: [Hello(1, session=7), move(2, 30.0, session=7)],
    })  # fmt: skip
    assert r.fw.counters["duplicates"] == 0 and r.fw.counters["commands_applied"] == 3
    assert r.fw._target_deg == 30.0 and r.arr("sp_pos_deg")[-1] > 20.0


def test_a_retry_within_the_session_is_answered_not_applied(make_bench):
    b = raw_bench(make_bench)
    first = move(2, 30.0, session=5)
    b.run(300, {5: [Hello(1, session=5), first], 100: [first], 200: [first]})
    assert [a for a in answers(b) if isinstance(a, Ack)] == [Ack(2, MsgType.MOVE)] * 3
    assert b.fw.counters["duplicates"] == 2 and b.fw.counters["commands_applied"] == 1


def test_commands_without_or_outside_the_session_are_refused(make_bench):
    b = raw_bench(make_bench)
    b.run(60, {
        5: [move(1, 30.0, session=0), move(2, 30.0, session=9)],  # before any Hello
        10: [Hello(3, session=9), GetStatus(4, session=9)],
        20: [Hello(5, session=10)],  # another program takes the board over
        30: [move(6, 30.0, session=9), Heartbeat(7, session=9), GetStatus(8, session=10)],
    })  # fmt: skip
    nacks = [(n.cmd_id, n.code, n.field, n.limit) for n in answers(b, Nack)]
    session_field = frame.field_index(Move, "session")
    assert nacks == [
        (1, NackCode.NO_SESSION, session_field, 0.0),
        (2, NackCode.NO_SESSION, session_field, 0.0),
        (6, NackCode.STALE_SESSION, session_field, 10.0),
        (7, NackCode.STALE_SESSION, 1, 10.0),
    ]
    status = answers(b, Status)
    assert [(s.cmd_id, s.session) for s in status] == [(4, 9), (8, 10)]
    assert b.fw.counters["commands_applied"] == 0


def test_hello_negotiates_the_version_and_states_the_capabilities(make_bench):
    b = raw_bench(make_bench, FirmwareParams(telemetry=TelemetryParams(baud=115200)))
    b.run(20, {
        2: [Hello(1, 3, 4, session=5)],  # a newer client only
        3: [Hello(2, 1, 1, session=5)],  # an older one only
        4: [Hello(3, session=0)],
        5: [Hello(4, 1, 9, session=6)],
    })  # fmt: skip
    nacks = answers(b, Nack)
    assert [(n.cmd_id, n.code, n.field, n.limit) for n in nacks] == [
        (1, NackCode.UNSUPPORTED_VERSION, 2, 2.0),
        (2, NackCode.UNSUPPORTED_VERSION, 2, 2.0),
        (3, NackCode.TOO_LOW, 1, 1.0),
    ]
    (reply,) = answers(b, HelloReply)
    assert (reply.cmd_id, reply.session, reply.protocol_version) == (4, 6, 2)
    # Every command type is announced, and nothing else.
    assert reply.command_mask == sum(1 << t for t in range(1, 19)) == 0x7FFFE
    assert (reply.queue_blocks, reply.stream_points) == (32, 64)
    assert reply.telemetry_min_decimation == 3  # 40-byte frames at 115200 baud
    assert (reply.max_payload_bytes, reply.rx_buffer_bytes) == (64, 256)
    assert (reply.heartbeat_ms, reply.watchdog_ms, reply.rx_silence_ms) == (200, 0, 20)
    assert reply.baud == 115200 and b.fw.session == 6


def test_a_new_session_leaves_motion_and_faults_alone(make_bench):
    b = raw_bench(make_bench)
    b.run(200, {5: [Hello(1, session=1), move(2, 50.0, session=1)], 40: [Hello(1, session=2)]})
    sp = b.arr("sp_pos_deg")
    assert sp[60] > sp[40] and sp[-1] == 50.0  # the move went on across the new Hello


# ---------------------------------------------------------------------------- watchdog


def _watchdog_params(watchdog_s=0.1):
    return FirmwareParams(safety=SafetyParams(watchdog_s=watchdog_s))


def test_heartbeats_feed_the_watchdog(make_bench):
    b = raw_bench(make_bench, _watchdog_params())
    beats = {k: [Heartbeat(0, session=3)] for k in range(10, 300, 40)}  # every 80 ms < 100
    beats[2] = [Hello(1, session=3)]
    b.run(300, beats)
    assert b.replies(FaultReport) == [] and b.arr("state")[-1] == State.IDLE
    assert b.fw.counters["heartbeats"] == len(beats) - 1
    assert answers(b) == []  # an accepted heartbeat is not answered


@pytest.mark.parametrize(
    "feed",
    [
        "echoed board frames",
        "board types",
        "garbage",
        "stale session",
        "malformed",
        "bad crc",
    ],
)
def test_only_frames_of_the_session_feed_the_watchdog(make_bench, feed):
    b = raw_bench(make_bench, _watchdog_params())
    status = frame.encode(Status(1, 5, State.IDLE, Fault.NONE, 0.0, 0.0, 0.0), 0)
    good = frame.encode(Heartbeat(0, session=3), 0)
    chunk = {
        "echoed board frames": frame.encode_telemetry_fields(0, 1, 0, 0, 0, 0, 0, 0, 1, 0),
        "board types": status,
        "garbage": bytes(range(0, 250, 7)),
        "stale session": frame.encode(Heartbeat(0, session=4), 0),
        "malformed": frame.frame_raw(MsgType.HEARTBEAT, b"\x00", 0),
        "bad crc": good[:-1] + bytes((good[-1] ^ 1,)),
    }[feed]
    rx = {k: chunk for k in range(10, 200, 20)}
    b.run(200, {2: [Hello(1, session=3)]}, rx_raw=rx)
    (report,) = b.replies(FaultReport)
    # Hello at tick 2 was the last feeding frame; 0.1 s = 50 ticks later the watchdog trips.
    assert report.fault is Fault.WATCHDOG and report.tick == 2 + 51
    assert report.value == 51.0 and report.threshold == 50.0
    assert report.fault_flags == FaultFlag.WATCHDOG
    if feed in ("echoed board frames", "board types"):
        assert {n.code for n in answers(b, Nack)} == {NackCode.NOT_A_COMMAND}


def test_board_to_pc_types_are_nacked_not_a_command(make_bench):
    b = raw_bench(make_bench)
    ack = frame.encode(Ack(0x0102, MsgType.MOVE), 0)
    b.run(10, {2: [Hello(1, session=3)]}, rx_raw={5: ack})
    (nack,) = answers(b, Nack)
    assert nack == Nack(0x0102, MsgType.ACK, NackCode.NOT_A_COMMAND)
    assert b.fw.counters["nack_NOT_A_COMMAND"] == 1


@pytest.mark.parametrize(
    "payload",
    [b"\x02\x01", b"\x02\x01\x83\x63\x00\x00\x00\x00\x00", bytes(9)],
    ids=["short", "undefined code", "zeros"],
)
def test_a_board_type_is_not_a_command_whatever_its_payload(make_bench, payload):
    """docs section 3: the type byte decides first; a Nack sent to the board with a short
    payload or an undefined NackCode is NOT_A_COMMAND too, not BAD_LENGTH/OUT_OF_RANGE
    (the board never decodes board -> PC payloads; board_c/ does the same)."""
    b = raw_bench(make_bench)
    b.run(10, {2: [Hello(1, session=3)]}, rx_raw={5: frame.frame_raw(MsgType.NACK, payload, 0)})
    (nack,) = answers(b, Nack)
    assert nack == Nack(int.from_bytes(payload[:2], "little"), MsgType.NACK,
                        NackCode.NOT_A_COMMAND)  # fmt: skip


def test_board_heartbeat_carries_state_flags_and_exact_receive_counters(make_bench):
    b = raw_bench(make_bench)
    good = frame.encode(GetStatus(2, session=3), 1)
    bad_crc = good[:-1] + bytes((good[-1] ^ 0x40,))
    fake = b"\xa5\x5a\x40\x01\x00" + bytes((frame.crc8(b"\x40\x01\x00"),))
    garbage = b"\x00\x11\x22"
    b.run(220, {2: [Hello(1, session=3)]}, rx_raw={
        10: bad_crc,  # a CRC error; its 18 bytes dropped
        20: garbage + good,  # 3 bytes dropped, then a good frame (seq 1 after 0: no gap)
        30: fake,  # a fake header claiming 64 bytes, then silence: discarded after 20 ms
        60: frame.encode(GetStatus(4, session=3), 9),  # a sequence gap
    })  # fmt: skip
    beats = b.replies(BoardHeartbeat)
    assert [h.tick for h in beats] == [100, 200]  # every 200 ms = 100 ticks
    last = beats[-1]
    assert last.session == 3 and last.state == State.IDLE and last.fault_flags == 0
    d = b.fw.decoder
    assert (last.rx_frames, last.rx_crc_errors, last.rx_header_errors) == (d.frames, 1, 0)
    assert last.rx_frames == 3  # Hello and the two GetStatus
    assert last.rx_bytes_dropped == len(bad_crc) + len(garbage) + len(fake)
    # Good frames came with seq 0 (Hello), 1, 9: one gap.
    assert (last.rx_seq_gaps, last.rx_silence_discards, last.rx_overflow_bytes) == (1, 1, 0)


def test_more_than_the_receive_buffer_in_one_tick_is_lost_and_counted(make_bench):
    b = raw_bench(make_bench)
    flood = bytes(1000)
    b.run(5, {}, rx_raw={2: flood})
    assert b.fw.link_status().rx_overflow_bytes == 1000 - 256
    assert b.fw.decoder.bytes_dropped == 256


# ---------------------------------------------------------------------------- receiving


@pytest.mark.parametrize("silence_ticks", [10, 11, 50])
def test_after_a_false_header_and_the_silence_the_next_command_is_answered_at_once(
    make_bench, silence_ticks
):
    # Issue #10: a false header claiming the longest payload, left by a killed tool, must
    # not hold back the next command beyond the documented silence (20 ms = 10 ticks).
    b = raw_bench(make_bench)
    head = bytes((frame.MAX_PAYLOAD_BYTES, 0x03, 0))
    fake = frame.SYNC + head + bytes((frame.crc8(head),))
    t_cmd = 20 + silence_ticks
    b.run(t_cmd + 3, {2: [Hello(1, session=3)], t_cmd: [GetStatus(7, session=3)]},
          rx_raw={20: fake})  # fmt: skip
    (status,) = answers(b, Status)
    assert status.cmd_id == 7 and status.tick == t_cmd  # answered in the tick it arrived
    assert b.fw.decoder.partial_discards == 1


def test_without_the_silence_a_false_header_holds_the_command_back(make_bench):
    # The control case: 9 ticks (18 ms) of silence are not enough, the command is taken as
    # part of the false frame and only the CRC failure (or the silence after it) frees it.
    b = raw_bench(make_bench)
    head = bytes((frame.MAX_PAYLOAD_BYTES, 0x03, 0))
    fake = frame.SYNC + head + bytes((frame.crc8(head),))
    b.run(60, {2: [Hello(1, session=3)], 29: [GetStatus(7, session=3)]}, rx_raw={20: fake})
    (status,) = answers(b, Status)
    assert status.tick == 29 + 10  # freed by the silence after the command


def test_appended_fields_from_a_newer_client_are_ignored(make_bench):
    b = raw_bench(make_bench)
    _, payload = frame.encode_payload(GetStatus(7, session=3))
    b.run(
        10,
        {2: [Hello(1, session=3)]},
        rx_raw={5: frame.frame_raw(MsgType.GET_STATUS, payload + b"\x01\x02\x03", 1)},
    )
    (status,) = answers(b, Status)
    assert status.cmd_id == 7


# ---------------------------------------------------------------------------- faults


def test_fault_flags_details_and_the_trip_threshold_on_the_wire(make_bench):
    b = make_bench()
    # Lower the trip below the clamp's present value: refused (the clamp may not exceed it).
    lim = SetLimits(5, 990.0, 2000.0, 5.0, 10.0, 4.0)
    ok = SetLimits(6, 990.0, 2000.0, 3.0, 10.0, 4.0)
    b.run(20, {2: [lim, ok, GetLimits(7)]})
    nack = answers(b, Nack)[0]
    assert (nack.code, frame.field_name(nack.msg_type, nack.field), nack.limit) == (
        NackCode.TOO_HIGH, "current_limit_a", 4.0,
    )  # fmt: skip
    (limits,) = b.replies(Limits)
    assert (limits.current_limit_a, limits.over_current_trip_a) == (3.0, 4.0)
    assert limits.over_current_max_a == 7.5 and limits.over_speed_dps == 1100.0
    # 5.2 A sensed during a move: above the new 4 A trip, below the configured 7.5 A.
    b.adc_override = lambda k, adc: np.full_like(adc, 756) if 40 <= k < 45 else adc
    b.run(50, {25: [Move(1, 100.0, 200.0, 2000.0)],
               60: [GetStatus(8), GetFault(9, 0), GetFault(10, 8)]})  # fmt: skip
    (report,) = b.replies(FaultReport)
    assert report.fault is Fault.OVER_CURRENT and report.threshold == 4.0
    assert report.value == pytest.approx(756 * b.fw.params.current.a_per_adc, rel=1e-3)
    assert 4.0 < report.value < 7.5
    assert report.fault_flags == FaultFlag.OVER_CURRENT
    (status,) = b.replies(Status)
    assert status.state is State.FAULT and status.fault_flags == FaultFlag.OVER_CURRENT
    latched, other = b.replies(FaultInfo)
    assert latched == FaultInfo(9, 0, True, report.tick, report.value, 4.0)
    assert other == FaultInfo(10, 8, False, 0, 0.0, 0.0)
    tel = [t for t in b.replies(Telemetry) if t.tick >= report.tick]
    assert tel and all(t.fault_flags == FaultFlag.OVER_CURRENT for t in tel)
    assert all(t.duty == 0.0 for t in tel)
    # ClearFault clears the flags and the details.
    b.run(10, {b.fw.tick + 1: [ClearFault(11), GetFault(12, 0)]})
    assert b.replies(FaultInfo)[-1].latched is False and b.fw.fault_flags() == 0


def test_every_fault_code_has_its_own_flag():
    assert set(FAULT_FLAG) == set(Fault) - {Fault.NONE}
    bits = [int(f) for f in FAULT_FLAG.values()]
    assert len(set(bits)) == len(bits) and all(b & (b - 1) == 0 for b in bits)


# ---------------------------------------------------------------------------- v1 contradictions


def test_clear_fault_without_a_fault_changes_nothing(make_bench):
    b = make_bench()
    b.run(20, {5: [ClearFault(1)]})
    assert answers(b) == [Ack(1, MsgType.CLEAR_FAULT)]
    assert b.arr("state")[-1] == State.IDLE  # still enabled


def test_status_target_after_enable_is_the_position_held(make_bench):
    b = make_bench(FirmwareParams(servo=ServoParams(start_enabled=False)), theta0_rad=3.0)
    b.run(20, {5: [SetEnable(1, True)], 10: [GetStatus(2)]})
    (status,) = b.replies(Status)
    assert status.target_deg == pytest.approx(b.fw.sp_pos_deg, abs=1e-4)
    assert status.target_deg == pytest.approx(3.0 * 180 / np.pi / 80, abs=0.01)


def test_duty_is_zero_in_the_first_disabled_frame(make_bench):
    b = make_bench()
    b.run(60, {5: [Move(1, 20.0, 200.0, 2000.0)], 40: [SetEnable(2, False)]})
    tel = {t.tick: t for t in b.replies(Telemetry)}
    assert tel[39].state == State.MOVING and tel[39].duty != 0.0
    assert tel[40].state == State.DISABLED and tel[40].duty == 0.0


def test_set_telemetry_below_the_minimum_is_refused_with_the_minimum(make_bench):
    b = make_bench(FirmwareParams(telemetry=TelemetryParams(baud=115200)))
    b.run(10, {2: [SetTelemetry(1, 1), SetTelemetry(2, 3), SetTelemetry(3, 0)]})
    nack, ack2, ack3 = answers(b)
    assert (nack.code, nack.field, nack.limit) == (
        NackCode.TOO_LOW, frame.field_index(SetTelemetry, "decimation"), 3.0,
    )  # fmt: skip
    assert isinstance(ack2, Ack) and isinstance(ack3, Ack)
    assert b.fw.telemetry_decimation == 0


def test_set_limits_refuses_rather_than_clips(make_bench):
    b = make_bench()
    b.run(10, {2: [SetLimits(1, 5000.0, 2000.0, 5.0, 10.0), GetLimits(2)]})
    (nack,) = answers(b, Nack)
    assert (nack.code, frame.field_name(nack.msg_type, nack.field), nack.limit) == (
        NackCode.TOO_HIGH, "v_max_dps", 1100.0,
    )  # fmt: skip
    assert b.replies(Limits)[0].v_max_dps == 1000.0  # unchanged
