"""The link soak of issue #10 §2, shared by the test suite (a bounded run) and
``benchmarks/soak_link.py`` (the 1,000,000-frame run whose figures docs/benchmarks.md
quotes).

A stream of protocol v2 frames (telemetry, commands and answers, each identifiable) goes
through the fault mix below; the receiver is the reference ``frame.Decoder``, fed in random
chunks, with the silence rule applied at random idle points. Checked:

* **no corrupted frame accepted**: every message delivered is one of the frames sent, with
  its sequence number (a damaged frame that passed both checks would not be);
* **intact frames recovered**: every frame that reached the line unmodified is delivered;
* **every counter exact**: the decoder's counters equal those of an independent, naive
  receiver written from docs/protocol.md section 3 (byte by byte, whole stream), and every
  byte is accounted for (in a good frame, dropped, or held).

The fault mix, per frame (``p_frame_fault`` of the frames are damaged, one kind each, drawn
uniformly): 1-3 bit flips, 1-2 bytes dropped, 1-3 random bytes inserted, a byte
duplicated, truncation (the frame cut short, the rest lost). Between frames, each with
probability ``p_between``: a garbage burst (1-40 random bytes), a fake sync pair, a fake
header with a valid header check (a random type and length, half of them the longest
payload), an idle period (the silence rule fires).

The residual rate also compares the CRC-32 with version 1's CRC-16/CCITT on the very same
damaged frames: how many of them would still have passed a 16-bit check.
"""

from __future__ import annotations

import random
from binascii import crc_hqx
from dataclasses import dataclass, field
from zlib import crc32

from serial_protocol import frame
from serial_protocol.messages import (
    Ack,
    GetStatus,
    Move,
    MsgType,
    Nack,
    NackCode,
    Profile,
    State,
    Status,
    Telemetry,
)

FAULT_KINDS = ("bit_flip", "drop", "insert", "duplicate", "truncate")
BETWEEN_KINDS = ("garbage", "fake_sync", "fake_header", "idle")


@dataclass
class SoakReport:
    """What one soak run sent, damaged, delivered and counted."""

    frames: int = 0
    intact: int = 0
    damaged: int = 0
    damaged_by_kind: dict[str, int] = field(default_factory=dict)
    between_by_kind: dict[str, int] = field(default_factory=dict)
    delivered: int = 0
    recovered_intact: int = 0
    accepted_corrupted: int = 0
    damaged_delivered_intact: int = 0  # a fault that left the frame valid (e.g. 0x00 dup)
    stream_bytes: int = 0
    counters: dict[str, int] = field(default_factory=dict)
    reference_counters: dict[str, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    kind_of: list[str | None] = field(default_factory=list)  # per frame: its damage or None
    lost_intact: list[int] = field(default_factory=list)  # indices of intact frames not seen

    @property
    def recovery(self) -> float:
        return self.recovered_intact / self.intact if self.intact else 1.0


def _message(k: int, rng: random.Random) -> object:
    """Frame k's message: telemetry mostly, answers and commands too; unique by ``k``
    (k < 2^24)."""
    r = rng.random()
    low, high = k & 0xFFFF, k >> 16
    if r < 0.7:
        return Telemetry(k, k * 1e-3, 1.5, k * 1e-3 - 0.01, 1.25, 0.5, 0.25, State.MOVING, 0)
    if r < 0.8:
        return Ack(low, high)
    if r < 0.85:
        return Nack(low, MsgType.MOVE, NackCode.TOO_HIGH, 3, float(k))
    if r < 0.9:
        return Status(low, k, State.HOLDING, 0, 1.0, 0.0, 1.0, 0, 7)
    if r < 0.95:
        return Move(low, (k % 2_000_000) * 1e-1, 990.0, 148.0, 0.0, Profile.TRAPEZOID, 7)
    return GetStatus(low, high + 1)


def _damage(data: bytes, kind: str, rng: random.Random) -> bytes:
    b = bytearray(data)
    if kind == "bit_flip":
        for _ in range(rng.randint(1, 3)):
            bit = rng.randrange(len(b) * 8)
            b[bit // 8] ^= 0x80 >> (bit % 8)
    elif kind == "drop":
        for _ in range(rng.randint(1, 2)):
            del b[rng.randrange(len(b))]
    elif kind == "insert":
        for _ in range(rng.randint(1, 3)):
            b.insert(rng.randrange(len(b) + 1), rng.randrange(256))
    elif kind == "duplicate":
        i = rng.randrange(len(b))
        b.insert(i, b[i])
    else:  # truncate: the frame cut short, the rest never sent
        del b[rng.randrange(1, len(b)) :]
    return bytes(b)


def _between(kind: str, rng: random.Random) -> bytes:
    if kind == "garbage":
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 40)))
    if kind == "fake_sync":
        return frame.SYNC
    if kind == "fake_header":
        length = frame.MAX_PAYLOAD_BYTES if rng.random() < 0.5 else rng.randint(0, 64)
        head = bytes((length, rng.randrange(256), rng.randrange(256)))
        return frame.SYNC + head + bytes((frame.crc8(head),))
    return b""  # idle: handled by the caller


