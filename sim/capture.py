"""Captures with timestamps: what came off the line, and when.

A serial capture (``monitor --capture FILE``, ``serve --capture``) is the received bytes in
chunks, each with the host's wall time since the capture began, so ``replay`` can play it at
its recorded pace (as python-can's ``can.player`` plays a CAN log). The file is::

    b"TTCAP1\\n"                                 magic, 7 bytes
    then per chunk: <f8 wall_s> <u4 n_bytes> <n_bytes of data>   (little-endian)

A file without the magic is a plain raw capture (the bytes only); :func:`read_chunks` reads
both, giving a plain capture one chunk at time 0. CAN captures are python-can's own logs
(``.asc``, ``.blf``, ``.trc``), which carry a timestamp per frame already.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

__all__ = [
    "CAN_LOG_SUFFIXES",
    "MAGIC",
    "TimestampedCapture",
    "is_can_log",
    "is_timestamped",
    "read_chunks",
]

MAGIC = b"TTCAP1\n"
_HEADER = struct.Struct("<dI")
#: python-can log formats (read with ``can.LogReader``).
CAN_LOG_SUFFIXES = (".asc", ".blf", ".trc")
#: Plain raw captures are read in chunks of this size.
CHUNK_BYTES = 1 << 16


def is_can_log(path: str | Path) -> bool:
    """True for a python-can log file (by its suffix)."""
    return str(path).lower().endswith(CAN_LOG_SUFFIXES)


class TimestampedCapture:
    """A binary file object that records every ``write(data)`` as a timestamped chunk.

    Hand it to ``SerialLink(capture=...)`` in place of a plain file. ``clock`` returns wall
    seconds (injectable for tests); times are stored relative to the first call.
    """

    def __init__(self, out: BinaryIO, clock: Callable[[], float] = time.monotonic) -> None:
        self._out = out
        self._clock = clock
        self._start_wall_s = clock()
        out.write(MAGIC)

    def write(self, data: bytes) -> int:
        if data:
            wall_s = self._clock() - self._start_wall_s
            self._out.write(_HEADER.pack(wall_s, len(data)) + bytes(data))
        return len(data)

    def flush(self) -> None:
        self._out.flush()

    def close(self) -> None:
        self._out.close()

    def __enter__(self) -> TimestampedCapture:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def is_timestamped(path: str | Path) -> bool:
    """True if ``path`` starts with the timestamped capture's magic."""
    with open(path, "rb") as f:
        return f.read(len(MAGIC)) == MAGIC


def read_chunks(source: BinaryIO) -> Iterator[tuple[float, bytes]]:
    """``(wall_s, data)`` of each chunk of a capture (timestamped or plain).

    A truncated last chunk (a capture cut off mid-write) gives the bytes that are there.
    """
    head = source.read(len(MAGIC))
    if head != MAGIC:
        if head:
            yield 0.0, head
        while chunk := source.read(CHUNK_BYTES):
            yield 0.0, chunk
        return
    while True:
        header = source.read(_HEADER.size)
        if len(header) < _HEADER.size:
            return
        wall_s, n = _HEADER.unpack(header)
        data = source.read(n)
        if data:
            yield wall_s, data
        if len(data) < n:
            return
