"""A small progress display on stderr: a bar with percentage and ETA on a terminal, plain
lines otherwise (a log file, CI, a pipe).

Standard library only. Wall-clock time (``wall_s``) is read here and nowhere in the
simulation. Typical use::

    with Progress("fig8", total=n_ticks) as bar:
        result = run(exp, progress=bar.callback)     # sim.loop.run's progress(tick, n)

or ``bar.update(done)`` / ``bar.advance()`` from any loop. On a terminal the bar is redrawn
in place at most every ``min_interval_s``; when the stream is not a terminal one line is
written per ``line_step`` of progress (default every 25 %) and at the end, so a log stays
short.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["Progress", "format_duration"]


def format_duration(wall_s: float) -> str:
    """``"42 s"``, ``"3:05"`` (min:s) or ``"1:02:03"`` (h:min:s) for a wall duration."""
    if wall_s != wall_s or wall_s < 0.0:  # NaN or negative: unknown
        return "?"
    if wall_s < 60.0:
        return f"{wall_s:.0f} s" if wall_s >= 10.0 else f"{wall_s:.1f} s"
    total = int(round(wall_s))
    hours, rest = divmod(total, 3600)
    minutes, seconds = divmod(rest, 60)
    if hours:
        return f"{hours}:{minutes:02d}:{seconds:02d}"
    return f"{minutes}:{seconds:02d}"


class Progress:
    """Progress of one task of ``total`` units.

    Args:
        label: shown before the bar (e.g. ``"[3/9] fig7 S_2"``).
        total: number of units (> 0); may be changed by ``update(done, total)``.
        stream: where to write (default ``sys.stderr``).
        tty: force the terminal (True) or line (False) mode; default ``stream.isatty()``.
        width: bar width in characters.
        min_interval_s: shortest wall time between two redraws on a terminal.
        line_step: fraction of the task between two lines in line mode.
        clock: the wall clock (seconds), injectable for tests.
        enabled: False makes every method a no-op (``--quiet``).
    """

    def __init__(
        self,
        label: str,
        total: int,
        *,
        stream: TextIO | None = None,
        tty: bool | None = None,
        width: int = 30,
        min_interval_s: float = 0.1,
        line_step: float = 0.25,
        clock: Callable[[], float] = time.monotonic,
        enabled: bool = True,
    ) -> None:
        if not isinstance(total, int) or total < 1:
            raise ValueError(f"total = {total!r}: must be an integer >= 1")
        if not 0.0 < line_step <= 1.0:
            raise ValueError(f"line_step = {line_step!r}: must be in (0, 1]")
        self.label = label
        self.total = total
        self.stream = stream if stream is not None else sys.stderr
        if tty is None:
            isatty = getattr(self.stream, "isatty", None)
            tty = bool(isatty()) if isatty is not None else False
        self.tty = tty
        self.width = width
        self.min_interval_s = min_interval_s
        self.line_step = line_step
        self.enabled = enabled
        self._clock = clock
        self._start_wall_s = clock()
        self._last_draw_wall_s = -float("inf")
        self._next_line_fraction = line_step
        self._done = 0
        self._closed = False
        self._line_len = 0

    # ---------------------------------------------------------------- reporting
    @property
    def done(self) -> int:
        return self._done

    @property
    def elapsed_s(self) -> float:
        """Wall seconds since the task started."""
        return self._clock() - self._start_wall_s

    def eta_s(self) -> float:
        """Estimated wall seconds left (NaN before the first unit is done)."""
        if self._done <= 0:
            return float("nan")
        rate = self.elapsed_s / self._done
        return rate * max(self.total - self._done, 0)

    def text(self) -> str:
        """The current status as one line (no carriage return, no newline)."""
        fraction = min(self._done / self.total, 1.0)
        percent = f"{100.0 * fraction:3.0f}%"
        if self._done >= self.total:
            timing = f"done in {format_duration(self.elapsed_s)}"
        else:
            timing = f"ETA {format_duration(self.eta_s())}"
        if self.tty:
            filled = int(self.width * fraction)
            bar = "#" * filled + "." * (self.width - filled)
            return f"{self.label} [{bar}] {percent} {timing}"
        return f"{self.label}: {percent} ({self._done}/{self.total}) {timing}"

    # ---------------------------------------------------------------- updating
    def update(self, done: int, total: int | None = None) -> None:
        """Set the units done (and optionally a new total); redraw if due."""
        if total is not None:
            if not isinstance(total, int) or total < 1:
                raise ValueError(f"total = {total!r}: must be an integer >= 1")
            self.total = total
        self._done = max(0, int(done))
        if not self.enabled or self._closed:
            return
        finished = self._done >= self.total
        if finished:
            self.close()  # draws the final state once
            return
        if self.tty:
            now = self._clock()
            if now - self._last_draw_wall_s >= self.min_interval_s:
                self._last_draw_wall_s = now
                self._draw()
        else:
            fraction = self._done / self.total
            if fraction >= self._next_line_fraction:
                while self._next_line_fraction <= fraction:
                    self._next_line_fraction += self.line_step
                self._write_line()

    def advance(self, n: int = 1) -> None:
        """Add ``n`` units done."""
        self.update(self._done + n)

    def callback(self, done: int, total: int) -> None:
        """The ``progress(done, total)`` signature of ``sim.loop.run``."""
        self.update(done, total)

    def close(self) -> None:
        """Finish the display (writes the final line once)."""
        if self._closed:
            return
        self._closed = True
        if not self.enabled:
            return
        if self.tty:
            self._draw()
            self.stream.write("\n")
            self.stream.flush()
        else:
            self._write_line()

    def __enter__(self) -> Progress:
        if self.enabled and not self.tty:
            self._write_line()  # "started" line, so a log shows what is running
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- output
    def _draw(self) -> None:
        line = self.text()
        pad = " " * max(self._line_len - len(line), 0)
        self._line_len = len(line)
        self.stream.write("\r" + line + pad)
        self.stream.flush()

    def _write_line(self) -> None:
        self.stream.write(self.text() + "\n")
        self.stream.flush()
