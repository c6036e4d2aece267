"""A PC client written from ``docs/protocol.md`` ALONE, as an independent engineer would
(issue #10 §5: "independent engineers will write clients from docs/protocol.md alone and
run them against serve"), run against a real ``turntable-sim serve --tcp``.

Nothing of the project is imported here: the frame (section 2), the receiver's hunt
(section 3), the layouts (section 4.4), the session, retry and watchdog rules (section 5)
are written again from the page with ``socket``, ``struct`` and ``zlib.crc32``. A spec that
leaves something open shows up here as a guess; the guesses this client needed were fixed
in the spec (the TCP transport of ``serve`` in section 1, the ACK timeout as the host
library's default rather than a rule in 5.2).

Deadlines are generous and every wait is for an event (an answer, a state, a tick count
reported by the board), never a fixed sleep, so a loaded machine only makes it slower.
"""

from __future__ import annotations

import signal
import socket
import struct
import subprocess
import sys
import time
import zlib

import pytest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

# ------------------------------------------------------------------ section 2: the frame

SYNC = b"\xa5\x5a"
MAX_PAYLOAD = 64


def crc8_smbus(data: bytes) -> int:
    """CRC-8/SMBUS: poly 0x07, init 0x00, not reflected, no final XOR."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def frame(msg_type: int, seq: int, payload: bytes) -> bytes:
    head = bytes([len(payload), msg_type, seq & 0xFF])
    body = head + bytes([crc8_smbus(head)]) + payload
    return SYNC + body + struct.pack("<I", zlib.crc32(body))


class Receiver:
    """Section 3: hunt for A5 5A, check the header (len <= 64, CRC-8), wait for the body,
    check the CRC-32; after a failed check back up to the byte after the A5."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.crc_errors = 0
        self.header_errors = 0

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        """(type, seq, payload) of every good frame completed by ``data``."""
        self.buf += data
        out = []
        i = 0
        buf = self.buf
        while True:
            j = buf.find(SYNC, i)
            if j < 0:
                i = len(buf) - 1 if buf and buf[-1] == SYNC[0] else len(buf)
                break
            if len(buf) - j < 6:
                i = j
                break
            length, msg_type, seq, hdr = buf[j + 2], buf[j + 3], buf[j + 4], buf[j + 5]
            if length > MAX_PAYLOAD or crc8_smbus(bytes(buf[j + 2 : j + 5])) != hdr:
                self.header_errors += 1
                i = j + 1
                continue
            if len(buf) - j < 10 + length:
                i = j
                break
            body = bytes(buf[j + 2 : j + 6 + length])
            (crc,) = struct.unpack_from("<I", buf, j + 6 + length)
            if zlib.crc32(body) != crc:
                self.crc_errors += 1
                i = j + 1
                continue
            out.append((msg_type, seq, body[4:]))
            i = j + 10 + length
        del buf[:i]
        return out


# ------------------------------------------------------------------ section 4: messages

HELLO, HEARTBEAT, MOVE, STOP, SET_ENABLE, GET_STATUS = 0x01, 0x02, 0x03, 0x04, 0x05, 0x0B
HELLO_REPLY, TELEMETRY, ACK, NACK, FAULT_REPORT = 0x81, 0x82, 0x83, 0x84, 0x85
STATUS, BOARD_HEARTBEAT = 0x88, 0x89
# State codes (4.2)
DISABLED, IDLE, MOVING, HOLDING, FAULT = 0, 1, 2, 3, 4
# NackCode (4.2)
NO_SESSION, STALE_SESSION, TOO_HIGH, TOO_LOW = 9, 10, 12, 13
WATCHDOG = 5  # Fault code

# The answers' layouts (section 4.4); unpack_from ignores appended fields (section 6).
LAYOUTS = {
    HELLO_REPLY: (
        "<HHBBBBHHIBHBHHHHI",
        "cmd_id session protocol_version fw_major fw_minor fw_patch tick_hz counts_per_rev "
        "command_mask max_payload_bytes rx_buffer_bytes reply_queue_frames "
        "telemetry_min_decimation heartbeat_ms watchdog_ms rx_silence_ms baud",
    ),
    TELEMETRY: (
        "<IiiiihhBBI",
        "tick sp_pos sp_vel pos vel current_ma duty state fault fault_flags",
    ),
    ACK: ("<HB", "cmd_id msg_type"),
    NACK: ("<HBBBf", "cmd_id msg_type code field limit"),
    FAULT_REPORT: ("<IBfIf", "tick fault value fault_flags threshold"),
    STATUS: ("<HIBBiiiIH", "cmd_id tick state fault pos vel target fault_flags session"),
    BOARD_HEARTBEAT: (
        "<IHBIIIIIIIIII",
        "tick session state fault_flags rx_frames rx_crc_errors rx_header_errors "
        "rx_bytes_dropped rx_seq_gaps rx_overflow_bytes rx_silence_discards rx_nacked "
        "tx_telemetry_dropped",
    ),
}
DEG = 1e-4  # 1 LSB of positions and velocities (4.1)


