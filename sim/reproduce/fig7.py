"""Seed 000, Fig. 7: from position 0 at 400 deg/s, the targets S_1..S_4, one per strategy.

``bench_configs/fig7.toml`` holds the run-up (how the bench gets to 400 deg/s at 0) and the
move to S_1; the four runs replace the last move's target by S_1..S_4. The strategy of each
run is read back from the decoded setpoint (does it reverse? does it cruise at v_max?), and
compared with what the seed's conditions (planner.plan_trapezoid) say.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from planner import plan_trapezoid
from sim.reproduce.experiments import Runner, Trace, load, replace_move, with_duration
from sim.reproduce.metrics import RunMetrics, measure
from sim.reproduce.plots import SHAFT_NOTE, Curve, paper_figure, position_label, quick_note, sci

__all__ = [
    "PAPER_TARGETS",
    "Fig7Result",
    "Fig7Run",
    "SETTLE_S",
    "observed_strategy",
    "plot",
    "run",
]

# Seed 000, section 5: (name, target in the paper's units = mdeg, the strategy the paper
# set it up for, does the paper's curve cruise). "S_2 and S_3 have no constant-velocity part".
PAPER_TARGETS = (
    ("S_1", 1e7, "a", True),
    ("S_2", 3e6, "b", False),
    ("S_3", -3e6, "c", False),
    ("S_4", -8e6, "d", True),
)
PAPER_V0_DPS = 400.0
# Time simulated after the planned end of each move (settling, and to show the stop).
SETTLE_S = 1.0
# A cruise is at least this long at |v| = v_max (the setpoint is exact there).
_MIN_CRUISE_S = 0.1


def observed_strategy(
    trace: Trace, t_start_s: float, v_max_dps: float, v0_sign: float = 1.0
) -> tuple[str, bool, bool]:
    """Read the strategy off the board's setpoint after ``t_start_s``.

    Returns ``(case, reverses, cruises)``: ``reverses`` if the planned velocity changes sign
    against the start velocity's direction, ``cruises`` if it holds |v| = v_max for at
    least 0.1 s; the case is a (forward, cruise), b (forward), c (reverse), d (reverse,
    cruise), as in seed 000's table of strategies.
    """
    i = trace.index_at(t_start_s)
    sp = trace.sp_vel_dps[i:] * v0_sign
    reverses = bool(np.any(sp < -1e-9))
    at_vmax = np.abs(np.abs(sp) - v_max_dps) <= 1e-6 * v_max_dps
    longest = 0
    run_len = 0
    for flag in at_vmax:
        run_len = run_len + 1 if flag else 0
        longest = max(longest, run_len)
    cruises = longest * trace.dt_s >= _MIN_CRUISE_S
    case = {(False, True): "a", (False, False): "b", (True, False): "c", (True, True): "d"}
    return case[(reverses, cruises)], reverses, cruises


@dataclass(frozen=True)
class Fig7Run:
    name: str
    target_mdeg: float
    paper_case: str
    paper_cruises: bool
    planner_case: str
    observed_case: str
    cruises: bool
    reverses: bool
    t_interrupt_s: float
    start_pos_deg: float
    start_vel_dps: float
    trace: Trace
    metrics: RunMetrics


@dataclass(frozen=True)
class Fig7Result:
    runs: tuple[Fig7Run, ...]
    v_max_dps: float
    a_max_dps2: float
    time_scale: float
    run_up_s: float


def run(runner: Runner, *, scurve_ramp_s: float | None = None) -> Fig7Result:
    """Run the four targets (trapezoid, or S-curve with ``j_max = a_max / scurve_ramp_s``;
    the run-up then uses a jerk so high that it matches the trapezoid run-up's timing)."""
    from sim.reproduce.experiments import move_commands, to_scurve

    base = load("fig7")
    _, last = move_commands(base)[-1]
    v_max = float(last.get("v_max_dps"))
    a_max = float(last.get("a_max_dps2"))
    k = 4.0 if runner.quick else 1.0
    runs = []
    for name, target_mdeg, paper_case, paper_cruises in PAPER_TARGETS:
        plan = plan_trapezoid(0.0, target_mdeg / 1000.0, v_max=v_max, a_max=a_max, v0=PAPER_V0_DPS)
        exp = replace_move(base, -1, target_mdeg=target_mdeg)
        exp = with_duration(exp, last.t_s + plan.duration + SETTLE_S)
        label = f"fig7 {name}"
        if scurve_ramp_s is not None:
            exp = to_scurve(exp, scurve_ramp_s, run_up_j_max_dps3=1e6)
            label += " S-curve"
        exp = runner.prepare(exp)
        trace = runner.run(label, exp)
        t_int = trace.command_t_s[-1]
        i = trace.index_at(t_int)
        # The commanded state at the replan: the new plan starts from it (tick i).
        start_vel = float(trace.sp_vel_dps[i])
        case, reverses, cruises = observed_strategy(trace, t_int, v_max / k)
        limit = exp.bench.firmware.limits.current_limit_a
        runs.append(
            Fig7Run(
                name=name,
                target_mdeg=target_mdeg,
                paper_case=paper_case,
                paper_cruises=paper_cruises,
                planner_case=plan.case,
                observed_case=case,
                cruises=cruises,
                reverses=reverses,
                t_interrupt_s=t_int,
                start_pos_deg=float(trace.sp_pos_deg[i]) * k * k,
                start_vel_dps=start_vel * k,
                trace=trace,
                metrics=measure(trace, limit, from_t_s=t_int),
            )
        )
    return Fig7Result(tuple(runs), v_max, a_max, k, runs[0].t_interrupt_s)


def plot(
    result: Fig7Result,
    path: str | Path | None,
    current_limit_a: float,
    title: str = "",
    acceleration: bool = False,
) -> Figure:
    """Fig. 7 drawn like the paper's: the four runs, time 0 at the interrupt (returns the
    figure, saved to ``path`` if given). Labels give this run's values (``--quick`` runs
    are scaled) with the paper's target beside; ``acceleration`` adds the planned
    acceleration/jerk panel (the S-curve figure)."""
    colors = ("tab:blue", "tab:orange", "tab:green", "tab:red")
    k = result.time_scale
    curves = []
    for r, c in zip(result.runs, colors, strict=True):
        name = "S$_{" + r.name.split("_")[-1] + "}$"
        target_deg = r.target_mdeg / 1000.0 / (k * k)
        paper = f"; paper {sci(r.target_mdeg)}" if k != 1.0 else f" ({sci(r.target_mdeg)} m°)"
        label = f"{name} = {sci(target_deg)} °{paper}: case {r.observed_case}"
        curves.append(Curve(r.trace, label, c, t_offset_s=r.t_interrupt_s))
    v0 = PAPER_V0_DPS / k
    k2 = k * k
    profile = "S-curve" if acceleration else "trapezoid"
    return paper_figure(
        curves,
        path,
        title=(title or f"Fig. 7: four targets from 0 ° at {v0:g} °/s ({profile})") + quick_note(k),
        current_limit_a=current_limit_a,
        pos_label=position_label(k),
        shade=(-result.run_up_s, 0.0, f"run-up to {v0:g} °/s"),
        time_label="time from the interrupt (s)",
        acceleration=acceleration,
        note=f"Grey: the run-up (move to {-200 / k2:g} °, then towards {50000 / k2:g} ° at "
        f"{v0:g} °/s), interrupted at 0 ° by the Fig. 7 move. S$_3$ and S$_4$ share their "
        "first part: the later curve is drawn narrower. " + SHAFT_NOTE,
    )
