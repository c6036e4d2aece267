"""The monitor's live plot (``monitor --plot``), after odrivetool's liveplotter: planned and
measured velocity and position and the motor current over a rolling window, redrawn while
the board talks.

Two parts, so that drawing never costs telemetry:

* :class:`LiveBuffer` takes every ``Telemetry`` as it is decoded (``append``, from the
  ``BoardClient``'s ``on_message``; thread-safe) into fixed numpy ring arrays, and counts
  them. It never drops a frame: the window is what is shown, not what is kept elsewhere
  (the CSV writer gets every frame too).
* :class:`LivePlot` draws the latest window of a buffer on a matplotlib ``Figure``
  (``update()``: set the lines' data, rescale). It works on any canvas: a window of an
  interactive backend, or Agg off screen (the benchmark, the README's picture).

The rate a machine can draw is measured in ``benchmarks/bench_liveplot.py``.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
from matplotlib.figure import Figure

__all__ = ["COLUMNS", "LiveBuffer", "LivePlot", "LiveWindow", "has_display"]

#: The telemetry fields kept, in column order (``t_s`` = tick / tick_hz, unwrapped).
COLUMNS = ("t_s", "sp_pos_deg", "sp_vel_dps", "pos_deg", "vel_dps", "current_a", "bus_voltage_v")

#: At most this many points per line are drawn (min/max pairs keep the peaks visible).
MAX_POINTS = 1500


class LiveBuffer:
    """The last ``capacity`` telemetry frames as columns (ring arrays).

    Args:
        capacity: frames kept (e.g. window 10 s at 500 Hz = 5000).
        tick_hz: the board's servo rate, for ``t_s``.
    """

    def __init__(self, capacity: int, tick_hz: float = 500.0) -> None:
        if capacity < 2:
            raise ValueError(f"capacity = {capacity!r}: must be >= 2")
        if not tick_hz > 0:
            raise ValueError(f"tick_hz = {tick_hz!r}: must be > 0")
        self.capacity = capacity
        self.tick_hz = tick_hz
        self.received = 0  # every frame appended, ever
        self._data = np.zeros((len(COLUMNS), capacity))
        self._lock = threading.Lock()
        self._last_tick: int | None = None
        self._tick_base = 0  # unwraps the u32 tick counter

    def append(self, msg: Any) -> None:
        """Add one ``Telemetry`` (anything with its fields)."""
        tick = int(msg.tick)
        with self._lock:
            if self._last_tick is not None and tick < self._last_tick - (1 << 31):
                self._tick_base += 1 << 32
            self._last_tick = tick
            row = self.received % self.capacity
            d = self._data
            d[0, row] = (tick + self._tick_base) / self.tick_hz
            d[1, row] = msg.sp_pos_deg
            d[2, row] = msg.sp_vel_dps
            d[3, row] = msg.pos_deg
            d[4, row] = msg.vel_dps
            d[5, row] = msg.current_a
            # 0 from a board that does not send it (an older one)
            d[6, row] = getattr(msg, "bus_voltage_v", 0.0)
            self.received += 1

    def __call__(self, msg: Any) -> None:
        """``on_message``-style: keeps telemetry, ignores other messages."""
        if hasattr(msg, "sp_vel_dps") and hasattr(msg, "tick"):
            self.append(msg)

    def window(self, window_s: float | None = None) -> dict[str, np.ndarray]:
        """A copy of the frames held (the last ``window_s`` seconds of them), oldest first:
        column name -> ``(n,)`` array."""
        with self._lock:
            n = min(self.received, self.capacity)
            start = self.received % self.capacity if self.received > self.capacity else 0
            order = (np.arange(n) + start) % self.capacity
            data = self._data[:, order]
        if window_s is not None and n:
            keep = data[0] >= data[0, -1] - window_s
            data = data[:, keep]
        return dict(zip(COLUMNS, data, strict=True))


def _reduce(t: np.ndarray, y: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_points`` points that keep each bucket's minimum and maximum."""
    n = len(t)
    if n <= max_points:
        return t, y
    buckets = max_points // 2
    edges = np.linspace(0, n, buckets + 1).astype(int)
    lo = np.minimum.reduceat(y, edges[:-1])
    hi = np.maximum.reduceat(y, edges[:-1])
    tt = np.repeat(t[edges[:-1]], 2)
    yy = np.column_stack((lo, hi)).ravel()
    return tt, yy


