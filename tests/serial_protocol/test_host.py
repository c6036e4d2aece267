"""The PC-side client and the serial link: loop://, socket:// to a tiny board, retries."""

from __future__ import annotations

import io
import socket
import threading
import time

import pytest

from serial_protocol.exceptions import LinkError, LinkTimeout
from serial_protocol.frame import Decoder, crc8, encode
from serial_protocol.host import BoardClient
from serial_protocol.messages import (
    Ack,
    FaultReport,
    GetStatus,
    Hello,
    HelloReply,
    Move,
    Nack,
    NackCode,
    State,
    Status,
    Telemetry,
)
from serial_protocol.transport import IDLE_FLUSH_S, SerialLink, open_serial


def telemetry(tick: int) -> Telemetry:
    return Telemetry(tick, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, State.IDLE, 0)


class ScriptedBoard:
    """An in-memory ``Link`` standing in for a board: it answers commands, can ignore the
    first ``lose`` of them (a lost frame) and interleaves telemetry with its answers."""

    def __init__(self, lose: int = 0, answer=None, after_answer: bool = False) -> None:
        self.lose = lose
        self.after_answer = after_answer
        self.sent: list = []
        self._inbox: list = []
        self._tick = 0
        self.answer = answer or self._default_answer

    def _default_answer(self, msg):
        if isinstance(msg, Hello):
            return HelloReply(1, 0, 1, 0, 500, 16384)
        if isinstance(msg, GetStatus):
            return Status(msg.cmd_id, self._tick, State.IDLE, 0, 1.5, 0.0, 2.0)
        if isinstance(msg, Move) and msg.a_max_dps2 <= 0:
            return Nack(msg.cmd_id, Move.MSG_TYPE, NackCode.OUT_OF_RANGE)
        return Ack(msg.cmd_id, msg.MSG_TYPE)

    def send(self, msg) -> None:
        self.sent.append(msg)
        if self.lose:
            self.lose -= 1
            return
        self._tick += 1
        self._inbox += [telemetry(self._tick), self.answer(msg)]
        if self.after_answer:
            self._tick += 1
            self._inbox.append(telemetry(self._tick))

    def poll(self, timeout_s: float) -> list:
        out, self._inbox = self._inbox, []
        return out

    def close(self) -> None:
        pass


def test_command_returns_the_matching_ack_and_collects_telemetry():
    board = ScriptedBoard()
    client = BoardClient(board)
    reply = client.move(100.0, 990.0, 148.0)
    assert reply == Ack(board.sent[0].cmd_id, Move.MSG_TYPE)
    assert list(client.telemetry) == [telemetry(1)]
    assert client.stats.acks == 1 and client.stats.retries == 0


def test_messages_after_the_answer_in_the_same_read_are_kept():
    client = BoardClient(ScriptedBoard(after_answer=True))
    client.hello()
    client.stop()
    assert [t.tick for t in client.telemetry] == [1, 2, 3, 4]


def test_nack_is_data_not_an_exception():
    client = BoardClient(ScriptedBoard())
    reply = client.move(100.0, 990.0, 0.0)
    assert isinstance(reply, Nack) and reply.code is NackCode.OUT_OF_RANGE
    assert client.stats.nacks == 1


def test_lost_frames_are_retried_with_the_same_cmd_id():
    board = ScriptedBoard(lose=2)
    client = BoardClient(board, ack_timeout_s=0.01, retries=3)
    assert isinstance(client.stop(), Ack)
    assert len(board.sent) == 3
    assert len({m.cmd_id for m in board.sent}) == 1
    assert client.stats.retries == 2


def test_no_answer_raises_link_timeout_after_the_retries():
    board = ScriptedBoard(lose=100)
    client = BoardClient(board, ack_timeout_s=0.005, retries=2)
    with pytest.raises(LinkTimeout, match="3 attempts"):
        client.clear_fault()
    assert len(board.sent) == 3
    assert client.stats.timeouts == 1
    with pytest.raises(TimeoutError):  # LinkTimeout is also the built-in
        client.status()


def test_a_stale_answer_is_not_taken_for_the_awaited_one():
    def answer(msg):
        return Ack((msg.cmd_id + 7) & 0xFFFF, msg.MSG_TYPE)

    board = ScriptedBoard(answer=answer)
    client = BoardClient(board, ack_timeout_s=0.005, retries=0)
    with pytest.raises(LinkTimeout):
        client.stop()
    assert client.stats.stale_replies == 1


