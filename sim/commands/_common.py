"""What the subcommands share: argument types that refuse bad values at parse time (one line,
exit status 2, the option named by argparse), and the output folder of ``run``, ``tune`` and
``reproduce`` (checked before the work starts; after Ctrl-C or an error, removed again if it
is still empty, and what was kept is said)."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

__all__ = ["integer", "number", "output_dir", "tcp_port", "wire_number"]


def number(
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    allow_inf: bool = False,
) -> Callable[[str], float]:
    """An argparse ``type``: a float in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``), finite
    unless ``allow_inf`` (``inf`` above ``lo`` only)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if math.isnan(value) or (math.isinf(value) and not (allow_inf and value > 0)):
            raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number")
        if lo is not None and (value < lo or (lo_open and value == lo)):
            raise argparse.ArgumentTypeError(f"{text!r}: must be {'>' if lo_open else '>='} {lo:g}")
        if hi is not None and value > hi:
            raise argparse.ArgumentTypeError(f"{text!r}: must be <= {hi:g}")
        return value

    parse.__name__ = "number"
    return parse


def integer(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """An argparse ``type``: an integer in ``[lo, hi]`` (``0x`` prefixes allowed)."""

    def parse(text: str) -> int:
        try:
            value = int(text, 0)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            span = f"{'' if lo is None else lo} .. {'' if hi is None else hi}".strip()
            raise argparse.ArgumentTypeError(f"{text!r}: must be in {span}")
        return value

    parse.__name__ = "integer"
    return parse


tcp_port = integer(0, 65535)


def wire_number(cls: type, field: str) -> Callable[[str], float | int]:
    """An argparse ``type``: a finite number that field ``field`` of message ``cls`` can carry
    on the wire (asked of the codec, ``sim.wire``); whether the board accepts it is the
    board's to say, with a NACK."""

    def parse(text: str) -> float | int:
        import typing

        from sim import wire

        is_int = typing.get_type_hints(cls).get(field) is int
        value: float | int = integer()(text) if is_int else number()(text)
        if not wire.fits(cls, field, value):
            lo, hi = wire.field_range(cls, field)
            raise argparse.ArgumentTypeError(
                f"{text!r}: does not fit the wire ({cls.__name__}.{field} holds "
                f"{lo:.10g} .. {hi:.10g})"
            )
        return value

    parse.__name__ = "number"
    return parse


def _files(folder: Path, outputs: tuple[str, ...]) -> dict[Path, int]:
    """The files of ``folder`` matching the glob patterns ``outputs``, with their
    modification times (ns)."""
    found = {}
    for pattern in outputs:
        for p in folder.glob(pattern):
            with contextlib.suppress(OSError):
                if p.is_file():
                    found[p] = p.stat().st_mtime_ns
    return found


@contextlib.contextmanager
def output_dir(path: Path, outputs: tuple[str, ...], option: str = "--out") -> Iterator[Path]:
    """Check and create the output folder ``path`` for a command's results.

    Refused (``CommandError``) before any work if it is a file, lies under a file or cannot
    be written. If the command is interrupted (Ctrl-C) or fails, the folders this call or the
    command created and left empty are removed again, and on Ctrl-C the files written so far
    (those of the glob patterns ``outputs`` that are new or changed) are listed on stderr:
    they are kept.
    """
    from serial_protocol.exceptions import CommandError

    if path.exists() and not path.is_dir():
        raise CommandError(f"{option} {str(path)!r}: is a file, not a folder")
    missing = [p for p in (path, *path.parents) if not p.exists()]
    before = _files(path, outputs) if path.is_dir() else {}
    subdirs = {path / pattern.split("/")[0] for pattern in outputs if "/" in pattern}
    new_subdirs = sorted(d for d in subdirs if not d.exists())
    probe = path / ".turntable-sim-write-test"
    try:
        try:
            path.mkdir(parents=True, exist_ok=True)
            probe.touch()
            probe.unlink()
        except OSError as exc:
            what = "cannot create the folder" if not path.is_dir() else "cannot write there"
            raise CommandError(f"{option} {str(path)!r}: {what}: {exc.strerror}") from None
        yield path
    except BaseException as exc:
        # Ctrl-C or an error, wherever it came (also between the mkdir and the work)
        with contextlib.suppress(OSError):
            probe.unlink()
        written = sorted(p for p, t in _files(path, outputs).items() if before.get(p) != t)
        _remove_empty(new_subdirs + missing)
        if isinstance(exc, KeyboardInterrupt):
            if written:
                names = ", ".join(str(p.relative_to(path)) for p in written)
                print(f"kept in {path}: {names} (written before the interrupt)", file=sys.stderr)
            elif missing and not path.exists():
                print(f"nothing was written; removed the empty folder {path}", file=sys.stderr)
            else:
                print(f"nothing was written to {path}", file=sys.stderr)
        raise


def _remove_empty(created: list[Path]) -> None:
    """Remove the folders of ``created`` (deepest first) that are empty."""
    for folder in created:
        with contextlib.suppress(OSError):
            folder.rmdir()  # only succeeds if empty
