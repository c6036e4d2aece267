"""The messages of the PC link, one frozen dataclass per message.

Fields are engineering units with the suffixes of ``firmware_model/units.py``; the codec
(``serial_protocol/frame.py``) scales them to integers or float32 on the wire, as laid out in
``docs/protocol.md``. This module does no I/O and imports nothing of ours.

Every message from the PC starts with ``cmd_id`` (u16, chosen by the PC) and ``session``
(u16, the session its ``Hello`` opened; in the dataclasses ``session`` is the last field):
the board answers it with ``Ack``/``Nack`` (or with the requested data) carrying the same
``cmd_id``, and answers a retry of the last command of the session (the same payload) again
without applying it again, so a retry after a lost ACK is harmless (docs/protocol.md,
section 5).

Command fields that are rates, limits or gains travel as IEEE-754 float32 so that a PC can
send NaN or infinity and the firmware can NACK them (``NackCode.NOT_FINITE``); positions
travel as fixed-point int32. Nothing here validates values: bad values are the firmware's
to reject, on the wire, with a NACK.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import ClassVar

__all__ = [
    "Ack",
    "BoardHeartbeat",
    "ClearFault",
    "FAULT_FLAG",
    "Fault",
    "FaultFlag",
    "FaultInfo",
    "FaultReport",
    "Gains",
    "GetFault",
    "GetGains",
    "GetLimits",
    "GetStatus",
    "Hello",
    "Heartbeat",
    "HelloReply",
    "Limits",
    "Loop",
    "Malformed",
    "Message",
    "Move",
    "MsgType",
    "Nack",
    "NackCode",
    "NO_FIELD",
    "Profile",
    "QueueAction",
    "QueueControl",
    "QueueSegment",
    "QueueState",
    "QueueStatus",
    "PROTOCOL_VERSION",
    "STREAM_POINTS_PER_FRAME",
    "Interp",
    "Jog",
    "StreamAction",
    "StreamControl",
    "StreamPoints",
    "StreamState",
    "StreamStatus",
    "PROTOCOL_VERSION_MIN",
    "SetEnable",
    "SetGains",
    "SetLimits",
    "SetTelemetry",
    "State",
    "Status",
    "Stop",
    "Telemetry",
    "COMMAND_TYPES",
    "fault_flag_names",
]

PROTOCOL_VERSION = 2
#: Oldest protocol version this code speaks (v1 framing is not compatible: see docs).
PROTOCOL_VERSION_MIN = 2


class MsgType(IntEnum):
    """The type byte of a frame (protocol v2 numbering). PC -> board below 0x80, board ->
    PC from 0x80."""

    HELLO = 0x01
    HEARTBEAT = 0x02
    MOVE = 0x03
    STOP = 0x04
    SET_ENABLE = 0x05
    CLEAR_FAULT = 0x06
    SET_GAINS = 0x07
    GET_GAINS = 0x08
    SET_LIMITS = 0x09
    GET_LIMITS = 0x0A
    GET_STATUS = 0x0B
    SET_TELEMETRY = 0x0C
    GET_FAULT = 0x0D
    QUEUE_SEGMENT = 0x0E
    QUEUE_CONTROL = 0x0F
    STREAM_CONTROL = 0x10
    STREAM_POINTS = 0x11
    JOG = 0x12
    HELLO_REPLY = 0x81
    TELEMETRY = 0x82
    ACK = 0x83
    NACK = 0x84
    FAULT_REPORT = 0x85
    GAINS = 0x86
    LIMITS = 0x87
    STATUS = 0x88
    BOARD_HEARTBEAT = 0x89
    FAULT_INFO = 0x8A
    QUEUE_STATUS = 0x8B
    STREAM_STATUS = 0x8C


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
    """Why the board refused a command (``Nack.code``); ``Nack.field`` names the field."""

    UNKNOWN_TYPE = 1  # type byte not defined (or not a command this board supports)
    BAD_LENGTH = 2  # payload shorter than the type's length
    NOT_FINITE = 3  # NaN or infinity in a float field
    OUT_OF_RANGE = 4  # an enum or bool byte holds an undefined value
    UNSTABLE_GAINS = 5  # the board's stability check refuses the gains
    FAULT_ACTIVE = 6  # motion or enable refused while a fault is latched
    DISABLED = 7  # motion refused while the bridge is disabled
    NOT_A_COMMAND = 8  # a board -> PC type (0x80..0xFF) sent to the board
    NO_SESSION = 9  # a command before any Hello
    STALE_SESSION = 10  # a command whose session is not the board's current one
    UNSUPPORTED_VERSION = 11  # Hello's version range excludes the board's (limit = it)
    TOO_HIGH = 12  # field > limit
    TOO_LOW = 13  # field < limit
    BUSY = 14  # not now: e.g. a Move changing the profile kind while moving
    TRAVEL = 15  # the trajectory asked for would leave the travel (limit = the end crossed)
    QUEUE_FULL = 16  # the program or point queue has no free slot (limit = its capacity)
    NO_STREAM = 17  # points with no stream open to take them (StreamStatus.state says why)
    SENSE_OFFSET = 18  # SetEnable: the IS offset calibrated implausible (limit = ceiling, A)


class QueueAction(IntEnum):
    """What a ``QueueControl`` does to the board's program queue."""

    STATUS = 0  # nothing: answer the queue's state
    HOLD = 1  # feed hold: stop on the path, keep the blocks not reached
    RESUME = 2  # go on from where the hold stopped
    ABORT = 3  # stop and empty the queue
    OVERRIDE = 4  # set the speed override to override_pct