def build_stream(
    n_frames: int, seed: int, p_frame_fault: float = 0.3, p_between: float = 0.05
) -> tuple[list[bytes], dict[object, int], list[bool], SoakReport]:
    """The segments of the line (split at idle points), the index of each message sent,
    which frames went out intact, and the report's send-side counts."""
    if n_frames >= 1 << 24:
        raise ValueError(f"n_frames = {n_frames}: messages are unique below 2^24")
    rng = random.Random(seed)
    report = SoakReport(frames=n_frames)
    sent: dict[object, int] = {}
    intact: list[bool] = []
    segments: list[bytes] = []
    current = bytearray()
    for k in range(n_frames):
        msg = _message(k, rng)
        seq = k & 0xFF
        data = frame.encode(msg, seq)
        # the message as the receiver decodes it (wire rounding): every one is unique
        sent[frame.decode_payload(data[3], data[frame.HEADER_BYTES : -frame.CRC_BYTES])] = k
        if rng.random() < p_between:
            kind = BETWEEN_KINDS[rng.randrange(len(BETWEEN_KINDS))]
            report.between_by_kind[kind] = report.between_by_kind.get(kind, 0) + 1
            if kind == "idle":
                segments.append(bytes(current))
                current = bytearray()
            else:
                current += _between(kind, rng)
        if rng.random() < p_frame_fault:
            kind = FAULT_KINDS[rng.randrange(len(FAULT_KINDS))]
            report.kind_of.append(kind)
            damaged = _damage(data, kind, rng)
            report.damaged_by_kind[kind] = report.damaged_by_kind.get(kind, 0) + 1
            if damaged == data:  # e.g. a duplicated byte that re-creates the same bytes
                report.damaged_delivered_intact += 1
                intact.append(True)
            else:
                intact.append(False)
            current += damaged
        else:
            report.kind_of.append(None)
            intact.append(True)
            current += data
    segments.append(bytes(current))
    report.intact = sum(intact)
    report.damaged = n_frames - report.intact
    report.stream_bytes = sum(len(s) for s in segments)
    return segments, sent, intact, report


def crc_residual(n_frames: int, seed: int, kind: str) -> dict[str, int]:
    """For ``n_frames`` random frames damaged by ``kind`` and followed on the line by the
    start of another frame: how many pass a CRC-32 (v2) and a CRC-16/CCITT (v1) frame
    check, read at the frame's start with the length its (possibly damaged) header claims.

    Returns counts per check (``32`` and ``16``): ``damaged`` frames (a fault that leaves
    the bytes as they were is not counted), ``corrupt`` passes (a header or payload that
    differs from the one sent: an undetected error) and ``benign`` passes (the frame's own
    header and payload, only its check field hit: a lost check byte replaced by the next
    frame's first byte, which then costs that next frame). Each frame is damaged in both
    versions from the same random state; only the check field differs (4 or 2 bytes)."""
    rng = random.Random(seed)
    out = dict.fromkeys(("damaged32", "corrupt32", "benign32",
                         "damaged16", "corrupt16", "benign16"), 0)  # fmt: skip
    for k in range(n_frames):
        msg = _message(k, rng)
        head = bytes((frame.payload_bytes(type(msg)), msg.MSG_TYPE, k & 0xFF))
        _, payload = frame.encode_payload(msg)
        body = head + bytes((frame.crc8(head),)) + payload
        sent = {
            "32": frame.SYNC + body + crc32(body).to_bytes(4, "little"),
            "16": frame.SYNC + body + crc_hqx(body, 0xFFFF).to_bytes(2, "little"),
        }
        state = rng.getstate()
        # On the line the next frame follows: a frame that lost bytes takes its first ones.
        following = frame.SYNC + bytes(rng.randrange(256) for _ in range(8))
        for name, data in sent.items():
            rng.setstate(state)
            damaged = _damage(data, kind, rng)
            if damaged == data:
                continue
            out["damaged" + name] += 1
            got = _check(damaged + following, 4 if name == "32" else 2)
            if got is not None:
                out[("benign" if got == body else "corrupt") + name] += 1
    return out


