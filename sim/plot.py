"""Plots of a run: position, velocity and current against time (matplotlib, no pyplot
state, so it works headless and in threads)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from sim.loop import RunLog

__all__ = ["plot_run"]


def plot_run(log: RunLog, path: str | Path, title: str = "", dpi: int = 110) -> Path:
    """Save a three-panel figure (axis position, axis velocity, motor current) to ``path``.

    Setpoints are dashed, firmware estimates solid, the plant's true values thin; ticks with
    a latched fault are shaded red.
    """
    t = log.t_s
    fig = Figure(figsize=(10, 8.5), layout="constrained")
    ax_p, ax_v, ax_i = fig.subplots(3, 1, sharex=True)

    ax_p.plot(t, log.sp_pos_deg, "--", color="tab:gray", label="setpoint")
    ax_p.plot(t, log.pos_deg, color="tab:blue", label="measured (encoder)")
    ax_p.plot(t, log.true_pos_deg, color="tab:orange", lw=0.8, label="true axis")
    ax_p.set_ylabel("axis position (deg)")

    ax_v.plot(t, log.sp_vel_dps, "--", color="tab:gray", label="setpoint")
    ax_v.plot(t, log.vel_raw_dps, color="tab:green", lw=0.5, alpha=0.5, label="raw difference")
    ax_v.plot(t, log.vel_dps, color="tab:blue", label="estimated")
    ax_v.plot(t, log.true_vel_dps, color="tab:orange", lw=0.8, label="true axis")
    ax_v.set_ylabel("axis velocity (deg/s)")

    ax_i.plot(t, log.current_ref_a, "--", color="tab:gray", label="reference")
    ax_i.plot(t, log.current_meas_a, color="tab:blue", lw=0.8, label="measured (IS pin)")
    ax_i.plot(t, log.current_a, color="tab:orange", lw=0.8, label="true")
    ax_i.set_ylabel("motor current (A)")
    ax_i.set_xlabel("time (s)")

    faulted = np.asarray(log.fault) != 0
    for ax in (ax_p, ax_v, ax_i):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
        if faulted.any():
            ax.fill_between(
                t,
                0,
                1,
                where=faulted,
                transform=ax.get_xaxis_transform(),
                color="tab:red",
                alpha=0.12,
                label="_fault",
            )
    if title:
        fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    return path
