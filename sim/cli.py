"""The ``turntable-sim`` console command.

Each subcommand is a module in ``sim/commands/`` with ``HELP`` (one line),
``add_arguments(parser)`` and ``main(args) -> int``. Modules are imported only when their
subcommand runs, so ``turntable-sim --help`` stays fast. Nothing imports this module.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from serial_protocol.exceptions import TurntableError

# name -> (module, one-line help). Add a line here when a subcommand lands.
COMMANDS: dict[str, tuple[str, str]] = {
    "reproduce": ("sim.commands.reproduce", "the paper's Fig. 6-8 and Table 1: PNGs and REPORT.md"),
    "run": ("sim.commands.run", "run a scripted experiment (TOML) and write log.csv and plot.png"),
    "decode": ("sim.commands.decode", "decode a raw captured serial byte stream to CSV"),
    "monitor": ("sim.commands.monitor", "talk to a board or 'serve --pty': commands, status, CSV"),
    "serve": ("sim.commands.serve", "run the simulated bench in real time behind a pty"),
    "tune": ("sim.commands.tune", "tune the three loops' gains offline; writes a tuned TOML"),
    "plot": ("sim.commands.plot", "plot any log.csv, telemetry CSV, capture or CAN log"),
    "replay": ("sim.commands.replay", "play a capture or CAN log back at its recorded pace"),
}


class _HelpFormatter(argparse.HelpFormatter):
    """argparse sizes the help column before the subcommands are added, so a long command
    name ("reproduce") would push its help to the next line; reserve room for it."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog)
        self._action_max_length = 4 + max(map(len, COMMANDS), default=0)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="turntable-sim",
        description="Firmware-in-the-loop simulator of the seed-000 servo turntable.",
        formatter_class=_HelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module_name)
        importlib.import_module(module_name).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    module = importlib.import_module(args._module)
    try:
        return int(module.main(args) or 0)
    except TurntableError as exc:
        print(f"turntable-sim {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"turntable-sim {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
