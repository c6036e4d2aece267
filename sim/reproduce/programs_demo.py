"""Beyond the paper (issue #14 §3): whole motion programs and streams run by the board.

1. **The inspection scan** (``bench_configs/inspection_scan.toml``: four sectors crossed at
   20 deg/s, transits at 300 deg/s, three reversals, a pause at home) three ways:

   * through the board's **program queue** (``QueueSegment``; the board plans the junction
     speeds with seed 001's look-ahead over what it holds, docs/protocol.md 4.5);
   * **stopping at every waypoint**: one ``Move`` per block (the block's speed limit), each
     sent when the previous one has ended by its plan (rounded up to the PC's 10 ms grid);
   * the **PC-side plan**: the same blocks through ``planner.lookahead.LookaheadQueue``
     holding the whole program (what the board's queue must match), not run.

   Reported: junction speeds planned and executed (the board's setpoint and the encoder
   velocity where the axis crosses each waypoint), the time saved, the tracking error.
2. **Seed 002's Tables 1 and 2 streamed** (``StreamPoints``, PVT every 150 ms from the
   planner's fixed-period samples, docs/protocol.md 4.6): the board's setpoint and encoder
   position every 75 ticks from the stream's start, against the tables.

Both run as written under ``--quick`` (28 s of simulated time, well under a second of wall
time; the 150 ms grid and the programs' speeds do not survive a time scaling).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

import bench_configs
from planner import sample_fixed_period, scurve_from_periods, trapezoid_from_periods
from planner.lookahead import LookaheadQueue
from planner.trapezoid import plan_trapezoid
from serial_protocol.messages import Interp, State
from sim.config import Experiment, ScriptedCommand, stream_commands
from sim.motionfile import load_program
from sim.reproduce import seed002
from sim.reproduce.experiments import Runner, Trace, load
from sim.reproduce.plots import SHAFT_NOTE, Curve, Marker, Point, paper_figure

__all__ = [
    "ProgramsResult",
    "crossing",
    "junction_speeds",
    "max_err",
    "plot_programs",
    "plot_stream",
    "rest_t_s",
    "run",
    "stream_rows",
]

A_MAX_DPS2 = 500.0  # the program's acceleration (SetLimits before it; the queue uses it)
V_LIMIT_DPS = 990.0
GRID_S = 0.01  # the stop-at-each PC sends on a 10 ms grid
T_START_S = 0.1  # when the PC sends the program (after SetLimits at 0)
SETTLE_S = 0.6
PERIOD_S = seed002.PERIOD_S


@dataclass(frozen=True)
class ProgramsResult:
    waypoints_deg: tuple[float, ...]  # start, then each block's target
    block_v_dps: tuple[float, ...]
    dwell_s: tuple[float, ...]
    planned_junction_dps: tuple[float, ...]  # PC-side plan, junctions 1..n-1
    board_junction_dps: tuple[float, ...]  # the board's setpoint |v| crossing each junction
    measured_junction_dps: tuple[float, ...]  # the encoder's |v| there
    plan_s: float  # PC-side plan: at rest at the last waypoint (dwells before it included)
    plan_stop_each_s: float  # sum of the rest-to-rest trapezoids (and dwells before the end)
    done_queue_s: float | None  # measured from the first block sent to rest at the end
    done_stop_each_s: float | None
    max_err_queue_deg: float
    max_err_stop_each_deg: float
    queue: Trace
    stop_each: Trace
    stream: Trace
    tables: tuple[seed002.TableComparison, seed002.TableComparison]
    # per table: the board's setpoint velocity and the encoder's velocity at each row
    table_vel_dps: tuple[tuple[np.ndarray, np.ndarray], ...]
    # per table: when its stream was sent (s) and the position it starts from (deg)
    stream_starts: tuple[tuple[float, float], ...] = ()


def _limits(t_s: float) -> ScriptedCommand:
    return ScriptedCommand(t_s, "set_limits", (
        ("v_max_dps", V_LIMIT_DPS), ("a_max_dps2", A_MAX_DPS2), ("current_limit_a", 5.0),
        ("following_error_deg", 30.0)))  # fmt: skip


def pc_plan(blocks: tuple[tuple[float, float, float], ...], p0: float = 0.0) -> list:
    """The PC-side plan of the program: ``LookaheadQueue`` holding all of it, flushed
    (the segments, each with its profile; dwells are stops at its end)."""
    la = LookaheadQueue(p0, v_max=V_LIMIT_DPS, a_max=A_MAX_DPS2, period=0.002,
                        window=max(1, len(blocks)))  # fmt: skip
    for target, v, dwell in blocks:
        la.append(target, v_max=v, stop=dwell > 0.0)
    return la.flush()


def crossing(trace: Trace, waypoint: float, t_from: float, direction: float,
             a_max_dps2: float = A_MAX_DPS2) -> tuple[float, float, float]:  # fmt: skip
    """``(|setpoint v|, |encoder v|, t_s)`` where the setpoint first reaches ``waypoint``
    moving in ``direction`` after ``t_from`` (within what one tick at ``a_max_dps2`` moves
    near a stop: the setpoint of a reversal comes to rest there between two ticks)."""
    i0 = trace.index_at(t_from)
    d = (trace.sp_pos_deg[i0:] - waypoint) * direction
    hits = np.flatnonzero(d >= -a_max_dps2 * trace.dt_s**2)
    if not hits.size:
        return math.nan, math.nan, t_from
    i = i0 + int(hits[0])
    return abs(float(trace.sp_vel_dps[i])), abs(float(trace.vel_dps[i])), float(trace.t_s[i])


def rest_t_s(trace: Trace, t_from: float, target: float) -> float | None:
    """When the setpoint comes to rest at ``target`` for good (after ``t_from``)."""
    i0 = trace.index_at(t_from)
    moving = np.flatnonzero(
        (np.abs(trace.sp_pos_deg[i0:] - target) > 1e-6) | (trace.sp_vel_dps[i0:] != 0.0)
    )
    if not moving.size:
        return None
    i = i0 + int(moving[-1]) + 1
    return float(trace.t_s[i]) if i < len(trace.t_s) else None


def junction_speeds(trace: Trace, waypoints: tuple[float, ...]) -> tuple[list, list]:
    """The board's setpoint |v| and the encoder's |v| where the queue run ``trace``
    crosses each inner waypoint (deg/s)."""
    board, measured = [], []
    t_from = T_START_S
    for k in range(1, len(waypoints) - 1):
        direction = 1.0 if waypoints[k] > waypoints[k - 1] else -1.0
        v_sp, v_enc, t_from = crossing(trace, waypoints[k], t_from, direction)
        board.append(v_sp)
        measured.append(v_enc)
    return board, measured


def max_err(trace: Trace) -> float:
    """Largest |setpoint - encoder| while moving (deg)."""
    live = trace.state == int(State.MOVING)
    return float(np.max(np.abs(trace.sp_pos_deg - trace.pos_deg)[live]))


def stream_rows(trace: Trace, t_s: float, rows: int) -> np.ndarray:
    """Indices of the frames every 150 ms of a stream sent at ``t_s``, ``rows`` of them,
    from its start (the first MOVING frame after its START)."""
    i0 = trace.index_at(t_s)
    i_start = i0 + int(np.argmax(trace.state[i0:] == int(State.MOVING)))
    ticks = int(round(PERIOD_S / trace.dt_s))
    return np.minimum(i_start + ticks * np.arange(rows), len(trace.t_s) - 1)


def _table_stream(table: int, p0: float) -> tuple[list[float], list[float], object]:
    if table == 1:
        prof = trapezoid_from_periods(120.0, 50.0, PERIOD_S, n_acc=4)
    else:
        prof = scurve_from_periods(120.0, 50.0, PERIOD_S, n_jerk=3, n_const=3)
    s = sample_fixed_period(prof, PERIOD_S)
    return [p0 + p for p in s.p[1:]], list(s.v[1:]), s


def run(runner: Runner) -> ProgramsResult:
    prog = load_program(bench_configs.path("inspection_scan.toml"))
    blocks = prog.blocks
    bench = load("inspection_scan_run").bench
    waypoints = (0.0, *(b[0] for b in blocks))
    # 1. the PC-side plan
    segs = pc_plan(blocks)
    planned = tuple(abs(float(s.profile.v0)) for s in segs[1:])
    plan_s = sum(s.profile.duration for s in segs) + sum(b[2] for b in blocks[:-1])
    # 2. through the queue
    cmds = [_limits(0.0)] + [
        ScriptedCommand(T_START_S, "queue_segment",
                        (("target_deg", t), ("v_max_dps", v), ("dwell_s", d)))
        for t, v, d in blocks
    ]  # fmt: skip
    queue_exp = Experiment(bench, T_START_S + plan_s + blocks[-1][2] + SETTLE_S, tuple(cmds),
                           title="inspection scan through the board's queue")  # fmt: skip
    # 3. stopping at every waypoint: a Move per block on the PC's 10 ms grid
    cmds = [_limits(0.0)]
    t, prev, plan_each = T_START_S, 0.0, -blocks[-1][2]
    for target, v, dwell in blocks:
        cmds.append(ScriptedCommand(t, "move", (("target_deg", target), ("v_max_dps", v),
                                                ("a_max_dps2", A_MAX_DPS2))))  # fmt: skip
        d = plan_trapezoid(prev, target, v_max=v, a_max=A_MAX_DPS2).duration + dwell
        plan_each += d
        t = math.ceil((t + d) / GRID_S - 1e-9) * GRID_S
        prev = target
    stop_exp = Experiment(bench, t + SETTLE_S, tuple(cmds),
                          title="inspection scan, stopping at every waypoint")  # fmt: skip
    q_trace = runner.run("inspection scan, board queue", queue_exp)
    s_trace = runner.run("inspection scan, stop at each", stop_exp)
    board, measured = junction_speeds(q_trace, waypoints)
    done_q = rest_t_s(q_trace, T_START_S, waypoints[-1])
    done_s = rest_t_s(s_trace, T_START_S, waypoints[-1])

    # 4. seed 002's tables streamed: Table 1 from 0, Table 2 from 120 deg
    p1, v1, s1 = _table_stream(1, 0.0)
    p2, v2, s2 = _table_stream(2, 120.0)
    t2 = 0.1 + len(p1) * PERIOD_S + 0.6
    cmds = stream_commands(0.1, p1, v1, PERIOD_S, Interp.CUBIC, len(p1))
    cmds += stream_commands(t2, p2, v2, PERIOD_S, Interp.CUBIC, len(p2))
    stream_exp = Experiment(bench, t2 + len(p2) * PERIOD_S + 0.6, tuple(cmds),
                            title="seed 002 Tables 1 and 2 streamed")  # fmt: skip
    st_trace = runner.run("seed 002 tables, streamed", stream_exp)
    tables = []
    table_vel = []
    for k, (t_s, s, start, name, paper) in enumerate((
        (0.1, s1, 0.0, "Table 1 (trapezoid), streamed", seed002.PAPER_TABLE1),
        (t2, s2, 120.0, "Table 2 (S-curve), streamed", seed002.PAPER_TABLE2),
    )):  # fmt: skip
        idx = stream_rows(st_trace, t_s, len(s.p))
        cols = [s.p, s.v, s.a_held] if k == 0 else [s.p, s.v, s.a, s.j_held]
        names = ("position", "velocity", "acceleration") + (("jerk",) if k else ())
        tables.append(seed002.TableComparison(
            name, names, np.array(paper, dtype=float), np.column_stack(cols),
            st_trace.sp_pos_deg[idx] - start, st_trace.pos_deg[idx] - start))  # fmt: skip
        table_vel.append((st_trace.sp_vel_dps[idx], st_trace.vel_dps[idx]))
    return ProgramsResult(
        waypoints_deg=waypoints,
        block_v_dps=tuple(b[1] for b in blocks),
        dwell_s=tuple(b[2] for b in blocks),
        planned_junction_dps=planned,
        board_junction_dps=tuple(board),
        measured_junction_dps=tuple(measured),
        plan_s=plan_s,
        plan_stop_each_s=plan_each,
        done_queue_s=None if done_q is None else done_q - T_START_S,
        done_stop_each_s=None if done_s is None else done_s - T_START_S,
        max_err_queue_deg=max_err(q_trace),
        max_err_stop_each_deg=max_err(s_trace),
        queue=q_trace,
        stop_each=s_trace,
        stream=st_trace,
        tables=(tables[0], tables[1]),
        table_vel_dps=tuple(table_vel),
        stream_starts=((0.1, 0.0), (t2, 120.0)),
    )


def plot_programs(result: ProgramsResult, path: str | Path | None, current_limit_a: float
                  ) -> Figure:  # fmt: skip
    """The inspection scan through the queue against stopping at every waypoint; crosses:
    the PC-side plan's junction speeds (at the queue run's crossing times)."""
    markers = []
    for name, t in (("stop at each: done", result.done_stop_each_s),
                    ("queue: done", result.done_queue_s)):  # fmt: skip
        if t is not None:
            markers.append(Marker(t + T_START_S, name, at_top=False))
    points = []
    t_from = T_START_S
    w = result.waypoints_deg
    for k, v in enumerate(result.planned_junction_dps, start=1):
        direction = 1.0 if w[k] > w[k - 1] else -1.0
        _, _, t_from = crossing(result.queue, w[k], t_from, direction)
        points.append(Point(t_from, direction * v, ""))
    return paper_figure(
        [
            Curve(result.stop_each, "stop at every waypoint (a Move per block)", "tab:gray"),
            Curve(result.queue, "board's program queue (look-ahead on the board)", "tab:blue"),
        ],
        path,
        title="Inspection scan: 4 sectors at 20 °/s, transits at 300 °/s, 3 reversals "
        f"($a_{{max}}$ {A_MAX_DPS2:g} °/s$^2$)",
        current_limit_a=current_limit_a,
        markers=markers,
        points=points,
        points_label="PC-side plan's junction speed",
        pos_scale=1.0,
        pos_label="output shaft\nposition (°)",
        note="Crosses: the PC-side plan's junction speeds (planner.lookahead holding the whole "
        "program). Dotted lines: at rest at home. " + SHAFT_NOTE,
    )


def plot_stream(result: ProgramsResult, path: str | Path | None) -> Figure:
    """Seed 002's tables streamed: the board's setpoint and encoder at each row against
    the printed rows (position and velocity), and the encoder's error per row."""
    fig = Figure(figsize=(10, 7), layout="constrained")
    axes = fig.subplots(3, 2, sharex="col", height_ratios=(2, 2, 1.2))
    for col, table in enumerate(result.tables):
        rows = np.arange(len(table.paper))
        t = rows * PERIOD_S
        ax_p, ax_v, ax_e = axes[0, col], axes[1, col], axes[2, col]
        ax_p.plot(t, table.paper[:, 0], "x", color="k", label="paper (printed)")
        ax_p.plot(t, table.bench_sp_pos, "-", color="tab:blue", lw=1.2,
                  label="board setpoint (telemetry)")  # fmt: skip
        ax_p.plot(t, table.bench_pos, "--", color="tab:orange", lw=1.0,
                  label="encoder (telemetry)")  # fmt: skip
        ax_p.set_title(table.name)
        ax_p.set_ylabel("position (°)")
        sp_v, enc_v = result.table_vel_dps[col]
        ax_v.plot(t, table.paper[:, 1], "x", color="k", label="paper (printed)")
        ax_v.plot(t, sp_v, "-", color="tab:blue", lw=1.2, label="board setpoint (telemetry)")
        ax_v.plot(t, enc_v, "--", color="tab:orange", lw=1.0, label="estimated (telemetry)")
        ax_v.set_ylabel("velocity (°/s)")
        ax_e.plot(t, (table.bench_sp_pos - table.planner[:, 0]) * 1e3, "o-", ms=3,
                  color="tab:blue", label="setpoint − table")  # fmt: skip
        ax_e.plot(t, (table.bench_pos - table.planner[:, 0]) * 1e3, "s-", ms=3,
                  color="tab:orange", label="encoder − table")  # fmt: skip
        ax_e.set_ylabel("error (m°)")
        ax_e.set_xlabel("time from the stream's start (s)")
        for ax in (ax_p, ax_v, ax_e):
            ax.grid(True, alpha=0.4)
            ax.legend(fontsize=8)
    fig.suptitle("Seed 002's Tables 1 and 2 streamed to the board as PVT points every 150 ms")
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig
