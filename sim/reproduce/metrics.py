"""Numbers measured on a :class:`~sim.reproduce.experiments.Trace` (what the PC decoded).

All of them come from the telemetry frames, as a PC program would compute them, except
``peak_true_current_a`` (the simulator's true armature current, for the cross-check of the
IS-pin reading).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.reproduce.experiments import Trace

__all__ = [
    "ARRIVAL_TOL_DEG",
    "RunMetrics",
    "arrival_t_s",
    "direction_of_approach",
    "measure",
    "replan_steps",
]

# A move has arrived when the encoder is within this of the target: the firmware's
# [limits] in_position_deg of paper_bench.toml, which also ends a STEP move.
ARRIVAL_TOL_DEG = 0.5


@dataclass(frozen=True)
class RunMetrics:
    """Per-run figures of merit (axis units).

    Attributes:
        max_sp_vel_step_dps: largest change of the planned velocity between two frames.
        max_vel_step_dps: largest change of the measured (estimated) velocity between two
            frames.
        max_sp_acc_dps2: largest |planned acceleration|, from the planned velocity's
            differences.
        max_sp_jerk_dps3: largest |planned jerk|, from the second differences (a trapezoid's
            acceleration steps show up as a / dt: 74,000 deg/s^3 for 148 deg/s^2).
        overshoot_deg: how far the position went beyond the final target, in the direction
            of the final approach (0 if never).
        peak_current_a: largest |current| decoded from the telemetry (IS pin).
        peak_true_current_a: largest |true armature current| (simulator only).
        current_limit_a: the firmware's limit it is compared with.
        rms_tracking_error_deg, max_tracking_error_deg: setpoint minus encoder position
            from the first command on.
        arrival_t_s: first time after the last command at which the position is within
            ARRIVAL_TOL_DEG of the final target (None if never).
        plan_end_t_s: first time after the last command at which the setpoint has reached the
            final target (None if never): the planned duration.
        faults: fault codes seen in the telemetry.
        frame_gaps: ticks without a telemetry frame (0 when the link keeps up).
    """

    name: str
    max_sp_vel_step_dps: float
    max_vel_step_dps: float
    max_sp_acc_dps2: float
    max_sp_jerk_dps3: float
    overshoot_deg: float
    peak_current_a: float
    peak_true_current_a: float
    current_limit_a: float
    rms_tracking_error_deg: float
    max_tracking_error_deg: float
    arrival_t_s: float | None
    plan_end_t_s: float | None
    faults: tuple[int, ...]
    frame_gaps: int


def direction_of_approach(trace: Trace) -> float:
    """+1 if the final move approaches its target from below, -1 from above.

    The sign of ``target - position`` where the last move was applied: after a reversal (case
    c) the approach is still towards the target from that side.
    """
    t_cmd = trace.command_t_s[-1]
    target = trace.command_target_deg[-1]
    pos = trace.pos_deg[trace.index_at(t_cmd)]
    return 1.0 if target >= pos else -1.0


def arrival_t_s(trace: Trace, tol_deg: float = ARRIVAL_TOL_DEG) -> float | None:
    """First time after the last command at which |pos - target| <= ``tol_deg``."""
    start = trace.index_at(trace.command_t_s[-1])
    err = np.abs(trace.pos_deg[start:] - trace.command_target_deg[-1])
    hits = np.flatnonzero(err <= tol_deg)
    return float(trace.t_s[start + hits[0]]) if hits.size else None


def _plan_end_t_s(trace: Trace) -> float | None:
    start = trace.index_at(trace.command_t_s[-1])
    target = trace.command_target_deg[-1]
    sp = trace.sp_pos_deg[start:]
    done = np.flatnonzero((np.abs(sp - target) <= 1e-3) & (trace.sp_vel_dps[start:] == 0.0))
    return float(trace.t_s[start + done[0]]) if done.size else None


def replan_steps(trace: Trace, window_ticks: int = 5) -> list[tuple[float, float, float]]:
    """For each move applied while the axis was moving: ``(t_s, largest planned-velocity
    step, largest measured-velocity step)`` between frames within ``window_ticks`` of it."""
    out = []
    for t_cmd in trace.command_t_s:
        k = trace.index_at(t_cmd)
        lo, hi = max(k - window_ticks, 1), min(k + window_ticks + 1, len(trace.t_s))
        if lo >= hi:
            continue
        sp_step = float(np.max(np.abs(np.diff(trace.sp_vel_dps[lo - 1 : hi]))))
        vel_step = float(np.max(np.abs(np.diff(trace.vel_dps[lo - 1 : hi]))))
        out.append((float(t_cmd), sp_step, vel_step))
    return out


def measure(trace: Trace, current_limit_a: float, from_t_s: float | None = None) -> RunMetrics:
    """Compute :class:`RunMetrics` for ``trace`` from ``from_t_s`` on (default: all of it;
    tracking errors are taken from the first command or ``from_t_s``, whichever is later)."""
    if from_t_s is not None:
        trace = trace.since(from_t_s)
    t = trace.t_s
    dt = np.diff(t)
    dt = np.where(dt > 0, dt, trace.dt_s)
    sp_vel_steps = np.abs(np.diff(trace.sp_vel_dps))
    vel_steps = np.abs(np.diff(trace.vel_dps))
    sp_acc = np.diff(trace.sp_vel_dps) / dt
    sp_jerk = np.diff(sp_acc) / dt[1:] if sp_acc.size > 1 else np.zeros(1)
    start = trace.index_at(trace.command_t_s[0]) if trace.command_t_s else 0
    err = trace.sp_pos_deg[start:] - trace.pos_deg[start:]
    d = direction_of_approach(trace) if trace.command_t_s else 1.0
    last = trace.index_at(trace.command_t_s[-1]) if trace.command_t_s else 0
    beyond = d * (trace.pos_deg[last:] - trace.command_target_deg[-1]) if trace.command_t_s else 0
    overshoot = float(max(np.max(beyond), 0.0)) if np.size(beyond) else 0.0
    faults = tuple(sorted({int(f) for f in trace.fault if f}))
    true_peak = (
        float(np.max(np.abs(trace.true_current_a))) if trace.true_current_a.size else math.nan
    )
    return RunMetrics(
        name=trace.name,
        max_sp_vel_step_dps=float(np.max(sp_vel_steps)) if sp_vel_steps.size else 0.0,
        max_vel_step_dps=float(np.max(vel_steps)) if vel_steps.size else 0.0,
        max_sp_acc_dps2=float(np.max(np.abs(sp_acc))) if sp_acc.size else 0.0,
        max_sp_jerk_dps3=float(np.max(np.abs(sp_jerk))) if sp_jerk.size else 0.0,
        overshoot_deg=overshoot,
        peak_current_a=float(np.max(np.abs(trace.current_a))),
        peak_true_current_a=true_peak,
        current_limit_a=float(current_limit_a),
        rms_tracking_error_deg=float(np.sqrt(np.mean(err * err))) if err.size else 0.0,
        max_tracking_error_deg=float(np.max(np.abs(err))) if err.size else 0.0,
        arrival_t_s=arrival_t_s(trace) if trace.command_t_s else None,
        plan_end_t_s=_plan_end_t_s(trace) if trace.command_t_s else None,
        faults=faults,
        frame_gaps=trace.frame_gaps,
    )