class QueueState(IntEnum):
    """State of the program queue (``QueueStatus.state``)."""

    EMPTY = 0  # no block held
    RUNNING = 1  # executing (or at rest at the end of what it holds, waiting for more)
    HELD = 2  # feed hold: stopping or stopped, blocks kept


class StreamAction(IntEnum):
    """What a ``StreamControl`` does to the board's point stream."""

    STATUS = 0  # nothing: answer the stream's state
    START = 1  # open a stream (period_s, interp, prefill) from where the axis rests
    END = 2  # no more points: after the last one, decelerate to rest (not an underrun)
    ABORT = 3  # stop now (the board's Stop) and close the stream


class Interp(IntEnum):
    """How the board interpolates between streamed points (docs/protocol.md 4.6)."""

    LINEAR = 0  # constant velocity between points (the points' velocities are ignored)
    CUBIC = 1  # PVT: the cubic through both points' positions and velocities


class StreamState(IntEnum):
    """State of the point stream (``StreamStatus.state``)."""

    IDLE = 0  # no stream open
    FILLING = 1  # started, holding still until ``prefill`` points are held
    RUNNING = 2  # following the points, one every period
    ENDED = 3  # END received: following the rest, then decelerating to rest
    UNDERRUN = 4  # the points ran out before END: decelerating to rest, stream closed


#: Points one ``StreamPoints`` frame carries at most.
STREAM_POINTS_PER_FRAME = 5

#: ``Nack.field`` when no single field is at fault (the whole command was refused).
NO_FIELD = 0xFF


class State(IntEnum):
    """State of the board's servo state machine."""

    DISABLED = 0
    IDLE = 1
    MOVING = 2
    HOLDING = 3
    FAULT = 4