class LivePlot:
    """Three panels over a rolling window: velocity (planned dashed, measured solid),
    position (the same), motor current; time runs from ``-window_s`` to 0 (now).

    Drawing is cheap per frame: the axes, ticks and grid are rendered once into a
    background and only the lines are drawn over it (matplotlib's blitting); the whole
    figure is rendered again only when a y range has to change (the data left it, or
    fill less than a quarter of it; at most every ``rescale_interval_s``) or the canvas was
    resized.

    Args:
        buffer: where the frames come from.
        window_s: the rolling window (s).
        figure: draw on this figure (e.g. ``pyplot.figure()`` for a window); default a new
            off-screen ``Figure`` on an Agg canvas.
        title: shown above the panels.
    """

    def __init__(
        self,
        buffer: LiveBuffer,
        window_s: float = 10.0,
        figure: Figure | None = None,
        title: str = "",
    ) -> None:
        if not window_s > 0:
            raise ValueError(f"window_s = {window_s!r}: must be > 0")
        self.buffer = buffer
        self.window_s = window_s
        self.frames = 0  # frames drawn
        self.full_redraws = 0  # of which the whole figure
        if figure is None:
            from matplotlib.backends.backend_agg import FigureCanvasAgg

            figure = Figure(figsize=(9, 8.5))
            FigureCanvasAgg(figure)
        self.fig = figure
        ax_v, ax_p, ax_i, ax_b = self.fig.subplots(
            4, 1, sharex=True, gridspec_kw={"height_ratios": (1.0, 1.0, 1.0, 0.6)}
        )
        self.axes = (ax_v, ax_p, ax_i, ax_b)
        style = {"animated": True}
        # measured wide and translucent, planned thin on top: both stay visible
        wide = {"lw": 3.0, "alpha": 0.5, "color": "tab:blue", **style}
        (vel,) = ax_v.plot([], [], label="measured", **wide)
        (sp_vel,) = ax_v.plot([], [], "--", color="black", lw=0.9, label="planned", **style)
        (pos,) = ax_p.plot([], [], label="measured", **wide)
        (sp_pos,) = ax_p.plot([], [], "--", color="black", lw=0.9, label="planned", **style)
        (cur,) = ax_i.plot([], [], color="tab:red", lw=0.9, label="IS pin", **style)
        (bus,) = ax_b.plot([], [], color="tab:green", lw=0.9, label="bus", **style)
        # drawn in this order
        self._lines = ((vel, "vel_dps"), (sp_vel, "sp_vel_dps"), (pos, "pos_deg"),
                       (sp_pos, "sp_pos_deg"), (cur, "current_a"),
                       (bus, "bus_voltage_v"))  # fmt: skip
        self._panels = (("sp_vel_dps", "vel_dps"), ("sp_pos_deg", "pos_deg"), ("current_a",),
                        ("bus_voltage_v",))  # fmt: skip
        # The smallest y span per panel: a steady bus (24.000 V) is drawn on a 1 V scale.
        self._min_span = (1e-3, 1e-3, 1e-3, 1.0)
        ax_v.set_ylabel("output shaft\nvelocity (°/s)")
        ax_p.set_ylabel("output shaft\nposition (°)")
        ax_i.set_ylabel("motor current (A)")
        ax_b.set_ylabel("bus voltage (V)\n(0: not sent)")
        ax_b.ticklabel_format(axis="y", useOffset=False)
        ax_b.set_xlabel("time before the latest frame (s)")
        ax_b.set_xlim(-window_s, 0.0)
        for ax in self.axes:
            ax.grid(True, alpha=0.3)
            ax.set_ylim(-1.0, 1.0)
        ax_v.legend(loc="upper left", fontsize="small")
        # The status line sits in the top margin, clear of the lines: rendering text costs
        # as much as all the lines, so it is rendered a few times a second and its pixels
        # are reused in between.
        self._status = self.fig.text(
            0.97, 0.985, "", ha="right", va="top", fontsize="small", animated=True
        )
        if title:
            self.fig.text(0.12, 0.985, title, ha="left", va="top", fontsize="medium")
        self.fig.subplots_adjust(left=0.12, right=0.97, top=0.95, bottom=0.08)
        self._background: Any = None
        self._size: Any = None
        self._status_pixels: Any = None
        self._status_due_wall_s = 0.0
        self.status_interval_s = 0.25
        self.rescale_interval_s = 0.5
        self._rescale_due_wall_s = 0.0

    def update(self) -> bool:
        """Put the latest window on the lines; return True if a y range changed (the
        whole figure must be rendered again)."""
        w = self.buffer.window(self.window_s)
        t = w["t_s"]
        rescale = False
        # A full render costs several frames: at most one per rescale_interval_s (a line
        # may leave its axis for that long, e.g. during a fast ramp).
        now_wall_s = time.monotonic()
        may_rescale = now_wall_s >= self._rescale_due_wall_s
        if len(t):
            x = t - t[-1]
            for line, name in self._lines:
                line.set_data(*_reduce(x, w[name], MAX_POINTS))
            for ax, names, min_span in zip(self.axes, self._panels, self._min_span, strict=True):
                lo = min(float(w[n].min()) for n in names)
                hi = max(float(w[n].max()) for n in names)
                y0, y1 = ax.get_ylim()
                span = max(hi - lo, min_span)
                # Grow with room to spare (a ramp would otherwise force a full render per
                # frame); shrink only when the data fill less than a quarter of the axis.
                if may_rescale and (lo < y0 or hi > y1 or span < (y1 - y0) / 4.0):
                    ax.set_ylim(lo - 0.5 * span, hi + 0.5 * span)
                    rescale = True
            if rescale:
                self._rescale_due_wall_s = now_wall_s + self.rescale_interval_s
            self._last = (w["vel_dps"][-1], w["pos_deg"][-1])
        return rescale

    def status_text(self) -> str:
        """The status line: frames received, latest velocity and position."""
        vel, pos = getattr(self, "_last", (0.0, 0.0))
        return f"{self.buffer.received} frames received; v {vel:.1f} °/s, pos {pos:.2f} °"

    def draw(self) -> None:
        """Update and render a frame on the figure's canvas (window or Agg)."""
        canvas = self.fig.canvas
        rescale = self.update()
        size = canvas.get_width_height()
        if rescale or self._background is None or size != self._size:
            canvas.draw()  # everything but the animated lines
            self._background = canvas.copy_from_bbox(self.fig.bbox)
            self._size = size
            self.full_redraws += 1
        else:
            canvas.restore_region(self._background)
        for line, _ in self._lines:
            line.axes.draw_artist(line)
        now_wall_s = time.monotonic()
        if rescale or self._status_pixels is None or now_wall_s >= self._status_due_wall_s:
            self._status_due_wall_s = now_wall_s + self.status_interval_s
            self._status.set_text(self.status_text())
            self.fig.draw_artist(self._status)
            box = self._status.get_window_extent().expanded(1.05, 1.3)
            self._status_pixels = canvas.copy_from_bbox(box)
        else:
            canvas.restore_region(self._status_pixels)
        canvas.blit(self.fig.bbox)
        self.frames += 1

    def save(self, path: Any, dpi: float = 110) -> None:
        """Save the current window as a still image (the lines drawn normally)."""
        for line, _ in self._lines:
            line.set_animated(False)
        self._status.set_animated(False)
        self._status.set_text(self.status_text())
        try:
            self.fig.savefig(path, dpi=dpi)
        finally:
            for line, _ in self._lines:
                line.set_animated(True)
            self._status.set_animated(True)
            self._background = None
            self._status_pixels = None


