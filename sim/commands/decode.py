"""``turntable-sim decode FILE``: decode a raw captured byte stream (board → PC, or PC →
board) to CSV and print the link statistics."""

from __future__ import annotations

import argparse
import sys

HELP = "decode a raw captured serial byte stream to CSV and print link statistics"

CHUNK_BYTES = 1 << 16


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="raw bytes as captured from the line ('-' for stdin)")
    parser.add_argument(
        "-o",
        "--csv",
        metavar="OUT",
        help="write the telemetry to this CSV file ('-' for stdout; default: FILE.csv)",
    )
    parser.add_argument(
        "--tick-hz", type=float, default=500.0, help="servo rate for the t_s column (500)"
    )
    parser.add_argument(
        "--messages",
        action="store_true",
        help="also print every non-telemetry message (answers, fault reports, commands)",
    )


def main(args: argparse.Namespace) -> int:
    import contextlib
    from collections import Counter

    from serial_protocol.exceptions import CommandError
    from serial_protocol.frame import Decoder
    from serial_protocol.messages import Malformed, Telemetry
    from serial_protocol.telemetry_csv import TelemetryCsvWriter

    csv_path = args.csv if args.csv is not None else f"{args.file}.csv"
    if args.file == "-" and args.csv is None:
        csv_path = "-"
    report = sys.stderr if csv_path == "-" else sys.stdout
    decoder = Decoder()
    kinds: Counter[str] = Counter()
    tick_steps: Counter[int] = Counter()
    last_tick: int | None = None
    total_bytes = 0
    with contextlib.ExitStack() as stack:
        try:
            if args.file == "-":
                source = sys.stdin.buffer
            else:
                source = stack.enter_context(open(args.file, "rb"))
        except OSError as exc:
            raise CommandError(f"cannot read {args.file!r}: {exc.strerror}") from exc
        try:
            if csv_path == "-":
                out = sys.stdout
            else:
                out = stack.enter_context(open(csv_path, "w", newline=""))
        except OSError as exc:
            raise CommandError(f"cannot write {csv_path!r}: {exc.strerror}") from exc
        writer = TelemetryCsvWriter(out, args.tick_hz)

        def handle(messages: list) -> None:
            nonlocal last_tick
            for msg in messages:
                kinds[type(msg).__name__] += 1
                if isinstance(msg, Telemetry):
                    writer.write(msg)
                    if last_tick is not None:
                        tick_steps[(msg.tick - last_tick) & 0xFFFFFFFF] += 1
                    last_tick = msg.tick
                elif args.messages or isinstance(msg, Malformed):
                    print(f"  {msg}", file=report)

        while chunk := source.read(CHUNK_BYTES):
            total_bytes += len(chunk)
            handle(decoder.feed(chunk))
        handle(decoder.flush())

    stats = decoder.stats()
    print(f"decoded {total_bytes} bytes from {args.file}", file=report)
    for name, count in sorted(kinds.items()):
        print(f"  {name:<14} {count}", file=report)
    print(
        f"  frames {stats.frames}, malformed {stats.malformed}, crc errors {stats.crc_errors}, "
        f"header errors {stats.header_errors}, resyncs {stats.resyncs}, "
        f"bytes dropped {stats.bytes_dropped}, sequence gaps {stats.seq_gaps} "
        f"(~{stats.frames_missed} frames lost)",
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