class Fault(IntEnum):
    """Fault code (u8): the first fault latched since the last ``ClearFault``, ``NONE``
    when none is. All the latched faults are the bits of ``FaultFlag``."""

    NONE = 0
    OVER_CURRENT = 1
    FOLLOWING_ERROR = 2
    OVER_SPEED = 3
    ENCODER = 4
    WATCHDOG = 5
    TRAVEL = 6  # the estimated position beyond the travel by more than the margin
    BRIDGE = 7
    ENCODER_DIAG = 8  # the AS5048 reports an error (SPI parity, EF, CORDIC, magnetic field)
    SENSOR_MISMATCH = 9  # the encoder disagrees with the back-EMF: frozen sensor, runaway
    THERMAL = 10  # the firmware's estimate of the winding temperature above its trip
    BUS_OVER_VOLTAGE = 11  # the measured bus above [safety] bus_over_voltage_v
    BUS_UNDER_VOLTAGE = 12  # the measured bus below [safety] bus_under_voltage_v
    SENSE_OFFSET = 13  # the IS offset calibrated at enable above the chip's maximum
    CALIBRATION_MOTION = 14  # the axis turned during the IS-offset calibration at enable


class FaultFlag(IntFlag):
    """Latched faults as a u32 bitfield, one byte per subsystem.

    Byte 0 power stage, byte 1 motion, byte 2 position sensor, byte 3 link and system.
    Undefined bits are reserved (a receiver shows them as ``bit N``, never rejects them).
    """

    OVER_CURRENT = 1 << 0  # power stage: |i| above the trip threshold
    BRIDGE = 1 << 1  # power stage: driver fault reported on the IS pin
    THERMAL = 1 << 2  # power stage: the winding temperature estimate above its trip
    BUS_OVER_VOLTAGE = 1 << 3  # power stage: the measured bus voltage too high
    BUS_UNDER_VOLTAGE = 1 << 4  # power stage: the measured bus voltage too low
    SENSE_OFFSET = 1 << 5  # power stage: an IS pin's offset implausible (calibration at enable)
    FOLLOWING_ERROR = 1 << 8  # motion: |setpoint - position| above following_error_deg
    OVER_SPEED = 1 << 9  # motion: |velocity| above over_speed_dps
    TRAVEL = 1 << 10  # motion: position outside the travel limits
    CALIBRATION_MOTION = 1 << 11  # motion: the axis turned during the IS-offset calibration
    ENCODER = 1 << 16  # sensor: implausible jump or stuck reading
    ENCODER_DIAG = 1 << 17  # sensor: the AS5048 reports an error
    SENSOR_MISMATCH = 1 << 18  # sensor: the encoder disagrees with the back-EMF
    WATCHDOG = 1 << 24  # link: no PC frame of the session within the watchdog time


#: The flag bit of each fault code.
FAULT_FLAG: dict[Fault, FaultFlag] = {
    Fault.OVER_CURRENT: FaultFlag.OVER_CURRENT,
    Fault.FOLLOWING_ERROR: FaultFlag.FOLLOWING_ERROR,
    Fault.OVER_SPEED: FaultFlag.OVER_SPEED,
    Fault.ENCODER: FaultFlag.ENCODER,
    Fault.WATCHDOG: FaultFlag.WATCHDOG,
    Fault.TRAVEL: FaultFlag.TRAVEL,
    Fault.BRIDGE: FaultFlag.BRIDGE,
    Fault.ENCODER_DIAG: FaultFlag.ENCODER_DIAG,
    Fault.SENSOR_MISMATCH: FaultFlag.SENSOR_MISMATCH,
    Fault.THERMAL: FaultFlag.THERMAL,
    Fault.BUS_OVER_VOLTAGE: FaultFlag.BUS_OVER_VOLTAGE,
    Fault.BUS_UNDER_VOLTAGE: FaultFlag.BUS_UNDER_VOLTAGE,
    Fault.SENSE_OFFSET: FaultFlag.SENSE_OFFSET,
    Fault.CALIBRATION_MOTION: FaultFlag.CALIBRATION_MOTION,
}


def fault_flag_names(flags: int) -> list[str]:
    """Names of the bits set in ``flags`` (``"bit N"`` for a reserved bit)."""
    names = []
    for bit in range(32):
        if flags >> bit & 1:
            try:
                names.append(FaultFlag(1 << bit).name or f"bit {bit}")
            except ValueError:
                names.append(f"bit {bit}")
    return names


