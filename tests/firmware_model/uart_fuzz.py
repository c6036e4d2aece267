"""Fuzzers of the board through the emulated UART, shared by the tests (bounded budgets) and
``benchmarks/fuzz_firmware.py`` (the long runs whose figures docs/model.md quotes).

Both drive the real closed loop of ``sim.loop.Simulation`` (plant, encoder, ADC, bridge,
both UART directions) and talk to the board in wire frames only, as a PC would.

* :func:`fuzz_commands`: random frames, valid and not (NaN, +-inf, denormals, float32
  extremes, random bit patterns, every enum byte, every payload length, unknown and
  board-to-PC types, repeats of the last frame), in bursts. Checks that nothing raises,
  that every answerable frame gets exactly one answer of the right kind in order, and that
  no NACKed command changed anything (the board's settings, motion and flags are compared
  before and after every NACKed command).
* :func:`travel_search`: random motion sequences aimed at the travel limits (moves towards
  and across the ends, soft Stops, SetLimits lowering a_max or v_max mid-move, interrupting
  Moves with small a_max, S-curves, step moves), recording how far the *true* plant axis
  ever went beyond the travel.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np

import bench_configs
from serial_protocol import frame
from serial_protocol.messages import (
    COMMAND_TYPES,
    Ack,
    ClearFault,
    FaultInfo,
    FaultReport,
    Gains,
    GetFault,
    GetGains,
    GetLimits,
    GetStatus,
    Heartbeat,
    Hello,
    HelloReply,
    Interp,
    Limits,
    Malformed,
    Move,
    MsgType,
    Nack,
    Profile,
    QueueAction,
    QueueControl,
    QueueSegment,
    QueueStatus,
    SetEnable,
    SetGains,
    SetLimits,
    Status,
    Stop,
    StreamAction,
    StreamControl,
    StreamPoints,
    StreamStatus,
)
from sim.config import load_bench
from sim.loop import Simulation

_F32_SPECIAL = (
    math.nan,
    math.inf,
    -math.inf,
    0.0,
    -0.0,
    1.401298464324817e-45,  # the smallest float32 denormal
    -1.401298464324817e-45,
    1e-40,  # a float32 denormal
    1.1754943508222875e-38,  # the smallest normal float32
    3.4028234663852886e38,  # the largest float32
    -3.4028234663852886e38,
    1e9,
    -1.0,
)
_TARGET_SPECIAL = (0.0, 214748.3647, -214748.3648, 1e5, -1e5, 3600.0, -3600.0)
_ANSWER = {
    GetStatus: (Status,),
    GetGains: (Gains,),
    GetLimits: (Limits,),
    GetFault: (FaultInfo, Nack),
    QueueSegment: (QueueStatus, Nack),
    QueueControl: (QueueStatus, Nack),
    StreamControl: (StreamStatus, Nack),
    StreamPoints: (StreamStatus, Nack),
}
_REPLY_TYPES = (
    Ack, Nack, Status, Gains, Limits, HelloReply, FaultInfo, QueueStatus, StreamStatus,
)  # fmt: skip
#: The session the fuzzing PC opens; a few frames carry another one (or none).
SESSION = 0x5EED
_BOARD_TO_PC = tuple(t for t in MsgType if t >= 0x80)


def paper_bench(**overrides: Any) -> Any:
    """The paper bench with ``{"table.key": value}`` overrides (validated as the loader does)."""
    from sim.loop import apply_overrides

    bench = load_bench(bench_configs.path("paper_bench.toml"))
    return apply_overrides(bench, overrides) if overrides else bench


def _f32(rng: np.random.Generator, scale: float) -> float:
    """A float32-representable value: special, random bits, or plausible at ``scale``."""
    r = rng.random()
    if r < 0.3:
        return _F32_SPECIAL[rng.integers(len(_F32_SPECIAL))]
    if r < 0.45:
        return struct.unpack("<f", rng.bytes(4))[0]
    value = float(rng.uniform(-0.2, 1.5) * scale)
    return struct.unpack("<f", struct.pack("<f", value))[0]


def _random_message(rng: np.random.Generator, cmd_id: int, scales: dict[str, float]) -> Any:
    cls = COMMAND_TYPES[rng.integers(len(COMMAND_TYPES))]
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        name = f.name
        if name == "cmd_id":
            kwargs[name] = cmd_id
        elif name == "session":  # mostly the open one; sometimes none or another program's
            kwargs[name] = SESSION if rng.random() < 0.9 else int(rng.choice([0, 1, 0xFFFF]))
        elif name in ("version_min", "version_max"):
            kwargs[name] = int(rng.choice([2, 2, 2, 2, 0, 1, 3, 255]))
        elif name == "bit":
            kwargs[name] = int(rng.integers(0, 40))
        elif name in ("first_index", "count", "prefill"):
            kwargs[name] = int(rng.choice([0, 1, 1, 2, 6, 7, 64, 65, 255]))
        elif name == "timeout_ms":
            kwargs[name] = int(rng.choice([0, 0, 1, 10, 200, 60000, 65535]))
        elif name == "interp":
            kwargs[name] = list(Interp)[rng.integers(len(Interp))]
        elif name == "target_deg" or (name.startswith("pos") and name.endswith("_deg")):
            if rng.random() < 0.3:
                kwargs[name] = _TARGET_SPECIAL[rng.integers(len(_TARGET_SPECIAL))]
            else:
                kwargs[name] = round(float(rng.uniform(-1.3, 1.3) * scales["travel"]), 4)
        elif name in ("profile", "loop", "action"):
            action = StreamAction if cls is StreamControl else QueueAction
            enum: type[IntEnum] = {"profile": Profile, "action": action}.get(name, _loop_enum())
            kwargs[name] = list(enum)[rng.integers(len(enum))]
        elif name == "enable":
            kwargs[name] = bool(rng.random() < 0.7)
        elif name == "decimation":
            kwargs[name] = int(rng.choice([0, 1, 2, 5, 100, 65535]))
        else:
            kwargs[name] = _f32(rng, scales.get(name, 10.0))
    return cls(**kwargs)


def _loop_enum() -> type[IntEnum]:
    from serial_protocol.messages import Loop

    return Loop


@dataclass
class FuzzReport:
    """What :func:`fuzz_commands` sent and saw. ``problems`` lists every violation found
    (empty for a pass); the counts are for the record (docs/model.md)."""

    frames_sent: int = 0
    answers_expected: int = 0
    answers: int = 0
    acks: int = 0
    nacks: int = 0
    nacks_checked: int = 0
    half_applied: int = 0
    fault_reports: int = 0
    ticks: int = 0
    kinds: dict[str, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)


def _snapshot(fw: Any) -> str:
    """Everything a command may change, as one comparable string (NaN-safe by repr)."""
    gains = {k: np.asarray(v).tolist() for k, v in fw.law.gains.items()}
    planners = {
        k: (id(p.profile), p.t_start_s, p.moving, p._p_rest) for k, p in fw._planners.items()
    }
    parts = (
        fw.v_max_dps, fw.a_max_dps2, fw.current_limit_a, fw.following_error_deg, fw._mode,
        fw._kind, fw._target_deg, fw._moving, fw._moved, fw._j_max, fw._move_limits,
        fw._v_clamp_dps, fw._decimation, fw._enabled.tolist(), fw._fault.tolist(), gains,
        planners, fw.sp_pos_deg, id(fw.program), fw.program.held, fw.program.override_pct,
        len(fw.program._pending), len(fw.program._committed), fw.stream.state,
        fw.stream.next_index, fw.stream.t0_s, fw._jog_timeout_ticks,
    )  # fmt: skip
    return repr(parts)


def _watch_nacks(fw: Any, report: FuzzReport) -> None:
    """Wrap the board's command application: a NACKed command must change nothing."""
    apply = fw._apply

    def checked(msg: Any) -> Any:
        # The program queue catches up with the clock first (ProgramQueue.finish: blocks
        # started are committed, finished ones forgotten), as QueueControl does before it
        # validates and every QueueStatus query does: time passing, not the command's doing.
        # The 1,000,000-frame run flagged 112 NACKed QueueControl(OVERRIDE) for exactly that
        # (docs/model.md).
        fw.program.finish(fw.tick * fw.dt_s)
        before = _snapshot(fw)
        reply = apply(msg)
        if isinstance(reply, Nack):
            report.nacks_checked += 1
            after = _snapshot(fw)
            if after != before:
                report.half_applied += 1
                report.problems.append(f"NACKed {msg!r} changed the board:\n{before}\n{after}")
        return reply

    fw._apply = checked


