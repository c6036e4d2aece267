"""The PC-facing ends of ``turntable-sim serve``: a pseudo-terminal, a TCP port, a CAN bus.

Each endpoint moves the simulated board's byte stream to and from one PC program:

- ``receive(room)`` returns at most ``room`` bytes the PC sent (the rest waits in a bounded
  ``FrameQueue``: a writer faster than the line loses whole frames, counted);
- ``deliver(data, line_idle)`` queues bytes the board sent; ``service(wall_s)`` writes them
  at the pace of a ``LinePacer`` (never faster than the emulated line, however late the
  process runs); a reader that falls behind loses whole frames, the oldest telemetry and
  board heartbeats first (answers only when nothing else is queued), counted;
- ``lost_peer`` is set when the PC program went away (TCP disconnect), so that the server
  forgets what it had not yet passed to the board.

Counters (``counters``): ``bytes_from_pc``, ``bytes_to_pc``, ``frames_dropped_to_pc`` and
``bytes_dropped_to_pc`` (reader too slow), ``frames_dropped_from_pc`` and
``bytes_dropped_from_pc`` (writer faster than the line), ``bytes_unheard`` (board output
while no client was connected), ``clients`` and ``clients_refused`` (TCP).
"""

from __future__ import annotations

import errno
import os
import socket
from typing import Any

from serial_protocol.exceptions import CommandError
from serial_protocol.messages import MsgType
from serial_protocol.pacing import FrameQueue, LinePacer

__all__ = ["BUSY_MESSAGE", "CanEndpoint", "PtyEndpoint", "TcpEndpoint"]

#: Board bytes waiting for a PC program that reads too slowly: past this, the oldest whole
#: frames are dropped (a real USB–serial adapter with nobody reading loses bytes too).
OUTPUT_QUEUE_BYTES = 4096
#: What a reader that falls behind loses first: the periodic frames, of which the next one
#: carries the news (a program waiting for its answer still gets it; the answer goes only if
#: the queue holds nothing else).
EXPENDABLE_TYPES = frozenset({MsgType.TELEMETRY, MsgType.BOARD_HEARTBEAT})
#: Bytes from the PC waiting for the emulated line (0.7 s of a 115200-baud line): a program
#: that writes faster than the line loses whole frames past this, counted.
INPUT_BACKLOG_BYTES = 8192
#: One read from the OS takes at most this much; a flood is drained this many per pass.
READ_CHUNK_BYTES = 65536
READS_PER_PASS = 16
#: When a second client knocks, up to this much of the first one's input is drained to see
#: whether it has in fact gone (more than the kernel buffers of a loopback connection).
DRAIN_ON_ACCEPT_BYTES = 64 << 20
#: The kernel's send buffer of a TCP client (it doubles the value): a client that stops
#: reading sees at most this much stale output queued in the kernel.
TCP_SNDBUF_BYTES = 8192
#: Set on every client's socket (benchmarks/bench_link.py turns it off to measure Nagle).
TCP_NODELAY = True
#: What a second TCP client receives before the server closes its connection.
BUSY_MESSAGE = (
    "turntable-sim serve: busy: this port serves one client at a time and {peer} is "
    "connected; try again when it disconnects\r\n"
)


def _counters() -> dict[str, int]:
    names = (
        "bytes_from_pc", "bytes_to_pc", "frames_dropped_to_pc", "bytes_dropped_to_pc",
        "frames_dropped_from_pc", "bytes_dropped_from_pc", "bytes_unheard", "clients",
        "clients_refused",
    )  # fmt: skip
    return dict.fromkeys(names, 0)


