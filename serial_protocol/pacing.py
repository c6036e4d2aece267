"""Pacing a byte stream to a serial line, and queueing it a whole frame at a time.

Used by ``turntable-sim serve`` between the simulated board and a real pty or socket. No
I/O here: callers pass the time (``wall_s``, host monotonic seconds) and the bytes.

``LinePacer`` is a token bucket at the line's byte rate with a hard cap per window: a
sender that writes only what ``allowance`` grants puts at most ``burst_bytes + rate * w``
bytes into any interval of ``w`` seconds and never more than the line carries in any
``window_s`` window (100 ms), however late it runs. The bucket lets a process that a loaded
machine wakes only every few tens of milliseconds still keep up with the line (a 2 ms bucket
let such a process send 2 ms of line per wake-up: it fell behind, and its queue dropped
frames, answers among them); the window cap keeps a stalled process from catching up with
a burst above the line. It also measures the largest number of bytes it granted in any
``window_s`` window, so that a server can state its peak line use.

``FrameQueue`` holds bytes on their way to a slow reader (or from a fast writer) in units
that are whole frames: a complete frame of ``docs/protocol.md`` (found by its sync pair and
its header check), or a run of bytes that is not a frame (line noise). When the queue is
over its size the units that must go are dropped whole and counted, never part of a frame;
a unit whose first bytes have been taken is always finished.
"""

from __future__ import annotations

from collections import deque

from serial_protocol.frame import (
    HEADER_BYTES,
    MAX_PAYLOAD_BYTES,
    OVERHEAD_BYTES,
    SYNC,
    Decoder,
    crc8,
)

__all__ = ["FrameQueue", "LinePacer", "frame_length_at"]


def frame_length_at(buf: bytes | bytearray, i: int) -> int | None:
    """Length in bytes of the frame whose header starts at ``buf[i]`` (the sync pair), or
    None if the header there is not a valid one. ``buf`` must hold the whole header."""
    length = buf[i + 2]
    if buf[i : i + 2] != SYNC or length > MAX_PAYLOAD_BYTES:
        return None
    if crc8(bytes(buf[i + 2 : i + HEADER_BYTES - 1])) != buf[i + HEADER_BYTES - 1]:
        return None
    return OVERHEAD_BYTES + length


def _is_frame(data: bytes) -> bool:
    """``data`` is exactly one frame that passes its header and frame checks."""
    decoder = Decoder()
    decoder.feed(data)
    return decoder.frames == 1 and decoder.pending_bytes == 0


class LinePacer:
    """A token bucket at ``bytes_per_s`` holding at most ``burst_bytes``, capped so that no
    half-open interval of ``window_s`` seconds holds more than ``window_cap_bytes`` (the
    line's capacity in that window, ``floor(bytes_per_s * window_s)``, at least 1).

    ``allowance(wall_s)`` is how many bytes may be written now; ``spend(wall_s, n)`` records
    a write of ``n`` of them. ``peak_window_bytes`` is the largest number of bytes spent in
    any half-open interval of ``window_s`` seconds (the sliding window ends at each write).
    """

    def __init__(self, bytes_per_s: float, burst_bytes: int, window_s: float = 0.1) -> None:
        if not bytes_per_s > 0:
            raise ValueError(f"bytes_per_s = {bytes_per_s!r}: must be > 0")
        if not burst_bytes >= 1:
            raise ValueError(f"burst_bytes = {burst_bytes!r}: must be >= 1")
        self.bytes_per_s = float(bytes_per_s)
        self.burst_bytes = int(burst_bytes)
        self.window_s = float(window_s)
        self.peak_window_bytes = 0
        self.bytes_spent = 0
        self._tokens = float(burst_bytes)
        self._last_s: float | None = None
        self._window: deque[tuple[float, int]] = deque()
        self._window_bytes = 0
        self.window_cap_bytes = max(1, int(self.bytes_per_s * self.window_s))

    @property
    def window_capacity_bytes(self) -> float:
        """What the line carries in ``window_s`` seconds."""
        return self.bytes_per_s * self.window_s

    def _refill(self, wall_s: float) -> None:
        last = self._last_s
        if last is not None and wall_s > last:
            self._tokens = min(
                float(self.burst_bytes), self._tokens + (wall_s - last) * self.bytes_per_s
            )
        if last is None or wall_s > last:
            self._last_s = wall_s

    def _slide(self, wall_s: float) -> None:
        """Forget the writes that no longer lie in the window ending at ``wall_s``."""
        window = self._window
        while window and window[0][0] <= wall_s - self.window_s:
            self._window_bytes -= window.popleft()[1]

    def allowance(self, wall_s: float) -> int:
        """Bytes that may be written at ``wall_s``."""
        self._refill(wall_s)
        self._slide(wall_s)
        return max(0, min(int(self._tokens), self.window_cap_bytes - self._window_bytes))

    def spend(self, wall_s: float, n_bytes: int) -> None:
        """Record that ``n_bytes`` (at most ``allowance(wall_s)``) were written at
        ``wall_s``."""
        if n_bytes <= 0:
            return
        allowed = self.allowance(wall_s)
        if n_bytes > allowed:
            raise ValueError(f"n_bytes = {n_bytes}: more than the allowance {allowed}")
        self._tokens -= n_bytes
        self.bytes_spent += n_bytes
        self._window.append((wall_s, n_bytes))
        self._window_bytes += n_bytes
        self.peak_window_bytes = max(self.peak_window_bytes, self._window_bytes)

    def wait_s(self, n_bytes: int) -> float:
        """Seconds from the last ``allowance``/``spend`` until ``n_bytes`` (capped at the
        bucket and at the window cap) may be written."""
        want = min(n_bytes, self.burst_bytes, self.window_cap_bytes)
        wait = max(0.0, (want - self._tokens) / self.bytes_per_s)
        excess = self._window_bytes + want - self.window_cap_bytes
        if excess > 0 and self._last_s is not None:
            # the window frees room as its oldest writes leave it
            for t_s, n in self._window:
                excess -= n
                if excess <= 0:
                    wait = max(wait, t_s + self.window_s - self._last_s)
                    break
        return wait