# ---------------------------------------------------------------- PC -> board
#
# Every PC -> board message begins with ``cmd_id`` (u16) and ``session`` (u16) on the wire.
# In the dataclasses ``session`` is the last field, with a default of 0, so that a message
# can be built before a session exists; ``BoardClient`` stamps its session on it.


@dataclass(frozen=True, slots=True)
class Hello:
    """Open a session: the board adopts ``session`` (non-zero), forgets the duplicate
    memory of the previous session and answers ``HelloReply`` if its protocol version is
    in ``[version_min, version_max]`` (else ``Nack UNSUPPORTED_VERSION``)."""

    MSG_TYPE: ClassVar[int] = MsgType.HELLO
    cmd_id: int = 0
    version_min: int = PROTOCOL_VERSION
    version_max: int = PROTOCOL_VERSION
    session: int = 0


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """PC keep-alive: feeds the board's command watchdog. Not answered (NACKed only when
    the session is not the current one)."""

    MSG_TYPE: ClassVar[int] = MsgType.HEARTBEAT
    cmd_id: int = 0
    session: int = 0


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
    session: int = 0


@dataclass(frozen=True, slots=True)
class Stop:
    """Decelerate to rest at ``a_max_dps2`` (0 means the board's ``Limits.a_max_dps2``)."""

    MSG_TYPE: ClassVar[int] = MsgType.STOP
    cmd_id: int
    a_max_dps2: float = 0.0
    session: int = 0


@dataclass(frozen=True, slots=True)
class SetGains:
    """Set the PI gains of one loop (units of the loop's error -> output, docs section 4)."""

    MSG_TYPE: ClassVar[int] = MsgType.SET_GAINS
    cmd_id: int
    loop: Loop
    kp: float
    ki: float
    kd: float = 0.0
    session: int = 0


@dataclass(frozen=True, slots=True)
class GetGains:
    """Read the gains of one loop; answered by ``Gains``."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_GAINS
    cmd_id: int
    loop: Loop
    session: int = 0


@dataclass(frozen=True, slots=True)
class SetLimits:
    """Set the motion limits, the current clamp and the trip thresholds (all or none).

    ``current_limit_a`` clamps the current reference (never trips); ``over_current_trip_a``
    is the over-current trip threshold (must be >= the clamp). NaN for
    ``over_current_trip_a`` is refused like any other field.

    Appended (extension rule): the bus over/under-voltage trips' thresholds (V), the
    thermal protection's derating start and trip (degC), then the cap on the fault
    reaction's brake current (A). For these and ``over_current_trip_a``, 0 keeps the board's
    present value: an older PC's shorter payload reads them as 0, so it changes none of them.
    """

    MSG_TYPE: ClassVar[int] = MsgType.SET_LIMITS
    cmd_id: int
    v_max_dps: float
    a_max_dps2: float
    current_limit_a: float
    following_error_deg: float
    over_current_trip_a: float = 0.0
    session: int = 0
    bus_over_voltage_v: float = 0.0
    bus_under_voltage_v: float = 0.0
    thermal_derate_c: float = 0.0
    thermal_trip_c: float = 0.0
    brake_current_limit_a: float = 0.0


@dataclass(frozen=True, slots=True)
class GetLimits:
    """Read the limits; answered by ``Limits``."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_LIMITS
    cmd_id: int
    session: int = 0