def _frame_for(rng: np.random.Generator, cmd_id: int, seq: int, scales: dict[str, float],
               last: bytes | None) -> tuple[bytes, str]:  # fmt: skip
    """One random frame and its kind."""
    r = rng.random()
    if r < 0.55:
        return frame.encode(_random_message(rng, cmd_id, scales), seq), "message"
    if r < 0.7:  # a command type with a random payload of the right length
        t = int(COMMAND_TYPES[rng.integers(len(COMMAND_TYPES))].MSG_TYPE)
        n = frame.payload_size_of_type(t) or 0
        payload = cmd_id.to_bytes(2, "little") + rng.bytes(max(0, n - 2)) if n >= 2 else b""
        return frame.frame_raw(t, payload, seq), "random_payload"
    if r < 0.8:  # every length
        t = int(COMMAND_TYPES[rng.integers(len(COMMAND_TYPES))].MSG_TYPE)
        n = int(rng.integers(0, frame.MAX_PAYLOAD_BYTES + 1))
        payload = (cmd_id.to_bytes(2, "little") + rng.bytes(n))[:n]
        return frame.frame_raw(t, payload, seq), "any_length"
    if r < 0.87:  # a type byte the board does not know, or a board -> PC type
        if rng.random() < 0.5:
            t = int(_BOARD_TO_PC[rng.integers(len(_BOARD_TO_PC))])
        else:
            t = int(rng.integers(0, 256))
        n = int(rng.integers(0, frame.MAX_PAYLOAD_BYTES + 1))
        payload = (cmd_id.to_bytes(2, "little") + rng.bytes(n))[:n]
        return frame.frame_raw(t, payload, seq), "other_type"
    if r < 0.95 and last is not None:
        return last, "repeat"  # a retry: same cmd_id, same type
    msg = dataclasses.replace(_motion_message(rng, cmd_id, scales["travel"]), session=SESSION)
    return frame.encode(msg, seq), "motion"


