"""The PC side: send a command, wait for its answer with timeout and retries, collect
telemetry. Works over any ``Link`` (``transport.SerialLink``, ``can_link.CanLink``), against
the simulator (``turntable-sim serve --pty``) or a real board.

Expected outcomes are data: a refused command returns the ``Nack``. Only a board that does
not answer at all (after the retries) raises ``LinkTimeout``.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from serial_protocol.exceptions import LinkTimeout
from serial_protocol.messages import (
    Ack,
    ClearFault,
    FaultReport,
    Gains,
    GetGains,
    GetLimits,
    GetStatus,
    Hello,
    HelloReply,
    Limits,
    Loop,
    Malformed,
    Message,
    Move,
    Nack,
    Profile,
    SetEnable,
    SetGains,
    SetLimits,
    SetTelemetry,
    Status,
    Stop,
    Telemetry,
)
from serial_protocol.transport import Link

__all__ = ["ACK_TIMEOUT_S", "RETRIES", "BoardClient", "ClientStats"]

#: How long the PC waits for an answer before it retries (docs/protocol.md, section 5).
ACK_TIMEOUT_S = 0.1
#: Retries after the first attempt, each with the same cmd_id.
RETRIES = 3

_REPLIES = (Ack, Nack, Gains, Limits, Status)


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


class BoardClient:
    """Talk to a board over ``link``.

    ``ack_timeout_s`` and ``retries``: see docs/protocol.md, section 5. ``on_message`` is
    called with every message that is not the awaited answer (telemetry, fault reports, ...)
    as it arrives; telemetry is also kept in ``telemetry`` (at most ``keep_telemetry``
    frames, the oldest dropped first) and fault reports in ``fault_reports``.
    """

    def __init__(
        self,
        link: Link,
        ack_timeout_s: float = ACK_TIMEOUT_S,
        retries: int = RETRIES,
        on_message: Callable[[Message | Malformed], None] | None = None,
        keep_telemetry: int = 1_000_000,
    ) -> None:
        if not ack_timeout_s > 0:
            raise ValueError(f"ack_timeout_s = {ack_timeout_s!r}: must be > 0")
        if retries < 0:
            raise ValueError(f"retries = {retries!r}: must be >= 0")
        self.link = link
        self.ack_timeout_s = ack_timeout_s
        self.retries = retries
        self.on_message = on_message
        self.telemetry: deque[Telemetry] = deque(maxlen=keep_telemetry)
        self.fault_reports: list[FaultReport] = []
        self.last_status: Status | None = None
        self.stats = ClientStats()
        self._cmd_id = 0

    # ------------------------------------------------------------------ commands

    def next_cmd_id(self) -> int:
        """A fresh command id: 1, 2, ... 65535, 1, ... (0 is reserved for "unknown")."""
        self._cmd_id = self._cmd_id % 0xFFFF + 1
        return self._cmd_id

    def hello(self) -> HelloReply:
        """Ask the board who it is."""
        reply = self._exchange(Hello(), lambda m: isinstance(m, HelloReply))
        assert isinstance(reply, HelloReply)
        return reply

    def command(self, msg: Message) -> Ack | Nack | Gains | Limits | Status:
        """Send ``msg`` (which carries its ``cmd_id``) and return the board's answer,
        retrying with the same ``cmd_id``; ``LinkTimeout`` if it never answers."""
        cmd_id = msg.cmd_id  # type: ignore[union-attr]
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
    ) -> Ack | Nack:
        """Set the motion limits and trip thresholds."""
        msg = SetLimits(
            self.next_cmd_id(), v_max_dps, a_max_dps2, current_limit_a, following_error_deg
        )
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
            for msg in self.link.poll(min(left_s, 0.05)):
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
            batch = self.link.poll(min(left_s, 0.05))
            for k, msg in enumerate(batch):
                self._dispatch(msg)
                if predicate(msg):
                    for later in batch[k + 1 :]:
                        self._dispatch(later)
                    return msg

    def _exchange(self, msg: Message, is_answer: Callable[[Message | Malformed], bool]) -> Message:
        self.stats.commands += 1
        for attempt in range(self.retries + 1):
            if attempt:
                self.stats.retries += 1
            self.link.send(msg)
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
        elif isinstance(msg, Malformed):
            self.stats.malformed += 1
        elif isinstance(msg, _REPLIES):
            self.stats.stale_replies += 1
            if isinstance(msg, Status):
                self.last_status = msg
        if self.on_message is not None:
            self.on_message(msg)
