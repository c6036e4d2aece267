"""The messages over CAN: splitting, reassembly, the python-can virtual bus, ASC/BLF logs."""

from __future__ import annotations

import threading
import uuid

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from serial_protocol.can_link import CanLink, CanReassembler, can_frames
from serial_protocol.frame import payload_bytes
from serial_protocol.host import BoardClient
from serial_protocol.messages import (
    Ack,
    ClearFault,
    Fault,
    FaultReport,
    Gains,
    GetGains,
    GetLimits,
    GetStatus,
    Hello,
    HelloReply,
    Limits,
    Loop,
    Malformed,
    Move,
    MsgType,
    Nack,
    NackCode,
    Profile,
    SetEnable,
    SetGains,
    SetLimits,
    SetTelemetry,
    State,
    Status,
    Stop,
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
    HelloReply(1, 0, 1, 2, 500, 16384),
    Telemetry(11, 1.5, -2.5, 1.25, -2.0, 0.5, -0.25, State.MOVING, Fault.NONE),
    Ack(12, MsgType.MOVE),
    Nack(13, MsgType.MOVE, NackCode.NOT_FINITE),
    FaultReport(14, Fault.OVER_CURRENT, 5.5),
    Gains(15, Loop.CURRENT, 0.25, 0.5, 0.0),
    Limits(16, 990.0, 148.0, 5.0, 10.0),
    Status(17, 18, State.HOLDING, Fault.NONE, 3000.0, 0.0, 3000.0),
]


def test_one_of_each_covers_every_type():
    assert {type(m).MSG_TYPE for m in ONE_OF_EACH} == set(MsgType)


@pytest.mark.parametrize("msg", ONE_OF_EACH, ids=lambda m: type(m).__name__)
def test_split_and_reassemble_every_message(msg):
    frames = can_frames(msg, counter=5)
    size = payload_bytes(type(msg))
    assert all(len(data) <= 8 for _, data in frames)
    assert {frame_id for frame_id, _ in frames} == {0x100 + msg.MSG_TYPE}
    if size <= 8:
        assert len(frames) == 1 and len(frames[0][1]) == size
    else:
        assert len(frames) == -(-size // 7)
        assert [data[0] & 0x0F for _, data in frames] == list(range(len(frames)))
        assert [data[0] >> 5 for _, data in frames] == [5] * len(frames)
        assert [bool(data[0] & 0x10) for _, data in frames] == [False] * (len(frames) - 1) + [True]
    reassembler = CanReassembler()
    got = [reassembler.feed(frame_id, data) for frame_id, data in frames]
    assert got == [None] * (len(frames) - 1) + [msg]


def test_telemetry_takes_four_frames():
    frames = can_frames(ONE_OF_EACH[12])
    assert [len(data) for _, data in frames] == [8, 8, 8, 6]


@settings(max_examples=50)
@given(st.permutations(range(3)), st.integers(0, 7))
def test_interleaved_identifiers_reassemble_independently(order, counter):
    msgs = [ONE_OF_EACH[12], ONE_OF_EACH[18], ONE_OF_EACH[1]]
    queues = [can_frames(m, counter) for m in msgs]
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
    assert reassembler.stats.discarded_frames == 2  # segments 2 and 3 of the broken one
    # a transfer cut short by the start of the next one is also one error
    got = [reassembler.feed(*f) for f in first[:2] + second]
    assert [m for m in got if m is not None] == [ONE_OF_EACH[12]]
    assert reassembler.stats.reassembly_errors == 2


def test_wrong_dlc_and_unknown_type_are_malformed():
    reassembler = CanReassembler()
    assert reassembler.feed(0x100 + MsgType.GET_STATUS, b"\x07") == Malformed(
        MsgType.GET_STATUS, 0, 0, NackCode.BAD_LENGTH
    )
    assert reassembler.feed(0x100 + 0x42, b"\x09\x00") == Malformed(
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
                assert client.move(100.0 * k, 990.0, 148.0) == Ack(k + 1, MsgType.MOVE)
        finally:
            stop.set()
            worker.join(timeout=5)
        assert [t.tick for t in client.telemetry] == list(range(1, 11))
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


@settings(max_examples=100, deadline=None)
@given(st.lists(st.booleans(), min_size=40, max_size=160), st.integers(0, 7))
def test_lost_frames_never_yield_a_wrong_message(keep, first_counter):
    msgs = [
        Telemetry(k, k / 4, 1.0, -k / 8, 2.0, 0.5, 0.25, State.MOVING, Fault.NONE)
        if k % 3
        else Status(k, k, State.MOVING, Fault.NONE, k / 2, 1.0, 3.0)
        for k in range(40)
    ]
    counters = {}
    frames = []
    for msg in msgs:
        counter = counters.get(msg.MSG_TYPE, first_counter)
        frames += [(msg, f) for f in can_frames(msg, counter)]
        counters[msg.MSG_TYPE] = (counter + 1) & 7
    reassembler = CanReassembler()
    got = []
    for k, (_msg, (frame_id, data)) in enumerate(frames):
        if keep[k % len(keep)] or k % 7 == 0:  # drop frames, but never 8 transfers in a row
            out = reassembler.feed(frame_id, data)
            if out is not None:
                got.append(out)
    complete = [
        m for m in msgs
        if all(keep[k % len(keep)] or k % 7 == 0 for k, (src, _) in enumerate(frames) if src is m)
    ]  # fmt: skip
    assert got == complete