def _expected_answer(data: bytes, state: dict[str, int]) -> tuple[int, tuple[type, ...]] | None:
    """``(cmd_id, reply classes)`` the board owes for the frame ``data``, or None, by
    docs/protocol.md sections 5 and 11; ``state["session"]`` is the session a ``Hello``
    opened (updated here as the spec says the board does)."""
    msg = frame.Decoder().feed(data)[0]
    if isinstance(msg, Malformed):
        return msg.cmd_id, (Nack,)
    cmd_id = getattr(msg, "cmd_id", 0)
    if type(msg) not in COMMAND_TYPES:
        return cmd_id, (Nack,)  # a board -> PC message sent to the board: NOT_A_COMMAND
    if isinstance(msg, Hello):
        if msg.version_min <= 2 <= msg.version_max and msg.session != 0:
            state["session"] = msg.session
            return cmd_id, (HelloReply,)
        return cmd_id, (Nack,)
    if msg.session != state["session"] or not state["session"]:
        return cmd_id, (Nack,)  # NO_SESSION / STALE_SESSION
    if isinstance(msg, Heartbeat):
        return None  # a heartbeat of the session is not answered
    return cmd_id, _ANSWER.get(type(msg), (Ack, Nack))


def fuzz_commands(
    n_frames: int,
    *,
    seed: int = 0,
    batch: int | None = None,
    travel_deg: float = 3600.0,
    max_gap_ticks: int = 400,
) -> FuzzReport:
    """Send ``n_frames`` random frames in bursts of 1-4 through the emulated UART and check
    the answers (see the module docstring). A burst is sent once the previous one is
    answered (as a PC waiting for its answers would), then the loop runs on for a random
    0..``max_gap_ticks`` ticks so that motion, trips and timeouts happen in between."""
    rng = np.random.default_rng(seed)
    bench = paper_bench(**{"limits.travel_min_deg": -travel_deg,
                           "limits.travel_max_deg": travel_deg})  # fmt: skip
    sim = Simulation(bench, batch=batch, seed=seed, keep_log=False)
    fw = sim.fw
    report = FuzzReport()
    _watch_nacks(fw, report)
    scales = {
        "travel": travel_deg,
        "v_max_dps": bench.firmware.limits.v_max_dps,
        "a_max_dps2": bench.firmware.limits.a_max_dps2,
        "j_max_dps3": 1e5,
        "current_limit_a": 7.5,
        "following_error_deg": 50.0,
        "kp": 0.2,
        "ki": 50.0,
        "kd": 0.01,
    }
    decoder = frame.Decoder()
    # Like any PC, open a session first (not counted among the fuzzed frames).
    sim.pc_write(frame.encode(Hello(0, session=SESSION), 0))
    sim.step(4)
    decoder.feed(sim.pc_read())
    state = {"session": SESSION}
    pc_seq = 1
    cmd_id = 1
    last: bytes | None = None
    pending: list[tuple[int, tuple[type, ...]]] = []
    while report.frames_sent < n_frames or pending:
        if not pending and report.frames_sent < n_frames:
            for _ in range(int(rng.integers(1, 5))):
                if report.frames_sent >= n_frames:
                    break
                data, kind = _frame_for(rng, cmd_id, pc_seq, scales, last)
                cmd_id = cmd_id % 0xFFFF + 1  # never 0: a short Malformed frame says 0
                pc_seq = (pc_seq + 1) & 0xFF
                report.frames_sent += 1
                report.kinds[kind] = report.kinds.get(kind, 0) + 1
                expected = _expected_answer(data, state)
                if expected is not None:
                    pending.append(expected)
                    report.answers_expected += 1
                last = data
                sim.pc_write(data)
        waited = 0
        while pending and waited < 500:
            sim.step(2)
            waited += 2
            _collect(decoder.feed(sim.pc_read()), pending, report)
        if pending:
            report.problems.append(f"no answer within 1 s to {pending[0]}")
            pending.clear()
        gap = int(rng.integers(0, max_gap_ticks + 1)) if rng.random() < 0.3 else 0
        if gap:
            sim.step(gap)
            _collect(decoder.feed(sim.pc_read()), pending, report)
    report.ticks = sim.tick
    counters = fw.counters
    if counters["tx_replies_dropped"]:
        report.problems.append(f"{counters['tx_replies_dropped']} replies dropped")
    return report