def _check(data: bytes, crc_bytes: int) -> bytes | None:
    """The body (header from ``len`` on, and payload) of the frame at the start of
    ``data`` if it passes the header check and the frame check, else None."""
    if len(data) < 6 or data[:2] != frame.SYNC:
        return None
    length = data[2]
    if length > frame.MAX_PAYLOAD_BYTES or frame.crc8(data[2:5]) != data[5]:
        return None
    end = 6 + length + crc_bytes
    if len(data) < end:
        return None
    body = data[2 : 6 + length]
    stored = int.from_bytes(data[6 + length : end], "little")
    ok = (crc32(body) if crc_bytes == 4 else crc_hqx(body, 0xFFFF)) == stored
    return bytes(body) if ok else None


# ------------------------------------------------------------------ the naive receiver


def reference_counters(segments: list[bytes]) -> dict[str, int]:
    """docs/protocol.md section 3, literally: hunt, header, body, back up one byte; at the
    end of each segment (silence) a held candidate is abandoned one byte at a time."""
    c = dict.fromkeys(vars(frame.Decoder().stats()), 0)
    hunting = False
    last_seq = None
    for seg in segments:
        n = len(seg)
        i = 0
        held = False
        while i < n:
            if not (seg[i] == 0xA5 and i + 1 < n and seg[i + 1] == 0x5A):
                c["bytes_dropped"] += 1
                hunting = True
                if seg[i] == 0xA5 and i + 1 == n:
                    held = True
                i += 1
                continue
            if n - i < 6:
                held = True
                c["bytes_dropped"] += 1
                hunting = True
                i += 1
                continue
            length = seg[i + 2]
            if length > 64 or frame.crc8(seg[i + 2 : i + 5]) != seg[i + 5]:
                c["header_errors"] += 1
                c["bytes_dropped"] += 1
                hunting = True
                i += 1
                continue
            end = i + 10 + length
            if end > n:
                held = True
                c["bytes_dropped"] += 1
                hunting = True
                i += 1
                continue
            if crc32(seg[i + 2 : end - 4]) != int.from_bytes(seg[end - 4 : end], "little"):
                c["crc_errors"] += 1
                c["bytes_dropped"] += 1
                hunting = True
                i += 1
                continue
            c["frames"] += 1
            if hunting:
                c["resyncs"] += 1
                hunting = False
            seq = seg[i + 4]
            if last_seq is not None and seq != (last_seq + 1) & 0xFF:
                c["seq_gaps"] += 1
                c["frames_missed"] += (seq - last_seq - 1) & 0xFF
            last_seq = seq
            decoded = frame.decode_payload(seg[i + 3], bytes(seg[i + 6 : end - 4]))
            if type(decoded).__name__ == "Malformed":
                c["malformed"] += 1
            i = end
        c["partial_discards"] += held
    return c


# ------------------------------------------------------------------ the run


def run_soak(
    n_frames: int, seed: int = 0, p_frame_fault: float = 0.3, p_between: float = 0.05
) -> SoakReport:
    """Build the stream, decode it (random chunks, ``flush`` at every idle point and at the
    end) and check it against what was sent and against the naive receiver."""
    segments, sent, intact, report = build_stream(n_frames, seed, p_frame_fault, p_between)
    rng = random.Random(seed + 1)
    decoder = frame.Decoder()
    got_frames = [False] * n_frames
    for seg in segments:
        i = 0
        while i < len(seg):
            step = rng.choice((1, 7, 64, 600, 4096))
            out = decoder.feed(seg[i : i + step])
            i += step
            _account(out, sent, got_frames, report)
        _account(decoder.flush(), sent, got_frames, report)
    report.counters = dict(vars(decoder.stats()))
    report.reference_counters = reference_counters(segments)
    report.recovered_intact = sum(g and ok for g, ok in zip(got_frames, intact, strict=True))
    report.lost_intact = [
        k for k, (g, ok) in enumerate(zip(got_frames, intact, strict=True)) if ok and not g
    ]
    if report.counters != report.reference_counters:
        report.problems.append(
            f"counters differ from the reference receiver: {report.counters} vs "
            f"{report.reference_counters}"
        )
    if report.accepted_corrupted:
        report.problems.append(f"{report.accepted_corrupted} corrupted frames accepted")
    return report


def _account(out: list, sent: dict, got: list, report: SoakReport) -> None:
    """Match delivered messages to the frames sent (every message sent is unique, so a
    delivered message that is not one of them, or comes twice, is a corrupted frame)."""
    for msg in out:
        report.delivered += 1
        k = sent.get(msg)
        if k is None or got[k]:
            report.accepted_corrupted += 1
            continue
        got[k] = True
