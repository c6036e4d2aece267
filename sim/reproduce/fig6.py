"""Seed 000, Fig. 6: the step command S = 3e6 (3000 axis degrees) without planning and
with the trapezoid planner.

Without planning the setpoint jumps to the target (``Profile.STEP``): the position loop
saturates the velocity command at v_max and the current loop at the 5 A limit, so the axis
accelerates and brakes as hard as the electromechanics allow, and overshoots. With the
trapezoid the velocity command ramps at a_max.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from serial_protocol.messages import Profile
from sim.reproduce.experiments import Runner, Trace, load, replace_move
from sim.reproduce.metrics import RunMetrics, measure
from sim.reproduce.plots import SHAFT_NOTE, Curve, paper_figure, position_label, quick_note, sci

__all__ = [
    "PAPER_ARRIVAL_S",
    "Fig6Result",
    "overshoot_peak_t_s",
    "plot",
    "run",
    "settle_t_s",
    "time_to_speed_s",
    "velocity_jumps",
]

# Seed 000, section 5: "the velocity jumps at 0 s and at 3.5 s, with a large overshoot at
# 3.5 s" (no number is printed for the overshoot).
PAPER_ARRIVAL_S = 3.5


@dataclass(frozen=True)
class Fig6Result:
    step: Trace
    planned: Trace
    step_metrics: RunMetrics
    planned_metrics: RunMetrics
    time_scale: float

    @property
    def target_deg(self) -> float:
        return self.step.command_target_deg[-1]


def velocity_jumps(trace: Trace, min_dps2: float = 1000.0) -> list[tuple[float, float]]:
    """``(t_s, acceleration)`` where the measured velocity changes faster than
    ``min_dps2`` (grouped: the first frame of each burst), the paper's "velocity jumps"."""
    acc = np.diff(trace.vel_dps) / np.diff(trace.t_s)
    fast = np.flatnonzero(np.abs(acc) >= min_dps2)
    out: list[tuple[float, float]] = []
    last = -(10**9)
    for i in fast:
        if i > last + 25:  # a new burst after 50 ms of calm
            out.append((float(trace.t_s[i]), float(acc[i])))
        last = i
    return out


def settle_t_s(trace: Trace, tol_deg: float) -> float | None:
    """The time from which the position stays within ``tol_deg`` of the target."""
    outside = np.flatnonzero(np.abs(trace.pos_deg - trace.command_target_deg[-1]) > tol_deg)
    if not outside.size:
        return float(trace.t_s[0])
    if outside[-1] + 1 >= len(trace.t_s):
        return None
    return float(trace.t_s[outside[-1] + 1])


def overshoot_peak_t_s(trace: Trace) -> float:
    """When the position is farthest beyond the target (forward moves)."""
    return float(trace.t_s[int(np.argmax(trace.pos_deg))])


def time_to_speed_s(trace: Trace, speed_dps: float) -> float:
    """Time from the (first) command until the measured speed first reaches ``speed_dps``."""
    t0 = trace.command_t_s[0]
    i0 = trace.index_at(t0)
    hits = np.flatnonzero(np.abs(trace.vel_dps[i0:]) >= speed_dps)
    return float(trace.t_s[i0 + hits[0]] - t0) if hits.size else float("nan")


def run(runner: Runner) -> Fig6Result:
    """Both runs, always as written (also under ``--quick``): a step command is shaped by
    the motor's limits, not by a planner, so a time-scaled copy would not be the same
    experiment."""
    exp = load("fig6")
    planned_exp = replace_move(exp, -1, profile=Profile.TRAPEZOID)
    step = runner.run("fig6 no planning (step)", exp)
    planned = runner.run("fig6 trapezoid", planned_exp)
    limit = exp.bench.firmware.limits.current_limit_a
    return Fig6Result(step, planned, measure(step, limit), measure(planned, limit), 1.0)


def plot(result: Fig6Result, path: str | Path | None, current_limit_a: float) -> Figure:
    """Fig. 6 drawn like the paper's: both runs on one set of axes (returns the figure,
    saved to ``path`` if given)."""
    a_max = result.planned.command_a_max_dps2[-1]
    target_deg = result.planned.command_target_deg[-1]
    return paper_figure(
        [
            Curve(result.step, "without planning (step command)", "tab:red"),
            Curve(
                result.planned, f"trapezoid planning ($a_{{max}}$ = {a_max:g} °/s$^2$)", "tab:blue"
            ),
        ],  # fmt: skip
        path,
        title=f"Fig. 6: step command S = {sci(target_deg * 1000.0)} m° ({target_deg:g} °), "
        f"with and without planning{quick_note(result.time_scale)}",
        current_limit_a=current_limit_a,
        pos_label=position_label(result.time_scale),
        note="Without planning the setpoint is the target itself (dashed line at 0 °/s). "
        + SHAFT_NOTE,
    )
