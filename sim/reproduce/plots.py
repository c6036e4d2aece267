"""Figures drawn like the paper's: velocity against time with the planned (ideal) curve and
the measured curve, the velocity error, position and motor current beneath (and, for the
S-curve runs, the planned acceleration and jerk).

matplotlib's object API only (no pyplot state, no backend chosen at import), so it runs
headless, in threads and in a notebook; every function returns the ``Figure`` and saves it
when given a path (PNG, SVG or PDF by the extension). Units are written in mathtext (°/s²).
Everything plotted is what the PC decoded from the telemetry frames (``Trace``).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from sim.reproduce.experiments import Trace

__all__ = [
    "Curve",
    "Marker",
    "Point",
    "paper_figure",
    "position_label",
    "quick_note",
    "save",
    "sci",
]

COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


@dataclass(frozen=True)
class Curve:
    """One run on a figure: ``label`` in the legend, times shifted by ``t_offset_s``
    (plotted at ``t_s - t_offset_s``) and positions by ``pos_offset_deg``."""

    trace: Trace
    label: str
    color: str
    t_offset_s: float = 0.0
    pos_offset_deg: float = 0.0


@dataclass(frozen=True)
class Marker:
    """A vertical line at ``t_s`` (plotted time) with a short label on the velocity panel."""

    t_s: float
    label: str
    color: str = "0.3"
    at_top: bool = True


@dataclass(frozen=True)
class Point:
    """A reference value to mark on the velocity panel (e.g. the paper's Table 1):
    ``vel_dps`` at plotted time ``t_s``, drawn as a cross with ``label``."""

    t_s: float
    vel_dps: float
    label: str
    color: str = "black"


#: Axis labels (mathtext units). The firmware's axis is the gearmotor output shaft.
VEL_LABEL = "output shaft velocity (°/s)"
ERR_LABEL = "measured − planned\nvelocity (°/s)"
ACC_LABEL = "planned\nacceleration (°/s$^2$)"
JERK_LABEL = "planned jerk (°/s$^3$)"
CURRENT_LABEL = "motor current (A)\n(IS pin, decoded)"
BUS_LABEL = "bus voltage (V)\n(measured, decoded)"
SHAFT_NOTE = "Shaft: the gearmotor output shaft (motor / 80; the platter turns 5 times slower)."


def sci(value: float) -> str:
    """``3e6`` as mathtext ``3×10$^{6}$`` (minus sign, 3 significant digits); values in
    [1e-3, 1e4) plainly."""
    if value == 0 or 1e-3 <= abs(value) < 1e4:
        return f"{value:g}".replace("-", "−")
    exponent = math.floor(math.log10(abs(value)))
    mantissa = round(value / 10.0**exponent, 2)
    if abs(mantissa) >= 10.0:  # rounding carried into the next decade
        mantissa, exponent = mantissa / 10.0, exponent + 1
    sign = "−" if mantissa < 0 else ""
    digits = f"{abs(mantissa):g}"
    head = f"{sign}10" if digits == "1" else f"{sign}{digits}×10"
    return f"{head}$^{{{exponent}}}$"


def quick_note(time_scale: float) -> str:
    """The title suffix of a time-scaled (``--quick``) run; empty when not scaled."""
    if time_scale == 1.0:
        return ""
    k = time_scale
    return (
        f"\n(--quick: times and velocities / {k:g}, positions / {k * k:g}; the labels give "
        "this run's values)"
    )


def position_label(time_scale: float) -> str:
    """The position axis label of a figure in 10³ ° (the paper's 10⁶ only when unscaled)."""
    if time_scale == 1.0:
        return "output shaft position\n(10$^3$ °; the paper's 10$^6$)"
    return "output shaft position\n(10$^3$ °)"


def _limit_y(ax: object, curves: Sequence[Curve], t_from_s: float, order: int) -> None:
    """Y limits of the planned acceleration (order 0) or jerk (1) after ``t_from_s``."""
    lo, hi = 0.0, 0.0
    for c in curves:
        t = c.trace.t_s - c.t_offset_s
        y = np.gradient(c.trace.sp_vel_dps, c.trace.t_s)
        if order:
            y = np.gradient(y, c.trace.t_s)
        keep = y[t >= t_from_s + 2 * c.trace.dt_s]
        if keep.size:
            lo, hi = min(lo, float(keep.min())), max(hi, float(keep.max()))
    if hi > lo:
        pad = 0.08 * (hi - lo)
        ax.set_ylim(lo - pad, hi + pad)  # type: ignore[attr-defined]


def save(fig: Figure, path: str | Path | None, dpi: int = 110) -> Figure:
    """Save ``fig`` to ``path`` (format from the extension; folders made) and return it."""
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=dpi)
    return fig


def paper_figure(
    curves: Sequence[Curve],
    path: str | Path | None = None,
    *,
    title: str,
    current_limit_a: float | None = None,
    markers: Sequence[Marker] = (),
    points: Sequence[Point] = (),
    points_label: str = "the paper's value",
    shade: tuple[float, float, str] | None = None,
    time_label: str = "time (s)",
    note: str = "",
    pos_scale: float = 1000.0,
    pos_label: str = "output shaft position\n(10$^3$ °)",
    acceleration: bool = False,
    bus: bool = False,
    dpi: int = 110,
) -> Figure:
    """The paper-style figure: velocity (planned dashed, measured solid), velocity error,
    [planned acceleration and jerk,] position (divided by ``pos_scale``), current.

    ``shade = (t0, t1, text)`` greys a time span (e.g. a run-up); ``points`` are reference
    values crossed on the velocity panel; ``current_limit_a`` draws the firmware's limit;
    ``bus`` adds the measured bus voltage on the current panel's right axis (dotted) for the
    curves whose trace carries one (``Trace.bus_voltage_v``, not all 0).
    Several curves overlay (one colour each); a curve drawn later is thinner, so that one
    that coincides with an earlier one leaves it visible. Returns the figure; saves it to
    ``path`` if given (format by extension).
    """
    n_panels = 5 if acceleration else 4
    ratios = (2.4, 0.9, 1.2, 1.1, 1.0) if acceleration else (2.4, 0.9, 1.1, 1.0)
    fig = Figure(figsize=(10, 11.5 if acceleration else 10), layout="constrained")
    axes = list(fig.subplots(n_panels, 1, sharex=True, height_ratios=ratios))
    ax_v, ax_e = axes[0], axes[1]
    ax_a = axes[2] if acceleration else None
    ax_p, ax_i = axes[-2], axes[-1]
    ax_j = ax_a.twinx() if ax_a is not None else None
    n = len(curves)
    for k, c in enumerate(curves):
        tr = c.trace
        t = tr.t_s - c.t_offset_s
        # The measured curve is drawn wide and translucent, the planned one thin on top:
        # they coincide to a fraction of a °/s, and both must stay visible. Later curves
        # are narrower, so a run that retraces an earlier one does not hide it.
        widest = 2.0 + 1.6 * (n - 1)  # 3.6 for two curves, 6.8 for four
        wide = widest - (widest - 2.0) * k / (n - 1) if n > 1 else 3.0
        ax_v.plot(t, tr.vel_dps, color=c.color, lw=wide, alpha=0.55, label=c.label)
        ax_v.plot(t, tr.sp_vel_dps, "--", color="black", lw=0.8)
        ax_e.plot(t, tr.vel_dps - tr.sp_vel_dps, color=c.color, lw=0.8, alpha=0.9)
        pos = (tr.pos_deg - c.pos_offset_deg) / pos_scale
        ax_p.plot(t, pos, color=c.color, lw=wide, alpha=0.55)
        ax_p.plot(t, (tr.sp_pos_deg - c.pos_offset_deg) / pos_scale, "--", color="black", lw=0.8)
        ax_i.plot(t, tr.current_a, color=c.color, lw=0.8, alpha=0.85)
        if ax_a is not None and len(t) > 2:
            acc = np.gradient(tr.sp_vel_dps, tr.t_s)
            ax_a.plot(t, acc, color=c.color, lw=1.4)
            ax_j.plot(t, np.gradient(acc, tr.t_s), color=c.color, lw=0.7, ls=":")
    ax_v.set_ylabel(VEL_LABEL)
    ax_e.set_ylabel(ERR_LABEL)
    ax_p.set_ylabel(pos_label)
    ax_i.set_ylabel(CURRENT_LABEL)
    if ax_a is not None:
        if shade is not None:
            # scale the panel to the subject, not to the run-up's much harder ramps
            _limit_y(ax_a, [c for c in curves], shade[1], 0)
            _limit_y(ax_j, [c for c in curves], shade[1], 1)
        ax_a.set_ylabel(ACC_LABEL)
        ax_j.set_ylabel(JERK_LABEL)
        ax_a.legend(
            handles=[
                Line2D([], [], color="0.3", lw=1.4, label="acceleration (left axis)"),
                Line2D([], [], color="0.3", lw=0.7, ls=":", label="jerk (right axis)"),
            ],
            loc="upper right", fontsize="x-small", framealpha=0.9,
        )  # fmt: skip
    with_bus = [c for c in curves if bus and np.any(c.trace.bus_voltage_v)]
    if with_bus:
        ax_b = ax_i.twinx()
        for c in with_bus:
            t, volts = c.trace.t_s - c.t_offset_s, c.trace.bus_voltage_v
            ax_b.plot(t, volts, color=c.color, lw=0.9, ls=":")
        ax_b.set_ylabel(BUS_LABEL)
        ax_i.legend(
            handles=[
                Line2D([], [], color="0.3", lw=0.8, label="current (left axis)"),
                Line2D([], [], color="0.3", lw=0.9, ls=":", label="bus voltage (right axis)"),
            ],
            loc="lower right", fontsize="x-small", framealpha=0.9,
        )  # fmt: skip
    # Wrap the note to the figure width so a long one is not cut off at the edge.
    ax_i.set_xlabel(time_label + ("\n" + textwrap.fill(note, 120) if note else ""))
    if current_limit_a is not None:
        for sign in (1.0, -1.0):
            ax_i.axhline(sign * current_limit_a, color="tab:red", ls=":", lw=1.0)
        ax_i.set_ylim(-1.25 * current_limit_a, 1.25 * current_limit_a)
        ax_i.text(
            0.995, 0.98, f"firmware limit ±{current_limit_a:g} A", transform=ax_i.transAxes,
            ha="right", va="top", fontsize="small", color="tab:red",
        )  # fmt: skip
    for m in markers:
        for ax in axes:
            ax.axvline(m.t_s, color=m.color, ls=":", lw=1.0)
        ax_v.annotate(
            m.label, (m.t_s, 1.0 if m.at_top else 0.0), xycoords=("data", "axes fraction"),
            xytext=(2, -4 if m.at_top else 4), textcoords="offset points",
            va="top" if m.at_top else "bottom", ha="left", rotation=90,
            fontsize="small", color=m.color,
        )  # fmt: skip
    for pt in points:
        ax_v.plot(pt.t_s, pt.vel_dps, "x", color=pt.color, ms=10, mew=2.2, zorder=5)
        ax_v.annotate(
            pt.label, (pt.t_s, pt.vel_dps), xytext=(6, 6), textcoords="offset points",
            fontsize="small", color=pt.color, fontweight="bold",
        )  # fmt: skip
    if shade is not None:
        t0, t1, text = shade
        for ax in axes:
            ax.axvspan(t0, t1, color="0.85", alpha=0.6, lw=0)
        ax_v.annotate(
            text, (0.5 * (t0 + t1), 0.02), xycoords=("data", "axes fraction"), ha="center",
            va="bottom", fontsize="small", color="0.3",
        )  # fmt: skip
    for ax in axes:
        ax.grid(True, alpha=0.3)
    style = [Line2D([], [], color="black", ls="--", lw=0.8, label="planned (board setpoint)")]
    if points:
        style.append(
            Line2D([], [], color="black", marker="x", ls="", mew=2, label=points_label)
        )
    run_handles, _ = ax_v.get_legend_handles_labels()
    ax_v.legend(handles=run_handles + style, loc="best", fontsize="small")
    fig.suptitle(title)
    return save(fig, path, dpi)
