"""``turntable-sim replay CAPTURE``: play a capture back at its recorded pace, as python-can's
``can.player`` plays a CAN log.

* A serial capture (``monitor --capture``, timestamped; or a raw one, paced by ``--baud``)
  is written to ``--to``: a pyserial URL or port (``/dev/pts/N``, ``socket://host:port``) or
  ``-`` for standard output, so that it can be piped into ``decode -``::

      turntable-sim replay run.cap --to - | turntable-sim decode - -o run.csv

* A CAN log (``.asc``, ``.blf``, ``.trc``) is sent to ``--to can://INTERFACE/CHANNEL``
  frame by frame at the logged times.

``--speed 2`` plays twice as fast, ``--speed inf`` as fast as the receiver takes it.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

HELP = "play a capture or CAN log back at its recorded pace (to a port, a CAN bus or stdout)"

T = TypeVar("T")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("capture", help="timestamped or raw serial capture, or a CAN log")
    parser.add_argument(
        "--to",
        default="-",
        metavar="URL",
        help="where to play it: '-' (stdout, the default), a serial port or pyserial URL, or "
        "can://INTERFACE/CHANNEL for a CAN log",
    )
    parser.add_argument(
        "--speed", type=float, default=1.0, help="times faster than recorded (1; inf = no pause)"
    )
    parser.add_argument(
        "--baud",
        type=int,
        default=460800,
        help="pace of a raw capture without timestamps: bytes at this line rate (460800)",
    )
    parser.add_argument("--quiet", action="store_true", help="no summary on stderr")


def schedule(
    items: Iterable[tuple[float, T]],
    speed: float,
    *,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[T]:
    """Yield each ``(t_s, item)``'s item at ``t_s / speed`` after the first (wall clock).

    Times are relative to the first item; one that is late is yielded at once (the ones
    after it keep their own times, so a slow receiver does not stretch the whole replay).
    """
    start_wall_s: float | None = None
    t0_s = 0.0
    for t_s, item in items:
        if start_wall_s is None:
            start_wall_s, t0_s = clock(), t_s
        elif math.isfinite(speed):
            wait_s = start_wall_s + (t_s - t0_s) / speed - clock()
            if wait_s > 0:
                sleep(wait_s)
        yield item


def raw_times(chunks: Iterable[tuple[float, bytes]], baud: int) -> Iterator[tuple[float, bytes]]:
    """Times for a capture without them: each chunk when a line at ``baud`` (8N1, 10 bits a
    byte) would have delivered it, in pieces of at most 1 ms of line time."""
    t_s = 0.0
    per_byte_s = 10.0 / baud
    piece = max(1, int(0.001 / per_byte_s))
    for _, data in chunks:
        for k in range(0, len(data), piece):
            part = data[k : k + piece]
            yield t_s, part
            t_s += len(part) * per_byte_s


#: The slowest ``--speed`` (a recorded second lasts 11.6 days).
MIN_SPEED = 1e-6


def main(args: argparse.Namespace) -> int:
    import contextlib

    from serial_protocol.exceptions import CommandError
    from sim.capture import is_can_log, is_timestamped, read_chunks

    # A slower speed stretches a 1 s gap past what the clock can sleep (1e-320 overflowed
    # time_t: found by the CLI fuzz); also NaN.
    if not args.speed >= MIN_SPEED:
        raise CommandError(
            f"--speed {args.speed!r}: must be >= {MIN_SPEED:g} (times the recorded pace; "
            "inf: no pause)"
        )
    if args.baud <= 0:
        raise CommandError(f"--baud {args.baud!r}: must be > 0")
    if is_can_log(args.capture):
        return _replay_can(args)
    if args.to.startswith("can://"):
        raise CommandError(f"--to {args.to!r}: a serial capture plays to a port or '-'")
    try:
        stamped = is_timestamped(args.capture)
        source = open(args.capture, "rb")  # noqa: SIM115 - closed by the ExitStack
    except OSError as exc:
        raise CommandError(f"cannot read {args.capture!r}: {exc.strerror}") from None
    with contextlib.ExitStack() as stack:
        stack.enter_context(source)
        write, flush = _sink(args.to, stack)
        chunks = read_chunks(source)
        timed = chunks if stamped else raw_times(chunks, args.baud)
        sent = 0
        start_wall_s = time.monotonic()
        try:
            for data in schedule(timed, args.speed):
                write(data)
                flush()
                sent += len(data)
        except BrokenPipeError:
            # the reader went away (e.g. "| head"): stop quietly, as a shell tool does, and
            # point stdout at /dev/null so that Python's exit flush does not fail again
            import os

            with contextlib.suppress(OSError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 0
        except OSError as exc:
            raise CommandError(f"cannot write to {args.to!r}: {exc}") from None
        wall_s = time.monotonic() - start_wall_s
    if not args.quiet:
        pace = "recorded times" if stamped else f"{args.baud} baud"
        print(
            f"replayed {sent} bytes of {args.capture} to {args.to} in {wall_s:.2f} s "
            f"({pace}, speed {args.speed:g})",
            file=sys.stderr,
        )
    return 0


#: Seconds a write to a port may block before the replay stops (nobody reads the port).
WRITE_TIMEOUT_S = 2.0


def _sink(to: str, stack: Any) -> tuple[Callable[[bytes], Any], Callable[[], None]]:
    if to == "-":
        out = sys.stdout.buffer
        return out.write, out.flush
    from serial_protocol.transport import open_serial

    port = open_serial(to, 460800)  # LinkError (a TurntableError) names the URL
    stack.callback(port.close)
    # A port nobody reads (loop://, a pty without a reader, flow control held) would block
    # the write for ever; pyserial then raises SerialTimeoutException, an OSError.
    port.write_timeout = WRITE_TIMEOUT_S

    def write(data: bytes) -> None:
        import queue

        import serial

        try:
            port.write(data)
        except queue.Full:  # pyserial's loop:// times out with its queue's exception
            raise serial.SerialTimeoutException("Write timeout (nothing reads the port)") from None

    return write, port.flush


def _replay_can(args: argparse.Namespace) -> int:
    import can

    from serial_protocol.exceptions import CommandError

    if not args.to.startswith("can://"):
        raise CommandError(f"--to {args.to!r}: a CAN log plays to can://INTERFACE/CHANNEL")
    interface, _, channel = args.to[len("can://") :].partition("/")
    if not interface or not channel:
        raise CommandError(f"--to {args.to!r}: expected can://INTERFACE/CHANNEL")
    try:
        frames = [(float(m.timestamp), m) for m in can.LogReader(args.capture)]
    except (OSError, ValueError) as exc:
        raise CommandError(f"cannot read the CAN log {args.capture!r}: {exc}") from None
    try:
        bus = can.Bus(interface=interface, channel=channel)
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        raise CommandError(f"cannot open CAN {args.to!r}: {exc}") from None
    start_wall_s = time.monotonic()
    sent = 0
    try:
        for msg in schedule(frames, args.speed):
            bus.send(msg)
            sent += 1
    except can.CanError as exc:
        raise CommandError(f"CAN send on {args.to!r} failed: {exc}") from None
    finally:
        bus.shutdown()
    if not args.quiet:
        print(
            f"replayed {sent} CAN frames of {args.capture} to {args.to} in "
            f"{time.monotonic() - start_wall_s:.2f} s (speed {args.speed:g})",
            file=sys.stderr,
        )
    return 0