def _collect(msgs: list[Any], pending: list[tuple[int, tuple[type, ...]]],
             report: FuzzReport) -> None:  # fmt: skip
    for m in msgs:
        if isinstance(m, FaultReport):
            report.fault_reports += 1
            continue
        if not isinstance(m, _REPLY_TYPES):
            continue  # telemetry
        report.answers += 1
        report.acks += isinstance(m, Ack)
        report.nacks += isinstance(m, Nack)
        if not pending:
            report.problems.append(f"unexpected answer {m!r}")
            continue
        want_id, want_types = pending.pop(0)
        got_id = getattr(m, "cmd_id", None)
        if not isinstance(m, want_types) or got_id != want_id:
            report.problems.append(f"answer {m!r}, expected {want_types} for cmd_id {want_id}")


# ---------------------------------------------------------------------- travel search


def _motion_message(rng: np.random.Generator, cmd_id: int, travel_deg: float) -> Any:
    """A motion command aimed at the travel ends: mostly valid, often soft."""
    r = rng.random()
    v = float(rng.choice([990.0, 1000.0, 500.0, float(rng.uniform(1.0, 1000.0))]))
    a = float(rng.choice([1.0, 2.0, 20.0, 148.0, 2000.0, float(rng.uniform(0.5, 2000.0))]))
    if r < 0.45:
        target = float(rng.choice([travel_deg, -travel_deg, rng.uniform(-1, 1) * travel_deg]))
        profile = Profile(int(rng.choice([0, 0, 0, 1, 2])))
        j = float(rng.choice([1e3, 1e4, 1e5, float(rng.uniform(1.0, 1e5))]))
        return Move(cmd_id, round(target, 4), v, a, j, profile)
    if r < 0.65:
        return Stop(cmd_id, float(rng.choice([0.0, 0.001, 1.0, a])))
    if r < 0.85:
        return SetLimits(cmd_id, v, a, 5.0, float(rng.choice([30.0, 1e5])))
    if r < 0.9:
        return SetGains(cmd_id, _loop_enum()(int(rng.integers(3))), float(rng.uniform(0, 0.2)),
                        float(rng.uniform(0, 20)), 0.0)  # fmt: skip
    if r < 0.95:
        return ClearFault(cmd_id)
    return SetEnable(cmd_id, True)


