"""The protocol's messages over classic CAN (python-can), docs/protocol.md section 8.

``arbitration_id = base_id + type`` (11-bit). A payload of at most 8 bytes is one CAN frame;
a longer one is segmented: each CAN frame carries a segment byte (bits 7..5 transfer counter,
bit 4 last segment, bits 3..0 segment index) and up to 7 payload bytes. The splitting
(``can_frames``) and reassembly (``CanReassembler``) are pure; ``CanLink`` sends and receives
through a ``can.BusABC`` (``virtual`` in tests, ``socketcan`` on Linux) and can log every
frame with python-can's own writers (``.asc``, ``.blf``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import can
from can.util import channel2int

from serial_protocol.exceptions import LinkError
from serial_protocol.frame import decode_payload, encode_payload, payload_size_of_type
from serial_protocol.messages import Malformed, Message

__all__ = [
    "DEFAULT_BASE_ID",
    "CanLink",
    "CanReassembler",
    "CanStats",
    "can_frames",
]

DEFAULT_BASE_ID = 0x100
CAN_DATA_BYTES = 8
SEGMENT_DATA_BYTES = 7
_LAST = 0x10


def can_frames(
    msg: Message, counter: int = 0, base_id: int = DEFAULT_BASE_ID
) -> list[tuple[int, bytes]]:
    """Split ``msg`` into ``(arbitration_id, data)`` CAN frames.

    ``counter`` (taken modulo 8) is the transfer counter of a segmented message; the sender
    increments it per segmented message of the same identifier.
    """
    msg_type, payload = encode_payload(msg)
    arbitration_id = base_id + msg_type
    if not 0 <= arbitration_id <= 0x7FF:
        raise ValueError(f"base_id = {base_id:#x}: id {arbitration_id:#x} is not 11-bit")
    if len(payload) <= CAN_DATA_BYTES:
        return [(arbitration_id, payload)]
    chunks = [
        payload[k : k + SEGMENT_DATA_BYTES] for k in range(0, len(payload), SEGMENT_DATA_BYTES)
    ]
    top = (counter & 0x7) << 5
    return [
        (arbitration_id, bytes((top | (_LAST if k == len(chunks) - 1 else 0) | k,)) + chunk)
        for k, chunk in enumerate(chunks)
    ]


@dataclass(slots=True)
class CanStats:
    """Counters of a ``CanReassembler``."""

    frames: int = 0
    messages: int = 0
    malformed: int = 0
    reassembly_errors: int = 0  # transfers broken by a lost or out-of-order segment
    discarded_frames: int = 0  # segments thrown away with a broken transfer
    foreign_ids: int = 0


class CanReassembler:
    """Turn received CAN frames back into messages (one reassembly per identifier)."""

    def __init__(self, base_id: int = DEFAULT_BASE_ID) -> None:
        self.base_id = base_id
        self.stats = CanStats()
        # arbitration id -> (counter, next index, bytes so far or None while discarding)
        self._partial: dict[int, tuple[int, int, bytearray | None]] = {}

    def feed(self, arbitration_id: int, data: bytes) -> Message | Malformed | None:
        """One CAN frame in; a complete message (or ``Malformed``) out, else None."""
        raw = self.feed_raw(arbitration_id, data)
        if raw is None:
            return None
        msg = decode_payload(*raw)
        if isinstance(msg, Malformed):
            self.stats.malformed += 1
        else:
            self.stats.messages += 1
        return msg

    def feed_raw(self, arbitration_id: int, data: bytes) -> tuple[int, bytes] | None:
        """One CAN frame in; ``(type, payload)`` of a complete message out, else None.

        The payload is not decoded (a gateway forwards it as it came, so that the board can
        NACK a bad one itself).
        """
        stats = self.stats
        stats.frames += 1
        msg_type = arbitration_id - self.base_id
        if not 0 <= msg_type <= 0xFF:
            stats.foreign_ids += 1
            return None
        size = payload_size_of_type(msg_type)
        if size is None or size <= CAN_DATA_BYTES:
            return msg_type, bytes(data)
        if not data:
            stats.reassembly_errors += 1
            return None
        head = data[0]
        counter, last, index = head >> 5, bool(head & _LAST), head & 0x0F
        partial = self._partial.get(arbitration_id)
        if index == 0:
            if partial is not None and partial[2] is not None:
                stats.reassembly_errors += 1  # the previous transfer never finished
            partial = (counter, 0, bytearray())
        elif partial is not None and partial[2] is None and partial[0] == counter:
            stats.discarded_frames += 1  # the rest of a transfer already counted as broken
            return None
        elif partial is None or partial[0] != counter or partial[1] != index:
            stats.reassembly_errors += 1
            stats.discarded_frames += 1
            self._partial[arbitration_id] = (counter, 0, None)
            return None
        buf = partial[2]
        buf += data[1:]
        if not last:
            self._partial[arbitration_id] = (counter, index + 1, buf)
            return None
        del self._partial[arbitration_id]
        return msg_type, bytes(buf)


class CanLink:
    """Messages over a python-can bus (the ``Link`` interface of ``transport``).

    ``bus``: an open ``can.BusABC``; ``log_path``: optional ``.asc``/``.blf`` (or any suffix
    ``can.Logger`` knows) receiving every frame sent and received.
    """

    def __init__(
        self, bus: can.BusABC, base_id: int = DEFAULT_BASE_ID, log_path: str | None = None
    ) -> None:
        self.bus = bus
        self.base_id = base_id
        self.reassembler = CanReassembler(base_id)
        self.frames_out = 0
        self._counters: dict[int, int] = {}
        try:
            self._logger = can.Logger(log_path) if log_path else None
        except (ValueError, OSError) as exc:
            raise LinkError(f"cannot log CAN frames to {log_path!r}: {exc}") from exc

    @classmethod
    def open(
        cls,
        interface: str = "virtual",
        channel: str = "turntable",
        bitrate: int | None = None,
        base_id: int = DEFAULT_BASE_ID,
        log_path: str | None = None,
    ) -> CanLink:
        """Open a python-can bus (``virtual``, ``socketcan``, ...) and wrap it."""
        kwargs = {"interface": interface, "channel": channel}
        if bitrate is not None:
            kwargs["bitrate"] = bitrate
        try:
            bus = can.Bus(**kwargs)
        except (can.CanError, ValueError, OSError, ImportError) as exc:
            raise LinkError(f"cannot open CAN bus {interface}:{channel}: {exc}") from exc
        return cls(bus, base_id, log_path)

    def __enter__(self) -> CanLink:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def send(self, msg: Message) -> None:
        """Send ``msg`` as one or more CAN frames."""
        arbitration_id = self.base_id + msg.MSG_TYPE
        counter = self._counters.get(arbitration_id, 0)
        frames = can_frames(msg, counter, self.base_id)
        if len(frames) > 1:
            self._counters[arbitration_id] = (counter + 1) & 0x7
        for frame_id, data in frames:
            out = can.Message(
                timestamp=time.time(), arbitration_id=frame_id, data=data, is_extended_id=False
            )
            try:
                self.bus.send(out)
            except can.CanError as exc:
                raise LinkError(f"CAN send failed: {exc}") from exc
            self.frames_out += 1
            if self._logger is not None:
                out.is_rx = False
                self._log(out)

    def poll(self, timeout_s: float) -> list[Message | Malformed]:
        """Wait up to ``timeout_s`` for frames; return the messages they complete."""
        return self._receive(timeout_s, self.reassembler.feed)

    def poll_raw(self, timeout_s: float) -> list[tuple[int, bytes]]:
        """Like ``poll`` but return ``(type, payload)`` pairs, undecoded (for a gateway)."""
        return self._receive(timeout_s, self.reassembler.feed_raw)

    def _receive(self, timeout_s: float, feed: Any) -> list[Any]:
        out = []
        frame = self.bus.recv(timeout=max(0.0, timeout_s))
        while frame is not None:
            if self._logger is not None:
                self._log(frame)
            if not frame.is_extended_id and not frame.is_remote_frame:
                got = feed(frame.arbitration_id, bytes(frame.data))
                if got is not None:
                    out.append(got)
            frame = self.bus.recv(timeout=0.0)
        return out

    def _log(self, frame: can.Message) -> None:
        # BLF stores the channel as a 16-bit number parsed from the channel name's trailing
        # digits (python-can's channel2int); a name such as "bench-4117297" would overflow it
        # and make the writer raise, so such a channel is logged as "no channel".
        number = channel2int(frame.channel)
        if number is not None and not 0 <= number < 0xFFFF:
            frame.channel = None
        self._logger.on_message_received(frame)

    def close(self) -> None:
        """Stop the log writer and shut the bus down."""
        if self._logger is not None:
            self._logger.stop()
            self._logger = None
        self.bus.shutdown()