class FrameQueue:
    """A byte queue of at most ``max_bytes`` that keeps and drops whole frames.

    ``push(data)`` appends stream bytes; they become units as soon as they form a complete
    frame or a run of non-frame bytes (a frame still arriving waits in the tail).
    ``pop(n)`` takes up to ``n`` bytes from the head. Past ``max_bytes``:

    - ``drop_oldest=True`` (output to a reader that falls behind): the oldest units not yet
      started are dropped, so the reader gets the newest frames; frames whose type is in
      ``expendable_types`` (e.g. telemetry) and runs of noise go first, so that a reader
      that falls behind loses telemetry before it loses an answer;
    - ``drop_oldest=False`` (input from a writer faster than the line): the new units are
      dropped, and once anything was dropped every byte is dropped until the next valid
      frame header, so the consumer never sees the rest of a frame cut short.

    Counters: ``dropped_frames`` (whole frames dropped), ``dropped_bytes`` (all bytes
    dropped, frames and noise).
    """

    def __init__(
        self, max_bytes: int, *, drop_oldest: bool, expendable_types: frozenset[int] = frozenset()
    ) -> None:
        if not max_bytes >= 1:
            raise ValueError(f"max_bytes = {max_bytes!r}: must be >= 1")
        self.max_bytes = max_bytes
        self.drop_oldest = drop_oldest
        self.expendable_types = frozenset(expendable_types)
        self.dropped_frames = 0
        self.dropped_bytes = 0
        self._units: deque[tuple[bytes, bool]] = deque()  # (bytes, is_frame)
        self._head = b""  # the rest of a unit already started: never dropped
        self._queued = 0  # bytes in _units
        self._tail = bytearray()  # not yet a unit
        self._skipping = False  # input side: dropping up to the next frame header
        self._resync = False  # after clear(): the stream restarts at the next frame header

    def __len__(self) -> int:
        """Bytes queued (complete units and the started one; not the tail)."""
        return len(self._head) + self._queued

    @property
    def tail_bytes(self) -> int:
        """Bytes waiting for the rest of a frame."""
        return len(self._tail)

    def push(self, data: bytes) -> None:
        """Append stream bytes."""
        if not data:
            return
        if not self.drop_oldest:
            room = self.max_bytes - len(self) - len(self._tail)
            if len(data) > room:
                # Over the size: split only what fits (a flood costs at most the size per
                # chunk), then drop the rest, the frame it cuts, and everything up to the
                # next frame header after it.
                if room > 0:
                    self._tail += data[:room]
                    self._split()
                self.dropped_bytes += len(self._tail) + len(data) - max(room, 0)
                self._tail.clear()
                self._skipping = True
                return
        self._tail += data
        self._split()

    def flush_tail(self) -> None:
        """The stream went idle: what waits in the tail will not become a frame; queue it
        as noise."""
        if self._tail:
            self._noise(bytes(self._tail))
            self._tail.clear()

    def clear(self) -> int:
        """Drop everything (the peer went away, or a new one came); return the bytes
        dropped. Not counted as drops: nobody is there to miss them. What comes next starts
        at the next frame header (the bytes before it are the rest of a frame the new peer
        never saw the start of)."""
        n = len(self) + len(self._tail)
        self._units.clear()
        self._head = b""
        self._queued = 0
        self._tail.clear()
        self._skipping = False
        self._resync = True
        return n

    def peek(self, n_bytes: int) -> bytes:
        """Up to ``n_bytes`` from the head of the queue, left in place (see ``consume``)."""
        out = bytearray(self._head[:n_bytes])
        for unit, _ in self._units:
            if len(out) >= n_bytes:
                break
            out += unit[: n_bytes - len(out)]
        return bytes(out)

    def consume(self, n_bytes: int) -> None:
        """Remove ``n_bytes`` (at most ``len(self)``) from the head: they were sent. A unit
        cut by this is finished by the next bytes taken, never dropped."""
        while n_bytes > 0:
            if not self._head:
                if not self._units:
                    raise ValueError("consume past the end of the queue")
                unit, _ = self._units.popleft()
                self._queued -= len(unit)
                self._head = unit
            take = min(n_bytes, len(self._head))
            self._head = self._head[take:]
            n_bytes -= take

    def pop(self, n_bytes: int) -> bytes:
        """Take up to ``n_bytes`` from the head of the queue."""
        out = self.peek(n_bytes)
        self.consume(len(out))
        return out

    def _split(self) -> None:
        buf = self._tail
        i = 0
        n = len(buf)
        noise_from = 0
        while i < n:
            j = buf.find(SYNC, i)
            if j < 0:
                # keep a trailing first sync byte: its partner may come next
                i = n - 1 if buf[n - 1] == SYNC[0] else n
                break
            if n - j < HEADER_BYTES:
                i = j
                break
            length = frame_length_at(buf, j)
            if length is None:
                i = j + 1
                continue
            if n - j < length:
                i = j
                break
            if (self._resync or self._skipping) and not _is_frame(bytes(buf[j : j + length])):
                # Restarting mid-stream: a sync pair and header inside the rest of a cut
                # frame pass the 8-bit header check 1 time in 256; only a whole frame that
                # passes the frame check restarts the stream.
                i = j + 1
                continue
            if j > noise_from:
                self._noise(bytes(buf[noise_from:j]))
            self._skipping = self._resync = False
            self._add(bytes(buf[j : j + length]), True)
            i = noise_from = j + length
        if i > noise_from:
            self._noise(bytes(buf[noise_from:i]))
        del buf[:i]

    def _noise(self, data: bytes) -> None:
        if self._resync:
            return
        if self._skipping:
            self.dropped_bytes += len(data)
        else:
            self._add(data, False)

    def _add(self, unit: bytes, is_frame: bool) -> None:
        size = len(unit)
        if self.drop_oldest:
            units = self._units
            units.append((unit, is_frame))
            self._queued += size
            while len(self) > self.max_bytes and len(units) > 1:
                k = self._first_expendable()
                old, old_is_frame = units[k]
                del units[k]
                self._queued -= len(old)
                self._count_drop(old, old_is_frame)
            return
        if len(self) + size > self.max_bytes:
            self._count_drop(unit, is_frame)
            self._skipping = True
            return
        self._units.append((unit, is_frame))
        self._queued += size

    def _first_expendable(self) -> int:
        """Index of the unit to drop first: the oldest noise or expendable frame, else the
        oldest unit (never the newest, which was just added)."""
        if self.expendable_types:
            for k in range(len(self._units) - 1):
                unit, is_frame = self._units[k]
                if not is_frame or unit[3] in self.expendable_types:  # [3]: the type byte
                    return k
        return 0

    def _count_drop(self, unit: bytes, is_frame: bool) -> None:
        self.dropped_bytes += len(unit)
        self.dropped_frames += is_frame
