# PYTHON_ARGCOMPLETE_OK  (argcomplete's global completion looks for this marker)
"""The ``turntable-sim`` console command.

Each subcommand is a module in ``sim/commands/`` with ``HELP`` (one line),
``add_arguments(parser)`` and ``main(args) -> int``. The modules import their heavy parts
only when their subcommand runs, so ``turntable-sim --help`` and tab completion stay fast.
Nothing imports this module.

Exit status: 0 done, 1 the link failed during the work (monitor), 2 a bad argument, file or
config value (one line naming it, never a traceback), 70 an internal error (a bug: one line,
``TURNTABLE_SIM_TRACEBACK=1`` shows the traceback), 130 interrupted by Ctrl-C.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import typing

from serial_protocol.exceptions import TurntableError

#: Exit status of an unexpected exception (sysexits.h EX_SOFTWARE).
EXIT_INTERNAL = 70

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
    "ports": ("sim.commands.ports", "list the serial ports of this machine (pyserial)"),
}


class _HelpFormatter(argparse.HelpFormatter):
    """argparse sizes the help column before the subcommands are added, so a long command
    name ("reproduce") would push its help to the next line; reserve room for it."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog)
        self._action_max_length = 4 + max(map(len, COMMANDS), default=0)


class _Parser(argparse.ArgumentParser):
    """argparse with a usage error as one line (the usage itself is one ``--help`` away)."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def version_text() -> str:
    """``turntable-sim X.Y.Z (protocol N, Python A.B.C)``."""
    from importlib import metadata

    from serial_protocol.messages import PROTOCOL_VERSION

    try:
        version = metadata.version("turntable-sim")
    except metadata.PackageNotFoundError:  # run from a source tree that is not installed
        version = "unknown (not installed)"
    python = ".".join(map(str, sys.version_info[:3]))
    return f"turntable-sim {version} (protocol {PROTOCOL_VERSION}, Python {python})"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="turntable-sim",
        description="Firmware-in-the-loop simulator of the seed-000 servo turntable.",
        formatter_class=_HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=version_text())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module_name)
        importlib.import_module(module_name).add_arguments(p)
    _add_completers(sub)
    return parser


def _add_completers(sub: argparse._SubParsersAction) -> None:
    """Tab completion beyond option names: TOML files for configs, serial ports and URL
    schemes for ``monitor``. argcomplete reads the ``completer`` attribute of an action."""
    try:
        from argcomplete.completers import FilesCompleter
    except ImportError:  # completion is optional at run time
        return
    toml = FilesCompleter(allowednames=("toml",), directories=True)
    for name, parser in sub.choices.items():
        for action in parser._actions:
            if action.dest in ("config", "bench"):
                action.completer = toml  # type: ignore[attr-defined]
            elif name == "monitor" and action.dest == "url":
                action.completer = _complete_url  # type: ignore[attr-defined]


def _complete_url(prefix: str, **_: object) -> list[str]:
    """The serial ports of this machine and the URL schemes ``monitor`` opens."""
    from serial.tools import list_ports

    ports = [p.device for p in list_ports.comports()]
    schemes = ["socket://127.0.0.1:", "can://socketcan/", "can://virtual/", "loop://"]
    return [c for c in ports + schemes if c.startswith(prefix)]


def _complete(parser: argparse.ArgumentParser) -> None:
    """Answer a shell's completion request (``_ARGCOMPLETE`` set) and exit; else nothing."""
    if "_ARGCOMPLETE" not in os.environ:
        return
    try:
        import argcomplete
    except ImportError:
        return
    argcomplete.autocomplete(parser)


def main(argv: list[str] | None = None) -> int:
    """Run the command line ``argv``; returns the exit status (never raises, except on a
    bug with ``TURNTABLE_SIM_TRACEBACK=1``)."""
    parser = build_parser()
    _complete(parser)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) or a usage error (2, already printed)
        return exc.code if isinstance(exc.code, int) else 2
    if args.command is None:
        parser.print_help()
        return 2
    name = f"turntable-sim {args.command}"
    try:
        module = importlib.import_module(args._module)
        return int(module.main(args) or 0)
    except TurntableError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of our stdout went away (``... | head``)
        _silence_stdout()
        return 0
    except OSError as exc:  # a file or device the user named: one line naming it
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{name}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except Exception as exc:
        if os.environ.get("TURNTABLE_SIM_TRACEBACK"):
            raise
        print(
            f"{name}: internal error: {type(exc).__name__}: {exc} (a bug; please report it "
            "with the command line; TURNTABLE_SIM_TRACEBACK=1 shows the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's final flush does not fail too."""
    with open(os.devnull, "w") as devnull:
        os.dup2(devnull.fileno(), sys.stdout.fileno())


if __name__ == "__main__":
    sys.exit(main())
