"""The PC side: open a session, send a command, wait for its answer with timeout and
retries, keep the board's watchdog fed, collect telemetry. Works over any ``Link``
(``transport.SerialLink``, ``can_link.CanLink``), against the simulator (``turntable-sim
serve --pty``) or a real board.

Expected outcomes are data: a refused command returns the ``Nack`` (``nack_text`` says why
in words). Only a board that does not answer at all (after the retries) raises
``LinkTimeout``; a value the wire cannot carry raises ``ValueError`` naming the field.
"""

from __future__ import annotations

import dataclasses
import math
import random
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from serial_protocol.exceptions import LinkError, LinkTimeout
from serial_protocol.frame import encode_payload, field_name
from serial_protocol.messages import (
    COMMAND_TYPES,
    PROTOCOL_VERSION,
    PROTOCOL_VERSION_MIN,
    STREAM_POINTS_PER_FRAME,
    Ack,
    BoardHeartbeat,
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
    Jog,
    Limits,
    Loop,
    Malformed,
    Message,
    Move,
    MsgType,
    Nack,
    NackCode,
    Profile,
    QueueAction,
    QueueControl,
    QueueSegment,
    QueueStatus,
    SetEnable,
    SetGains,
    SetLimits,
    SetTelemetry,
    Status,
    Stop,
    StreamAction,
    StreamControl,
    StreamPoints,
    StreamState,
    StreamStatus,
    Telemetry,
)
from serial_protocol.transport import Link

__all__ = ["ACK_TIMEOUT_S", "RETRIES", "BoardClient", "ClientStats", "nack_text"]

#: How long the PC waits for an answer before it retries (docs/protocol.md, section 5).
ACK_TIMEOUT_S = 0.1
#: Retries after the first attempt, each with the same cmd_id.
RETRIES = 3

_REPLIES = (Ack, Nack, Gains, Limits, Status, FaultInfo, QueueStatus, StreamStatus)
_COMMANDS = frozenset(COMMAND_TYPES)
# What a NackCode says about the refused field or command, for nack_text.
_NACK_WORDS = {
    NackCode.UNKNOWN_TYPE: "unknown message type",
    NackCode.BAD_LENGTH: "payload too short for its type",
    NackCode.NOT_FINITE: "is not finite",
    NackCode.OUT_OF_RANGE: "is not a defined value",
    NackCode.UNSTABLE_GAINS: "the board's stability check refuses these gains",
    NackCode.FAULT_ACTIVE: "a fault is latched (clear it, then enable)",
    NackCode.DISABLED: "the bridge is disabled (enable it first)",
    NackCode.NOT_A_COMMAND: "a board-to-PC message type was sent to the board",
    NackCode.NO_SESSION: "no session is open (send Hello first)",
    NackCode.STALE_SESSION: "another session has taken over the board",
    NackCode.UNSUPPORTED_VERSION: "the board speaks another protocol version",
    NackCode.BUSY: "refused while the board is busy",
    NackCode.TRAVEL: "the trajectory would leave the travel",
    NackCode.QUEUE_FULL: "the program or point queue is full (wait for free slots)",
    NackCode.NO_STREAM: "no stream is open to take points (START one; it may have run dry)",
    NackCode.SENSE_OFFSET: "the current-sense offset calibrated at enable is implausible",
}


def nack_text(nack: Nack, command: object | None = None) -> str:
    """One line saying why the board refused a command, e.g. ``"Move refused: v_max_dps =
    2000 > limit 990 (TOO_HIGH)"``. ``command`` (the message sent) supplies the value."""
    try:
        type_name = MsgType(nack.msg_type).name
    except ValueError:
        type_name = f"type 0x{nack.msg_type:02X}"
    if command is not None and type(command).MSG_TYPE == nack.msg_type:
        type_name = type(command).__name__
    name = field_name(nack.msg_type, nack.field)
    code = NackCode(nack.code)
    value = getattr(command, name, None) if (command is not None and name) else None
    shown = f"{name} = {value:g}" if isinstance(value, float | int) else (name or "")
    if code is NackCode.TOO_HIGH:
        why = f"{shown} > limit {nack.limit:g}"
    elif code is NackCode.TOO_LOW:
        why = f"{shown} < limit {nack.limit:g}"
    elif code is NackCode.UNSUPPORTED_VERSION:
        why = f"the board speaks protocol version {nack.limit:g}"
    elif code is NackCode.TRAVEL:
        why = f"the trajectory would cross the travel end {nack.limit:g} deg" + (
            f" ({shown})" if shown else ""
        )
    elif code in (NackCode.NOT_FINITE, NackCode.OUT_OF_RANGE) and name:
        why = f"{shown} {_NACK_WORDS[code]}"
    else:
        why = _NACK_WORDS.get(code, code.name) + (f" ({name})" if name else "")
    return f"{type_name} refused: {why} ({code.name})"


