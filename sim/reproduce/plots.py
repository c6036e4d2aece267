"""Figures drawn like the paper's: velocity against time with the planned (ideal) curve and
the measured curve, position and motor current beneath.

matplotlib's object API only (no pyplot state), so it runs headless and in threads.
Everything plotted is what the PC decoded from the telemetry frames (``Trace``).
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: no display needed, whatever the user's backend
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from sim.reproduce.experiments import Trace  # noqa: E402

__all__ = ["Curve", "Marker", "paper_figure"]

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


def paper_figure(
    curves: Sequence[Curve],
    path: str | Path,
    *,
    title: str,
    current_limit_a: float,
    markers: Sequence[Marker] = (),
    shade: tuple[float, float, str] | None = None,
    time_label: str = "time (s)",
    note: str = "",
    dpi: int = 110,
) -> Path:
    """Save the three-panel figure (velocity, position, current) to ``path``.

    Planned curves (the board's setpoint) are dashed and dark, measured ones solid in the
    run's colour. ``shade = (t0, t1, text)`` greys a time span (e.g. a run-up).
    """
    fig = Figure(figsize=(10, 10), layout="constrained")
    ax_v, ax_e, ax_p, ax_i = fig.subplots(4, 1, sharex=True, height_ratios=(2.4, 0.9, 1.1, 1.0))
    for c in curves:
        tr = c.trace
        t = tr.t_s - c.t_offset_s
        # The measured curve is drawn wide and translucent, the planned one thin on top:
        # they coincide to a fraction of a deg/s, and both must stay visible.
        ax_v.plot(t, tr.vel_dps, color=c.color, lw=3.0, alpha=0.55, label=c.label)
        ax_v.plot(t, tr.sp_vel_dps, "--", color="black", lw=0.8)
        ax_e.plot(t, tr.vel_dps - tr.sp_vel_dps, color=c.color, lw=0.8, alpha=0.9)
        ax_p.plot(t, (tr.pos_deg - c.pos_offset_deg) / 1000.0, color=c.color, lw=3.0, alpha=0.55)
        ax_p.plot(t, (tr.sp_pos_deg - c.pos_offset_deg) / 1000.0, "--", color="black", lw=0.8)
        ax_i.plot(t, tr.current_a, color=c.color, lw=0.8, alpha=0.85)
    ax_v.set_ylabel("axis velocity (deg/s)")
    ax_e.set_ylabel("measured - planned\nvelocity (deg/s)")
    ax_p.set_ylabel("axis position\n(10^3 deg = paper's 10^6)")
    ax_i.set_ylabel("motor current (A)\n(IS pin, decoded)")
    # Wrap the note to the figure width so a long one is not cut off at the edge.
    ax_i.set_xlabel(time_label + ("\n" + textwrap.fill(note, 120) if note else ""))
    for sign in (1.0, -1.0):
        ax_i.axhline(sign * current_limit_a, color="tab:red", ls=":", lw=1.0)
    ax_i.set_ylim(-1.25 * current_limit_a, 1.25 * current_limit_a)
    ax_i.text(
        0.995, 0.98, f"firmware limit +-{current_limit_a:g} A", transform=ax_i.transAxes,
        ha="right", va="top", fontsize="small", color="tab:red",
    )  # fmt: skip
    for m in markers:
        for ax in (ax_v, ax_e, ax_p, ax_i):
            ax.axvline(m.t_s, color=m.color, ls=":", lw=1.0)
        ax_v.annotate(
            m.label, (m.t_s, 1.0 if m.at_top else 0.0), xycoords=("data", "axes fraction"),
            xytext=(2, -4 if m.at_top else 4), textcoords="offset points",
            va="top" if m.at_top else "bottom", ha="left", rotation=90,
            fontsize="small", color=m.color,
        )  # fmt: skip
    if shade is not None:
        t0, t1, text = shade
        for ax in (ax_v, ax_e, ax_p, ax_i):
            ax.axvspan(t0, t1, color="0.85", alpha=0.6, lw=0)
        ax_v.annotate(
            text, (0.5 * (t0 + t1), 0.02), xycoords=("data", "axes fraction"), ha="center",
            va="bottom", fontsize="small", color="0.3",
        )  # fmt: skip
    for ax in (ax_v, ax_e, ax_p, ax_i):
        ax.grid(True, alpha=0.3)
    style = [Line2D([], [], color="black", ls="--", lw=0.8, label="planned (board setpoint)")]
    run_handles, _ = ax_v.get_legend_handles_labels()
    ax_v.legend(handles=run_handles + style, loc="best", fontsize="small")
    fig.suptitle(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path
