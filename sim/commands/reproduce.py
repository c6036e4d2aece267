"""``turntable-sim reproduce [--out DIR] [--quick]``: run the paper's experiments and the
extras, write the figures and REPORT.md (see README, "Reproduce the paper")."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sim.commands._common import integer, output_dir

HELP = "reproduce the paper's Fig. 6-8 / Table 1 and seed 002's tables: PNGs and REPORT.md"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", type=Path, default=Path("reproduce_out"),
        help="output directory (default: ./reproduce_out)",
    )  # fmt: skip
    parser.add_argument(
        "--quick", action="store_true",
        help="every time divided by 4 (same planning problems, shorter runs); about 1.3x "
        "faster, not 4x: start-up, Fig. 6, seed 002 and the figures stay (README)",
    )  # fmt: skip
    parser.add_argument(
        "--paper-only", action="store_true",
        help="only Fig. 6-8 (no seed 002 tables, S-curve or look-ahead runs)",
    )  # fmt: skip
    parser.add_argument(
        "--sensitivity", action="store_true",
        help="the full sensitivity study: Fig. 6 over 27 motors (R, Kt, J x0.7/1/1.3) with "
        "every plant effect on every motor, Fig. 7-8 as run (default: a cheap form)",
    )  # fmt: skip
    parser.add_argument(
        "--retune", choices=("classic", "de"), default="classic",
        help="how the study re-tunes each motor's gains: the tuner's classic baseline "
        "(default, instant) or its differential evolution (seconds per motor)",
    )  # fmt: skip
    parser.add_argument(
        "--noise-copies", type=integer(2, 64), default=None, metavar="N",
        help="noise realisations of every run (the report's error bars: mean ± sd), 2..64 "
        "(default 3; 5 with --sensitivity)",
    )  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress display or summary")


def execute(args: argparse.Namespace):
    """Run the reproduction for parsed ``args``; returns ``sim.reproduce.ReproduceOutput``."""
    from sim.reproduce import reproduce

    return reproduce(
        args.out,
        quick=args.quick,
        extras=not args.paper_only,
        show_progress=not args.quiet,
        sensitivity=args.sensitivity,
        retune=args.retune,
        noise_copies=args.noise_copies,
    )


def main(args: argparse.Namespace) -> int:
    from sim.progress import format_duration

    with output_dir(args.out, ("*.png", "REPORT.md", "telemetry/*.csv")):
        result = execute(args)
    if not args.quiet:
        print(
            f"reproduce: {result.simulated_s:.0f} s simulated in "
            f"{format_duration(result.wall_s)} of wall time",
            file=sys.stderr,
        )
        for path in result.paths:
            print(f"wrote {path}")
    return 0