@dataclass
class TravelReport:
    """What :func:`travel_search` saw: the worst excursion of the true axis beyond the
    travel over all sequences (deg, 0 if it stayed inside) and counts for the record."""

    sequences: int = 0
    commands: int = 0
    acks: int = 0
    nacks: int = 0
    faults: dict[str, int] = field(default_factory=dict)
    worst_excess_deg: float = 0.0
    worst_sequence: int = -1
    ticks: int = 0


def travel_search(
    n_sequences: int,
    *,
    seed: int = 0,
    commands_per_sequence: int = 6,
    ticks_per_sequence: int = 2500,
) -> TravelReport:
    """Random command sequences against random travel windows (+-20..400 deg from a start
    near 0, so that 990 deg/s reaches an end within the sequence); each sequence is a fresh
    board and plant. Returns the worst excursion of the true axis beyond the travel."""
    from serial_protocol.messages import Fault

    rng = np.random.default_rng(seed)
    report = TravelReport()
    for k in range(n_sequences):
        travel = float(rng.uniform(20.0, 400.0))
        bench = paper_bench(**{"limits.travel_min_deg": -travel,
                               "limits.travel_max_deg": travel})  # fmt: skip
        sim = Simulation(bench, seed=int(rng.integers(1 << 30)))
        times = np.sort(rng.integers(0, ticks_per_sequence - 250, commands_per_sequence))
        times[0] = 0
        sim.pc_write(frame.encode(Hello(0, session=SESSION), 0))  # open the session
        seq = 1
        tick = 0
        for i, t in enumerate(times):
            if t > tick:
                sim.step(int(t - tick))
                tick = int(t)
            msg = (
                Move(i + 1, math.floor(travel * 1e4) / 1e4, 990.0, 2000.0, 0.0, Profile.TRAPEZOID)
                if i == 0
                else _motion_message(rng, i + 1, travel)
            )
            sim.pc_write(frame.encode(dataclasses.replace(msg, session=SESSION), seq))
            seq += 1
        sim.step(ticks_per_sequence - tick)
        log = sim.log()
        # The true axis in the board's coordinates: the board's zero is the encoder reading
        # at boot (within one motor revolution, 4.5 deg of the axis, of the plant's zero).
        pos = log.true_pos_deg + (log.pos_deg[0] - log.true_pos_deg[0])
        excess = float(max(pos.max() - travel, -travel - pos.min(), 0.0))
        if excess > report.worst_excess_deg:
            report.worst_excess_deg, report.worst_sequence = excess, k
        for m in frame.Decoder().feed(sim.pc_read()):
            report.acks += isinstance(m, Ack)
            report.nacks += isinstance(m, Nack)
            if isinstance(m, FaultReport):
                name = Fault(m.fault).name
                report.faults[name] = report.faults.get(name, 0) + 1
        report.sequences += 1
        report.commands += len(times)
        report.ticks += sim.tick
    return report
