"""Loading, varying and running the reproduction's experiment files; what the PC decoded.

Every run goes through ``sim.loop.run``: the simulated PC sends the scripted commands as wire
frames over the emulated UART and decodes the board's telemetry frames. A :class:`Trace` holds
only what the PC decoded (as the paper's PC plotted what the board sent), plus the
simulator's own log for cross-checks that a real bench could not make (the true current).

The variants the reproduction needs are built from the files, never typed twice:
:func:`replace_move` (another target, another profile), :func:`to_scurve` and
:func:`scale_quick` (the ``--quick`` form: the same dimensionless problem, shorter).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import bench_configs
from serial_protocol.messages import Ack, Nack, Profile
from sim.config import Experiment, ScriptedCommand, load_experiment
from sim.loop import RunLog, RunResult, run

__all__ = [
    "QUICK_TIME_SCALE",
    "Runner",
    "Trace",
    "load",
    "move_commands",
    "replace_move",
    "run_trace",
    "scale_quick",
    "to_scurve",
    "trace_from_log",
    "with_duration",
    "write_telemetry_csv",
]

# --quick runs the same planning problems with every time divided by 4: positions / 16,
# velocities / 4, accelerations unchanged, jerks x 4. The strategy boundaries of seed 000
# (S_2 = (2 v_max^2 - v0^2) / (2 a_max), S_3 = v0^2 / (2 a_max)) scale like the positions,
# so every move keeps its case; only the bench's electromechanics see smaller speeds.
QUICK_TIME_SCALE = 4.0


def load(name: str) -> Experiment:
    """A built-in experiment file of ``bench_configs`` (``"fig8"`` or ``"fig8.toml"``)."""
    return load_experiment(bench_configs.path(name))


def move_commands(exp: Experiment) -> list[tuple[int, ScriptedCommand]]:
    """``(index in exp.commands, command)`` of every ``move``, in time order."""
    return [(k, c) for k, c in enumerate(exp.commands) if c.type == "move"]


def _replace_fields(cmd: ScriptedCommand, **changes: Any) -> ScriptedCommand:
    values = dict(cmd.fields)
    if "target_deg" in changes or "target_mdeg" in changes:
        values.pop("target_deg", None)
        values.pop("target_mdeg", None)
    values.update({k: v for k, v in changes.items() if k != "t_s"})
    t_s = changes.get("t_s", cmd.t_s)
    return ScriptedCommand(float(t_s), cmd.type, tuple(values.items()))


def replace_move(exp: Experiment, which: int, **changes: Any) -> Experiment:
    """A copy of ``exp`` whose ``which``-th move (Python index, -1 = last) has ``changes``
    (``target_mdeg``/``target_deg``, ``v_max_dps``, ``a_max_dps2``, ``j_max_dps3``,
    ``profile``, ``t_s``)."""
    moves = move_commands(exp)
    index, cmd = moves[which]
    commands = list(exp.commands)
    commands[index] = _replace_fields(cmd, **changes)
    commands.sort(key=lambda c: c.t_s)
    return dataclasses.replace(exp, commands=tuple(commands))


def with_duration(exp: Experiment, duration_s: float) -> Experiment:
    """A copy of ``exp`` that runs for ``duration_s``."""
    return dataclasses.replace(exp, duration_s=float(duration_s))


def to_scurve(exp: Experiment, ramp_s: float, run_up_j_max_dps3: float | None = None) -> Experiment:
    """Every planned move of ``exp`` as a 7-segment S-curve.

    Each move gets ``j_max = a_max / ramp_s`` (its acceleration ramps from 0 to a_max in
    ``ramp_s``). If ``run_up_j_max_dps3`` is given, every move but the last uses it instead
    (the Fig. 7 run-up, whose timing is not the subject and should stay as scripted).
    """
    moves = move_commands(exp)
    out = exp
    for n, (_, cmd) in enumerate(moves):
        if cmd.get("profile", Profile.TRAPEZOID) is Profile.STEP:
            continue
        j_max = cmd.get("a_max_dps2") / ramp_s
        if run_up_j_max_dps3 is not None and n < len(moves) - 1:
            j_max = run_up_j_max_dps3
        out = replace_move(out, n, profile=Profile.SCURVE, j_max_dps3=float(j_max))
    return out


def scale_quick(exp: Experiment, k: float = QUICK_TIME_SCALE) -> Experiment:
    """The same experiment with every time divided by ``k`` (positions / k^2, velocities / k,
    accelerations kept, jerks x k, dwells / k), see :data:`QUICK_TIME_SCALE`."""
    commands = []
    for cmd in exp.commands:
        values = dict(cmd.fields)
        for key in ("target_deg", "target_mdeg"):
            if key in values:
                values[key] = values[key] / (k * k)
        if "v_max_dps" in values:
            values["v_max_dps"] = values["v_max_dps"] / k
        if "j_max_dps3" in values:
            values["j_max_dps3"] = values["j_max_dps3"] * k
        if "dwell_s" in values:  # a program block's pause
            values["dwell_s"] = values["dwell_s"] / k
        commands.append(ScriptedCommand(cmd.t_s / k, cmd.type, tuple(values.items())))
    return dataclasses.replace(exp, duration_s=exp.duration_s / k, commands=tuple(commands))


@dataclass(frozen=True, eq=False)
class Trace:
    """One run as the PC saw it: decoded telemetry, one row per received frame.

    Arrays have shape ``(n_frames,)``; ``t_s = tick * dt_s`` is the board's servo time of
    each frame. ``sp_*`` is the board's planner setpoint (the "ideal" curve), ``pos_deg`` the
    encoder position, ``vel_dps`` the board's velocity estimate (the "measured" curve),
    ``current_a`` the board's signed reading of the BTN7971 IS pin. Axis degrees.

    Attributes:
        name: a short label (``"fig7 S_2"``).
        command_t_s: the servo time at which the board applied each move (the tick after
            the PC sent it: the frame crosses the UART within one 2 ms tick).
        command_target_deg: the target of each move, in the same order.
        replies: ACK/NACK replies the PC decoded (a NACK means the run is not valid).
        link: UART and decoder counters (``sim.loop.RunResult.link``).
        true_current_a, true_t_s: the simulator's true armature current per tick (not on
            the wire; for the cross-check of the IS-pin reading).
        bus_voltage_v: the bus voltage the board measured, per frame (``(n_frames,)``; 0
            from a board that does not send it; empty when not known).
    """

    name: str
    dt_s: float
    t_s: np.ndarray
    sp_pos_deg: np.ndarray
    sp_vel_dps: np.ndarray
    pos_deg: np.ndarray
    vel_dps: np.ndarray
    current_a: np.ndarray
    duty: np.ndarray
    state: np.ndarray
    fault: np.ndarray
    command_t_s: tuple[float, ...]
    command_target_deg: tuple[float, ...]
    command_a_max_dps2: tuple[float, ...]
    replies: tuple[Any, ...]
    link: dict[str, int] = field(default_factory=dict)
    true_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    true_current_a: np.ndarray = field(default_factory=lambda: np.zeros(0))
    bus_voltage_v: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def nacks(self) -> tuple[Nack, ...]:
        return tuple(r for r in self.replies if isinstance(r, Nack))

    @property
    def acks(self) -> tuple[Ack, ...]:
        return tuple(r for r in self.replies if isinstance(r, Ack))

    def index_at(self, t_s: float) -> int:
        """Index of the first frame at or after ``t_s``."""
        return int(min(np.searchsorted(self.t_s, t_s - 1e-9), len(self.t_s) - 1))

    def since(self, t_s: float) -> Trace:
        """The frames from ``t_s`` on, with only the commands applied from ``t_s`` on."""
        i = self.index_at(t_s)
        keep = [n for n, t in enumerate(self.command_t_s) if t >= t_s - 1e-9]
        arrays = {
            f: getattr(self, f)[i:]
            for f in ("t_s", "sp_pos_deg", "sp_vel_dps", "pos_deg", "vel_dps", "current_a",
                      "duty", "state", "fault")
        }  # fmt: skip
        j = int(np.searchsorted(self.true_t_s, t_s - 1e-9))
        return dataclasses.replace(
            self,
            **arrays,
            command_t_s=tuple(self.command_t_s[n] for n in keep),
            command_target_deg=tuple(self.command_target_deg[n] for n in keep),
            command_a_max_dps2=tuple(self.command_a_max_dps2[n] for n in keep),
            true_t_s=self.true_t_s[j:],
            true_current_a=self.true_current_a[j:],
        )

    @property
    def frame_gaps(self) -> int:
        """Ticks with no telemetry frame between the first and the last one received."""
        if len(self.t_s) < 2:
            return 0
        ticks = np.round(self.t_s / self.dt_s).astype(np.int64)
        return int(ticks[-1] - ticks[0] + 1 - len(ticks))


def _command_ticks(exp: Experiment, dt_s: float) -> list[tuple[int, ScriptedCommand]]:
    # Same rounding as sim.loop.run: a command leaves the PC at the first tick boundary at or
    # after its time and is applied by the board in the next servo tick.
    return [(math.ceil(c.t_s / dt_s - 1e-9) + 1, c) for c in exp.commands if c.type == "move"]


def _target_deg(cmd: ScriptedCommand) -> float:
    target = cmd.get("target_deg")
    return float(target) if target is not None else float(cmd.get("target_mdeg")) / 1000.0


def trace_from_result(name: str, exp: Experiment, result: RunResult) -> Trace:
    """Build a :class:`Trace` from a ``sim.loop.run`` result."""
    dt_s = exp.bench.dt_s
    tel = result.telemetry_arrays()
    applied = _command_ticks(exp, dt_s)
    log = result.log
    if np.ndim(log.current_a) == 2:  # a batch: the PC decodes member 0's telemetry
        log = log.member(0)
    return Trace(
        name=name,
        dt_s=dt_s,
        t_s=np.asarray(tel["tick"], dtype=float) * dt_s,
        sp_pos_deg=np.asarray(tel["sp_pos_deg"], dtype=float),
        sp_vel_dps=np.asarray(tel["sp_vel_dps"], dtype=float),
        pos_deg=np.asarray(tel["pos_deg"], dtype=float),
        vel_dps=np.asarray(tel["vel_dps"], dtype=float),
        current_a=np.asarray(tel["current_a"], dtype=float),
        duty=np.asarray(tel["duty"], dtype=float),
        state=np.asarray(tel["state"], dtype=np.int64),
        fault=np.asarray(tel["fault"], dtype=np.int64),
        command_t_s=tuple(tick * dt_s for tick, _ in applied),
        command_target_deg=tuple(_target_deg(c) for _, c in applied),
        command_a_max_dps2=tuple(float(c.get("a_max_dps2")) for _, c in applied),
        replies=result.replies,
        link=dict(result.link),
        true_t_s=np.asarray(log.t_s, dtype=float),
        true_current_a=np.asarray(log.current_a, dtype=float),
        bus_voltage_v=np.asarray(tel["bus_voltage_v"], dtype=float),
    )


def _wire(x: np.ndarray, scale: float) -> np.ndarray:
    """``x`` as the telemetry carries it: ``round(x * scale) / scale`` (the frame's rounding,
    half to even as Python's ``round``)."""
    return np.round(np.asarray(x, dtype=float) * scale) / scale


def trace_from_log(
    name: str, exp: Experiment, log: RunLog, ticks: np.ndarray | None = None
) -> Trace:
    """A :class:`Trace` from the simulator's log of one member: what its telemetry would
    carry, frame by frame (a batch sends the telemetry of member 0 only). Rounded to the
    wire's steps (1e-4 deg, 1e-4 deg/s, 1 mA, 1e-4 duty); the current and duty of the frame
    of tick k are tick k-1's (the frame is built before the tick's current loop; 0 in the
    first), so member 0's trace is its decoded telemetry value for value. ``ticks``: the
    ticks to keep (those the PC decoded; default every tick). No replies, no link
    counters and no bus voltage (the log holds the plant's, not the board's reading)."""
    from serial_protocol.frame import CURRENT_SCALE, DUTY_SCALE, POS_SCALE, VEL_SCALE

    dt_s = exp.bench.dt_s
    applied = _command_ticks(exp, dt_s)
    rows = np.arange(len(log.t_s)) if ticks is None else np.asarray(ticks, dtype=np.int64)

    def late(x: np.ndarray) -> np.ndarray:  # the previous tick's value; 0 before the first
        return np.where(rows > 0, np.asarray(x)[np.maximum(rows - 1, 0)], 0.0)

    return Trace(
        name=name,
        dt_s=dt_s,
        t_s=rows * dt_s,
        sp_pos_deg=_wire(log.sp_pos_deg[rows], POS_SCALE),
        sp_vel_dps=_wire(log.sp_vel_dps[rows], VEL_SCALE),
        pos_deg=_wire(log.pos_deg[rows], POS_SCALE),
        vel_dps=_wire(log.vel_dps[rows], VEL_SCALE),
        current_a=_wire(late(log.current_meas_a), CURRENT_SCALE),
        duty=_wire(late(log.duty), DUTY_SCALE),
        state=np.asarray(log.state, dtype=np.int64)[rows],
        fault=np.asarray(log.fault, dtype=np.int64)[rows],
        command_t_s=tuple(tick * dt_s for tick, _ in applied),
        command_target_deg=tuple(_target_deg(c) for _, c in applied),
        command_a_max_dps2=tuple(float(c.get("a_max_dps2")) for _, c in applied),
        replies=(),
        true_t_s=np.asarray(log.t_s, dtype=float),
        true_current_a=log.current_a,
    )


def run_trace(
    name: str,
    exp: Experiment,
    *,
    progress: Callable[[int, int], None] | None = None,
    seed: int = 0,
    copies: int = 1,
) -> tuple[Trace, tuple[Trace, ...]]:
    """Run ``exp`` through the simulated bench and the emulated UART in ``copies`` noise
    realisations (one batch: every member draws its own encoder noise); return what the PC
    decoded (member 0's telemetry) and every member as its telemetry would carry it
    (:func:`trace_from_log`; member 0's is the decoded trace value for value).
    ``progress(tick, n_ticks)`` as in ``sim.loop.run``."""
    result = run(exp, seed=seed, batch=copies if copies > 1 else None, progress=progress)
    trace = trace_from_result(name, exp, result)
    ticks = np.round(trace.t_s / trace.dt_s).astype(np.int64)
    log = result.log
    members = [log] if copies == 1 else [log.member(k) for k in range(copies)]
    return trace, tuple(trace_from_log(name, exp, m, ticks) for m in members)


class Runner:
    """Runs experiments one after another, each with its own progress display, each in
    ``copies`` noise realisations (one batch per run).

    Args:
        quick: run :func:`scale_quick` forms.
        show_progress: draw a ``sim.progress.Progress`` per run on ``stream``.
        total_runs: how many runs to expect (for the ``[k/n]`` label).
        seed: noise and line-fault seed of every run.
        copies: noise realisations of every run (the members of its batch; the PC decodes
            member 0's telemetry). :attr:`copies_of` holds them by run name.
    """

    def __init__(
        self,
        *,
        quick: bool = False,
        show_progress: bool = True,
        total_runs: int = 0,
        stream: Any = None,
        seed: int = 0,
        copies: int = 1,
    ) -> None:
        if copies < 1:
            raise ValueError(f"copies = {copies!r}: need at least 1")
        self.quick = quick
        self.show_progress = show_progress
        self.total_runs = total_runs
        self.stream = stream
        self.seed = seed
        self.copies = copies
        self.count = 0
        self.ticks = 0
        #: Every experiment run so far, by its name (to run it again).
        self.experiments: dict[str, Experiment] = {}
        #: Every run so far in its noise realisations, by its name (``run_trace``).
        self.copies_of: dict[str, tuple[Trace, ...]] = {}

    def prepare(self, exp: Experiment) -> Experiment:
        """The form of ``exp`` this runner runs (quick or as written)."""
        return scale_quick(exp) if self.quick else exp

    def run(self, name: str, exp: Experiment) -> Trace:
        """Run an experiment already in its final form (see :meth:`prepare`); return what
        the PC decoded (its noise realisations go to :attr:`copies_of`)."""
        from sim.progress import Progress

        self.count += 1
        self.experiments[name] = exp
        label = f"[{self.count}/{max(self.total_runs, self.count)}] {name}"
        n_ticks = max(1, int(round(exp.duration_s / exp.bench.dt_s)))
        with Progress(label, n_ticks, stream=self.stream, enabled=self.show_progress) as bar:
            trace, copies = run_trace(
                name, exp, progress=bar.callback, seed=self.seed, copies=self.copies
            )
        self.copies_of[name] = copies
        self.ticks += n_ticks
        return trace


def write_telemetry_csv(trace: Trace, path: Any) -> Any:
    """Write the decoded telemetry of ``trace`` as the PC records it (the columns of
    ``monitor --csv`` and ``decode``: ``serial_protocol.telemetry_csv``), so that a capture
    from a real board can be compared with the simulation column by column."""
    from pathlib import Path

    from serial_protocol.telemetry_csv import TelemetryCsvWriter

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ticks = np.round(trace.t_s / trace.dt_s).astype(np.int64)
    bus = trace.bus_voltage_v if len(trace.bus_voltage_v) == len(ticks) else np.zeros(len(ticks))
    with open(path, "w", newline="", encoding="utf-8") as fh:
        # from the columns: the rows of one Telemetry per tick, without building them
        TelemetryCsvWriter(fh, tick_hz=1.0 / trace.dt_s).write_columns(
            ticks, trace.sp_pos_deg, trace.sp_vel_dps, trace.pos_deg, trace.vel_dps,
            trace.current_a, trace.duty, trace.state, trace.fault, bus,
        )  # fmt: skip
    return path