class _ByteEndpoint:
    """A paced byte stream to one PC program; subclasses provide ``_pull``, ``_send``,
    ``_connected``."""

    kind = "bytes"
    address = ""

    def __init__(self, pacer: LinePacer) -> None:
        self.pacer = pacer
        self.outbox = FrameQueue(
            OUTPUT_QUEUE_BYTES, drop_oldest=True, expendable_types=EXPENDABLE_TYPES
        )
        self.inbox = FrameQueue(INPUT_BACKLOG_BYTES, drop_oldest=False)
        self.lost_peer = False
        self._counters = _counters()

    @property
    def counters(self) -> dict[str, int]:
        c = self._counters
        c["frames_dropped_to_pc"] = self.outbox.dropped_frames
        c["bytes_dropped_to_pc"] = self.outbox.dropped_bytes
        c["frames_dropped_from_pc"] = self.inbox.dropped_frames
        c["bytes_dropped_from_pc"] = self.inbox.dropped_bytes
        return dict(c)

    def receive(self, room: int) -> bytes:
        """Read what the PC sent; return at most ``room`` bytes of it for the board."""
        self._pull()
        return self.inbox.pop(room) if room > 0 else b""

    def _take(self, data: bytes) -> None:
        self._counters["bytes_from_pc"] += len(data)
        self.inbox.push(data)

    def deliver(self, data: bytes, line_idle: bool) -> None:
        """Queue board bytes for the PC; ``line_idle``: the board's TX line is empty, so a
        frame still incomplete will not be completed (line noise)."""
        if not self._connected():
            self._counters["bytes_unheard"] += len(data)
            return
        self.outbox.push(data)
        if line_idle:
            self.outbox.flush_tail()

    def service(self, wall_s: float) -> None:
        """Write what the pacer allows at ``wall_s``."""
        if not len(self.outbox) or not self._connected():
            return
        n = min(len(self.outbox), self.pacer.allowance(wall_s))
        if n <= 0:
            return
        written = self._send(self.outbox.peek(n))
        if written > 0:
            self.outbox.consume(written)
            self.pacer.spend(wall_s, written)
            self._counters["bytes_to_pc"] += written

    def wait_s(self) -> float | None:
        """Seconds until the pacer lets the next queued byte go (None: nothing queued)."""
        if not len(self.outbox) or not self._connected():
            return None
        return self.pacer.wait_s(len(self.outbox))

    def _pull(self) -> None:
        raise NotImplementedError

    def _send(self, data: bytes) -> int:
        raise NotImplementedError

    def _connected(self) -> bool:
        return True


class PtyEndpoint(_ByteEndpoint):
    """A new pseudo-terminal in raw mode; ``link``: a symlink to its slave, removed on
    close."""

    kind = "pty"

    def __init__(self, pacer: LinePacer, link: str | None) -> None:
        import pty
        import tty

        super().__init__(pacer)
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.address = os.ttyname(self._slave)
        self._link = link
        if link:
            try:
                if os.path.islink(link):
                    os.unlink(link)
                os.symlink(self.address, link)
            except OSError as exc:
                self._link = None
                self.close()
                raise CommandError(f"cannot create the link {link!r}: {exc.strerror}") from exc

    def fds(self) -> list[int]:
        return [self._master]

    def _pull(self) -> None:
        # Read only what the backlog has room for: a program writing faster than the line
        # blocks in write() once the pty's buffer is full, as on a real serial port.
        for _ in range(READS_PER_PASS):
            room = self.inbox.max_bytes - len(self.inbox) - self.inbox.tail_bytes
            if room <= 0:
                return
            try:
                data = os.read(self._master, min(room, READ_CHUNK_BYTES))
            except OSError:  # EAGAIN: nothing to read; EIO: nobody has the pty open
                return
            if not data:
                return
            self._take(data)

    def _send(self, data: bytes) -> int:
        try:
            return os.write(self._master, data)
        except OSError:  # EAGAIN: the pty buffer is full (nobody reads)
            return 0

    def close(self) -> None:
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        if self._link and os.path.islink(self._link):
            os.unlink(self._link)