@dataclass(frozen=True, slots=True)
class GetStatus:
    """Read the state; answered by ``Status``."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_STATUS
    cmd_id: int
    session: int = 0


@dataclass(frozen=True, slots=True)
class ClearFault:
    """Clear the latched faults; the board goes to ``State.DISABLED`` (send ``SetEnable``).
    Without a latched fault it is ACKed and changes nothing."""

    MSG_TYPE: ClassVar[int] = MsgType.CLEAR_FAULT
    cmd_id: int
    session: int = 0


@dataclass(frozen=True, slots=True)
class SetEnable:
    """Enable or disable the bridge."""

    MSG_TYPE: ClassVar[int] = MsgType.SET_ENABLE
    cmd_id: int
    enable: bool
    session: int = 0


@dataclass(frozen=True, slots=True)
class SetTelemetry:
    """Send telemetry every ``decimation`` ticks (1 = every tick, 0 = off)."""

    MSG_TYPE: ClassVar[int] = MsgType.SET_TELEMETRY
    cmd_id: int
    decimation: int
    session: int = 0


@dataclass(frozen=True, slots=True)
class GetFault:
    """Ask about one fault flag (``bit`` 0..31 of ``FaultFlag``); answered by
    ``FaultInfo``."""

    MSG_TYPE: ClassVar[int] = MsgType.GET_FAULT
    cmd_id: int
    bit: int
    session: int = 0


@dataclass(frozen=True, slots=True)
class QueueSegment:
    """Append a block to the program queue: go to ``target_deg`` at most at ``v_max_dps``
    (the board's acceleration limit), then rest ``dwell_s`` there (0: pass through at
    speed if the path goes on in the same direction). Answered by ``QueueStatus``."""

    MSG_TYPE: ClassVar[int] = MsgType.QUEUE_SEGMENT
    cmd_id: int
    target_deg: float
    v_max_dps: float
    dwell_s: float = 0.0
    session: int = 0


@dataclass(frozen=True, slots=True)
class QueueControl:
    """Feed hold, resume, abort, speed override (``override_pct``, OVERRIDE only) or just
    the queue's state (``QueueAction``). Answered by ``QueueStatus``."""

    MSG_TYPE: ClassVar[int] = MsgType.QUEUE_CONTROL
    cmd_id: int
    action: QueueAction
    override_pct: float = 100.0
    session: int = 0


@dataclass(frozen=True, slots=True)
class StreamControl:
    """Start, end, abort or read the point stream (``StreamAction``). START takes the
    period ``period_s`` between points, the interpolation ``interp`` and ``prefill``, the
    points the board waits for before it starts moving. Answered by ``StreamStatus``."""

    MSG_TYPE: ClassVar[int] = MsgType.STREAM_CONTROL
    cmd_id: int
    action: StreamAction
    interp: Interp = Interp.LINEAR
    period_s: float = 0.0
    prefill: int = 1
    session: int = 0


@dataclass(frozen=True, slots=True)
class StreamPoints:
    """Up to ``STREAM_POINTS_PER_FRAME`` consecutive points of the stream, the first being
    point ``first_index`` (point k is due k periods after the stream started moving; point
    0 is where the axis rested at START). ``count`` slots are used; ``vel*_dps`` only with
    ``Interp.CUBIC``. Build one with :meth:`of`. Answered by ``StreamStatus``."""

    MSG_TYPE: ClassVar[int] = MsgType.STREAM_POINTS
    cmd_id: int
    first_index: int
    count: int
    pos0_deg: float = 0.0
    pos1_deg: float = 0.0
    pos2_deg: float = 0.0
    pos3_deg: float = 0.0
    pos4_deg: float = 0.0
    vel0_dps: float = 0.0
    vel1_dps: float = 0.0
    vel2_dps: float = 0.0
    vel3_dps: float = 0.0
    vel4_dps: float = 0.0
    session: int = 0

    @classmethod
    def of(
        cls,
        cmd_id: int,
        first_index: int,
        pos_deg: list[float] | tuple[float, ...],
        vel_dps: list[float] | tuple[float, ...] | None = None,
    ) -> StreamPoints:
        """The frame of 1..``STREAM_POINTS_PER_FRAME`` points (velocities default to 0)."""
        n = len(pos_deg)
        if not 1 <= n <= STREAM_POINTS_PER_FRAME:
            raise ValueError(f"{n} points: a frame carries 1..{STREAM_POINTS_PER_FRAME}")
        vel = list(vel_dps) if vel_dps is not None else [0.0] * n
        if len(vel) != n:
            raise ValueError(f"{len(vel)} velocities for {n} positions")
        pad = [0.0] * (STREAM_POINTS_PER_FRAME - n)
        return cls(cmd_id, first_index, n, *map(float, pos_deg), *pad, *map(float, vel), *pad)

    @property
    def points(self) -> tuple[tuple[float, float], ...]:
        """The ``count`` points used, as ``(pos_deg, vel_dps)``."""
        pos = (self.pos0_deg, self.pos1_deg, self.pos2_deg, self.pos3_deg, self.pos4_deg)
        vel = (self.vel0_dps, self.vel1_dps, self.vel2_dps, self.vel3_dps, self.vel4_dps)
        n = max(0, min(self.count, STREAM_POINTS_PER_FRAME))
        return tuple(zip(pos[:n], vel[:n], strict=True))


