"""The protocol's messages over classic CAN (python-can), docs/protocol.md section 8.

``arbitration_id = base_id + type`` (11-bit). Every CAN frame starts with a *tail byte*
(after DroneCAN's): bit 7 start of transfer, bit 6 end of transfer, bit 5 toggle (0 in the
first frame of a transfer, alternating after), bits 4..0 the transfer id (+1 per message of
that identifier, wraps at 32); up to 7 payload bytes follow. A payload of up to 7 bytes is
one frame. A longer one is followed by its CRC-32 (the frame check of the UART link) and cut
into 7-byte pieces: a transfer whose pieces come from different messages (after an outage
of any length: the transfer id wraps, the CRC does not match) is never delivered. A frame
identical to the last one accepted on its identifier is a bus-level duplicate (a CAN
controller retransmits a frame whose acknowledgement it missed) and is dropped.

The splitting (``can_frames``) and reassembly (``CanReassembler``) are pure and never raise
on received frames; ``CanLink`` sends and receives through a ``can.BusABC`` (``virtual`` in
tests, ``socketcan`` on Linux) and can log every frame with python-can's own writers
(``.asc``, ``.blf``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import can
from can.util import channel2int

from serial_protocol.exceptions import LinkError
from serial_protocol.frame import MAX_PAYLOAD_BYTES, crc32, decode_payload, encode_payload
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
PIECE_BYTES = CAN_DATA_BYTES - 1  # payload bytes per frame after the tail byte
CRC_BYTES = 4
SOT = 0x80  # start of transfer
EOT = 0x40  # end of transfer
TOGGLE = 0x20
TRANSFER_ID_MASK = 0x1F
#: The longest multi-frame transfer: the longest payload and its CRC.
MAX_TRANSFER_BYTES = MAX_PAYLOAD_BYTES + CRC_BYTES


def can_frames(
    msg: Message, counter: int = 0, base_id: int = DEFAULT_BASE_ID
) -> list[tuple[int, bytes]]:
    """Split ``msg`` into ``(arbitration_id, data)`` CAN frames.

    ``counter``: the transfer id (taken modulo 32), the sender's count of the messages it
    sent on this identifier. Raises ``ValueError`` if ``base_id + type`` is not an 11-bit
    identifier.
    """
    msg_type, payload = encode_payload(msg)
    return frames_of_payload(msg_type, payload, counter, base_id)


def frames_of_payload(
    msg_type: int, payload: bytes, transfer_id: int = 0, base_id: int = DEFAULT_BASE_ID
) -> list[tuple[int, bytes]]:
    """``can_frames`` for a payload already encoded (a gateway forwards it unchanged)."""
    arbitration_id = base_id + msg_type
    if not 0 <= arbitration_id <= 0x7FF:
        raise ValueError(f"base_id = {base_id:#x}: id {arbitration_id:#x} is not 11-bit")
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise ValueError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    tid = transfer_id & TRANSFER_ID_MASK
    if len(payload) <= PIECE_BYTES:
        return [(arbitration_id, bytes((SOT | EOT | tid,)) + payload)]
    body = payload + crc32(payload).to_bytes(CRC_BYTES, "little")
    pieces = [body[k : k + PIECE_BYTES] for k in range(0, len(body), PIECE_BYTES)]
    last = len(pieces) - 1
    return [
        (
            arbitration_id,
            bytes(((SOT if k == 0 else 0) | (EOT if k == last else 0) | (TOGGLE * (k & 1)) | tid,))
            + piece,
        )
        for k, piece in enumerate(pieces)
    ]


@dataclass(slots=True)
class CanStats:
    """Counters of a ``CanReassembler``.

    ``frames`` received; ``messages`` and ``malformed`` delivered; ``duplicates``: frames
    identical to the last one accepted on their identifier, dropped; ``reassembly_errors``:
    transfers that could not be completed (a lost, foreign or out-of-order frame, a bad
    CRC, an over-long transfer), each counted once; ``discarded_frames``: the frames thrown
    away with them or arriving outside any transfer; ``crc_errors``: transfers refused by
    their CRC (also in ``reassembly_errors``); ``foreign_ids``: identifiers outside
    ``base_id .. base_id + 255``.
    """

    frames: int = 0
    messages: int = 0
    malformed: int = 0
    duplicates: int = 0
    reassembly_errors: int = 0
    discarded_frames: int = 0
    crc_errors: int = 0
    foreign_ids: int = 0


class _Transfer:
    """The partial transfer of one identifier."""

    __slots__ = ("tid", "toggle", "buf", "frames")

    def __init__(self, tid: int) -> None:
        self.tid = tid
        self.toggle = 0
        self.buf = bytearray()
        self.frames = 0


class CanReassembler:
    """Turn received CAN frames back into messages (one reassembly per identifier).

    ``feed`` never raises: any sequence of ``(arbitration_id, data)`` gives messages,
    ``Malformed`` (a complete transfer whose payload cannot be decoded, so that the board
    can NACK it) or nothing (counted in ``stats``).
    """

    def __init__(self, base_id: int = DEFAULT_BASE_ID) -> None:
        self.base_id = base_id
        self.stats = CanStats()
        self._partial: dict[int, _Transfer] = {}
        self._last_frame: dict[int, bytes] = {}

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
        """One CAN frame in; ``(type, payload)`` of a complete transfer out, else None.

        The payload is not decoded (a gateway forwards it as it came, so that the board can
        NACK a bad one itself).
        """
        stats = self.stats
        stats.frames += 1
        msg_type = arbitration_id - self.base_id
        if not 0 <= msg_type <= 0xFF:
            stats.foreign_ids += 1
            return None
        data = bytes(data)
        if not 1 <= len(data) <= CAN_DATA_BYTES:
            self._abandon(arbitration_id)
            stats.discarded_frames += 1
            return None
        if self._last_frame.get(arbitration_id) == data:
            stats.duplicates += 1
            return None
        self._last_frame[arbitration_id] = data
        tail, piece = data[0], data[1:]
        tid, toggle = tail & TRANSFER_ID_MASK, 1 if tail & TOGGLE else 0
        partial = self._partial.get(arbitration_id)
        if tail & SOT:
            if partial is not None:
                self._abandon(arbitration_id)  # the previous transfer never ended
            if toggle:
                stats.discarded_frames += 1
                return None
            if tail & EOT:
                return msg_type, piece
            partial = self._partial[arbitration_id] = _Transfer(tid)
        elif partial is None:
            stats.discarded_frames += 1  # the rest of a transfer already given up
            return None
        elif partial.tid != tid or partial.toggle != toggle:
            self._abandon(arbitration_id)
            stats.discarded_frames += 1
            return None
        partial.buf += piece
        partial.frames += 1
        partial.toggle ^= 1
        if len(partial.buf) > MAX_TRANSFER_BYTES:
            self._abandon(arbitration_id)
            return None
        if not tail & EOT:
            return None
        del self._partial[arbitration_id]
        body = partial.buf
        if len(body) <= CRC_BYTES or crc32(body[:-CRC_BYTES]) != int.from_bytes(
            body[-CRC_BYTES:], "little"
        ):
            stats.crc_errors += 1
            stats.reassembly_errors += 1
            stats.discarded_frames += partial.frames
            return None
        return msg_type, bytes(body[:-CRC_BYTES])

    def _abandon(self, arbitration_id: int) -> None:
        partial = self._partial.pop(arbitration_id, None)
        if partial is not None:
            self.stats.reassembly_errors += 1
            self.stats.discarded_frames += partial.frames


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
        self._transfer_ids: dict[int, int] = {}
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
        msg_type, payload = encode_payload(msg)
        self.send_payload(msg_type, payload)

    def send_payload(self, msg_type: int, payload: bytes) -> None:
        """Send an encoded payload under ``msg_type`` (a gateway forwarding it unchanged)."""
        arbitration_id = self.base_id + msg_type
        transfer_id = self._transfer_ids.get(arbitration_id, 0)
        frames = frames_of_payload(msg_type, payload, transfer_id, self.base_id)
        self._transfer_ids[arbitration_id] = (transfer_id + 1) & TRANSFER_ID_MASK
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
