"""The messages over CAN: splitting, reassembly, the python-can virtual bus, ASC/BLF logs."""

from __future__ import annotations

import threading
import uuid
from dataclasses import replace

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from serial_protocol.can_link import CanLink, CanReassembler, can_frames
from serial_protocol.frame import payload_bytes
from serial_protocol.host import BoardClient
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

ONE_OF_EACH = [
    Hello(),
    Move(1, -8000.0, 990.0, 148.0, 0.0, Profile.SCURVE),
    Stop(2, 148.0),
    SetGains(3, Loop.VELOCITY, 0.5, 2.0, 0.0),
    GetGains(4, Loop.POSITION),
    SetLimits(5, 990.0, 148.0, 5.0, 10.0),
    GetLimits(6),
    GetStatus(7),
    ClearFault(8),
    SetEnable(9, True),
    SetTelemetry(10, 2),
    HelloReply(1, 7, 2, 0, 1, 2, 500, 16384, 0x3FFE, 64, 256, 32, 1, 200, 0, 20, 460800),
    Telemetry(11, 1.5, -2.5, 1.25, -2.0, 0.5, -0.25, State.MOVING, Fault.NONE, 0, 24.25),
    Ack(12, MsgType.MOVE),
    Nack(13, MsgType.MOVE, NackCode.NOT_FINITE),
    FaultReport(14, Fault.OVER_CURRENT, 5.5),
    Gains(15, Loop.CURRENT, 0.25, 0.5, 0.0),
    Limits(16, 990.0, 148.0, 5.0, 10.0),
    Status(17, 18, State.HOLDING, Fault.NONE, 3000.0, 0.0, 3000.0),
    Heartbeat(0, 7),
    GetFault(19, 16, session=7),
    BoardHeartbeat(20, 7, State.IDLE, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9),
    FaultInfo(21, 16, True, 99, 1234.0, 1024.0),
    QueueSegment(22, 135.0, 30.0, 0.5, session=7),
    QueueControl(23, QueueAction.OVERRIDE, 150.0, session=7),
    QueueStatus(24, QueueState.HELD, 30, 2, 12345, 150.0),
    StreamControl(25, StreamAction.START, Interp.CUBIC, 0.125, 4, session=7),
    StreamPoints.of(26, 1, [0.9375, 3.75, 8.4375], [12.5, 25.0, 37.5]),
    Jog(27, -25.0, 500.0, 250, session=7),
    StreamStatus(28, StreamState.RUNNING, 60, 5, 0, 12.5),
]


MESSAGE_TYPES = tuple(type(m) for m in ONE_OF_EACH)


def test_one_of_each_covers_every_type():
    assert {type(m).MSG_TYPE for m in ONE_OF_EACH} == set(MsgType)