@dataclass(frozen=True, slots=True)
class Jog:
    """Move at ``vel_dps`` (signed; 0 = stop), reaching it at ``a_max_dps2``, until the
    next Jog, a Stop, the travel end (the board plans its stop at the end) or ``timeout_ms``
    without a frame of the session (0 = no timeout): then it decelerates to rest at
    ``a_max_dps2``. Answered by ``Ack``."""

    MSG_TYPE: ClassVar[int] = MsgType.JOG
    cmd_id: int
    vel_dps: float
    a_max_dps2: float
    timeout_ms: int = 0
    session: int = 0


# ---------------------------------------------------------------- board -> PC


@dataclass(frozen=True, slots=True)
class HelloReply:
    """Answer to ``Hello``: the session opened, the version chosen, who the board is and
    what it can do (``command_mask`` bit t set: command type t is supported) and its
    limits."""

    MSG_TYPE: ClassVar[int] = MsgType.HELLO_REPLY
    cmd_id: int
    session: int
    protocol_version: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    tick_hz: int
    counts_per_rev: int
    command_mask: int
    max_payload_bytes: int
    rx_buffer_bytes: int
    reply_queue_frames: int
    telemetry_min_decimation: int
    heartbeat_ms: int
    watchdog_ms: int
    rx_silence_ms: int
    baud: int
    # Appended (extension rule): what programs and streams may use.
    queue_blocks: int = 0
    stream_points: int = 0
    stream_period_min_ms: int = 0
    stream_period_max_ms: int = 0


