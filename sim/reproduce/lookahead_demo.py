"""Beyond the paper: a multi-waypoint turntable program through the seed 001 look-ahead
against stopping at every waypoint.

``bench_configs/lookahead_program.toml`` is the program as a PC that stops at every waypoint
sends it: one move per waypoint, each sent ``DWELL_S`` (rounded up to ``GRID_S``) after the
previous one has ended by its plan. The look-ahead version is built from the same waypoints:
``planner.plan_program`` gives the junction speeds; where a junction speed is 0 (a reversal)
or at the end the turntable must stop. The board's protocol has no "pass through at speed"
message (a ``Move`` always ends at rest), so the PC sends one ``Move`` per stop point, with
the same pause after each; the board's trapezoid then passes the same-direction waypoints at
speed. The report compares the seed 001 plan with what the board executed, junction by
junction, and gives the time saved, planned and measured.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from planner import plan_program, plan_trapezoid
from sim.config import Experiment, ScriptedCommand
from sim.reproduce.experiments import Runner, Trace, load, move_commands
from sim.reproduce.metrics import arrival_t_s
from sim.reproduce.plots import SHAFT_NOTE, Curve, Marker, paper_figure, position_label, quick_note

__all__ = ["DWELL_S", "GRID_S", "LookaheadResult", "plot", "run", "schedule"]

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


@dataclass(frozen=True)
class LookaheadResult:
    waypoints_deg: tuple[float, ...]
    junction_speeds_dps: tuple[float, ...]
    stop_points_deg: tuple[float, ...]
    v_max_dps: float
    a_max_dps2: float
    plan_stop_each_s: float  # sum of the rest-to-rest trapezoids (no pauses)
    plan_lookahead_s: float  # seed 001's plan_program duration
    plan_board_lookahead_s: float  # sum of the board's trapezoids between stop points
    stop_each: Trace
    lookahead: Trace
    done_stop_each_s: float | None  # measured: arrival at the last waypoint
    done_lookahead_s: float | None
    crossing_speeds_dps: tuple[float, ...]  # measured |v| where the look-ahead run passes
    time_scale: float
    schedule_ok: bool  # the TOML follows the PC's rule


def _crossing(trace: Trace, waypoint: float, t_from: float, stop: bool) -> tuple[float, float]:
    """``(|measured velocity|, t_s)`` at ``waypoint`` after ``t_from``: where the encoder
    first passes it, or for a stop point (which the axis need not pass) where the setpoint
    comes to rest on it. ``(NaN, t_from)`` if never."""
    i0 = trace.index_at(t_from)
    if stop:
        at = (np.abs(trace.sp_pos_deg[i0:] - waypoint) <= 1e-6) & (trace.sp_vel_dps[i0:] == 0.0)
        hits = np.flatnonzero(at)
    else:
        pos = trace.pos_deg[i0:] - waypoint
        hits = np.flatnonzero(np.sign(pos[:-1]) * np.sign(pos[1:]) <= 0)
    if not hits.size:
        return math.nan, t_from
    i = i0 + int(hits[0])
    return float(abs(trace.vel_dps[i])), float(trace.t_s[min(i + 1, len(trace.t_s) - 1)])


def run(runner: Runner) -> LookaheadResult:
    exp = load("lookahead_program")
    moves = [c for _, c in move_commands(exp)]
    v_max = float(moves[0].get("v_max_dps"))
    a_max = float(moves[0].get("a_max_dps2"))
    targets = [float(c.get("target_deg")) for c in moves]
    waypoints = [0.0] + targets
    la = plan_program(waypoints, v_max=v_max, a_max=a_max)
    speeds = tuple(float(v) for v in la.speeds)
    stops = [w for w, v in zip(waypoints[1:-1], speeds[1:-1], strict=True) if v == 0.0]
    stops.append(waypoints[-1])
    expected = schedule(targets, v_max, a_max)
    schedule_ok = bool(np.allclose(expected, [c.t_s for c in moves], atol=1e-9))

    la_times = schedule(stops, v_max, a_max)
    template = moves[0]
    commands = []
    prev = 0.0
    end = 0.0
    plan_board = 0.0
    for t_s, target in zip(la_times, stops, strict=True):
        values = dict(template.fields)
        values["target_deg"] = target
        commands.append(ScriptedCommand(t_s, "move", tuple(values.items())))
        duration = plan_trapezoid(prev, target, v_max=v_max, a_max=a_max).duration
        plan_board += duration
        end = t_s + duration
        prev = target
    la_exp: Experiment = dataclasses.replace(
        exp,
        commands=tuple(commands),
        duration_s=end + SETTLE_S,
        title="Waypoint program through the look-ahead (stops at reversals only)",
    )
    plan_stop_each = sum(
        plan_trapezoid(a, b, v_max=v_max, a_max=a_max).duration
        for a, b in zip(waypoints[:-1], waypoints[1:], strict=True)
    )
    k = 4.0 if runner.quick else 1.0
    stop_trace = runner.run("waypoints, stop at each", runner.prepare(exp))
    la_trace = runner.run("waypoints, look-ahead", runner.prepare(la_exp))
    done_stop = arrival_t_s(stop_trace)
    done_la = arrival_t_s(la_trace)
    crossings = []
    t_from = 0.0
    for w, v in zip(waypoints[1:-1], speeds[1:-1], strict=True):
        speed, t_from = _crossing(la_trace, w / (k * k), t_from, stop=v == 0.0)
        crossings.append(speed * k)
    return LookaheadResult(
        waypoints_deg=tuple(waypoints),
        junction_speeds_dps=speeds,
        stop_points_deg=tuple(stops),
        v_max_dps=v_max,
        a_max_dps2=a_max,
        plan_stop_each_s=plan_stop_each,
        plan_lookahead_s=la.duration,
        plan_board_lookahead_s=plan_board,
        stop_each=stop_trace,
        lookahead=la_trace,
        done_stop_each_s=None if done_stop is None else done_stop * k,
        done_lookahead_s=None if done_la is None else done_la * k,
        crossing_speeds_dps=tuple(crossings),
        time_scale=k,
        schedule_ok=schedule_ok,
    )


def plot(result: LookaheadResult, path: str | Path | None, current_limit_a: float) -> Figure:
    """Stop at every waypoint against the look-ahead (returns the figure, saved to
    ``path`` if given; labels give this run's values, scaled under ``--quick``)."""
    k = result.time_scale
    markers = []
    for name, t in (("stop at each: done", result.done_stop_each_s),
                    ("look-ahead: done", result.done_lookahead_s)):  # fmt: skip
        if t is not None:
            markers.append(Marker(t / k, name, at_top=False))
    wp = ", ".join(f"{w / (k * k):g}" for w in result.waypoints_deg)
    return paper_figure(
        [
            Curve(result.stop_each, "stop at every waypoint", "tab:gray"),
            Curve(result.lookahead, "seed 001 look-ahead (stop at reversals only)", "tab:blue"),
        ],
        path,
        title=f"Waypoint program {wp} ° ($v_{{max}}$ {result.v_max_dps / k:g} °/s, "
        f"$a_{{max}}$ {result.a_max_dps2:g} °/s$^2$)"
        + ("\n" + quick_note(k).strip() if k != 1.0 else ""),
        current_limit_a=current_limit_a,
        pos_label=position_label(k),
        markers=markers,
        note=f"Each stop is followed by a {DWELL_S / k:g} s pause (the PC's rule); dotted lines: "
        "arrival at the last waypoint. " + SHAFT_NOTE,
    )