@dataclass(slots=True)
class ClientStats:
    """Counters of a ``BoardClient``."""

    commands: int = 0
    retries: int = 0
    timeouts: int = 0
    acks: int = 0
    nacks: int = 0
    telemetry: int = 0
    fault_reports: int = 0
    malformed: int = 0
    stale_replies: int = 0  # answers to a cmd_id no longer awaited (late after a retry)
    sessions: int = 0  # sessions opened (Hello answered)
    heartbeats_sent: int = 0
    board_heartbeats: int = 0


class BoardClient:
    """Talk to a board over ``link``.

    The first command opens a session (``open()``: a ``Hello`` with a fresh random session
    id; the board forgets the previous session's duplicate memory, so nothing this client
    sends can be taken for a repeat of another program's command). Every command carries
    the session; a retry re-sends the same message (same ``cmd_id``, docs section 5).

    ``ack_timeout_s`` and ``retries``: see docs/protocol.md, section 5. ``heartbeat_s``:
    while the client waits or collects, it sends a ``Heartbeat`` when nothing was sent for
    that long (None: a quarter of the board's watchdog time, none if the watchdog is off);
    after a ``jog`` with a timeout it also keeps that jog alive (a heartbeat at least every
    quarter of its timeout), so the jog runs while this client waits or collects and stops
    on the board within the timeout once it falls silent (a dead-man's handle).
    ``on_message`` is called with every message that is not the awaited answer (telemetry,
    fault reports, board heartbeats, ...) as it arrives; telemetry is also kept in
    ``telemetry`` (at most ``keep_telemetry`` frames, the oldest dropped first), fault
    reports in ``fault_reports`` and the last board heartbeat in ``last_heartbeat``.
    """

    def __init__(
        self,
        link: Link,
        ack_timeout_s: float = ACK_TIMEOUT_S,
        retries: int = RETRIES,
        on_message: Callable[[Message | Malformed], None] | None = None,
        keep_telemetry: int = 1_000_000,
        heartbeat_s: float | None = None,
    ) -> None:
        if not ack_timeout_s > 0:
            raise ValueError(f"ack_timeout_s = {ack_timeout_s!r}: must be > 0")
        if retries < 0:
            raise ValueError(f"retries = {retries!r}: must be >= 0")
        if heartbeat_s is not None and not heartbeat_s > 0:
            raise ValueError(f"heartbeat_s = {heartbeat_s!r}: must be > 0")
        self.link = link
        self.ack_timeout_s = ack_timeout_s
        self.retries = retries
        self.on_message = on_message
        self.telemetry: deque[Telemetry] = deque(maxlen=keep_telemetry)
        self.fault_reports: list[FaultReport] = []
        self.last_status: Status | None = None
        self.last_heartbeat: BoardHeartbeat | None = None
        self.hello_reply: HelloReply | None = None
        self.last_command: Message | None = None  # the last command sent (for nack_text)
        self.session = 0  # 0 until open() succeeds
        self.stats = ClientStats()
        self._cmd_id = 0
        self._heartbeat_s = heartbeat_s
        self._jog_heartbeat_s: float | None = None  # keeps an accepted jog's timeout fed
        self._last_sent_wall_s = -math.inf

    @property
    def bus_voltage_v(self) -> float:
        """The bus voltage the board last reported (V): in its latest telemetry frame, else
        (an older board, whose telemetry does not carry it) in its latest
        ``BoardHeartbeat``; 0 before either."""
        if self.telemetry and self.telemetry[-1].bus_voltage_v:
            return self.telemetry[-1].bus_voltage_v
        return self.last_heartbeat.bus_voltage_v if self.last_heartbeat is not None else 0.0

    # ------------------------------------------------------------------ session

    def open(self, session: int | None = None) -> HelloReply | Nack:
        """Open a session (``Hello``); return the ``HelloReply`` (the board's version,
        capabilities and limits), or the ``Nack`` of a board that speaks no version this
        client does. ``session``: the id to use (default: random, 1..65535, different from
        this client's previous one)."""
        if session is None:
            session = self.session
            while session == self.session:
                session = random.randint(1, 0xFFFF)
        if not 1 <= session <= 0xFFFF:
            raise ValueError(f"session = {session!r}: must be 1..65535")
        msg = Hello(self.next_cmd_id(), PROTOCOL_VERSION_MIN, PROTOCOL_VERSION, session)
        cmd_id = msg.cmd_id
        reply = self._exchange(
            msg, lambda m: isinstance(m, HelloReply | Nack) and m.cmd_id == cmd_id
        )
        if isinstance(reply, HelloReply):
            self.session = reply.session
            self.hello_reply = reply
            self.stats.sessions += 1
            if self._heartbeat_s is None and reply.watchdog_ms:
                self._heartbeat_s = reply.watchdog_ms / 4000.0
        else:
            self.stats.nacks += 1
        return reply  # type: ignore[return-value]

    def hello(self) -> HelloReply:
        """Open a session and return the board's ``HelloReply``; a board that refuses the
        session (no common protocol version) raises ``LinkError`` saying why."""
        reply = self.open()
        if isinstance(reply, Nack):
            raise LinkError(nack_text(reply))
        return reply

    def heartbeat(self) -> None:
        """Send a ``Heartbeat`` now (feeds the board's command watchdog; not answered)."""
        if not self.session:
            self.hello()
        self.link.send(Heartbeat(0, self.session))
        self._last_sent_wall_s = time.monotonic()
        self.stats.heartbeats_sent += 1

    # ------------------------------------------------------------------ commands

    def next_cmd_id(self) -> int:
        """A fresh command id: 1, 2, ... 65535, 1, ... (0 is reserved for "unknown")."""
        self._cmd_id = self._cmd_id % 0xFFFF + 1
        return self._cmd_id

    def command(self, msg: Message) -> Ack | Nack | Gains | Limits | Status | FaultInfo:
        """Send ``msg`` (which carries its ``cmd_id``) in this client's session (opened
        first if need be) and return the board's answer, retrying with the same message;
        ``LinkTimeout`` if it never answers, ``ValueError`` naming the field if a value
        cannot go on the wire."""
        if type(msg) not in _COMMANDS or isinstance(msg, Hello | Heartbeat):
            raise TypeError(f"not a command with an answer: {msg!r}")
        encode_payload(msg)  # a value the wire cannot carry: ValueError, nothing sent
        if not self.session:
            self.hello()
        if msg.session != self.session:  # type: ignore[union-attr]
            msg = dataclasses.replace(msg, session=self.session)  # type: ignore[type-var]
        cmd_id = msg.cmd_id  # type: ignore[union-attr]
        self.last_command = msg
        reply = self._exchange(msg, lambda m: isinstance(m, _REPLIES) and m.cmd_id == cmd_id)
        if isinstance(reply, Ack):
            self.stats.acks += 1
        elif isinstance(reply, Nack):
            self.stats.nacks += 1
        elif isinstance(reply, Status):
            self.last_status = reply
        return reply  # type: ignore[return-value]

    def move(
        self,
        target_deg: float,
        v_max_dps: float,
        a_max_dps2: float,
        j_max_dps3: float = 0.0,
        profile: Profile = Profile.TRAPEZOID,
    ) -> Ack | Nack:
        """Move (or interrupt the current move) to ``target_deg`` (axis degrees)."""
        msg = Move(self.next_cmd_id(), target_deg, v_max_dps, a_max_dps2, j_max_dps3, profile)
        return self.command(msg)  # type: ignore[return-value]

    def stop(self, a_max_dps2: float = 0.0) -> Ack | Nack:
        """Decelerate to rest (0 = the board's configured a_max)."""
        return self.command(Stop(self.next_cmd_id(), a_max_dps2))  # type: ignore[return-value]

    def set_gains(self, loop: Loop, kp: float, ki: float, kd: float) -> Ack | Nack:
        """Set one loop's gains."""
        msg = SetGains(self.next_cmd_id(), loop, kp, ki, kd)
        return self.command(msg)  # type: ignore[return-value]

    def get_gains(self, loop: Loop) -> Gains | Nack:
        """Read one loop's gains."""
        return self.command(GetGains(self.next_cmd_id(), loop))  # type: ignore[return-value]

    def set_limits(
        self,
        v_max_dps: float,
        a_max_dps2: float,
        current_limit_a: float,
        following_error_deg: float,
        over_current_trip_a: float = 0.0,
        bus_over_voltage_v: float = 0.0,
        bus_under_voltage_v: float = 0.0,
        thermal_derate_c: float = 0.0,
        thermal_trip_c: float = 0.0,
        brake_current_limit_a: float = 0.0,
    ) -> Ack | Nack:
        """Set the motion limits, the current clamp and the trip thresholds
        (``over_current_trip_a``, the bus trips' V, the thermal protection's degC and the
        cap on the brake after a trip, A: 0 keeps the board's)."""
        msg = SetLimits(
            self.next_cmd_id(), v_max_dps, a_max_dps2, current_limit_a, following_error_deg,
            over_current_trip_a, bus_over_voltage_v=bus_over_voltage_v,
            bus_under_voltage_v=bus_under_voltage_v, thermal_derate_c=thermal_derate_c,
            thermal_trip_c=thermal_trip_c, brake_current_limit_a=brake_current_limit_a,
        )  # fmt: skip
        return self.command(msg)  # type: ignore[return-value]

    def get_limits(self) -> Limits | Nack:
        """Read the limits."""
        return self.command(GetLimits(self.next_cmd_id()))  # type: ignore[return-value]

    def status(self) -> Status | Nack:
        """Read the board's state."""
        return self.command(GetStatus(self.next_cmd_id()))  # type: ignore[return-value]

    def clear_fault(self) -> Ack | Nack:
        """Clear a latched fault."""
        return self.command(ClearFault(self.next_cmd_id()))  # type: ignore[return-value]

    def set_enable(self, enable: bool) -> Ack | Nack:
        """Enable or disable the bridge."""
        return self.command(SetEnable(self.next_cmd_id(), enable))  # type: ignore[return-value]

    def set_telemetry(self, decimation: int) -> Ack | Nack:
        """Telemetry every ``decimation`` ticks (0 = off)."""
        msg = SetTelemetry(self.next_cmd_id(), decimation)
        return self.command(msg)  # type: ignore[return-value]

    def get_fault(self, bit: int) -> FaultInfo | Nack:
        """Details of fault flag ``bit`` (0..31): latched, tick, value and threshold."""
        return self.command(GetFault(self.next_cmd_id(), bit))  # type: ignore[return-value]

    # ------------------------------------------------------------------ programs

    def queue_segment(
        self, target_deg: float, v_max_dps: float, dwell_s: float = 0.0
    ) -> QueueStatus | Nack:
        """Append a program block (docs/protocol.md section 4.5): to ``target_deg`` at
        most at ``v_max_dps``, then rest ``dwell_s`` there."""
        msg = QueueSegment(self.next_cmd_id(), target_deg, v_max_dps, dwell_s)
        return self.command(msg)  # type: ignore[return-value]

    def queue_control(self, action: QueueAction, override_pct: float = 100.0) -> QueueStatus | Nack:
        """Hold, resume, abort, override or just read the program queue."""
        msg = QueueControl(self.next_cmd_id(), action, override_pct)
        return self.command(msg)  # type: ignore[return-value]

    def queue_status(self) -> QueueStatus | Nack:
        return self.queue_control(QueueAction.STATUS)

    def hold(self) -> QueueStatus | Nack:
        """Feed hold: stop on the path, keep the program."""
        return self.queue_control(QueueAction.HOLD)

    def resume(self) -> QueueStatus | Nack:
        return self.queue_control(QueueAction.RESUME)

    def abort(self) -> QueueStatus | Nack:
        """Stop and empty the program queue."""
        return self.queue_control(QueueAction.ABORT)

    def set_override(self, pct: float) -> QueueStatus | Nack:
        """Speed override in percent (10..200) of the blocks not yet entered."""
        return self.queue_control(QueueAction.OVERRIDE, pct)

    def send_program(
        self,
        blocks: list[tuple[float, float, float]],
        *,
        poll_s: float = 0.05,
        timeout_s: float = 600.0,
    ) -> QueueStatus | Nack:
        """Stream ``(target_deg, v_max_dps, dwell_s)`` blocks with flow control: send while
        the board reports free slots, else poll its queue every ``poll_s`` (receiving
        telemetry in between). Returns the last ``QueueStatus``, or the first ``Nack`` (the
        blocks after it are not sent). ``LinkTimeout`` after ``timeout_s`` of wall time
        without a free slot."""
        free = 0
        last: QueueStatus | Nack = self.queue_status()
        if isinstance(last, Nack):
            return last
        free = last.free_slots
        end_wall_s = time.monotonic() + timeout_s
        for target, v_max, dwell in blocks:
            while free == 0:
                if time.monotonic() > end_wall_s:
                    raise LinkTimeout(f"the program queue stayed full for {timeout_s:g} s")
                self.collect(poll_s)
                last = self.queue_status()
                if isinstance(last, Nack):
                    return last
                free = last.free_slots
            last = self.queue_segment(target, v_max, dwell)
            if isinstance(last, Nack):
                return last
            free = last.free_slots
            end_wall_s = time.monotonic() + timeout_s
        return last

    # ------------------------------------------------------------------ streams and jog

    def stream_control(
        self,
        action: StreamAction,
        *,
        interp: Interp = Interp.LINEAR,
        period_s: float = 0.0,
        prefill: int = 1,
    ) -> StreamStatus | Nack:
        """Start, end, abort or read the point stream (docs/protocol.md section 4.6)."""
        msg = StreamControl(self.next_cmd_id(), action, interp, period_s, prefill)
        return self.command(msg)  # type: ignore[return-value]

    def stream_status(self) -> StreamStatus | Nack:
        return self.stream_control(StreamAction.STATUS)

    def stream_points(
        self,
        first_index: int,
        pos_deg: list[float],
        vel_dps: list[float] | None = None,
    ) -> StreamStatus | Nack:
        """Send 1..``STREAM_POINTS_PER_FRAME`` points, the first being point ``first_index``."""
        msg = StreamPoints.of(self.next_cmd_id(), first_index, pos_deg, vel_dps)
        return self.command(msg)  # type: ignore[return-value]

    def stream(
        self,
        pos_deg: list[float],
        period_s: float,
        *,
        vel_dps: list[float] | None = None,
        interp: Interp | None = None,
        prefill: int | None = None,
        end: bool = True,
        poll_s: float = 0.02,
        timeout_s: float = 600.0,
    ) -> StreamStatus | Nack:
        """Stream points 1..n (``pos_deg``, and ``vel_dps`` for PVT) every ``period_s`` from
        where the axis rests: START (CUBIC if velocities are given), the points
        (``STREAM_POINTS_PER_FRAME`` to a frame) as the board's free slots allow (polling
        every ``poll_s``, receiving telemetry in between), then END. Returns the last
        ``StreamStatus`` or the first ``Nack`` (the rest is not sent; an underrun shows as
        ``StreamState.UNDERRUN``). ``prefill``: points the board holds before it moves
        (default: 0.25 s of points, at most 48)."""
        if interp is None:
            interp = Interp.CUBIC if vel_dps is not None else Interp.LINEAR
        if vel_dps is not None and len(vel_dps) != len(pos_deg):
            raise ValueError(f"{len(vel_dps)} velocities for {len(pos_deg)} positions")
        if prefill is None:
            # a quarter second of points ahead (what a loaded PC may need), at most 48
            prefill = max(1, min(48, len(pos_deg), math.ceil(0.25 / period_s - 1e-9)))
        last = self.stream_control(StreamAction.START, interp=interp, period_s=period_s,
                                   prefill=prefill)  # fmt: skip
        if isinstance(last, Nack):
            return last
        free = last.free_slots
        end_wall_s = time.monotonic() + timeout_s
        k = 0
        while k < len(pos_deg):
            while free == 0:
                if time.monotonic() > end_wall_s:
                    raise LinkTimeout(f"the point buffer stayed full for {timeout_s:g} s")
                self.collect(poll_s)
                last = self.stream_status()
                if isinstance(last, Nack) or last.state is not StreamState.RUNNING:
                    return last
                free = last.free_slots
            n = min(STREAM_POINTS_PER_FRAME, free, len(pos_deg) - k)
            vel = list(vel_dps[k : k + n]) if vel_dps is not None else None
            last = self.stream_points(k + 1, list(pos_deg[k : k + n]), vel)
            if isinstance(last, Nack):
                return last
            free = last.free_slots
            k += n
            end_wall_s = time.monotonic() + timeout_s
        if end:
            last = self.stream_control(StreamAction.END)
        return last

    def jog(self, vel_dps: float, a_max_dps2: float, timeout_ms: int = 0) -> Ack | Nack:
        """Move at ``vel_dps`` (signed; 0 stops) reached at ``a_max_dps2``, until the next
        jog, a Stop, the travel end or ``timeout_ms`` without a frame (0: no timeout)."""
        msg = Jog(self.next_cmd_id(), vel_dps, a_max_dps2, timeout_ms)
        reply = self.command(msg)
        if isinstance(reply, Ack):
            # feed the jog's timeout while this client waits or collects (at least 1 ms apart)
            self._jog_heartbeat_s = max(timeout_ms / 4000.0, 0.001) if timeout_ms > 0 else None
        return reply  # type: ignore[return-value]

    def wait_status(
        self, done: Callable[[Status], bool], timeout_s: float, interval_s: float = 0.05
    ) -> Status | None:
        """Ask for the status every ``interval_s`` (receiving telemetry in between) until
        ``done(status)`` holds; return that status, or the last one after ``timeout_s`` of
        wall time (None if none came)."""
        end_wall_s = time.monotonic() + timeout_s
        last: Status | None = None
        while True:
            reply = self.status()
            if isinstance(reply, Status):
                last = reply
                if done(reply):
                    return reply
            if time.monotonic() >= end_wall_s:
                return last
            self.collect(interval_s)

    # ------------------------------------------------------------------ receiving

    def collect(self, duration_s: float) -> list[Message | Malformed]:
        """Receive for ``duration_s`` of wall time; return everything that arrived."""
        got: list[Message | Malformed] = []
        end_wall_s = time.monotonic() + duration_s
        while True:
            left_s = end_wall_s - time.monotonic()
            if left_s <= 0:
                return got
            for msg in self._poll(min(left_s, 0.05)):
                self._dispatch(msg)
                got.append(msg)

    def wait_for(
        self, predicate: Callable[[Message | Malformed], bool], timeout_s: float
    ) -> Message | Malformed | None:
        """Receive until a message satisfies ``predicate`` (returned) or ``timeout_s``
        of wall time passes (None)."""
        end_wall_s = time.monotonic() + timeout_s
        while True:
            left_s = end_wall_s - time.monotonic()
            if left_s <= 0:
                return None
            batch = self._poll(min(left_s, 0.05))
            for k, msg in enumerate(batch):
                self._dispatch(msg)
                if predicate(msg):
                    for later in batch[k + 1 :]:
                        self._dispatch(later)
                    return msg

    def _poll(self, timeout_s: float) -> list[Message | Malformed]:
        """``link.poll``, with a heartbeat first when the board's watchdog (or a jog's
        timeout) wants one."""
        hb = self._heartbeat_s
        if self._jog_heartbeat_s is not None:
            hb = self._jog_heartbeat_s if hb is None else min(hb, self._jog_heartbeat_s)
        if hb is not None and self.session and time.monotonic() - self._last_sent_wall_s >= hb:
            self.heartbeat()
            timeout_s = min(timeout_s, hb)
        elif hb is not None:
            timeout_s = min(timeout_s, hb)
        return self.link.poll(timeout_s)

    def _exchange(self, msg: Message, is_answer: Callable[[Message | Malformed], bool]) -> Message:
        self.stats.commands += 1
        for attempt in range(self.retries + 1):
            if attempt:
                self.stats.retries += 1
            self.link.send(msg)
            self._last_sent_wall_s = time.monotonic()
            end_wall_s = time.monotonic() + self.ack_timeout_s
            while True:
                left_s = end_wall_s - time.monotonic()
                if left_s <= 0:
                    break
                batch = self.link.poll(left_s)
                for k, got in enumerate(batch):
                    if is_answer(got):
                        # what arrived after the answer in the same read is not lost
                        for later in batch[k + 1 :]:
                            self._dispatch(later)
                        return got  # type: ignore[return-value]
                    self._dispatch(got)
        self.stats.timeouts += 1
        raise LinkTimeout(
            f"no answer to {msg!r} after {self.retries + 1} attempts "
            f"of {self.ack_timeout_s:g} s each"
        )

    def _dispatch(self, msg: Message | Malformed) -> None:
        if isinstance(msg, Telemetry):
            self.stats.telemetry += 1
            self.telemetry.append(msg)
        elif isinstance(msg, FaultReport):
            self.stats.fault_reports += 1
            self.fault_reports.append(msg)
        elif isinstance(msg, BoardHeartbeat):
            self.stats.board_heartbeats += 1
            self.last_heartbeat = msg
        elif isinstance(msg, Malformed):
            self.stats.malformed += 1
        elif isinstance(msg, _REPLIES):
            self.stats.stale_replies += 1
            if isinstance(msg, Status):
                self.last_status = msg
        if self.on_message is not None:
            self.on_message(msg)
