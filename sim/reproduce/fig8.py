"""Seed 000, Fig. 8 / Table 1: four moves, the last three replanned before the previous one
ended; the state (rest, accelerating, cruising, decelerating) and the velocity at each
replan, paper against simulation, and the a_max each row of Table 1 implies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from planner import OnlinePlanner
from sim.reproduce.experiments import Runner, Trace, load
from sim.reproduce.metrics import RunMetrics, measure, replan_steps
from sim.reproduce.plots import (
    SHAFT_NOTE,
    Curve,
    Marker,
    Point,
    paper_figure,
    position_label,
    quick_note,
    sci,
)

__all__ = [
    "PAPER_TABLE1",
    "Fig8Result",
    "ReplanRow",
    "classify_state",
    "implied_a_max",
    "plan_states",
    "plot",
    "run",
]

# Seed 000, Table 1: (target in the paper's units = mdeg, state at replan, velocity at
# replan in deg/s, time in s).
PAPER_TABLE1 = (
    (3e6, "at rest", 0.0, 0.0),
    (-8e6, "accelerating", 296.0, 2.0),
    (-6e6, "cruising", -990.0, 10.0),
    (-1e6, "decelerating", -294.0, 16.0),
)

# |planned acceleration| below this is "cruising"; |planned velocity| below the other is
# "at rest" (the setpoint is exact: its rounding is far below these).
_CRUISE_ACC_DPS2 = 1.0
_REST_VEL_DPS = 1e-6


def classify_state(vel_dps: float, acc_dps2: float) -> str:
    """ "at rest", "cruising", "accelerating" or "decelerating" (speed growing or shrinking)."""
    if abs(vel_dps) <= _REST_VEL_DPS and abs(acc_dps2) <= _CRUISE_ACC_DPS2:
        return "at rest"
    if abs(acc_dps2) <= _CRUISE_ACC_DPS2:
        return "cruising"
    if abs(vel_dps) <= _REST_VEL_DPS:
        return "accelerating"
    return "accelerating" if vel_dps * acc_dps2 > 0.0 else "decelerating"


@dataclass(frozen=True)
class ReplanRow:
    """One row of Table 1, paper and simulation side by side. Times, velocities and
    positions are in the paper's scale also for a ``--quick`` run; the velocity steps (per
    2 ms tick: a_max dt, which the time scaling keeps) are as measured."""

    target_mdeg: float
    paper_state: str
    paper_vel_dps: float
    paper_t_s: float
    sim_t_s: float
    sim_state: str
    sim_sp_vel_dps: float
    sim_vel_dps: float
    sim_sp_pos_deg: float
    sp_vel_step_dps: float
    vel_step_dps: float


@dataclass(frozen=True)
class Fig8Result:
    trace: Trace
    metrics: RunMetrics
    rows: tuple[ReplanRow, ...]
    a_max_dps2: float
    time_scale: float
    profile: str


def plan_states(a_max: float, v_max: float = 990.0) -> list[tuple[float, float, float, str]]:
    """The planner alone (no bench) through Table 1's four commands with one ``a_max``:
    ``(t_s, p_deg, v_dps, case)`` of the commanded state at each replan instant."""
    planner = OnlinePlanner("trapezoid")
    planner.reset(0.0)
    out = []
    for target_mdeg, _, _, t_s in PAPER_TABLE1:
        p, v, a = planner.sample(t_s)
        prof = planner.command(t_s, target_mdeg / 1000.0, v_max=v_max, a_max=a_max)
        out.append((t_s, p, v, classify_state(v, a) + f"/{prof.case}"))
    return out


def implied_a_max() -> dict[str, float]:
    """The a_max each row of Table 1 asks for, planner only (see REPORT.md).

    * row 2: 296 deg/s at 2 s, accelerating from rest: a = 296 / 2.
    * row 3: already cruising at -990 deg/s at 10 s after reversing from +296 at 2 s:
      (296 + 990) / a <= 8 s, so a >= 160.75.
    * row 4: -294 deg/s at 16 s (decelerating): solved by bisection on the planner.
    """
    row2 = PAPER_TABLE1[1][2] / PAPER_TABLE1[1][3]
    row3 = (PAPER_TABLE1[1][2] - PAPER_TABLE1[2][2]) / (PAPER_TABLE1[2][3] - PAPER_TABLE1[1][3])
    target = PAPER_TABLE1[3][2]

    def v16(a: float) -> float:
        return plan_states(a)[3][2]

    lo, hi = 100.0, 400.0
    f_lo = v16(lo) - target
    row4 = math.nan
    if f_lo * (v16(hi) - target) < 0.0:
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            f_mid = v16(mid) - target
            if f_mid * f_lo > 0.0:
                lo, f_lo = mid, f_mid
            else:
                hi = mid
        row4 = 0.5 * (lo + hi)
    return {"row2": row2, "row3_min": row3, "row4": row4}


def _rows(trace: Trace, k: float) -> tuple[ReplanRow, ...]:
    steps = {round(t, 6): (s, v) for t, s, v in replan_steps(trace)}
    rows = []
    for n, (target_mdeg, state, vel, t_paper) in enumerate(PAPER_TABLE1):
        t_cmd = trace.command_t_s[n]
        i = trace.index_at(t_cmd)
        before = max(i - 1, 0)
        # The commanded state when the interrupt arrived, which the new plan starts from
        # (tick i), and the acceleration of the old plan just before it.
        v_sp = float(trace.sp_vel_dps[i])
        a_sp = float((trace.sp_vel_dps[i] - trace.sp_vel_dps[before]) / trace.dt_s)
        sp_step, vel_step = steps.get(round(t_cmd, 6), (0.0, 0.0))
        rows.append(
            ReplanRow(
                target_mdeg=target_mdeg,
                paper_state=state,
                paper_vel_dps=vel,
                paper_t_s=t_paper,
                sim_t_s=t_cmd * k,
                sim_state=classify_state(v_sp, a_sp) if i > 0 else "at rest",
                sim_sp_vel_dps=v_sp * k,
                sim_vel_dps=float(trace.vel_dps[i]) * k,
                sim_sp_pos_deg=float(trace.sp_pos_deg[i]) * k * k,
                sp_vel_step_dps=sp_step,
                vel_step_dps=vel_step,
            )
        )
    return tuple(rows)


def run(runner: Runner, *, scurve_ramp_s: float | None = None) -> Fig8Result:
    """Run Fig. 8 (trapezoid, or S-curve with ``j_max = a_max / scurve_ramp_s``)."""
    from sim.reproduce.experiments import to_scurve

    exp = load("fig8")
    profile = "trapezoid"
    if scurve_ramp_s is not None:
        exp = to_scurve(exp, scurve_ramp_s)
        profile = "scurve"
    exp = runner.prepare(exp)
    name = "fig8" if profile == "trapezoid" else "fig8 S-curve"
    trace = runner.run(name, exp)
    k = 4.0 if runner.quick else 1.0
    limit = exp.bench.firmware.limits.current_limit_a
    a_max = float(trace.command_a_max_dps2[0])
    return Fig8Result(trace, measure(trace, limit), _rows(trace, k), a_max, k, profile)


def run_choices(runner: Runner) -> tuple[Fig8Result, Fig8Result]:
    """Fig. 8 under two choices the paper leaves open (issue 13 §3): one a_max per move
    matching Table 1 exactly (``sensitivity.TABLE1_A_MAX``), and no velocity or acceleration
    feed-forward (the paper's Fig. 5 sends the position command only; ``sensitivity.FF_OFF``,
    which raises the following-error trip to 360 deg so that the whole motion shows)."""
    import dataclasses

    from sim.loop import apply_overrides
    from sim.reproduce.sensitivity import FF_OFF, table1_experiment

    base = load("fig8")
    out = []
    for name, exp in (
        ("fig8, a_max per move (Table 1)", table1_experiment()),
        ("fig8, no feed-forward (Fig. 5)",
         dataclasses.replace(base, bench=apply_overrides(base.bench, FF_OFF))),
    ):  # fmt: skip
        exp = runner.prepare(exp)
        trace = runner.run(name, exp)
        k = 4.0 if runner.quick else 1.0
        limit = exp.bench.firmware.limits.current_limit_a
        a_max = float(trace.command_a_max_dps2[0])
        out.append(Fig8Result(trace, measure(trace, limit), _rows(trace, k), a_max, k, "trapezoid"))
    return out[0], out[1]


def plot(result: Fig8Result, path: str | Path | None, current_limit_a: float) -> Figure:
    """Fig. 8 drawn like the paper's: replan instants marked, and the paper's Table 1
    velocities crossed at the paper's times, so that the difference is visible (returns the
    figure, saved to ``path`` if given)."""
    tr = result.trace
    k = result.time_scale
    markers = []
    for n, (t_cmd, target) in enumerate(zip(tr.command_t_s, tr.command_target_deg, strict=True)):
        markers.append(Marker(t_cmd, f"S$_{n + 1}$ = {sci(target)} °"))
    scaled = f" (÷{k:g})" if k != 1.0 else ""
    points = [
        Point(t_s / k, vel / k, f"Table 1{scaled}: {sci(vel / k)} °/s at {t_s / k:g} s")
        for _, _, vel, t_s in PAPER_TABLE1[1:]
    ]
    profile = "S-curve" if result.profile == "scurve" else result.profile
    a_text = f"$a_{{max}}$ = {result.a_max_dps2:g} °/s$^2$"
    title = f"Fig. 8: four moves, replanned before each ended ({profile}, {a_text})"
    return paper_figure(
        [Curve(tr, "measured (board velocity estimate)", "tab:blue")],
        path,
        title=title + quick_note(k),
        current_limit_a=current_limit_a,
        pos_label=position_label(k),
        markers=markers,
        points=points,
        acceleration=result.profile == "scurve",
        note="Dotted lines: the instants at which the board received each target (the "
        "paper's replans; paper targets 3, −8, −6, −1 ×10$^6$ m°). Crosses: the paper's "
        "Table 1. Data: telemetry frames decoded by the PC. " + SHAFT_NOTE,
    )


def vel_at(trace: Trace, t_s: float) -> float:
    """The measured velocity at ``t_s`` (for tests and the report)."""
    return float(np.interp(t_s, trace.t_s, trace.vel_dps))
