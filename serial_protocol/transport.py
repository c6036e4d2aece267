"""Message links over real ports: pyserial ``serial_for_url`` (``/dev/tty*``, ``loop://``,
``socket://host:port``, a ``serve --pty`` device).

A *link* moves messages, not bytes: ``send(msg)`` frames and writes one message,
``poll(timeout_s)`` returns the messages that arrived. ``SerialLink`` here and
``can_link.CanLink`` share that interface (``Link``), so the PC-side client
(``serial_protocol.host``) works the same over serial and CAN.

Only this module and ``can_link`` import the I/O libraries.
"""

from __future__ import annotations

import os
import select
import socket
import time
from typing import BinaryIO, Protocol

import serial

from serial_protocol.exceptions import LinkError
from serial_protocol.frame import Decoder, DecoderStats, encode
from serial_protocol.messages import Malformed, Message

__all__ = ["Link", "SerialLink", "open_serial"]

#: A line quiet for this long ends any partial frame (``Decoder.flush``).
IDLE_FLUSH_S = 0.05
#: One read takes at most this many bytes (a second of a 460800-baud line fits).
READ_CHUNK_BYTES = 65536


class Link(Protocol):
    """What the host client needs from a transport."""

    def send(self, msg: Message) -> None:
        """Send one message."""

    def poll(self, timeout_s: float) -> list[Message | Malformed]:
        """Wait up to ``timeout_s`` for input; return the messages that arrived."""

    def close(self) -> None:
        """Release the port."""


def open_serial(url: str, baud: int = 115200, timeout_s: float = 0.0) -> serial.SerialBase:
    """Open ``url`` with pyserial's ``serial_for_url`` (8N1, no flow control).

    Raises ``LinkError`` naming the URL when the port cannot be opened.
    """
    try:
        if not url.startswith("socket://"):
            return serial.serial_for_url(url, baudrate=baud, timeout=timeout_s)
        # pyserial's socket:// open() ends with reset_input_buffer(), which would swallow
        # what a server says at once (serve's one-line refusal of a second client):
        # skipped for the open; SerialLink.open drains the input itself.
        port = serial.serial_for_url(url, baudrate=baud, timeout=timeout_s, do_not_open=True)
        port.reset_input_buffer = lambda: None  # type: ignore[method-assign]
        try:
            port.open()
        finally:
            del port.reset_input_buffer
        return port
    except (serial.SerialException, ValueError, OSError) as exc:
        raise LinkError(f"cannot open serial port {url!r} at {baud} baud: {exc}") from exc


class SerialLink:
    """Frames over a pyserial port.

    ``port``: an open pyserial port (see ``open_serial``), or use ``SerialLink.open(url)``.
    ``capture``: a binary file that receives a copy of every byte read (for
    ``turntable-sim decode``). Counters: ``bytes_in``, ``bytes_out``, ``frames_out`` and the
    decoder's (``stats()``).
    """

    def __init__(self, port: serial.SerialBase, capture: BinaryIO | None = None) -> None:
        self.port = port
        self.decoder = Decoder()
        self.capture = capture
        self.bytes_in = 0
        self.bytes_out = 0
        self.frames_out = 0
        self._seq = 0
        self._last_rx_wall_s = time.monotonic()
        self._fd = _read_fd(port)
        self._last_text = b""

    @classmethod
    def open(cls, url: str, baud: int = 115200, capture: BinaryIO | None = None) -> SerialLink:
        """Open ``url`` (``/dev/ttyUSB0``, ``loop://``, ``socket://host:port``, ...).

        Bytes that were waiting in the port before it was opened (stale telemetry) are
        discarded.
        """
        port = open_serial(url, baud)
        sock = getattr(port, "_socket", None)
        try:
            if isinstance(sock, socket.socket):
                # A TCP stream (socket://) sends each frame at once instead of waiting for
                # the peer's delayed ACK (Nagle), as a serial line would.
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            else:
                port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            port.close()
            raise LinkError(f"cannot flush serial port {url!r}: {exc}") from exc
        link = cls(port, capture)
        if isinstance(sock, socket.socket):
            # pyserial's reset_input_buffer would also swallow a server's refusal and the
            # end of the stream; drain here instead, so that a refusal is reported.
            try:
                while link._read(0.0):
                    pass
            except LinkError:
                port.close()
                raise
        return link

    def __enter__(self) -> SerialLink:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def send(self, msg: Message) -> None:
        """Frame ``msg`` with the next sequence number and write it."""
        self.send_bytes(encode(msg, self._seq))
        self._seq = (self._seq + 1) & 0xFF
        self.frames_out += 1

    def send_bytes(self, data: bytes) -> None:
        """Write raw bytes (a prepared frame, or garbage in a robustness test)."""
        try:
            self.port.write(data)
            self.port.flush()
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"write to {self.port.port!r} failed: {exc}") from exc
        self.bytes_out += len(data)

    def poll(self, timeout_s: float) -> list[Message | Malformed]:
        """Wait up to ``timeout_s`` for bytes; return the messages they complete."""
        data = self._read(max(0.0, timeout_s))
        now_s = time.monotonic()
        if not data:
            if self.decoder.pending_bytes and now_s - self._last_rx_wall_s > IDLE_FLUSH_S:
                return self.decoder.flush()
            return []
        self._last_rx_wall_s = now_s
        self.bytes_in += len(data)
        if self.capture is not None:
            self.capture.write(data)
        return self.decoder.feed(data)

    def _read(self, timeout_s: float) -> bytes:
        """Wait up to ``timeout_s`` for input and return all of it that is there.

        A port with a file descriptor (a tty, a pty, ``socket://``) is read with one
        ``select`` and one ``os.read`` of up to ``READ_CHUNK_BYTES``; pyserial's own
        ``read`` would take one or two bytes per call over ``socket://``, whose
        ``in_waiting`` is only 0 or 1."""
        port = self.port
        fd = self._fd
        try:
            if fd is None:
                if port.timeout != timeout_s:
                    port.timeout = timeout_s
                data = port.read(1)
                if data and port.in_waiting:
                    data += port.read(port.in_waiting)
                return data
            ready, _, _ = select.select([fd], [], [], timeout_s)
            if not ready:
                return b""
            data = os.read(fd, READ_CHUNK_BYTES)
        except ConnectionResetError:
            data = b""  # the peer closed with data unread: the same end as a close
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"read from {port.port!r} failed: {exc}") from exc
        if not data:
            said = self._last_text.decode("ascii", "replace").strip()
            raise LinkError(
                f"{port.port!r}: the other end closed the connection"
                + (f"; it said: {said!r}" if said else "")
            )
        # Keep the last line of plain text received (a server's refusal, say) for the
        # message above; frames are binary and do not count.
        if all(32 <= b < 127 or b in (9, 10, 13) for b in data[-200:]):
            self._last_text = data[-200:]
        return data

    def stats(self) -> DecoderStats:
        """The receive decoder's counters."""
        return self.decoder.stats()

    def close(self) -> None:
        """Close the port (idempotent)."""
        if self.port.is_open:
            self.port.close()


def _read_fd(port: serial.SerialBase) -> int | None:
    """The file descriptor to ``select`` on for ``port``, or None (``loop://``, Windows)."""
    if os.name != "posix":
        return None
    try:
        fd = port.fileno()
    except (AttributeError, NotImplementedError, serial.SerialException, OSError, ValueError):
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None
