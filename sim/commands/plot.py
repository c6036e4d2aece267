"""``turntable-sim plot FILE... [-o OUT]``: the paper-style figure of any recorded run.

Reads a ``run`` log (``log.csv``), a telemetry CSV (``monitor --csv``, ``decode``), a serial
capture (raw or timestamped) or a CAN log (``.asc``/``.blf``/``.trc``), each recognised by
its content (``sim.runfile``). Several files are overlaid, one colour each (a simulation
against a real bench's capture). The output format follows the extension: PNG, SVG or PDF.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "plot any log.csv, telemetry CSV, capture or CAN log: the paper-style figure"

FORMATS = (".png", ".svg", ".pdf")
COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "files",
        nargs="+",
        metavar="FILE",
        help="log.csv, telemetry CSV, raw/timestamped capture or CAN log; several overlay",
    )
    parser.add_argument(
        "-o",
        "--out",
        metavar="OUT",
        help="figure file: .png, .svg or .pdf (default: the first FILE with .png)",
    )
    parser.add_argument("--dpi", type=float, default=110.0, help="resolution of a PNG (110)")
    parser.add_argument("--title", help="figure title (default: the file names)")
    parser.add_argument(
        "--tick-hz", type=float, default=500.0, help="servo rate of captures and CAN logs (500)"
    )
    parser.add_argument(
        "--current-limit",
        type=float,
        metavar="AMPS",
        help="draw the firmware's current limit at +-AMPS",
    )
    parser.add_argument(
        "--align",
        action="store_true",
        help="start every file's time at 0 (captures taken at different moments)",
    )
    parser.add_argument(
        "--acceleration",
        action="store_true",
        help="add the planned acceleration and jerk panel",
    )
    parser.add_argument(
        "--no-bus",
        action="store_true",
        help="leave out the measured bus voltage (drawn on the current panel's right axis "
        "when the file carries it)",
    )


def main(args: argparse.Namespace) -> int:
    import dataclasses
    import math

    from serial_protocol.exceptions import CommandError
    from sim.reproduce.plots import SHAFT_NOTE, Curve, paper_figure
    from sim.runfile import load_trace

    out = Path(args.out) if args.out else Path(args.files[0]).with_suffix(".png")
    if out.suffix.lower() not in FORMATS:
        raise CommandError(f"--out {str(out)!r}: the extension must be one of {FORMATS}")
    if not (math.isfinite(args.dpi) and 10.0 <= args.dpi <= 2400.0):
        raise CommandError(f"--dpi {args.dpi!r}: must be between 10 and 2400")
    if args.current_limit is not None and not (
        math.isfinite(args.current_limit) and args.current_limit > 0
    ):
        raise CommandError(f"--current-limit {args.current_limit!r}: must be > 0 A")
    if out.is_dir():
        raise CommandError(f"--out {str(out)!r} is a folder: name a file")
    if not out.parent.is_dir():
        raise CommandError(f"--out {str(out)!r}: no folder {str(out.parent)!r}")
    curves = []
    for k, name in enumerate(args.files):
        trace = load_trace(name, tick_hz=args.tick_hz)
        if args.align:
            trace = dataclasses.replace(trace, t_s=trace.t_s - trace.t_s[0])
        curves.append(Curve(trace, trace.name, COLORS[k % len(COLORS)]))
    title = args.title or "  vs  ".join(c.trace.name for c in curves)
    fig = paper_figure(
        curves,
        None,
        title=title,
        current_limit_a=args.current_limit,
        acceleration=args.acceleration,
        bus=not args.no_bus,
        pos_scale=1.0,
        pos_label="output shaft\nposition (°)",
        note="Measured: the board's velocity estimate and IS-pin current. " + SHAFT_NOTE,
    )
    try:
        fig.savefig(out, dpi=args.dpi)
    except OSError as exc:
        raise CommandError(f"cannot write {str(out)!r}: {exc.strerror or exc}") from None
    frames = ", ".join(f"{c.trace.name}: {len(c.trace.t_s)} rows" for c in curves)
    print(f"wrote {out} ({frames})")
    return 0