def decode(msg_type: int, payload: bytes) -> dict | None:
    layout = LAYOUTS.get(msg_type)
    if layout is None or len(payload) < struct.calcsize(layout[0]):
        return None
    fmt, names = layout
    return {
        "type": msg_type,
        **dict(zip(names.split(), struct.unpack_from(fmt, payload), strict=True)),
    }


class SpecClient:
    """Stop-and-wait (5.2): one command, wait for the answer carrying its cmd_id, retry the
    same payload (5.3) when none comes."""

    def __init__(self, address: tuple[str, int], ack_timeout_s: float = 1.0) -> None:
        self.sock = socket.create_connection(address, timeout=30)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.rx = Receiver()
        self.seq = 0
        self.cmd_id = 0
        self.session = 0
        self.ack_timeout_s = ack_timeout_s
        self.telemetry: list[dict] = []
        self.board_heartbeats: list[dict] = []
        self.fault_reports: list[dict] = []
        self.frames_sent = 0

    def close(self) -> None:
        self.sock.close()

    def send(self, msg_type: int, payload: bytes) -> None:
        self.sock.sendall(frame(msg_type, self.seq, payload))  # a frame in one go (3.6)
        self.seq = (self.seq + 1) & 0xFF
        self.frames_sent += 1

    def receive(self, timeout_s: float) -> list[dict]:
        self.sock.settimeout(max(timeout_s, 1e-3))
        try:
            data = self.sock.recv(65536)
        except TimeoutError:
            return []
        assert data, "serve closed the connection"
        out = []
        for msg_type, _seq, payload in self.rx.feed(data):
            msg = decode(msg_type, payload)
            if msg is None:
                continue  # a type this client does not know: ignored (section 6)
            {TELEMETRY: self.telemetry, BOARD_HEARTBEAT: self.board_heartbeats,
             FAULT_REPORT: self.fault_reports}.get(msg_type, out).append(msg)  # fmt: skip
        return out

    def exchange(self, msg_type: int, payload: bytes, retries: int = 3) -> dict:
        """Send (cmd_id is the payload's first u16) and return the answer with that id."""
        (cmd_id,) = struct.unpack_from("<H", payload)
        for _ in range(retries + 1):
            self.send(msg_type, payload)
            end_s = time.monotonic() + self.ack_timeout_s
            while time.monotonic() < end_s:
                for msg in self.receive(end_s - time.monotonic()):
                    if msg.get("cmd_id") == cmd_id:
                        return msg
        raise AssertionError(f"no answer to type 0x{msg_type:02X} cmd_id {cmd_id}")

    def next_id(self) -> int:
        self.cmd_id = self.cmd_id % 0xFFFF + 1
        return self.cmd_id

    def hello(self, session: int) -> dict:
        reply = self.exchange(HELLO, struct.pack("<HHBB", self.next_id(), session, 2, 2))
        assert reply["type"] == HELLO_REPLY, reply
        self.session = reply["session"]
        return reply

    def command(self, msg_type: int, fmt: str = "", *fields: object) -> dict:
        """A command of this session: ``cmd_id``, ``session``, then ``fields`` as ``fmt``."""
        payload = struct.pack("<HH" + fmt, self.next_id(), self.session, *fields)
        return self.exchange(msg_type, payload)

    def status(self) -> dict:
        reply = self.command(GET_STATUS)
        assert reply["type"] == STATUS, reply
        return reply

    def heartbeat(self) -> None:
        self.send(HEARTBEAT, struct.pack("<HH", 0, self.session))

    def wait_status(self, done, timeout_s: float = 120.0, heartbeat: bool = True) -> dict:
        end_s = time.monotonic() + timeout_s
        while True:
            status = self.status()
            if done(status) or time.monotonic() > end_s:
                return status
            self.pump(0.05, heartbeat)

    def pump(self, duration_s: float, heartbeat: bool = True) -> list[dict]:
        """Receive for ``duration_s``, with a Heartbeat every 100 ms (5.4)."""
        got = []
        end_s = time.monotonic() + duration_s
        while (left_s := end_s - time.monotonic()) > 0:
            if heartbeat and self.session:
                self.heartbeat()
            got += self.receive(min(left_s, 0.1))
        return got


def move_payload(cmd_id: int, session: int, target_deg: float, v_max: float, a_max: float) -> bytes:
    """``Move`` (0x03): target i32 in 1e-4 deg, v_max, a_max, j_max f32, profile u8."""
    return struct.pack("<HHifffB", cmd_id, session, round(target_deg / DEG), v_max, a_max, 0.0, 0)