def test_cmd_ids_are_fresh_and_skip_zero():
    client = BoardClient(ScriptedBoard())
    client._cmd_id = 0xFFFE
    assert [client.next_cmd_id() for _ in range(3)] == [0xFFFF, 1, 2]


def test_wait_status_polls_until_done_or_timeout():
    client = BoardClient(ScriptedBoard())
    status = client.wait_status(lambda s: s.tick >= 3, timeout_s=5.0, interval_s=0.0)
    assert status is not None and status.tick == 3
    status = client.wait_status(lambda s: False, timeout_s=0.05, interval_s=0.01)
    assert status is not None and status.tick > 3
    silent = BoardClient(ScriptedBoard(lose=100), ack_timeout_s=0.001, retries=0)
    with pytest.raises(LinkTimeout):
        silent.wait_status(lambda s: True, timeout_s=0.01)


def test_status_and_hello():
    client = BoardClient(ScriptedBoard())
    assert client.hello().tick_hz == 500
    status = client.status()
    assert isinstance(status, Status) and client.last_status == status


# ------------------------------------------------------------------ pyserial back-ends


def test_serial_link_over_loop_url_echoes_frames_and_captures():
    capture = io.BytesIO()
    with SerialLink.open("loop://", 115200, capture=capture) as link:
        msgs = [Move(1, 10.0, 100.0, 50.0), GetStatus(2), telemetry(3)]
        for msg in msgs:
            link.send(msg)
        got = []
        for _ in range(20):
            got += link.poll(0.05)
            if len(got) == len(msgs):
                break
        assert got == msgs
        assert link.frames_out == 3 and link.bytes_out == link.bytes_in
        assert link.stats().frames == 3 and link.stats().seq_gaps == 0
    out, decoder = capture.getvalue(), Decoder()
    assert decoder.feed(out) == msgs


def test_idle_line_releases_a_frame_held_by_a_false_header():
    head = bytes((64, 0x82, 0))
    fake = b"\xa5\x5a" + head + bytes((crc8(head),))  # claims 64 bytes that never come
    with SerialLink.open("loop://") as link:
        link.send_bytes(fake + encode(GetStatus(5), 0))
        # the status frame sits inside the claimed length: held back
        assert link.poll(0.5) == []
        assert link.decoder.pending_bytes == len(fake) + 10
        time.sleep(IDLE_FLUSH_S * 1.5)
        # quiet line: the decoder gives up on the false header
        assert link.poll(0.0) == [GetStatus(5)]
        assert link.stats().header_errors == 0 and link.stats().bytes_dropped == len(fake)


def test_open_serial_names_the_url_on_failure():
    with pytest.raises(LinkError, match="/dev/does-not-exist"):
        open_serial("/dev/does-not-exist", 115200)


class TinyBoard(threading.Thread):
    """A TCP peer speaking the protocol: ACKs every command, reports a fault once."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.garbage = b"\x00\xa5\x5a\x40\x99\x12"  # noise and a false sync

    def run(self) -> None:
        conn, _ = self.server.accept()
        decoder, seq = Decoder(), 0
        with conn:
            while True:
                data = conn.recv(4096)
                if not data:
                    return
                for msg in decoder.feed(data):
                    out = self.garbage
                    for reply in (FaultReport(seq, 2, 1.25), Ack(msg.cmd_id, msg.MSG_TYPE)):
                        out += encode(reply, seq)
                        seq += 1
                    conn.sendall(out)


def test_client_over_socket_url_against_a_tcp_board():
    board = TinyBoard()
    board.start()
    with SerialLink.open(f"socket://127.0.0.1:{board.port}") as link:
        client = BoardClient(link, ack_timeout_s=1.0)
        for k in range(5):
            assert client.move(10.0 * k, 100.0, 50.0) == Ack(k + 1, Move.MSG_TYPE)
        assert len(client.fault_reports) == 5
        assert link.stats().header_errors + link.stats().bytes_dropped > 0
        assert link.stats().frames == 10 and link.stats().resyncs == 5
    board.join(timeout=5)
