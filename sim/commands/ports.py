"""``turntable-sim ports [REGEX] [-v]``: the serial ports of this machine, from pyserial's
``serial.tools.list_ports`` (what ``python -m serial.tools.list_ports`` prints), to find the
board's USB–serial adapter for ``monitor``. ``serve --pty`` prints its own ``/dev/pts/N``
(a pty is not listed: it is not a hardware port)."""

from __future__ import annotations

import argparse
import re
import sys

HELP = "list the serial ports of this machine (pyserial), to find the board for 'monitor'"


def _regex(text: str) -> re.Pattern[str]:
    try:
        return re.compile(text, re.IGNORECASE)
    except re.error as exc:
        raise argparse.ArgumentTypeError(f"{text!r} is not a regular expression: {exc}") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "regex",
        nargs="?",
        type=_regex,
        help="only ports whose device, description or hardware id match (case-insensitive)",
    )
    parser.add_argument(
        "-v", "--verbose", action="store_true", help="also the hardware id (USB VID:PID, serial)"
    )


def main(args: argparse.Namespace) -> int:
    from serial.tools import list_ports

    ports = sorted(list_ports.comports(), key=lambda p: p.device)
    if args.regex is not None:
        ports = [
            p
            for p in ports
            if any(args.regex.search(s or "") for s in (p.device, p.description, p.hwid))
        ]
    if not ports:
        what = f" matching {args.regex.pattern!r}" if args.regex is not None else ""
        print(f"no serial ports found{what}", file=sys.stderr)
        return 0
    width = max(len(p.device) for p in ports)
    for p in ports:
        line = f"{p.device:<{width}}  {p.description}"
        if args.verbose:
            line += f"  [{p.hwid}]"
        print(line)
    print(f"{len(ports)} port{'s' if len(ports) != 1 else ''}", file=sys.stderr)
    return 0