def has_display() -> bool:
    """True if matplotlib's backend opens windows (not Agg, a file format or inline)."""
    import matplotlib

    backend = matplotlib.get_backend().lower()
    headless = ("agg", "pdf", "svg", "ps", "pgf", "cairo", "template")
    return backend not in headless and "inline" not in backend


class LiveWindow:
    """A :class:`LivePlot` paced at ``fps`` frames per second: ``tick()`` from the
    monitor's loop draws a frame when one is due (and lets a window's GUI run); frames not
    due cost nothing. ``show=False`` draws off screen (``--plot-save`` without a display).
    """

    def __init__(
        self, buffer: LiveBuffer, window_s: float = 10.0, fps: float = 25.0, *,
        show: bool = True, title: str = "",
    ) -> None:  # fmt: skip
        import time

        if not fps > 0:
            raise ValueError(f"fps = {fps!r}: must be > 0")
        self._clock = time.monotonic
        self._period_s = 1.0 / fps
        self._next_wall_s = 0.0
        self.slowest_frame_s = 0.0  # wall time of the slowest frame drawn (a full render)
        self.show = show
        self.closed = False
        figure = None
        if show:
            import matplotlib.pyplot as plt

            figure = plt.figure(figsize=(9, 7))
            figure.canvas.manager.set_window_title(title or "turntable-sim monitor")
            plt.show(block=False)
        self.plot = LivePlot(buffer, window_s, figure, title)
        # The first frame renders the whole figure (and loads the fonts): done here, before
        # any command is sent, and timed, so that the monitor knows what a frame can cost
        # before it schedules one near a timed command.
        start = self._clock()
        self.plot.draw()
        self.slowest_frame_s = self._clock() - start

    def due_in_s(self) -> float:
        """Wall seconds until the next frame is due (0 when it is)."""
        return max(0.0, self._next_wall_s - self._clock())

    def tick(self) -> None:
        """Draw a frame if one is due; keep the window responsive."""
        if self.closed:
            return
        fig = self.plot.fig
        if self.show:
            import matplotlib.pyplot as plt

            if not plt.fignum_exists(fig.number):  # the user closed the window
                self.closed = True
                return
        now = self._clock()
        if now >= self._next_wall_s:
            self._next_wall_s = max(now, self._next_wall_s + self._period_s)
            self.plot.draw()
            self.slowest_frame_s = max(self.slowest_frame_s, self._clock() - now)
        if self.show:
            fig.canvas.flush_events()
