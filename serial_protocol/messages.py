"""The messages of the PC link, one frozen dataclass per message.

Fields are engineering units with the suffixes of ``firmware_model/units.py``; the codec
(``serial_protocol/frame.py``) scales them to integers or float32 on the wire, as laid out in
``docs/protocol.md``. This module does no I/O and imports nothing of ours.

Every command from the PC except ``Hello`` starts with ``cmd_id`` (u16, chosen by the PC):
the board answers it with ``Ack``/``Nack`` (or with the requested data) carrying the same
``cmd_id``, and answers a repeat of its last ``(cmd_id, type)`` again without applying it
again, so a retry after a lost ACK is harmless.

Command fields that are rates, limits or gains travel as IEEE-754 float32 so that a PC can
send NaN or infinity and the firmware can NACK them (``NackCode.NOT_FINITE``); positions
travel as fixed-point int32. Nothing here validates values: bad values are the firmware's
to reject, on the wire, with a NACK.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import ClassVar

__all__ = [
    "Ack",
    "ClearFault",
    "Fault",
    "FaultReport",
    "Gains",
    "GetGains",
    "GetLimits",
    "GetStatus",
    "Hello",
    "HelloReply",
    "Limits",
    "Loop",
    "Malformed",
    "Message",
    "Move",
    "MsgType",
    "Nack",
    "NackCode",
    "Profile",
    "PROTOCOL_VERSION",
    "SetEnable",
    "SetGains",
    "SetLimits",
    "SetTelemetry",
    "State",
    "Status",
    "Stop",
    "Telemetry",
    "COMMAND_TYPES",
]

PROTOCOL_VERSION = 1


class MsgType(IntEnum):
    """The type byte of a frame. PC → board below 0x80, board → PC from 0x80."""

    HELLO = 0x01
    MOVE = 0x02
    STOP = 0x03
    SET_GAINS = 0x04
    GET_GAINS = 0x05
    SET_LIMITS = 0x06
    GET_LIMITS = 0x07
    GET_STATUS = 0x08
    CLEAR_FAULT = 0x09
    SET_ENABLE = 0x0A
    SET_TELEMETRY = 0x0B
    HELLO_REPLY = 0x81
    TELEMETRY = 0x82
    ACK = 0x83
    NACK = 0x84
    FAULT_REPORT = 0x85
    GAINS = 0x86
    LIMITS = 0x87
    STATUS = 0x88


class Profile(IntEnum):
    """Velocity profile of a ``Move``. ``STEP`` is no planning at all: the setpoint jumps to
    the target (the paper's Fig. 6 run without planning)."""

    TRAPEZOID = 0
    SCURVE = 1
    STEP = 2


class Loop(IntEnum):
    """Which of the three cascaded loops a gain set belongs to."""

    CURRENT = 0
    VELOCITY = 1
    POSITION = 2


class NackCode(IntEnum):
    """Why the board refused a command (``Nack.code``)."""

    UNKNOWN_TYPE = 1
    BAD_LENGTH = 2
    NOT_FINITE = 3
    OUT_OF_RANGE = 4
    UNSTABLE_GAINS = 5
    FAULT_ACTIVE = 6
    DISABLED = 7


class State(IntEnum):
    """State of the board's servo state machine."""

    DISABLED = 0
    IDLE = 1
    MOVING = 2
    HOLDING = 3
    FAULT = 4


class Fault(IntEnum):
    """Latched fault code (u8); ``NONE`` when no fault is active."""

    NONE = 0
    OVER_CURRENT = 1
    FOLLOWING_ERROR = 2
    OVER_SPEED = 3
    ENCODER = 4
    WATCHDOG = 5
    TRAVEL = 6  # the estimated position beyond the travel by more than the margin


# ---------------------------------------------------------------- PC -> board


@dataclass(frozen=True, slots=True)
class Hello:
    """Ask the board who it is; answered by ``HelloReply``."""

    MSG_TYPE: ClassVar[int] = MsgType.HELLO


@dataclass(frozen=True, slots=True)
class Move:
    """Move to ``target_deg`` (axis degrees); a Move while moving is the paper's interrupt.

    ``j_max_dps3`` is used by ``Profile.SCURVE`` only (send 0 for a trapezoid).
    """

    MSG_TYPE: ClassVar[int] = MsgType.MOVE
    cmd_id: int
    target_deg: float
    v_max_dps: float
    a_max_dps2: float
    j_max_dps3: float = 0.0
    profile: Profile = Profile.TRAPEZOID


@dataclass(frozen=True, slots=True)
class Stop:
    """Decelerate to rest at ``a_max_dps2`` (0 means the configured a_max)."""

    MSG_TYPE: ClassVar[int] = MsgType.STOP
    cmd_id: int
    a_max_dps2: float = 0.0


@dataclass(frozen=True, slots=True)
class SetGains:
    """Set the PID gains of one loop (units of the loop's error → output)."""

    MSG_TYPE: ClassVar[int] = MsgType.SET_GAINS
    cmd_id: int
    loop: Loop
    kp: float
    ki: float
    kd: float


@dataclass(frozen=True, slots=True)
class GetGains:
    """Read the gains of one loop; answered by ``Gains``."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_GAINS
    cmd_id: int
    loop: Loop


@dataclass(frozen=True, slots=True)
class SetLimits:
    """Set the motion limits and the trip thresholds."""

    MSG_TYPE: ClassVar[int] = MsgType.SET_LIMITS
    cmd_id: int
    v_max_dps: float
    a_max_dps2: float
    current_limit_a: float
    following_error_deg: float


@dataclass(frozen=True, slots=True)
class GetLimits:
    """Read the limits; answered by ``Limits``."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_LIMITS
    cmd_id: int


@dataclass(frozen=True, slots=True)
class GetStatus:
    """Read the state; answered by ``Status``."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_STATUS
    cmd_id: int


@dataclass(frozen=True, slots=True)
class ClearFault:
    """Clear a latched fault; the board goes to ``State.DISABLED`` (send ``SetEnable``)."""

    MSG_TYPE: ClassVar[int] = MsgType.CLEAR_FAULT
    cmd_id: int


@dataclass(frozen=True, slots=True)
class SetEnable:
    """Enable or disable the bridge."""

    MSG_TYPE: ClassVar[int] = MsgType.SET_ENABLE
    cmd_id: int
    enable: bool


@dataclass(frozen=True, slots=True)
class SetTelemetry:
    """Send telemetry every ``decimation`` ticks (1 = every tick, 0 = off)."""

    MSG_TYPE: ClassVar[int] = MsgType.SET_TELEMETRY
    cmd_id: int
    decimation: int


# ---------------------------------------------------------------- board -> PC


@dataclass(frozen=True, slots=True)
class HelloReply:
    """Who the board is: protocol and firmware versions, servo rate, encoder resolution."""

    MSG_TYPE: ClassVar[int] = MsgType.HELLO_REPLY
    protocol_version: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    tick_hz: int
    counts_per_rev: int


@dataclass(frozen=True, slots=True)
class Telemetry:
    """One servo tick as the board saw it (sent every ``decimation`` ticks).

    ``sp_*`` is the planner's setpoint, the others are measured/estimated. ``duty`` is the
    applied PWM duty in [-1, 1].
    """

    MSG_TYPE: ClassVar[int] = MsgType.TELEMETRY
    tick: int
    sp_pos_deg: float
    sp_vel_dps: float
    pos_deg: float
    vel_dps: float
    current_a: float
    duty: float
    state: State
    fault: Fault

    def __init__(
        self,
        tick: int,
        sp_pos_deg: float,
        sp_vel_dps: float,
        pos_deg: float,
        vel_dps: float,
        current_a: float,
        duty: float,
        state: State,
        fault: Fault,
    ) -> None:
        # Built every tick by the board and again by the PC: the dataclass's frozen __init__
        # goes through object.__setattr__ per field (about 2 us for nine); writing the slots
        # through their descriptors builds the same immutable object in about a third.
        s_tick, s_sp_pos, s_sp_vel, s_pos, s_vel, s_cur, s_duty, s_state, s_fault = _TEL_SLOTS
        s_tick(self, tick)
        s_sp_pos(self, sp_pos_deg)
        s_sp_vel(self, sp_vel_dps)
        s_pos(self, pos_deg)
        s_vel(self, vel_dps)
        s_cur(self, current_a)
        s_duty(self, duty)
        s_state(self, state)
        s_fault(self, fault)


# slot descriptors of the class dataclass(slots=True) returned, in field order
_TEL_SLOTS = tuple(getattr(Telemetry, name).__set__ for name in Telemetry.__slots__)


@dataclass(frozen=True, slots=True)
class Ack:
    """Command ``cmd_id`` of type ``msg_type`` was accepted (or was a harmless repeat)."""

    MSG_TYPE: ClassVar[int] = MsgType.ACK
    cmd_id: int
    msg_type: int


@dataclass(frozen=True, slots=True)
class Nack:
    """Command ``cmd_id`` of type ``msg_type`` was refused; nothing of it was applied."""

    MSG_TYPE: ClassVar[int] = MsgType.NACK
    cmd_id: int
    msg_type: int
    code: NackCode


@dataclass(frozen=True, slots=True)
class FaultReport:
    """A fault tripped at ``tick``; ``value`` is the measured value that tripped it, in the
    fault's unit (A for over-current, deg for following error, deg/s for over-speed, ticks
    without a command for the watchdog, raw counts for the encoder)."""

    MSG_TYPE: ClassVar[int] = MsgType.FAULT_REPORT
    tick: int
    fault: Fault
    value: float


@dataclass(frozen=True, slots=True)
class Gains:
    """Reply to ``GetGains``."""

    MSG_TYPE: ClassVar[int] = MsgType.GAINS
    cmd_id: int
    loop: Loop
    kp: float
    ki: float
    kd: float


@dataclass(frozen=True, slots=True)
class Limits:
    """Reply to ``GetLimits``."""

    MSG_TYPE: ClassVar[int] = MsgType.LIMITS
    cmd_id: int
    v_max_dps: float
    a_max_dps2: float
    current_limit_a: float
    following_error_deg: float


@dataclass(frozen=True, slots=True)
class Status:
    """Reply to ``GetStatus``."""

    MSG_TYPE: ClassVar[int] = MsgType.STATUS
    cmd_id: int
    tick: int
    state: State
    fault: Fault
    pos_deg: float
    vel_dps: float
    target_deg: float


# ---------------------------------------------------------------- decoder output


@dataclass(frozen=True, slots=True)
class Malformed:
    """A frame with a good CRC whose payload cannot be decoded.

    ``code`` is ``NackCode.UNKNOWN_TYPE`` (type byte not in ``MsgType``),
    ``NackCode.BAD_LENGTH`` (payload length wrong for the type) or
    ``NackCode.OUT_OF_RANGE`` (an enum or bool byte holds an undefined value).
    ``cmd_id`` is the payload's first two bytes (little-endian) when it has them, else 0,
    so that the board can NACK it.
    """

    msg_type: int
    seq: int
    cmd_id: int
    code: NackCode


Message = (
    Hello
    | Move
    | Stop
    | SetGains
    | GetGains
    | SetLimits
    | GetLimits
    | GetStatus
    | ClearFault
    | SetEnable
    | SetTelemetry
    | HelloReply
    | Telemetry
    | Ack
    | Nack
    | FaultReport
    | Gains
    | Limits
    | Status
)

#: Message classes the PC sends to the board.
COMMAND_TYPES: tuple[type, ...] = (
    Hello,
    Move,
    Stop,
    SetGains,
    GetGains,
    SetLimits,
    GetLimits,
    GetStatus,
    ClearFault,
    SetEnable,
    SetTelemetry,
)
