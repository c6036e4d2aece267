"""Figures of a tune: before/after tracking on the scenario, and Bode plots of the three
loop gains (matplotlib ``Figure`` objects, no pyplot state: headless-safe)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from sim.loop import RunLog
from sim.tuning.linear import LOOPS, LoopTransfer, margins

__all__ = ["plot_before_after", "plot_bode"]


def plot_before_after(
    logs: Mapping[str, RunLog],
    path: str | Path | None,
    title: str,
    pos_offset_deg: float = 0.0,
    time_scale: float = 1.0,
) -> Figure:
    """Tracking error, velocity error and current of each labelled single-axis log.

    ``time_scale``: the scenario ran with times and velocities / K, positions / K² (``tune
    --time-scale``); the title then says so, since its text gives the unscaled times.
    Returns the figure; saves it to ``path`` if given.
    """
    fig = Figure(figsize=(10, 8), layout="constrained")
    ax_e, ax_v, ax_i = fig.subplots(3, 1, sharex=True)
    for label, log in logs.items():
        t = log.t_s
        err = log.sp_pos_deg - (log.true_pos_deg + pos_offset_deg)
        ax_e.plot(t, err, lw=1.0, label=label)
        ax_v.plot(t, log.vel_dps - log.sp_vel_dps, lw=0.8, label=label)
        ax_i.plot(t, log.current_a, lw=0.8, label=label)
    ax_e.set_ylabel("tracking error\nsetpoint − true position (°)")
    ax_v.set_ylabel("velocity error\nestimate − setpoint (°/s)")
    ax_i.set_ylabel("motor current (A)")
    ax_i.set_xlabel("time of the scaled run (s)" if time_scale != 1.0 else "time (s)")
    ax_i.set_xlabel(ax_i.get_xlabel() + "\nAngles of the gearmotor output shaft (motor / 80).")
    for ax in (ax_e, ax_v, ax_i):
        ax.grid(True, alpha=0.3)
    ax_e.legend(loc="upper right")
    if time_scale != 1.0:
        k = time_scale
        title += (
            f"\nrun time-scaled: times and velocities / {k:g}, positions / {k * k:g} "
            f"(the times above are the unscaled scenario's; here they come {k:g}x sooner)"
        )
    fig.suptitle(title)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def plot_bode(
    loops: Mapping[str, Mapping[str, LoopTransfer]], path: str | Path | None, title: str = ""
) -> Figure:
    """Bode plots of the loop gains: one column per loop, one curve per labelled gain set;
    the gain crossover is marked, the margins are in the legend. Returns the figure; saves
    it to ``path`` if given."""
    fig = Figure(figsize=(13, 6.5), layout="constrained")
    axes = fig.subplots(2, len(LOOPS), sharex="col")
    for col, loop in enumerate(LOOPS):
        ax_m, ax_p = axes[0, col], axes[1, col]
        for label, per_loop in loops.items():
            lt = per_loop[loop]
            f = np.geomspace(0.05, lt.nyquist_hz, 600)
            resp = lt.response(f)
            mag_db = 20.0 * np.log10(np.abs(resp))
            phase = np.degrees(np.unwrap(np.angle(resp)))
            # Unwrapped from the low end: shift so that the low-frequency phase is in
            # (-360, 0], the usual reading of a loop gain.
            phase -= 360.0 * np.ceil(phase[0] / 360.0)
            m = margins(lt)
            text = f"{label}: PM {m.phase_margin_deg:.0f}°, GM {m.gain_margin_db:.1f} dB"
            (line,) = ax_m.semilogx(f, mag_db, label=text)
            ax_p.semilogx(f, phase, color=line.get_color())
            if np.isfinite(m.crossover_hz):
                ax_m.plot(m.crossover_hz, 0.0, "o", color=line.get_color())
                ax_p.plot(m.crossover_hz, m.phase_margin_deg - 180.0, "o", color=line.get_color())
        ax_m.axhline(0.0, color="k", lw=0.6)
        ax_p.axhline(-180.0, color="k", lw=0.6)
        ax_m.set_title(f"{loop} loop ({1.0 / lt.dt_s:.0f} Hz)")
        ax_m.set_ylabel("|L| (dB)")
        ax_p.set_ylabel("phase of L (°)")
        ax_p.set_xlabel("frequency (Hz)")
        for ax in (ax_m, ax_p):
            ax.grid(True, which="both", alpha=0.3)
        ax_m.legend(fontsize=7, loc="lower left")
    if title:
        fig.suptitle(title)
    if path is not None:
        fig.savefig(path, dpi=100)
    return fig
