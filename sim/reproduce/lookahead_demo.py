"""Beyond the paper: seed 001's multi-waypoint program run by the board's own look-ahead
queue, against stopping at every waypoint and against the PC-side plan.

``bench_configs/lookahead_program.toml`` is the program as a PC that stops at every waypoint
sends it: one ``Move`` per waypoint, each sent ``DWELL_S`` (rounded up to ``GRID_S``) after
the previous one has ended by its plan. The look-ahead version sends the same waypoints at
once as ``QueueSegment`` blocks (docs/protocol.md 4.5) after a ``SetLimits`` giving the
program's a_max: the board plans the junction speeds itself with seed 001's look-ahead over
what it holds, passes same-direction waypoints at speed and comes to rest where the
direction reverses, each reversal block carrying a ``DWELL_S`` dwell (the same pause after
each stop as the stop-at-each PC). The PC-side plan is ``planner.plan_program`` over the same
waypoints (not run). The report compares the junction speeds planned on the PC with the
board's setpoint and the encoder at each waypoint, and the times.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from planner import plan_program, plan_trapezoid
from sim.config import Experiment, ScriptedCommand
from sim.reproduce.experiments import Runner, Trace, load, move_commands
from sim.reproduce.plots import (
    SHAFT_NOTE,
    Curve,
    Marker,
    Point,
    paper_figure,
    position_label,
    quick_note,
)
from sim.reproduce.programs_demo import crossing, rest_t_s

__all__ = [
    "DWELL_S",
    "crossing_speeds",
    "max_err",
    "GRID_S",
    "LookaheadResult",
    "plot",
    "queue_experiment",
    "reversals",
    "run",
    "schedule",
]

DWELL_S = 0.2  # pause after each stop (the PC's rule in lookahead_program.toml)
GRID_S = 0.01  # the PC sends on a 10 ms grid
SETTLE_S = 1.0


def schedule(stops: list[float], v_max: float, a_max: float, p0: float = 0.0) -> list[float]:
    """Send times of moves to ``stops`` (each from rest at the previous one) by the PC's rule:
    ``DWELL_S`` after the planned end of the previous move, rounded up to ``GRID_S``."""
    times = []
    t = 0.0
    prev = p0
    for target in stops:
        times.append(t)
        duration = plan_trapezoid(prev, target, v_max=v_max, a_max=a_max).duration
        t = math.ceil((t + duration + DWELL_S) / GRID_S - 1e-9) * GRID_S
        prev = target
    return times


def reversals(waypoints: list[float] | tuple[float, ...]) -> list[bool]:
    """For each waypoint after the first: whether the path reverses (or ends) there."""
    w = waypoints
    return [k == len(w) - 1 or (w[k] - w[k - 1]) * (w[k + 1] - w[k]) < 0.0
            for k in range(1, len(w))]  # fmt: skip


@dataclass(frozen=True)
class LookaheadResult:
    """Speeds in deg/s, times in s, positions in axis degrees; the traces are as run
    (scaled by ``time_scale`` under ``--quick``), every other figure at full scale."""

    waypoints_deg: tuple[float, ...]
    junction_speeds_dps: tuple[float, ...]  # PC-side plan (plan_program), every waypoint
    stop_points_deg: tuple[float, ...]
    v_max_dps: float
    a_max_dps2: float
    plan_stop_each_s: float  # sum of the rest-to-rest trapezoids (no pauses)
    plan_lookahead_s: float  # the PC-side plan's duration (no pauses)
    board_motion_s: float  # the board's queue run: first setpoint motion to rest, less dwells
    stop_each: Trace
    queue: Trace
    done_stop_each_s: float | None  # setpoint at rest at the last waypoint, from the first send
    done_queue_s: float | None
    board_speeds_dps: tuple[float, ...]  # the board's setpoint |v| at each inner waypoint
    crossing_speeds_dps: tuple[float, ...]  # the encoder's |v| there
    max_err_queue_deg: float  # max |setpoint - encoder| as run (not rescaled under --quick)
    max_err_stop_each_deg: float
    time_scale: float
    schedule_ok: bool  # the TOML follows the PC's rule
    nacks: int  # NACKs in both runs (0 for a valid run)


def queue_experiment(exp: Experiment, waypoints: list[float], v_max: float, a_max: float
                     ) -> Experiment:  # fmt: skip
    """The program as ``QueueSegment`` blocks, all sent at 0 after a ``SetLimits`` with the
    program's a_max (the queue's acceleration) and v_max; a ``DWELL_S`` dwell at every
    reversal and none at the end."""
    cmds = [
        ScriptedCommand(0.0, "set_limits", (
            ("v_max_dps", v_max), ("a_max_dps2", a_max), ("current_limit_a", 5.0),
            ("following_error_deg", 30.0))),
    ]  # fmt: skip
    for target, stop in zip(waypoints[1:], reversals(waypoints), strict=True):
        dwell = DWELL_S if stop and target != waypoints[-1] else 0.0
        cmds.append(ScriptedCommand(0.0, "queue_segment", (
            ("target_deg", target), ("v_max_dps", v_max), ("dwell_s", dwell))))  # fmt: skip
    plan = plan_program(waypoints, v_max=v_max, a_max=a_max)
    n_dwell = sum(reversals(waypoints)) - 1
    return dataclasses.replace(
        exp,
        commands=tuple(cmds),
        duration_s=plan.duration + n_dwell * DWELL_S + SETTLE_S,
        title="Waypoint program through the board's look-ahead queue",
    )


def crossing_speeds(
    trace: Trace, waypoints: Sequence[float], a_max_dps2: float, k: float = 1.0
) -> tuple[list[float], list[float]]:
    """The board's setpoint |v| and the encoder's |v| where the queue run ``trace`` first
    reaches each inner waypoint (paper scale: ``waypoints`` in full-scale degrees, speeds
    times ``k`` for a ``--quick`` run)."""
    w_run = [w / (k * k) for w in waypoints]
    board, encoder = [], []
    t_from = 0.0
    for n in range(1, len(w_run) - 1):
        direction = 1.0 if w_run[n] > w_run[n - 1] else -1.0
        v_sp, v_enc, t_from = crossing(trace, w_run[n], t_from, direction, a_max_dps2)
        board.append(v_sp * k)
        encoder.append(v_enc * k)
    return board, encoder


def max_err(trace: Trace) -> float:
    """Largest |setpoint - encoder| (deg) as run (a tracking error does not scale as k^2)."""
    return float(np.max(np.abs(trace.sp_pos_deg - trace.pos_deg)))


def run(runner: Runner) -> LookaheadResult:
    exp = load("lookahead_program")
    moves = [c for _, c in move_commands(exp)]
    v_max = float(moves[0].get("v_max_dps"))
    a_max = float(moves[0].get("a_max_dps2"))
    targets = [float(c.get("target_deg")) for c in moves]
    waypoints = [0.0] + targets
    la = plan_program(waypoints, v_max=v_max, a_max=a_max)
    speeds = tuple(float(v) for v in la.speeds)
    stops = [w for w, r in zip(waypoints[1:], reversals(waypoints), strict=True) if r]
    expected = schedule(targets, v_max, a_max)
    schedule_ok = bool(np.allclose(expected, [c.t_s for c in moves], atol=1e-9))
    plan_stop_each = sum(
        plan_trapezoid(a, b, v_max=v_max, a_max=a_max).duration
        for a, b in zip(waypoints[:-1], waypoints[1:], strict=True)
    )
    k = 4.0 if runner.quick else 1.0
    stop_trace = runner.run("waypoints, stop at each", runner.prepare(exp))
    q_exp = queue_experiment(exp, waypoints, v_max, a_max)
    q_trace = runner.run("waypoints, board queue", runner.prepare(q_exp))
    board, crossings = crossing_speeds(q_trace, waypoints, a_max, k)
    done_stop = rest_t_s(stop_trace, 0.0, waypoints[-1] / (k * k))
    done_q = rest_t_s(q_trace, 0.0, waypoints[-1] / (k * k))
    moving = np.flatnonzero(q_trace.sp_vel_dps != 0.0)
    board_motion = (
        math.nan if done_q is None or not moving.size
        else (done_q - float(q_trace.t_s[moving[0]])) * k - (len(stops) - 1) * DWELL_S
    )  # fmt: skip

    return LookaheadResult(
        waypoints_deg=tuple(waypoints),
        junction_speeds_dps=speeds,
        stop_points_deg=tuple(stops),
        v_max_dps=v_max,
        a_max_dps2=a_max,
        plan_stop_each_s=plan_stop_each,
        plan_lookahead_s=la.duration,
        board_motion_s=board_motion,
        stop_each=stop_trace,
        queue=q_trace,
        done_stop_each_s=None if done_stop is None else done_stop * k,
        done_queue_s=None if done_q is None else done_q * k,
        board_speeds_dps=tuple(board),
        crossing_speeds_dps=tuple(crossings),
        max_err_queue_deg=max_err(q_trace),
        max_err_stop_each_deg=max_err(stop_trace),
        time_scale=k,
        schedule_ok=schedule_ok,
        nacks=len(stop_trace.nacks) + len(q_trace.nacks),
    )


def plot(result: LookaheadResult, path: str | Path | None, current_limit_a: float) -> Figure:
    """Stop at every waypoint against the board's look-ahead queue; crosses: the PC-side
    plan's junction speeds where the queue run crosses each waypoint (returns the figure,
    saved to ``path`` if given; labels give this run's values, scaled under ``--quick``)."""
    k = result.time_scale
    markers = []
    for name, t in (("stop at each: done", result.done_stop_each_s),
                    ("board queue: done", result.done_queue_s)):  # fmt: skip
        if t is not None:
            markers.append(Marker(t / k, name, at_top=False))
    w = [x / (k * k) for x in result.waypoints_deg]
    points = []
    t_from = 0.0
    for n, v in enumerate(result.junction_speeds_dps[1:-1], start=1):
        direction = 1.0 if w[n] > w[n - 1] else -1.0
        _, _, t_from = crossing(result.queue, w[n], t_from, direction, result.a_max_dps2)
        points.append(Point(t_from, direction * v / k, ""))
    wp = ", ".join(f"{x:g}" for x in w)
    return paper_figure(
        [
            Curve(result.stop_each, "PC stops at every waypoint (a Move each)", "tab:gray"),
            Curve(
                result.queue, "board's queue (QueueSegment; look-ahead on the board)", "tab:blue"
            ),  # fmt: skip
        ],
        path,
        title=f"Waypoint program {wp} ° ($v_{{max}}$ {result.v_max_dps / k:g} °/s, "
        f"$a_{{max}}$ {result.a_max_dps2:g} °/s$^2$)"
        + ("\n" + quick_note(k).strip() if k != 1.0 else ""),
        current_limit_a=current_limit_a,
        pos_label=position_label(k),
        markers=markers,
        points=points,
        points_label="PC-side plan's junction speed (plan_program)",
        note=f"Each stop is followed by a {DWELL_S / k:g} s pause (the PC's rule; a dwell in "
        "the queue's reversal blocks); dotted lines: at rest at the last waypoint. " + SHAFT_NOTE,
    )