class TcpEndpoint(_ByteEndpoint):
    """A TCP port serving one client at a time (``socket://HOST:PORT`` for pyserial).

    The client's socket has ``TCP_NODELAY`` (a frame goes out when it is written, not after
    the peer's delayed ACK) and a small send buffer. A second client is sent
    ``BUSY_MESSAGE`` (one line of text) and closed. The client's input is always drained
    (so that a disconnect is seen at once, even after a flood) and kept within
    ``INPUT_BACKLOG_BYTES``.
    """

    kind = "tcp"

    def __init__(self, pacer: LinePacer, host: str, port: int) -> None:
        super().__init__(pacer)
        try:
            self._server = socket.create_server((host, port))
        except OSError as exc:
            raise CommandError(f"cannot listen on {host}:{port}: {exc.strerror}") from exc
        self._server.setblocking(False)
        bound_host, bound_port = self._server.getsockname()[:2]
        self.address = f"socket://{bound_host}:{bound_port}"
        self._client: socket.socket | None = None
        self._peer = ""

    def fds(self) -> list[int]:
        fds = [self._server.fileno()]
        if self._client is not None:
            fds.append(self._client.fileno())
        return fds

    def _connected(self) -> bool:
        return self._client is not None

    def _accept(self) -> None:
        while True:
            try:
                conn, addr = self._server.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # e.g. ECONNABORTED: the client gave up while queued
                continue
            peer = f"{addr[0]}:{addr[1]}"
            if self._client is not None:
                # The current client may be gone with its last bytes still buffered (a
                # flood followed by a close): drain them to see, before refusing anyone.
                self._drain(DRAIN_ON_ACCEPT_BYTES)
            if self._client is None:
                conn.setblocking(False)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, int(TCP_NODELAY))
                conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, TCP_SNDBUF_BYTES)
                self._client, self._peer = conn, peer
                self._counters["clients"] += 1
                # a new client does not get the previous one's backlog
                self.outbox.clear()
                self.inbox.clear()
                continue
            self._counters["clients_refused"] += 1
            try:
                conn.setblocking(False)
                conn.send(BUSY_MESSAGE.format(peer=self._peer).encode())
            except OSError:
                pass
            conn.close()

    def _drop_client(self) -> None:
        if self._client is not None:
            self._client.close()
        self._client = None
        self._peer = ""
        self.outbox.clear()
        self.inbox.clear()
        self.lost_peer = True

    def _pull(self) -> None:
        self._accept()
        self._drain(READS_PER_PASS * READ_CHUNK_BYTES)

    def _drain(self, max_bytes: int) -> None:
        """Read what the client sent, up to ``max_bytes`` (into the bounded backlog)."""
        client = self._client
        if client is None:
            return
        for _ in range(max(1, max_bytes // READ_CHUNK_BYTES)):
            try:
                data = client.recv(READ_CHUNK_BYTES)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                data = b""
            if not data:
                self._drop_client()
                return
            self._take(data)

    def _send(self, data: bytes) -> int:
        client = self._client
        if client is None:
            return 0
        try:
            return client.send(data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                return 0
            self._drop_client()
            return 0

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        self._server.close()


class CanEndpoint:
    """Gateway: board bytes -> messages -> CAN frames; CAN commands -> frames -> board.

    The CAN bus paces itself (its bit rate), so there is no byte pacer here."""

    kind = "can"

    def __init__(self, spec: str) -> None:
        from serial_protocol.can_link import CanLink
        from serial_protocol.frame import Decoder

        interface, _, channel = spec.removeprefix("can://").partition("/")
        if not interface or not channel:
            raise CommandError(f"--can {spec!r}: expected INTERFACE/CHANNEL")
        self.link = CanLink.open(interface, channel)
        self.address = f"can://{interface}/{channel}"
        self.lost_peer = False
        self._counters = _counters()
        self._decoder = Decoder()
        self._seq = 0

    @property
    def counters(self) -> dict[str, int]:
        return dict(self._counters)

    def fds(self) -> list[int]:
        return []

    def receive(self, room: int) -> bytes:
        from serial_protocol.frame import frame_raw

        out = b""
        for msg_type, payload in self.link.poll_raw(0.0):
            out += frame_raw(msg_type, payload, self._seq)
            self._seq = (self._seq + 1) & 0xFF
        self._counters["bytes_from_pc"] += len(out)
        return out

    def deliver(self, data: bytes, line_idle: bool) -> None:
        from serial_protocol.messages import Malformed

        self._counters["bytes_to_pc"] += len(data)
        for msg in self._decoder.feed(data):
            if isinstance(msg, Malformed):
                self._counters["frames_dropped_to_pc"] += 1
                continue
            self.link.send(msg)

    def service(self, wall_s: float) -> None:
        return None

    def wait_s(self) -> float | None:
        return None

    def close(self) -> None:
        self.link.close()


Endpoint = Any  # PtyEndpoint | TcpEndpoint | CanEndpoint
