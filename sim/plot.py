"""Plots of a run: velocity, tracking error, position and current against time (matplotlib's
object API, no pyplot state, no backend chosen: works headless, in threads and in a notebook).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from sim.loop import RunLog

__all__ = ["plot_run"]


def plot_run(
    log: RunLog, path: str | Path | None = None, title: str = "", dpi: int = 110
) -> Figure:
    """The four-panel figure of a single-axis run: output shaft velocity, tracking error,
    position, motor current. Returns the figure; saves it to ``path`` if given (PNG, SVG or
    PDF by the extension).

    Setpoints are dashed, firmware estimates solid, the plant's true values thin; ticks with
    a latched fault are shaded red. The tracking error is setpoint − position (°): as the
    firmware sees it (encoder) and as it is (the true shaft angle).
    """
    t = log.t_s
    fig = Figure(figsize=(10, 10), layout="constrained")
    ax_v, ax_e, ax_p, ax_i = fig.subplots(4, 1, sharex=True, height_ratios=(1.6, 1.0, 1.2, 1.0))

    ax_v.plot(t, log.sp_vel_dps, "--", color="tab:gray", label="setpoint")
    ax_v.plot(t, log.vel_raw_dps, color="tab:green", lw=0.5, alpha=0.5, label="raw difference")
    ax_v.plot(t, log.vel_dps, color="tab:blue", label="estimated")
    ax_v.plot(t, log.true_vel_dps, color="tab:orange", lw=0.8, label="true")
    ax_v.set_ylabel("output shaft\nvelocity (°/s)")

    ax_e.plot(
        t, log.sp_pos_deg - log.pos_deg, color="tab:blue", lw=0.9, label="firmware's (encoder)"
    )
    ax_e.plot(t, log.sp_pos_deg - log.true_pos_deg, color="tab:orange", lw=0.8, label="true")
    ax_e.axhline(0.0, color="0.5", lw=0.6)
    ax_e.set_ylabel("tracking error\nsetpoint − position (°)")

    ax_p.plot(t, log.sp_pos_deg, "--", color="tab:gray", label="setpoint")
    ax_p.plot(t, log.pos_deg, color="tab:blue", label="measured (encoder)")
    ax_p.plot(t, log.true_pos_deg, color="tab:orange", lw=0.8, label="true")
    ax_p.set_ylabel("output shaft\nposition (°)")

    ax_i.plot(t, log.current_ref_a, "--", color="tab:gray", label="reference")
    ax_i.plot(t, log.current_meas_a, color="tab:blue", lw=0.8, label="measured (IS pin)")
    ax_i.plot(t, log.current_a, color="tab:orange", lw=0.8, label="true")
    ax_i.set_ylabel("motor current (A)")
    ax_i.set_xlabel(
        "time (s)\nShaft: the gearmotor output shaft (motor / 80; the platter turns 5 times "
        "slower)."
    )

    faulted = np.asarray(log.fault) != 0
    for ax in (ax_v, ax_e, ax_p, ax_i):
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
    if path is not None:
        fig.savefig(Path(path), dpi=dpi)
    return fig