@dataclass(frozen=True, slots=True)
class Telemetry:
    """One servo tick as the board saw it (sent every ``decimation`` ticks).

    ``sp_*`` is the planner's setpoint, the others are measured/estimated. ``duty`` is the
    PWM duty in [-1, 1] the bridge applies for the next period (0 when the state is
    ``DISABLED`` or ``FAULT``). ``fault`` is the first latched fault, ``fault_flags`` all
    of them (``FaultFlag`` bits). ``bus_voltage_v`` is the bus voltage the board measures
    (V, 1 mV steps; appended by the extension rule: 0 from an older board, or from one
    without a bus measurement), as ``BoardHeartbeat.bus_voltage_v`` but every frame.
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
    fault_flags: int
    # Appended (extension rule): the measured bus voltage (V; 0 = not reported).
    bus_voltage_v: float

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
        fault_flags: int = 0,
        bus_voltage_v: float = 0.0,
    ) -> None:
        # Built every tick by the board and again by the PC: the dataclass's frozen __init__
        # goes through object.__setattr__ per field (about 2 us for ten); writing the slots
        # through their descriptors builds the same immutable object in about a third.
        (s_tick, s_sp_pos, s_sp_vel, s_pos, s_vel, s_cur, s_duty, s_state, s_fault,
         s_flags, s_bus) = _TEL_SLOTS  # fmt: skip
        s_tick(self, tick)
        s_sp_pos(self, sp_pos_deg)
        s_sp_vel(self, sp_vel_dps)
        s_pos(self, pos_deg)
        s_vel(self, vel_dps)
        s_cur(self, current_a)
        s_duty(self, duty)
        s_state(self, state)
        s_fault(self, fault)
        s_flags(self, fault_flags)
        s_bus(self, bus_voltage_v)


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
    """Command ``cmd_id`` of type ``msg_type`` was refused; nothing of it was applied.

    ``field`` is the index of the refused field in the command's wire layout (0 =
    ``cmd_id``, 1 = ``session``, 2 = the first data field, ...), ``NO_FIELD`` (255) when no
    single field is at fault. ``limit`` is the bound the field broke for ``TOO_HIGH`` and
    ``TOO_LOW`` (in the field's unit), the board's version for ``UNSUPPORTED_VERSION``,
    else 0.
    """

    MSG_TYPE: ClassVar[int] = MsgType.NACK
    cmd_id: int
    msg_type: int
    code: NackCode
    field: int = NO_FIELD
    limit: float = 0.0


@dataclass(frozen=True, slots=True)
class FaultReport:
    """A fault tripped at ``tick``; ``value`` is the measured value that tripped it, in the
    fault's unit (A for over-current, deg for following error and travel, deg/s for
    over-speed, ticks without a PC frame for the watchdog, raw counts for the encoder);
    ``fault_flags`` all the faults latched now."""

    MSG_TYPE: ClassVar[int] = MsgType.FAULT_REPORT
    tick: int
    fault: Fault
    value: float
    fault_flags: int = 0
    threshold: float = 0.0


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
    """Reply to ``GetLimits``: the settable values and, read-only, the bounds the board
    checks them and ``Move`` against."""

    MSG_TYPE: ClassVar[int] = MsgType.LIMITS
    cmd_id: int
    v_max_dps: float
    a_max_dps2: float
    current_limit_a: float
    following_error_deg: float
    over_current_trip_a: float = 0.0
    travel_min_deg: float = 0.0
    travel_max_deg: float = 0.0
    over_speed_dps: float = 0.0
    over_current_max_a: float = 0.0
    # Appended (extension rule): the bus voltage trips' thresholds, 0 = the check off.
    bus_over_voltage_v: float = 0.0
    bus_under_voltage_v: float = 0.0
    # Appended (extension rule): the thermal protection (0, 0 when it is off; the trip is
    # settable, the estimate read-only), then where its derating starts (settable).
    thermal_trip_c: float = 0.0
    winding_estimate_c: float = 0.0
    thermal_derate_c: float = 0.0
    # Appended (extension rule): the cap on the fault reaction's brake current (A; 0 = none,
    # the full short).
    brake_current_limit_a: float = 0.0


@dataclass(frozen=True, slots=True)
class Status:
    """Reply to ``GetStatus``. ``target_deg`` is the target of the current or last move;
    after ``SetEnable`` (before any move) the position held since the enable."""

    MSG_TYPE: ClassVar[int] = MsgType.STATUS
    cmd_id: int
    tick: int
    state: State
    fault: Fault
    pos_deg: float
    vel_dps: float
    target_deg: float
    fault_flags: int = 0
    session: int = 0
    # Appended (extension rule): the IS offsets the firmware subtracts (A of load current;
    # calibrated at the last enable with [controller.current] sense_calibration), one per
    # IS pin: the positive half-bridge's (read while the duty is > 0), then the negative's.
    sense_offset_a: float = 0.0
    sense_offset_neg_a: float = 0.0


@dataclass(frozen=True, slots=True)
class BoardHeartbeat:
    """Sent by the board every ``HelloReply.heartbeat_ms``: its state and the counters of
    its receiver (each u32, wrapping), MAVLink HEARTBEAT + SYS_STATUS in one, and the
    bus voltage the board measures (``bus_voltage_v``, as SYS_STATUS's battery voltage)."""

    MSG_TYPE: ClassVar[int] = MsgType.BOARD_HEARTBEAT
    tick: int
    session: int
    state: State
    fault_flags: int
    rx_frames: int
    rx_crc_errors: int
    rx_header_errors: int
    rx_bytes_dropped: int
    rx_seq_gaps: int
    rx_overflow_bytes: int
    rx_silence_discards: int
    rx_nacked: int
    tx_telemetry_dropped: int
    # Appended (extension rule): flow control of the program queue and the point stream.
    queue_free: int = 0
    stream_free: int = 0
    stream_state: StreamState = StreamState.IDLE
    stream_underruns: int = 0
    # Appended (extension rule): the bus voltage as the board measures it (V, 1 mV steps;
    # 0 = not reported, an older board).
    bus_voltage_v: float = 0.0


@dataclass(frozen=True, slots=True)
class FaultInfo:
    """Reply to ``GetFault``: whether flag ``bit`` is latched and, if so, the tick it
    tripped, the measured value that tripped it and the threshold it crossed (fault units
    as in ``FaultReport``; 0 when not latched)."""

    MSG_TYPE: ClassVar[int] = MsgType.FAULT_INFO
    cmd_id: int
    bit: int
    latched: bool
    tick: int
    value: float
    threshold: float


@dataclass(frozen=True, slots=True)
class QueueStatus:
    """Answer to ``QueueSegment`` and ``QueueControl``: the program queue's state and its
    flow control (``free_slots`` more blocks may be sent now)."""

    MSG_TYPE: ClassVar[int] = MsgType.QUEUE_STATUS
    cmd_id: int
    state: QueueState
    free_slots: int
    queued: int
    done: int
    override_pct: float


@dataclass(frozen=True, slots=True)
class StreamStatus:
    """Answer to ``StreamControl`` and ``StreamPoints``: the stream's state, its flow
    control (``free_slots`` more points may be sent now; ``next_index`` is the index the
    next point must carry), the underruns since boot and point 0 (where the stream began)."""

    MSG_TYPE: ClassVar[int] = MsgType.STREAM_STATUS
    cmd_id: int
    state: StreamState
    free_slots: int
    next_index: int
    underruns: int
    start_pos_deg: float


# ---------------------------------------------------------------- decoder output


@dataclass(frozen=True, slots=True)
class Malformed:
    """A frame with a good CRC whose payload cannot be decoded.

    ``code`` is ``NackCode.UNKNOWN_TYPE`` (type byte not in ``MsgType``),
    ``NackCode.BAD_LENGTH`` (payload shorter than the type's) or
    ``NackCode.OUT_OF_RANGE`` (an enum or bool byte holds an undefined value; ``field`` is
    its index). ``cmd_id`` is the payload's first two bytes (little-endian) when it has
    them, else 0, so that the board can NACK it.
    """

    msg_type: int
    seq: int
    cmd_id: int
    code: NackCode
    field: int = NO_FIELD


Message = (
    Hello
    | Heartbeat
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
    | GetFault
    | HelloReply
    | Telemetry
    | Ack
    | Nack
    | FaultReport
    | Gains
    | Limits
    | Status
    | BoardHeartbeat
    | FaultInfo
    | QueueSegment
    | QueueControl
    | QueueStatus
    | StreamControl
    | StreamPoints
    | Jog
    | StreamStatus
)

#: Message classes the PC sends to the board.
COMMAND_TYPES: tuple[type, ...] = (
    Hello,
    Heartbeat,
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
    GetFault,
    QueueSegment,
    QueueControl,
    StreamControl,
    StreamPoints,
    Jog,
)