@pytest.mark.parametrize("msg", ONE_OF_EACH, ids=lambda m: type(m).__name__)
def test_split_and_reassemble_every_message(msg):
    frames = can_frames(msg, counter=37)
    size = payload_bytes(type(msg))
    assert all(1 <= len(data) <= 8 for _, data in frames)
    assert {frame_id for frame_id, _ in frames} == {0x100 + msg.MSG_TYPE}
    tails = [data[0] for _, data in frames]
    assert [t & 0x1F for t in tails] == [37 % 32] * len(frames)
    if size <= 7:
        assert len(frames) == 1 and tails[0] & 0xE0 == 0xC0 and len(frames[0][1]) == size + 1
    else:
        assert len(frames) == -(-(size + 4) // 7)  # the payload and its CRC-32
        assert [bool(t & 0x80) for t in tails] == [True] + [False] * (len(frames) - 1)
        assert [bool(t & 0x40) for t in tails] == [False] * (len(frames) - 1) + [True]
        assert [t >> 5 & 1 for t in tails] == [k & 1 for k in range(len(frames))]
    reassembler = CanReassembler()
    got = [reassembler.feed(frame_id, data) for frame_id, data in frames]
    assert got == [None] * (len(frames) - 1) + [msg]


def test_telemetry_takes_six_frames():
    frames = can_frames(ONE_OF_EACH[12])
    # 32 + 4 bytes of CRC (an older board's 30 + 4 took five: 8, 8, 8, 8, 7)
    assert [len(data) for _, data in frames] == [8, 8, 8, 8, 8, 2]


@settings(max_examples=50)
@given(st.permutations(range(3)), st.integers(0, 31))
def test_interleaved_identifiers_reassemble_independently(order, transfer_id):
    msgs = [ONE_OF_EACH[12], ONE_OF_EACH[18], ONE_OF_EACH[1]]
    queues = [can_frames(m, transfer_id) for m in msgs]
    reassembler = CanReassembler()
    got = []
    while any(queues):
        for k in order:
            if queues[k]:
                out = reassembler.feed(*queues[k].pop(0))
                if out is not None:
                    got.append(out)
    assert sorted(got, key=lambda m: m.MSG_TYPE) == sorted(msgs, key=lambda m: m.MSG_TYPE)
    assert reassembler.stats.reassembly_errors == 0


def test_lost_segment_discards_the_message_and_the_next_one_survives():
    first = can_frames(ONE_OF_EACH[12], counter=0)
    second = can_frames(ONE_OF_EACH[12], counter=1)
    reassembler = CanReassembler()
    got = [reassembler.feed(*f) for f in first[:1] + first[2:] + second]
    assert [m for m in got if m is not None] == [ONE_OF_EACH[12]]
    assert reassembler.stats.reassembly_errors == 1
    # the first segment, and the 4 after the gap (6 frames, the second one lost)
    assert reassembler.stats.discarded_frames == len(first) - 1 == 5
    # a transfer cut short by the start of the next one is also one error
    got = [reassembler.feed(*f) for f in first[:2] + second]
    assert [m for m in got if m is not None] == [ONE_OF_EACH[12]]
    assert reassembler.stats.reassembly_errors == 2


def _telemetry_stream(n: int) -> tuple[list[Telemetry], list[tuple[int, tuple[int, bytes]]]]:
    """``n`` distinct Telemetry messages and their frames, tagged with the message index."""
    msgs = [
        Telemetry(k, k / 4, 1.0, -k / 8, 2.0, 0.5, 0.25, State.MOVING, Fault.NONE) for k in range(n)
    ]
    frames = [(k, f) for k, m in enumerate(msgs) for f in can_frames(m, counter=k)]
    return msgs, frames


@pytest.mark.parametrize("lost_transfers", [8, 32, 64, 96])
def test_an_outage_of_whole_transfer_id_periods_cannot_mix_two_messages(lost_transfers):
    """Regression: the 3-bit counter of v1 let 32 k lost frames (8 k Telemetry transfers)
    join the start of one Telemetry to the end of another, a silently wrong message. Here
    the transfer id wraps at 32 and lines up again after 32 k transfers, the toggle too; the
    CRC-32 of the transfer refuses the mix."""
    msgs, frames = _telemetry_stream(lost_transfers + 3)
    per = len(can_frames(msgs[0]))
    # the first two frames of transfer 0, then nothing until frame 2 of the transfer whose
    # id and toggle line up with it again
    kept = frames[:2] + frames[lost_transfers * per + 2 :]
    reassembler = CanReassembler()
    got = [m for _, f in kept if (m := reassembler.feed(*f)) is not None]
    assert got == msgs[lost_transfers + 1 :]
    if lost_transfers % 32 == 0:
        assert reassembler.stats.crc_errors == 1


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.booleans(), min_size=1, max_size=300),
    st.lists(st.integers(0, 400), max_size=6),
    st.lists(st.integers(0, 700), max_size=20),
)
def test_lost_and_duplicated_frames_never_yield_a_wrong_message(keep, outages, duplicates):
    """Any loss pattern (including outages of hundreds of frames, a whole number of transfer
    id periods among them) and any frames repeated by the bus: every message all of whose
    frames arrived is delivered exactly once, and nothing else is delivered."""
    msgs, frames = _telemetry_stream(100)
    acks = [Ack(k, MsgType.MOVE) for k in range(30)]  # one-frame messages among the others
    for k, m in enumerate(acks):
        (frame,) = can_frames(m, counter=k)
        frames.insert(5 * k + 3, (100 + k, frame))
    lost = set()
    for start in outages:
        lost |= set(range(start, start + len(keep)))
    lost |= {k for k in range(len(frames)) if not keep[k % len(keep)]}
    received = []
    for k, frame in enumerate(frames):
        if k not in lost:
            received.append(frame)
            if k in duplicates:
                received.append(frame)  # a CAN controller retransmitted it
    reassembler = CanReassembler()
    got = [m for _, f in received if (m := reassembler.feed(*f)) is not None]
    everything = msgs + acks
    complete = [
        everything[src]
        for src in sorted({src for src, _ in frames}, key=lambda s: _last_index(frames, s))
        if all(k not in lost for k, (s, _) in enumerate(frames) if s == src)
    ]
    assert got == complete


