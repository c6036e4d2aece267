"""The PC-side client and the serial link: loop://, socket:// to a tiny board, retries."""

from __future__ import annotations

import io
import socket
import threading
import time

import pytest

from serial_protocol.exceptions import LinkError, LinkTimeout
from serial_protocol.frame import Decoder, crc8, encode, field_index
from serial_protocol.host import BoardClient, nack_text
from serial_protocol.messages import (
    Ack,
    FaultReport,
    GetStatus,
    Heartbeat,
    Hello,
    HelloReply,
    Move,
    MsgType,
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
            return HelloReply(msg.cmd_id, msg.session, 2, 0, 1, 0, 500, 16384, 0x3FFE, 64, 256,
                              32, 1, 200, 0, 20, 460800)  # fmt: skip
        if isinstance(msg, GetStatus):
            return Status(msg.cmd_id, self._tick, State.IDLE, 0, 1.5, 0.0, 2.0)
        if isinstance(msg, Move) and msg.a_max_dps2 <= 0:
            return Nack(msg.cmd_id, Move.MSG_TYPE, NackCode.TOO_LOW, 5, 0.001)
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


def test_command_opens_a_session_returns_the_matching_ack_and_collects_telemetry():
    board = ScriptedBoard()
    client = BoardClient(board)
    reply = client.move(100.0, 990.0, 148.0)
    hello, move = board.sent
    assert isinstance(hello, Hello) and 1 <= hello.session <= 0xFFFF
    assert (hello.version_min, hello.version_max) == (2, 2)
    assert move.session == hello.session == client.session
    assert reply == Ack(move.cmd_id, Move.MSG_TYPE)
    assert list(client.telemetry) == [telemetry(1), telemetry(2)]
    assert client.stats.acks == 1 and client.stats.retries == 0 and client.stats.sessions == 1


def test_each_client_opens_a_new_session():
    board = ScriptedBoard()
    first = BoardClient(board)
    first.open()
    again = first.session
    first.open()
    assert first.session != again  # a re-open never reuses the session it replaces
    assert [m.session for m in board.sent] == [again, first.session]


def test_messages_after_the_answer_in_the_same_read_are_kept():
    client = BoardClient(ScriptedBoard(after_answer=True))
    client.hello()
    client.stop()
    assert [t.tick for t in client.telemetry] == [1, 2, 3, 4]
    assert client.stats.stale_replies == 0


def test_nack_is_data_not_an_exception():
    client = BoardClient(ScriptedBoard())
    reply = client.move(100.0, 990.0, 0.0)
    assert isinstance(reply, Nack) and reply.code is NackCode.TOO_LOW
    assert client.stats.nacks == 1


def test_nack_text_names_the_field_value_and_limit():
    move = Move(3, 10.0, 2000.0, 148.0)
    nack = Nack(3, MsgType.MOVE, NackCode.TOO_HIGH, field_index(Move, "v_max_dps"), 990.0)
    assert nack_text(nack, move) == "Move refused: v_max_dps = 2000 > limit 990 (TOO_HIGH)"
    low = Nack(3, MsgType.MOVE, NackCode.TOO_LOW, field_index(Move, "a_max_dps2"), 0.001)
    assert nack_text(low) == "MOVE refused: a_max_dps2 < limit 0.001 (TOO_LOW)"
    whole = Nack(4, MsgType.MOVE, NackCode.DISABLED)
    assert nack_text(whole) == ("MOVE refused: the bridge is disabled (enable it first) (DISABLED)")


def test_lost_frames_are_retried_with_the_same_message():
    board = ScriptedBoard()
    client = BoardClient(board, ack_timeout_s=0.01, retries=3)
    client.open()
    board.sent.clear()
    board.lose = 2
    assert isinstance(client.stop(), Ack)
    assert len(board.sent) == 3
    assert len(set(board.sent)) == 1  # the same cmd_id, session and payload each time
    assert client.stats.retries == 2


def test_no_answer_raises_link_timeout_after_the_retries():
    board = ScriptedBoard(lose=100)
    client = BoardClient(board, ack_timeout_s=0.005, retries=2)
    with pytest.raises(LinkTimeout, match="3 attempts"):
        client.clear_fault()  # the Hello that opens the session is never answered
    assert len(board.sent) == 3 and all(isinstance(m, Hello) for m in board.sent)
    assert client.stats.timeouts == 1
    with pytest.raises(TimeoutError):  # LinkTimeout is also the built-in
        client.status()


def test_a_stale_answer_is_not_taken_for_the_awaited_one():
    def answer(msg):
        return Ack((msg.cmd_id + 7) & 0xFFFF, msg.MSG_TYPE)

    board = ScriptedBoard()
    client = BoardClient(board, ack_timeout_s=0.005, retries=0)
    client.open()
    board.answer = answer
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


def test_a_board_without_a_common_version_is_a_clear_link_error():
    def answer(msg):
        return Nack(msg.cmd_id, msg.MSG_TYPE, NackCode.UNSUPPORTED_VERSION, 2, 3.0)

    client = BoardClient(ScriptedBoard(answer=answer))
    with pytest.raises(LinkError, match="the board speaks protocol version 3"):
        client.hello()


def test_values_the_wire_cannot_carry_are_a_value_error_naming_the_field():
    with SerialLink.open("loop://") as link:
        client = BoardClient(link)
        client.session = 9  # a session as if opened: loop:// has no board to answer Hello
        with pytest.raises(ValueError, match=r"Move.target_deg = 1000000000.0 deg: beyond"):
            client.move(1e9, 100.0, 100.0)
        with pytest.raises(ValueError, match=r"SetTelemetry.decimation = 70000"):
            client.set_telemetry(70_000)
        assert link.frames_out == 0  # nothing half-sent


def test_heartbeats_keep_the_watchdog_fed_while_collecting():
    board = ScriptedBoard()
    client = BoardClient(board, heartbeat_s=0.01)
    client.open()
    client.collect(0.2)
    beats = [m for m in board.sent if isinstance(m, Heartbeat)]
    assert 3 <= len(beats) and all(m.session == client.session for m in beats)
    assert client.stats.heartbeats_sent == len(beats)


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
        assert link.decoder.pending_bytes == len(fake) + 14
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
                    if isinstance(msg, Hello):
                        answer = HelloReply(msg.cmd_id, msg.session, 2, 0, 1, 0, 500, 16384, 0,
                                            64, 256, 32, 1, 0, 0, 20, 460800)  # fmt: skip
                    else:
                        answer = Ack(msg.cmd_id, msg.MSG_TYPE)
                    for reply in (FaultReport(seq, 2, 1.25), answer):
                        out += encode(reply, seq)
                        seq += 1
                    conn.sendall(out)


def test_client_over_socket_url_against_a_tcp_board():
    board = TinyBoard()
    board.start()
    with SerialLink.open(f"socket://127.0.0.1:{board.port}") as link:
        client = BoardClient(link, ack_timeout_s=1.0)
        for k in range(5):
            reply = client.move(10.0 * k, 100.0, 50.0)
            # (the first move drew its id before the Hello that opened the session)
            assert reply == Ack(client._cmd_id - (k == 0), Move.MSG_TYPE)
        assert len(client.fault_reports) == 6  # one per frame the board got, Hello included
        assert link.stats().header_errors + link.stats().bytes_dropped > 0
        assert link.stats().frames == 12 and link.stats().resyncs == 6
    board.join(timeout=5)


def test_serial_link_over_socket_reads_what_is_there_in_one_poll():
    """issue #10 §4: ``SerialLink`` over ``socket://`` reads everything waiting with one
    select and one read (pyserial's own ``read`` took 1-2 bytes per poll, so a client polling
    once per tick fell behind 500 telemetry frames a second), and sets ``TCP_NODELAY`` on its
    side (a command goes out at once, not after the peer's delayed ACK)."""
    import fcntl
    import termios

    server = socket.create_server(("127.0.0.1", 0))
    stream = b"".join(encode(telemetry(k), k & 0xFF) for k in range(200))
    with SerialLink.open(f"socket://127.0.0.1:{server.getsockname()[1]}") as link:
        conn, _ = server.accept()
        with conn:
            sock = link.port._socket
            assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
            conn.sendall(stream)
            waiting = bytearray(4)
            deadline_s = time.monotonic() + 60.0
            while time.monotonic() < deadline_s:  # until the kernel holds the whole stream
                fcntl.ioctl(sock.fileno(), termios.FIONREAD, waiting)
                if int.from_bytes(waiting, "little") >= len(stream):
                    break
                time.sleep(0.01)
            msgs = link.poll(1.0)
    server.close()
    assert [m.tick for m in msgs] == list(range(200))
