"""The emulated UART of the simulation: one direction, paced in simulated time.

The simulation loop owns one ``EmulatedUart`` per direction (board TX → PC, PC → board RX).
The sender ``write``s into a TX FIFO of ``fifo_bytes``; bytes that do not fit are dropped and
counted in ``stats.overflow_bytes`` (never silent). Each tick the loop calls
``advance(dt_s)``, which shifts out ``baud / 10`` bytes per simulated second (8N1: a start
bit, 8 data bits, a stop bit), carrying the fractional byte over to the next call, applies
the seeded fault injection and returns what reaches the far end.

``telemetry_decimation`` gives the firmware the smallest telemetry decimation whose byte rate
fits the baud rate with a margin left for replies.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

__all__ = [
    "DEFAULT_MAX_UTILISATION",
    "EmulatedUart",
    "FaultEvent",
    "FaultInjection",
    "UartStats",
    "bytes_per_s",
    "pace",
    "link_utilisation",
    "telemetry_decimation",
]

BITS_PER_BYTE_8N1 = 10
_NEVER_BYTES = float(2**62)  # a fault gap no simulation reaches
#: Share of the line telemetry may use; the rest is left for ACKs, replies and fault reports
#: (the firmware's `[telemetry] reply_reserve`, 0.2 by default).
DEFAULT_MAX_UTILISATION = 0.8


def bytes_per_s(baud: int) -> float:
    """Byte rate of an 8N1 line at ``baud`` (10 bits per byte)."""
    if not baud > 0:
        raise ValueError(f"baud = {baud!r}: must be > 0")
    return baud / BITS_PER_BYTE_8N1


def link_utilisation(baud: int, frame_bytes: int, tick_hz: float, decimation: int = 1) -> float:
    """Fraction of the line taken by one ``frame_bytes`` frame every ``decimation`` ticks."""
    if decimation < 1:
        raise ValueError(f"decimation = {decimation!r}: must be >= 1")
    return frame_bytes * tick_hz / decimation / bytes_per_s(baud)


def telemetry_decimation(
    baud: int,
    frame_bytes: int,
    tick_hz: float,
    max_utilisation: float = DEFAULT_MAX_UTILISATION,
) -> int:
    """Smallest decimation d >= 1 such that one ``frame_bytes`` frame every d ticks uses at
    most ``max_utilisation`` of an 8N1 line at ``baud``.

    At 500 Hz a 40-byte telemetry frame (protocol v2) gives 1 at 460800 and 921600 baud and
    3 at 115200 (20000 B/s wanted, 9216 B/s of the 11520 available).
    """
    if not frame_bytes > 0 or not tick_hz > 0:
        raise ValueError(f"frame_bytes = {frame_bytes!r}, tick_hz = {tick_hz!r}: must be > 0")
    if not 0.0 < max_utilisation <= 1.0:
        raise ValueError(f"max_utilisation = {max_utilisation!r}: must be in (0, 1]")
    budget_bytes_per_s = max_utilisation * bytes_per_s(baud)
    decimation = max(1, math.ceil(frame_bytes * tick_hz / budget_bytes_per_s))
    # ceil of a float quotient may land one too high or low on exact ratios: settle it
    while decimation > 1 and frame_bytes * tick_hz / (decimation - 1) <= budget_bytes_per_s:
        decimation -= 1
    while frame_bytes * tick_hz / decimation > budget_bytes_per_s:
        decimation += 1
    return decimation


@dataclass(frozen=True, slots=True)
class FaultInjection:
    """Seeded line faults, as probabilities per byte shifted out.

    Each byte suffers at most one fault. A byte is faulty with probability
    ``bit_flip_rate + drop_rate + insert_rate + burst_rate`` (at most 1) and the kind is
    drawn in proportion to the rates:

    - flip: one random bit of the byte is inverted;
    - drop: the byte is lost;
    - insert: a random byte is delivered after it;
    - burst: this byte and the next ``burst_bytes - 1`` are XORed with random non-zero
      bytes (a noise burst; every byte of it is changed).
    """

    bit_flip_rate: float = 0.0
    drop_rate: float = 0.0
    insert_rate: float = 0.0
    burst_rate: float = 0.0
    burst_bytes: int = 4

    def __post_init__(self) -> None:
        for name in ("bit_flip_rate", "drop_rate", "insert_rate", "burst_rate"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} = {value!r}: must be a probability in [0, 1]")
        if self.total_rate > 1.0:
            raise ValueError(f"sum of the rates = {self.total_rate!r}: must be <= 1")
        if self.burst_bytes < 1:
            raise ValueError(f"burst_bytes = {self.burst_bytes!r}: must be >= 1")

    @property
    def total_rate(self) -> float:
        """Probability that a byte is faulty."""
        return self.bit_flip_rate + self.drop_rate + self.insert_rate + self.burst_rate


@dataclass(slots=True)
class UartStats:
    """Byte counters of one direction.

    ``written`` bytes accepted into the FIFO; ``overflow_bytes`` refused because the FIFO
    was full; ``sent`` shifted out of the FIFO; ``delivered`` handed to the far end
    (``sent - dropped + inserted``); ``flipped_bits`` single-bit flips; ``dropped`` bytes
    lost; ``inserted`` spurious bytes; ``bursts`` noise bursts, covering ``burst_bytes``
    bytes in all.
    """

    written: int = 0
    overflow_bytes: int = 0
    overflow_events: int = 0
    sent: int = 0
    delivered: int = 0
    flipped_bits: int = 0
    dropped: int = 0
    inserted: int = 0
    bursts: int = 0
    burst_bytes: int = 0


@dataclass(frozen=True, slots=True)
class FaultEvent:
    """One injected fault: ``index`` is the position of the byte in the sent stream."""

    index: int
    kind: str  # "flip" | "drop" | "insert" | "burst"


def pace(credit: float, dt_s: float, bytes_per_s: float, pending: int) -> tuple[int, float]:
    """How many of ``pending`` queued bytes a line shifts out in ``dt_s``, and the credit
    (line time in bytes) it banks: ``(n, credit)``. Plain arithmetic, so that a compiled
    caller (``sim/tick.py``) paces exactly as ``EmulatedUart.advance``."""
    credit = credit + dt_s * bytes_per_s
    # The line empties the FIFO (what a fast line does every tick): the snapping below
    # could not change that, and round(x, 9) costs more than the rest of this call.
    if credit >= pending + 1.0:
        return pending, 0.0
    # snapped to 1e-9 byte so that float error cannot accumulate over millions of ticks
    # (23.04 bytes per 2 ms at 115200 baud must give exactly 23040 bytes per second)
    credit = round(credit, 9)
    n = int(credit)
    if n >= pending:
        # the line goes idle: the next byte starts when it is written, no banked credit
        return pending, 0.0
    return n, credit - n


class EmulatedUart:
    """One direction of an 8N1 serial line with a TX FIFO, paced in simulated time.

    ``baud``: bits per second; ``fifo_bytes``: TX FIFO size (a ring buffer in the firmware);
    ``faults``: line faults or None for a clean line; ``seed``: seeds the fault draws;
    ``record_faults``: keep a list of ``FaultEvent`` in ``fault_log`` (tests).
    """

    __slots__ = (
        "baud",
        "fifo_bytes",
        "faults",
        "stats",
        "fault_log",
        "_bytes_per_s",
        "_fifo",
        "_credit",
        "_rng",
        "_countdown",
        "_burst_left",
        "_record",
        "_cumulative",
        "_log_clean",
    )

    def __init__(
        self,
        baud: int,
        fifo_bytes: int = 256,
        faults: FaultInjection | None = None,
        seed: int = 0,
        record_faults: bool = False,
    ) -> None:
        if not isinstance(baud, int) or baud <= 0:
            raise ValueError(f"baud = {baud!r}: must be a positive integer")
        if not isinstance(fifo_bytes, int) or fifo_bytes < 1:
            raise ValueError(f"fifo_bytes = {fifo_bytes!r}: must be a positive integer")
        self.baud = baud
        self.fifo_bytes = fifo_bytes
        self.faults = faults if faults is not None and faults.total_rate > 0.0 else None
        self.stats = UartStats()
        self.fault_log: list[FaultEvent] = []
        self._bytes_per_s = bytes_per_s(baud)
        self._fifo = bytearray()
        self._credit = 0.0
        self._rng = random.Random(seed)
        self._burst_left = 0
        self._record = record_faults
        if self.faults is not None:
            f = self.faults
            rates = (f.bit_flip_rate, f.drop_rate, f.insert_rate, f.burst_rate)
            total = f.total_rate
            self._cumulative = tuple(sum(rates[: k + 1]) / total for k in range(4))
            # log of the probability that a byte is clean, for the geometric gap draws
            self._log_clean = math.log1p(-total) if total < 1.0 else -math.inf
            self._countdown = self._draw_gap()
        else:
            self._cumulative = ()
            self._log_clean = 0.0
            self._countdown = 0

    @property
    def free(self) -> int:
        """Free FIFO space in bytes."""
        return self.fifo_bytes - len(self._fifo)

    @property
    def pending(self) -> int:
        """Bytes waiting in the FIFO."""
        return len(self._fifo)

    def write(self, data: bytes) -> int:
        """Queue ``data``; return how many bytes were accepted (the rest is counted lost)."""
        fifo = self._fifo
        space = self.fifo_bytes - len(fifo)
        n = len(data)
        if n <= space:
            fifo += data
            self.stats.written += n
            return n
        fifo += data[:space]
        self.stats.written += space
        self.stats.overflow_bytes += n - space
        self.stats.overflow_events += 1
        return space

    def advance(self, dt_s: float) -> bytes:
        """Shift out the bytes the line carries in ``dt_s`` simulated seconds and return
        what reaches the far end (after fault injection)."""
        if not dt_s >= 0.0:
            raise ValueError(f"dt_s = {dt_s!r}: must be >= 0")
        fifo = self._fifo
        n, self._credit = pace(self._credit, dt_s, self._bytes_per_s, len(fifo))
        if n == 0:
            return b""
        chunk = bytes(fifo[:n])
        del fifo[:n]
        return self._deliver(chunk, n)

    @property
    def credit(self) -> float:
        """Bytes' worth of line time banked towards the next byte (< 1 while busy)."""
        return self._credit

    def transfer(self, data: bytes, shifted: int, credit: float) -> bytes:
        """Catch up with a caller that paced this line itself (``pace``, e.g. the compiled
        simulation loop): ``data`` was written (whole frames that fitted, so no overflow),
        ``shifted`` bytes in all were shifted out (counting from the bytes queued before),
        ``credit`` is left. Returns what reaches the far end, after fault injection (which
        goes byte by byte, so one call for many ticks injects what per-tick calls would)."""
        self._fifo += data
        self.stats.written += len(data)
        self._credit = credit
        if not shifted:
            return b""
        chunk = bytes(self._fifo[:shifted])
        del self._fifo[:shifted]
        return self._deliver(chunk, shifted)

    def _deliver(self, chunk: bytes, n: int) -> bytes:
        """Count the ``n`` bytes of ``chunk`` shifted out, inject faults, return them."""
        stats = self.stats
        start = stats.sent
        stats.sent = start + n
        if self.faults is not None and (self._burst_left or self._countdown < n):
            chunk = self._inject(chunk, start)
        elif self.faults is not None:
            self._countdown -= n
        stats.delivered += len(chunk)
        return chunk

    # ------------------------------------------------------------------ faults

    def _draw_gap(self) -> int:
        """Number of clean bytes before the next faulty one (geometric)."""
        log_clean = self._log_clean
        if log_clean == -math.inf:  # total rate 1: every byte is faulty
            return 0
        if log_clean == 0.0:  # a rate so small that log1p(-p) is 0: practically never
            return int(_NEVER_BYTES)
        return int(min(math.log1p(-self._rng.random()) / log_clean, _NEVER_BYTES))

    def _inject(self, chunk: bytes, start: int) -> bytes:
        rng = self._rng
        stats = self.stats
        out = bytearray()
        for offset, byte in enumerate(chunk):
            index = start + offset
            if self._burst_left:
                # inside a burst: the byte is hit, other faults wait for the burst to end
                out.append(byte ^ rng.randrange(1, 256))
                self._burst_left -= 1
                stats.burst_bytes += 1
                continue
            if self._countdown:
                self._countdown -= 1
                out.append(byte)
                continue
            self._countdown = self._draw_gap()
            u = rng.random()
            cumulative = self._cumulative
            if u < cumulative[0]:
                out.append(byte ^ (1 << rng.randrange(8)))
                stats.flipped_bits += 1
                kind = "flip"
            elif u < cumulative[1]:
                stats.dropped += 1
                kind = "drop"
            elif u < cumulative[2]:
                out.append(byte)
                out.append(rng.randrange(256))
                stats.inserted += 1
                kind = "insert"
            else:
                out.append(byte ^ rng.randrange(1, 256))
                stats.bursts += 1
                stats.burst_bytes += 1
                self._burst_left = self.faults.burst_bytes - 1  # type: ignore[union-attr]
                kind = "burst"
            if self._record:
                self.fault_log.append(FaultEvent(index, kind))
        return bytes(out)