@pytest.fixture
def board():
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "serve", "--tcp", "0", "--set",
         "safety.watchdog_s=3.0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("socket://"), proc.stderr.read()
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        yield host, int(port)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def test_a_client_written_from_the_spec_alone(board):
    client = SpecClient(board)
    try:
        # 5.1: before any Hello, a command is refused NO_SESSION (field 1 = session)
        nack = client.exchange(GET_STATUS, struct.pack("<HH", client.next_id(), 777))
        assert (nack["type"], nack["code"], nack["field"]) == (NACK, NO_SESSION, 1)

        # 6: Hello negotiates version 2 and states the board's capabilities and limits
        reply = client.hello(0x1234)
        assert reply["session"] == 0x1234 and reply["protocol_version"] == 2
        assert reply["tick_hz"] == 500 and reply["watchdog_ms"] == 3000
        for t in (HELLO, HEARTBEAT, MOVE, STOP, SET_ENABLE, GET_STATUS):
            assert reply["command_mask"] >> t & 1
        assert reply["rx_silence_ms"] == 20 and reply["max_payload_bytes"] == 64

        # 4.4: a value beyond the board's limit is refused naming the field and the bound
        nack = client.exchange(MOVE, move_payload(client.next_id(), client.session, 10.0,
                                                  5000.0, 100.0))  # fmt: skip
        assert (nack["type"], nack["code"], nack["field"]) == (NACK, TOO_HIGH, 3)
        assert 0 < nack["limit"] < 5000.0  # Limits.v_max_dps

        assert client.command(SET_ENABLE, "B", 1)["type"] == ACK
        start = client.wait_status(lambda s: s["state"] in (IDLE, HOLDING))
        assert start["state"] in (IDLE, HOLDING), start
        assert start["session"] == 0x1234

        # a Move, and a retry of it (5.3: the same payload again, new seq): each frame is
        # answered with the same Ack, the move is done once
        target_deg = start["pos"] * DEG + 30.0
        payload = move_payload(client.next_id(), client.session, target_deg, 200.0, 400.0)
        first = client.exchange(MOVE, payload)
        again = client.exchange(MOVE, payload)
        assert first == again and first["type"] == ACK and first["msg_type"] == MOVE

        def arrived(s: dict) -> bool:
            on_target = abs(s["target"] * DEG - target_deg) < 1e-3
            return s["state"] == HOLDING and on_target and abs(s["pos"] * DEG - target_deg) < 0.5

        done = client.wait_status(arrived)
        assert done["state"] == HOLDING and abs(done["pos"] * DEG - target_deg) < 0.5, done

        # telemetry flowed, decoded with the section 4.4 layout; the board's heartbeat
        # carries our session
        moving = [t for t in client.telemetry if t["state"] == MOVING]
        assert moving and max(abs(t["vel"]) * DEG for t in moving) > 50.0
        assert client.board_heartbeats and client.board_heartbeats[-1]["session"] == 0x1234
        assert client.rx.crc_errors == client.rx.header_errors == 0

        # 5.4: Heartbeats alone keep the watchdog (3 s) fed: twice its time passes on the
        # board's clock (the telemetry's tick, not ours) with nothing else sent, no fault
        tick0 = client.status()["tick"]
        end_s = time.monotonic() + 300.0
        while client.telemetry[-1]["tick"] - tick0 < 2 * 3.0 * 500:
            assert time.monotonic() < end_s, "the board's clock stood still"
            client.pump(0.2)
        assert not client.fault_reports
        assert {t["state"] for t in client.telemetry if t["tick"] > tick0} == {HOLDING}
    finally:
        client.close()

    # 5.1: a reconnect is a new connection and a new Hello; the board kept the session,
    # the axis and the enable state; a command of the old session is now refused
    client = SpecClient(board)
    try:
        reply = client.hello(0x4321)
        assert reply["session"] == 0x4321
        status = client.status()
        assert status["state"] == HOLDING and status["session"] == 0x4321
        assert abs(status["pos"] * DEG - target_deg) < 0.5
        stale = client.exchange(GET_STATUS, struct.pack("<HH", client.next_id(), 0x1234))
        assert (stale["type"], stale["code"], stale["field"]) == (NACK, STALE_SESSION, 1)
        assert stale["limit"] == 0x4321
        # 5.3: the duplicate memory was cleared by the Hello: the old session's Move
        # payload with this session's id is a new command, applied (the axis goes back)
        back_deg = target_deg - 30.0
        payload = move_payload(first["cmd_id"], client.session, back_deg, 200.0, 400.0)
        assert client.exchange(MOVE, payload)["type"] == ACK
        back = client.wait_status(lambda s: s["state"] == HOLDING
                                  and abs(s["pos"] * DEG - back_deg) < 0.5)  # fmt: skip
        assert abs(back["pos"] * DEG - back_deg) < 0.5, back

        # 5.4: with nothing sent, the watchdog trips: one FaultReport WATCHDOG, bridge off
        end_s = time.monotonic() + 120.0
        while not client.fault_reports and time.monotonic() < end_s:
            client.pump(0.2, heartbeat=False)
        assert [r["fault"] for r in client.fault_reports] == [WATCHDOG]
        assert client.fault_reports[0]["value"] >= 3.0 * 500  # ticks since the last feed
        assert client.status()["state"] == FAULT
    finally:
        client.close()
