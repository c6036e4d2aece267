"""``turntable-sim decode FILE``: decode a raw captured byte stream (board → PC, or PC →
board) to CSV and print the link statistics. A python-can log (``.asc``, ``.blf``, ``.trc``,
as ``monitor can://... --capture`` writes) is reassembled from its CAN frames instead."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

from sim.commands._common import integer, number

HELP = "decode a raw captured serial byte stream to CSV and print link statistics"

CHUNK_BYTES = 1 << 16
CAN_LOG_SUFFIXES = (".asc", ".blf", ".trc")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "file",
        help="bytes as captured from the line, raw or timestamped (monitor --capture); "
        "'-' for stdin",
    )
    parser.add_argument(
        "-o",
        "--csv",
        metavar="OUT",
        help="write the telemetry to this CSV file ('-' for stdout; default: FILE.csv)",
    )
    parser.add_argument(
        "--tick-hz",
        type=number(lo=0.0, lo_open=True, hi=1e6),
        default=500.0,
        help="servo rate for the t_s column (500)",
    )
    parser.add_argument(
        "--can-base-id",
        type=integer(0, 0x7FF),
        default=0x100,
        help="CAN logs: identifier of message type 0 (0x100)",
    )
    parser.add_argument(
        "--messages",
        action="store_true",
        help="also print every non-telemetry message (answers, fault reports, commands)",
    )


def main(args: argparse.Namespace) -> int:
    import contextlib
    import os
    from collections import Counter

    from serial_protocol.exceptions import CommandError
    from serial_protocol.frame import Decoder
    from serial_protocol.messages import Malformed, Telemetry
    from serial_protocol.telemetry_csv import TelemetryCsvWriter
    from sim.capture import read_chunks

    csv_path = args.csv if args.csv is not None else f"{args.file}.csv"
    if args.file == "-" and args.csv is None:
        csv_path = "-"
    report = sys.stderr if csv_path == "-" else sys.stdout
    decoder = Decoder()
    kinds: Counter[str] = Counter()
    tick_steps: Counter[int] = Counter()
    last_tick: int | None = None
    total_bytes = 0
    is_can_log = args.file.lower().endswith(CAN_LOG_SUFFIXES)
    with contextlib.ExitStack() as stack:
        try:
            if args.file == "-":
                source = sys.stdin.buffer
            elif is_can_log:
                source = None
            else:
                source = stack.enter_context(open(args.file, "rb"))
        except OSError as exc:
            raise CommandError(f"cannot read {args.file!r}: {exc.strerror}") from exc
        if csv_path != "-" and os.path.isdir(csv_path):
            raise CommandError(f"cannot write {csv_path!r}: it is a folder")
        writer: TelemetryCsvWriter | None = None

        def open_writer() -> TelemetryCsvWriter:
            # Opened at the first decoded message: a file that holds none is an error and
            # leaves no empty CSV behind.
            try:
                if csv_path == "-":
                    out = sys.stdout
                else:
                    out = stack.enter_context(open(csv_path, "w", newline=""))
            except OSError as exc:
                raise CommandError(f"cannot write {csv_path!r}: {exc.strerror}") from exc
            return TelemetryCsvWriter(out, args.tick_hz)

        def handle(messages: list) -> None:
            nonlocal last_tick, writer
            for msg in messages:
                if writer is None:
                    writer = open_writer()
                kinds[type(msg).__name__] += 1
                if isinstance(msg, Telemetry):
                    writer.write(msg)
                    if last_tick is not None:
                        tick_steps[(msg.tick - last_tick) & 0xFFFFFFFF] += 1
                    last_tick = msg.tick
                elif args.messages or isinstance(msg, Malformed):
                    print(f"  {msg}", file=report)

        if is_can_log:
            reassembler = _decode_can_log(args.file, args.can_base_id, handle)
        else:
            # a raw capture, or a timestamped one (monitor --capture): the bytes either way
            for _, chunk in read_chunks(source):
                total_bytes += len(chunk)
                handle(decoder.feed(chunk))
            handle(decoder.flush())
        if writer is None:
            what = "CAN frame of the protocol" if is_can_log else "frame of the protocol"
            size = "" if is_can_log else f" in {total_bytes} bytes"
            raise CommandError(
                f"{args.file}: no {what} found{size} (not a capture of the turntable link?); "
                "nothing written"
            )

    if is_can_log:
        c = reassembler.stats
        print(f"decoded {c.frames} CAN frames from {args.file}", file=report)
    else:
        print(f"decoded {total_bytes} bytes from {args.file}", file=report)
    for name, count in sorted(kinds.items()):
        print(f"  {name:<14} {count}", file=report)
    if is_can_log:
        print(
            f"  messages {c.messages}, malformed {c.malformed}, reassembly errors "
            f"{c.reassembly_errors}, other identifiers {c.foreign_ids}",
            file=report,
        )
    else:
        stats = decoder.stats()
        print(
            f"  frames {stats.frames}, malformed {stats.malformed}, crc errors "
            f"{stats.crc_errors}, header errors {stats.header_errors}, resyncs "
            f"{stats.resyncs}, bytes dropped {stats.bytes_dropped}, sequence gaps "
            f"{stats.seq_gaps} (~{stats.frames_missed} frames lost)",
            file=report,
        )
    if tick_steps:
        # the telemetry period is the most common tick step; the others are gaps
        step = tick_steps.most_common(1)[0][0]
        irregular = sum(n for s, n in tick_steps.items() if s != step)
        print(
            f"  telemetry every {step} ticks; {irregular} irregular steps in the tick count",
            file=report,
        )
    if csv_path != "-":
        print(f"wrote {writer.rows} telemetry rows to {csv_path}", file=report)
    return 0


def _decode_can_log(path: str, base_id: int, handle: Callable[[list], None]) -> Any:
    """Feed every classic CAN frame of a python-can log through a ``CanReassembler``."""
    import can

    from serial_protocol.can_link import CanReassembler
    from serial_protocol.exceptions import CommandError

    reassembler = CanReassembler(base_id)
    try:
        reader = can.LogReader(path)
        for frame in reader:
            if not frame.is_extended_id and not frame.is_remote_frame:
                msg = reassembler.feed(frame.arbitration_id, bytes(frame.data))
                if msg is not None:
                    handle([msg])
    except (OSError, ValueError) as exc:
        raise CommandError(f"cannot read the CAN log {path!r}: {exc}") from exc
    return reassembler