def _last_index(frames: list, src: int) -> int:
    """Where the message ``src`` completes: its last frame."""
    return max(k for k, (s, _) in enumerate(frames) if s == src)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0x0F0, 0x210), st.binary(max_size=10)),
        max_size=60,
    )
)
def test_the_reassembler_never_raises(frames):
    """Arbitrary identifiers and data (empty, over-long, any tail byte): messages,
    Malformed or nothing, never an exception; the counters account for every frame."""
    reassembler = CanReassembler()
    out = [reassembler.feed(frame_id, data) for frame_id, data in frames]
    s = reassembler.stats
    assert s.frames == len(frames)
    assert s.messages + s.malformed == sum(m is not None for m in out)
    assert all(m is None or isinstance(m, (Malformed, *MESSAGE_TYPES)) for m in out)


def test_a_duplicated_one_frame_message_is_delivered_once():
    (frame,) = can_frames(Ack(5, MsgType.MOVE), counter=3)
    reassembler = CanReassembler()
    got = [reassembler.feed(*frame) for _ in range(3)]
    assert got == [Ack(5, MsgType.MOVE), None, None]
    assert reassembler.stats.duplicates == 2
    # the same message sent again as a new transfer is a new message
    (again,) = can_frames(Ack(5, MsgType.MOVE), counter=4)
    assert reassembler.feed(*again) == Ack(5, MsgType.MOVE)


def test_wrong_length_and_unknown_type_are_malformed():
    reassembler = CanReassembler()
    assert reassembler.feed(0x100 + MsgType.GET_STATUS, b"\xc0\x07") == Malformed(
        MsgType.GET_STATUS, 0, 0, NackCode.BAD_LENGTH
    )
    assert reassembler.feed(0x100 + 0x42, b"\xc1\x09\x00") == Malformed(
        0x42, 0, 9, NackCode.UNKNOWN_TYPE
    )
    assert reassembler.feed(0x7FF, b"") is None
    assert reassembler.stats.foreign_ids == 1 and reassembler.stats.malformed == 2


def test_base_id_must_keep_ids_11_bit():
    with pytest.raises(ValueError, match="11-bit"):
        can_frames(ONE_OF_EACH[12], base_id=0x780)


# ------------------------------------------------------------------ virtual bus


def _channel() -> str:
    return f"turntable-{uuid.uuid4().hex}"


def _serve_acks(board: CanLink, stop: threading.Event) -> None:
    tick = 0
    while not stop.is_set():
        for msg in board.poll(0.01):
            tick += 1
            board.send(Telemetry(tick, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, State.IDLE, 0))
            if isinstance(msg, Hello):
                board.send(replace(ONE_OF_EACH[11], cmd_id=msg.cmd_id, session=msg.session))
            else:
                board.send(Ack(msg.cmd_id, msg.MSG_TYPE))


def test_client_over_the_virtual_bus():
    channel = _channel()
    stop = threading.Event()
    with CanLink.open("virtual", channel) as pc, CanLink.open("virtual", channel) as board:
        worker = threading.Thread(target=_serve_acks, args=(board, stop), daemon=True)
        worker.start()
        client = BoardClient(pc, ack_timeout_s=1.0)
        try:
            for k in range(10):
                reply = client.move(100.0 * k, 990.0, 148.0)
                assert reply == Ack(client.last_command.cmd_id, MsgType.MOVE)
        finally:
            stop.set()
            worker.join(timeout=5)
        # one telemetry frame per command: the Hello that opened the session and 10 moves
        assert [t.tick for t in client.telemetry] == list(range(1, 12))
        assert pc.reassembler.stats.reassembly_errors == 0


@pytest.mark.parametrize(
    ("suffix", "channel_tail"),
    # A channel name ending in a number too large for BLF's 16-bit channel field used to make
    # python-can's BLF writer raise struct.error (uuid names end in digits at random).
    [(".asc", "x"), (".blf", "x"), (".blf", "-4117297"), (".asc", "-4117297")],
)
def test_frames_are_logged_with_python_can_writers(tmp_path, suffix, channel_tail):
    channel = _channel() + channel_tail
    path = tmp_path / f"run{suffix}"
    msgs = [ONE_OF_EACH[12], ONE_OF_EACH[13], ONE_OF_EACH[18]]
    with CanLink.open("virtual", channel, log_path=str(path)) as pc:
        with CanLink.open("virtual", channel) as board:
            for msg in msgs:
                board.send(msg)
            got = []
            for _ in range(50):
                got += pc.poll(0.02)
                if len(got) == len(msgs):
                    break
            pc.send(GetStatus(99))
    assert got == msgs
    logged = list(can.LogReader(str(path)))
    n_received = sum(len(can_frames(m)) for m in msgs)
    assert len(logged) == n_received + 1
    reassembler = CanReassembler()
    replayed = [reassembler.feed(f.arbitration_id, bytes(f.data)) for f in logged]
    assert [m for m in replayed if m is not None] == [*msgs, GetStatus(99)]
