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
    logs: Mapping[str, RunLog], path: str | Path, title: str, pos_offset_deg: float = 0.0
) -> Path:
    """Tracking error, velocity error and current of each labelled single-axis log."""
    fig = Figure(figsize=(10, 8), layout="constrained")
    ax_e, ax_v, ax_i = fig.subplots(3, 1, sharex=True)
    for label, log in logs.items():
        t = log.t_s
        err = log.sp_pos_deg - (log.true_pos_deg + pos_offset_deg)
        ax_e.plot(t, err, lw=1.0, label=label)
        ax_v.plot(t, log.vel_dps - log.sp_vel_dps, lw=0.8, label=label)
        ax_i.plot(t, log.current_a, lw=0.8, label=label)
    ax_e.set_ylabel("tracking error (axis deg)")
    ax_v.set_ylabel("velocity error (axis deg/s)")
    ax_i.set_ylabel("motor current (A)")
    ax_i.set_xlabel("time (s)")
    for ax in (ax_e, ax_v, ax_i):
        ax.grid(True, alpha=0.3)
    ax_e.legend(loc="upper right")
    fig.suptitle(title)
    fig.savefig(path, dpi=110)
    return Path(path)


def plot_bode(
    loops: Mapping[str, Mapping[str, LoopTransfer]], path: str | Path, title: str = ""
) -> Path:
    """Bode plots of the loop gains: one column per loop, one curve per labelled gain set;
    the gain crossover is marked, the margins are in the legend."""
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
            text = f"{label}: PM {m.phase_margin_deg:.0f} deg, GM {m.gain_margin_db:.1f} dB"
            (line,) = ax_m.semilogx(f, mag_db, label=text)
            ax_p.semilogx(f, phase, color=line.get_color())
            if np.isfinite(m.crossover_hz):
                ax_m.plot(m.crossover_hz, 0.0, "o", color=line.get_color())
                ax_p.plot(m.crossover_hz, m.phase_margin_deg - 180.0, "o", color=line.get_color())
        ax_m.axhline(0.0, color="k", lw=0.6)
        ax_p.axhline(-180.0, color="k", lw=0.6)
        ax_m.set_title(f"{loop} loop ({1.0 / lt.dt_s:.0f} Hz)")
        ax_m.set_ylabel("|L| (dB)")
        ax_p.set_ylabel("phase of L (deg)")
        ax_p.set_xlabel("frequency (Hz)")
        for ax in (ax_m, ax_p):
            ax.grid(True, which="both", alpha=0.3)
        ax_m.legend(fontsize=7, loc="lower left")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=100)
    return Path(path)
