"""The simulated STM32F103 board: the 500 Hz servo tick, the current-loop ISR, command
handling, safety and telemetry, around the control law of ``firmware_model/servo.py``.

The simulation loop (``sim/loop.py``) calls, per servo tick::

    tx = fw.servo_tick(encoder_counts, rx_bytes, tx_free)      # once
    duty, enable = fw.current_tick(adc_counts)                  # current_loop_multiple times

One servo tick, in order (seed 000 Fig. 5): read the encoder and unwrap it; estimate the
velocity; handle the commands received since the last tick; take the setpoint from the
planner (or the raw target for ``Profile.STEP``); run the position and velocity loops; check
the trips; queue replies and telemetry into the UART TX FIFO (whole frames only).

States (``serial_protocol.messages.State``): ``DISABLED`` (bridge off) -> ``SetEnable`` ->
``IDLE`` (holding where it was enabled) -> ``Move`` -> ``MOVING`` -> ``HOLDING`` (holding
the target). Any trip -> ``FAULT`` (bridge off, motion abandoned) -> ``ClearFault`` ->
``DISABLED``. Faults are data: a code in the status and telemetry and a ``FaultReport``.

Batch (``batch=N``): the control law and the trips run per member; the planner and the
command handling are shared. A command is refused (``FAULT_ACTIVE`` / ``DISABLED``) only
if no member could follow it; the replies, ``Status`` and telemetry describe member 0.
"""

from __future__ import annotations

import copy
import functools
import math
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from firmware_model import as5048, programs, safety, sense_calibration, stream
from firmware_model import tick as ftick
from firmware_model.laws import Law
from firmware_model.laws.layout import (
    C_BUS_ADC,
    C_CAL_LEFT,
    C_CAL_SUM_A,
    C_CAL_SUM_B,
    C_SENSE_OFFSET_A,
    C_SENSE_OFFSET_B,
    P_DERATE,
    P_DUTY,
    P_EMF_RISE,
    P_IMEAS,
    P_IREF,
    P_POS,
    P_R_RISE,
    P_VEL,
    P_VEL_RAW,
)
from firmware_model.params import FirmwareParams
from firmware_model.stability import unstable_reason
from firmware_model.thermal import N_TP, TP_DERATE_C, TP_TRIP_C, protection_constants
from planner.online import OnlinePlanner
from planner.profile import build_profile
from serial_protocol import frame
from serial_protocol.messages import (
    COMMAND_TYPES,
    FAULT_FLAG,
    NO_FIELD,
    PROTOCOL_VERSION,
    STREAM_POINTS_PER_FRAME,
    Ack,
    BoardHeartbeat,
    ClearFault,
    Fault,
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
    Jog,
    Limits,
    Loop,
    Malformed,
    Move,
    Nack,
    NackCode,
    Profile,
    QueueAction,
    QueueControl,
    QueueSegment,
    QueueState,
    QueueStatus,
    SetEnable,
    SetGains,
    SetLimits,
    SetTelemetry,
    State,
    Status,
    Stop,
    StreamAction,
    StreamControl,
    StreamPoints,
    StreamState,
    StreamStatus,
)

__all__ = ["FW_VERSION", "SIGNAL_NAMES", "Firmware"]

FW_VERSION = (0, 1, 0)
#: The keys of ``Firmware.signals()``, in order (the order of ``Firmware.signal_row()``).
SIGNAL_NAMES = (
    "sp_pos_deg",
    "sp_vel_dps",
    "sp_acc_dps2",
    "pos_deg",
    "vel_dps",
    "vel_raw_dps",
    "current_meas_a",
    "current_ref_a",
    "duty",
    "state",
    "fault",
)

_PROFILE_KIND = {Profile.TRAPEZOID: "trapezoid", Profile.SCURVE: "scurve"}
# Loop -> the run-time gain names of (kp, ki).
_LOOP_GAINS = {
    Loop.CURRENT: ("kp_i", "ki_i"),
    Loop.VELOCITY: ("kp_v", "ki_v"),
    Loop.POSITION: ("kp_p", None),
}
# Commands that change something: a repeat of the last one of the session is answered
# again, not re-applied.
_MUTATING = (
    Move, Stop, SetGains, SetLimits, ClearFault, SetEnable, SetTelemetry, QueueSegment,
    QueueControl, StreamControl, StreamPoints, Jog,
)  # fmt: skip
#: Smallest positive rate or limit a command may carry (deg/s, deg/s², A, deg): the lower
#: bound of the documented ranges (docs/protocol.md section 4).
MIN_POSITIVE = 1e-3
#: The range of the thermal protection's thresholds (degC; ``[safety] thermal_*_c``).
THERMAL_MIN_C, THERMAL_MAX_C = -40.0, 250.0
#: The largest cap on the brake after a trip (A; ``[safety] brake_current_limit_a``): above
#: any short-circuit current of a motor on this bridge (the BTN7971B limits at 70 A), so it
#: also stands for "no cap" over the wire, where 0 keeps the board's value.
BRAKE_CAP_MAX_A = 100.0
#: Longest dwell of a program block (s).
MAX_DWELL_S = 3600.0
#: Smallest receive ring of the board (bytes per servo tick); at high baud rates the ring
#: holds two ticks' worth of the line. More in one tick is lost and counted.
RX_BUFFER_BYTES = 256
#: Bit t set: command type t is handled (HelloReply.command_mask).
COMMAND_MASK = sum(1 << int(cls.MSG_TYPE) for cls in COMMAND_TYPES)
_COMMAND_CLASSES = frozenset(COMMAND_TYPES)
# A refusal: (code, refused field name or None, limit in the field's unit).
_Refusal = tuple[NackCode, str | None, float]
# The faults whose reaction is the bridge off at once, without the brake (_trip).
_NO_BRAKE = frozenset({Fault.OVER_CURRENT, Fault.SENSE_OFFSET, Fault.CALIBRATION_MOTION})
# A command answered later (a SetEnable calibrating the IS offset), by _apply's handlers.
_PENDING: Any = object()
# link_status: the heartbeat's wire values as the PC decodes them.
_HEARTBEAT_FROM_WIRE = functools.partial(frame.from_wire_values, BoardHeartbeat)
_MODES = {"hold": ftick.MODE_HOLD, "plan": ftick.MODE_PLAN, "step": ftick.MODE_STEP}
_DISABLED, _IDLE, _MOVING, _HOLDING, _FAULT = (
    int(State.DISABLED),
    int(State.IDLE),
    int(State.MOVING),
    int(State.HOLDING),
    int(State.FAULT),
)


class Firmware:
    """The board. See the module docstring for the call sequence and the states.

    Args:
        params: the firmware tables.
        batch: None for one axis (scalars in and out), or N for N axes in lock-step
            (``(N,)`` arrays in and out; gains in ``params`` may be ``(N,)`` arrays).
        gain_check: ``(params, gains) -> reason or None``, run on every ``SetGains`` (a
            reason NACKs it with ``UNSTABLE_GAINS``); ``gains`` holds ``kp_i, ki_i, kp_v,
            ki_v, kp_p`` and the feed-forward terms. Default: ``stability.unstable_reason``.

    Attributes:
        tick: servo ticks done.
        counters: what happened on the link and in the command handler (never silent):
            ``rx_messages, rx_malformed, commands_applied, duplicates, nacks, nack_<CODE>,
            sessions, heartbeats, faults, fault_<NAME>, tx_frames, tx_bytes,
            tx_telemetry_dropped, tx_replies_dropped, telemetry_decimation``; the receive
            side's are in ``link_status()`` (what ``BoardHeartbeat`` sends).
        decoder: the ``serial_protocol.frame.Decoder`` fed with the received bytes.
        session: the session opened by the last ``Hello`` (0 = none yet); commands of any
            other session are refused (docs/protocol.md section 5).
        sensor_mismatch_peak_deg: per member (``(N,)``), the largest value the back-EMF
            check's integrated excess reached since power-up (its margin against
            ``[safety] sensor_mismatch_deg``; ``benchmarks/sensor_check.py`` reports it).
    """

    def __init__(
        self,
        params: FirmwareParams,
        *,
        batch: int | None = None,
        gain_check: Callable[[FirmwareParams, dict[str, float]], str | None] = unstable_reason,
    ) -> None:
        gain_batch = params.batch_size()
        if gain_batch is not None and gain_batch != batch:
            raise ValueError(f"batch = {batch!r}: gain arrays have length {gain_batch}")
        if batch is not None and batch < 1:
            raise ValueError(f"batch = {batch!r}: must be >= 1")
        self.params = params
        self.batch = batch
        self._gain_check = gain_check
        self._scalar = batch is None
        n = batch or 1
        # One law for every N: one axis is a batch of one (scalars only at this API's edge).
        self.law = Law(params, n)
        self._n = n
        self._raw = np.zeros(n, dtype=np.int64)  # the encoder reading of a single axis
        self.dt_s = params.servo.dt_s
        self.tick = 0
        self._booted = False
        # Per member: latched fault code and bridge enable.
        self._fault = np.zeros(n, dtype=np.int64)
        self._enabled = np.zeros(n, dtype=bool)
        # Bumped whenever _fault or _enabled change: the batch state/fault arrays are cached.
        self._flags_version = 0
        self._state_cache: tuple[Any, Any] = (None, None)
        self._fault_cache: tuple[Any, Any] = (None, None)
        self._fault_s = 0  # member 0 / scalar copies for the fast path
        self._enabled_s = False
        self._oc_ticks = np.zeros(n, dtype=np.int64)
        self._oc_s = 0
        # The over-current trip threshold (SetLimits.over_current_trip_a), separate from the
        # clamp current_limit_a; the configured value is its ceiling.
        self._oc_thr_a = params.safety.over_current_a
        # Per member: latched FaultFlag bits; member 0's trip details per bit (GetFault).
        self._flags = np.zeros(n, dtype=np.int64)
        self._fault_info: dict[int, tuple[int, float, float]] = {}
        self._oc_samples = params.safety.over_current_ticks
        # Limits that SetLimits may change.
        lim = params.limits
        self.v_max_dps = lim.v_max_dps
        self.a_max_dps2 = lim.a_max_dps2
        self.current_limit_a = lim.current_limit_a
        self.following_error_deg = lim.following_error_deg
        # Motion (shared by the batch).
        self._planners: dict[str, OnlinePlanner] = {}
        self._kind = "trapezoid"
        self._mode = "hold"  # hold | plan | step
        self._moved = False
        self._moving = False
        self._target_deg = 0.0
        self._j_max = 0.0
        self._move_limits = (lim.v_max_dps, lim.a_max_dps2)  # v_max, a_max of the move
        self._v_clamp_dps = lim.v_max_dps
        self.sp_pos_deg = 0.0
        self.sp_vel_dps = 0.0
        self.sp_acc_dps2 = 0.0
        # The motion-program queue (firmware_model/programs.py); its profile is followed
        # through the trapezoid planner like a Move's.
        self.program = programs.ProgramQueue(programs.QUEUE_CAPACITY, self.dt_s)
        # The point stream (firmware_model/stream.py), followed the same way.
        self.stream = stream.PointStream(stream.STREAM_CAPACITY)
        # A jog's dead-man timeout (ticks without a frame of the session; 0 = none) and
        # its deceleration.
        self._jog_timeout_ticks = 0
        self._jog_a_max_dps2 = lim.a_max_dps2
        # Link.
        self.decoder = frame.Decoder()
        self._replies: deque[Any] = deque()
        self.session = 0  # 0: no session opened yet
        self._last_cmd: Any = None  # last mutating command of the session, and its answer
        self._last_reply: Any = None
        self._seq = 0
        self._last_rx_tick = 0  # last tick a frame of the session fed the watchdog
        self._last_byte_tick = 0  # last tick a byte arrived (the silence rule)
        tick_hz = params.servo.tick_hz
        self._silence_ticks = max(1, math.ceil(frame.RX_SILENCE_S * tick_hz - 1e-9))
        self._heartbeat_ticks = round(params.telemetry.heartbeat_s * tick_hz)
        self._rx_overflow_bytes = 0
        tel = params.telemetry
        bytes_per_tick = tel.baud / 10.0 / params.servo.tick_hz
        self._rx_ring_bytes = max(RX_BUFFER_BYTES, 2 * math.ceil(bytes_per_tick))
        budget = bytes_per_tick * (1.0 - tel.reply_reserve)
        self._auto_decimation = max(1, math.ceil(frame.TELEMETRY_FRAME_BYTES / budget))
        self._watchdog_ticks = round(params.safety.watchdog_s * params.servo.tick_hz)
        # The hard position trip's window: the travel widened by the margin (and, from an
        # enable outside the travel, to where the axis was; see _enable).
        self._pos_lo_deg = self._pos_hi_deg = 0.0
        self._set_position_window()
        # The sensor checks: the back-EMF model (per member) and its filter state, and the
        # AS5048's reported errors (ticks in a row with an error, the last error bits).
        cur = params.current
        self._supply_v = float(cur.supply_v)
        self._r_ohm = np.broadcast_to(np.asarray(cur.resistance_ohm, float), (n,)).copy()
        self._emf_v_per_dps = np.broadcast_to(
            np.asarray(cur.back_emf_v_per_dps, float), (n,)
        ).copy()
        self._mismatch_deg = np.zeros(n)
        # Dynamic braking after a trip: servo ticks left per member (see _trip).
        self._brake_ticks_setting = round(params.safety.brake_s * params.servo.tick_hz)
        self._brake_ticks = np.zeros(n, dtype=np.int64)
        self._diag_ticks = np.zeros(n, dtype=np.int64)
        self._diag_errors = np.zeros(n, dtype=np.int64)
        # The same arrays as the compiled tick's ``sf`` (firmware_model.tick.SF_*): they are
        # only ever changed in place.
        self.sensor_mismatch_peak_deg = np.zeros(n)
        # The thermal protection (firmware_model.thermal): its constants and its estimate of
        # the winding and housing temperatures (from power-up at the assumed ambient) live in
        # fs from ftick.FS_THERMAL (the constants, then (T_w, T_h) per member).
        self._fs = np.zeros(ftick.FS_THERMAL + N_TP + 2 * n)
        self._fs[ftick.FS_THERMAL : ftick.FS_THERMAL + N_TP] = protection_constants(
            params.safety, self.dt_s
        )
        self._thermal_est = self._fs[ftick.FS_THERMAL + N_TP :].reshape(n, 2)
        self._thermal_est[:] = float(params.safety.thermal_ambient_c)
        # The bus voltage screen: current-loop readings in a row beyond a threshold.
        self._bus_ticks = np.zeros(n, dtype=np.int64)
        # The IS-offset calibration at enable (firmware_model.sense_calibration): the members
        # calibrating, and the SetEnable answered when they are done (None: the power-up's).
        self._calibrating = np.zeros(n, dtype=bool)
        self._cal_command: SetEnable | None = None
        self._sf = (
            self._mismatch_deg, self._r_ohm, self._emf_v_per_dps, self._brake_ticks,
            self._diag_ticks, self._diag_errors, self.sensor_mismatch_peak_deg,
            self._bus_ticks,
        )  # fmt: skip
        # Rare events count here; the per-tick TX counters are plain ints (see counters).
        self._counts: dict[str, int] = {
            "rx_messages": 0,
            "rx_malformed": 0,
            "commands_applied": 0,
            "duplicates": 0,
            "nacks": 0,
            "faults": 0,
            "tx_replies_dropped": 0,
            "sessions": 0,
            "heartbeats": 0,
            "jog_timeouts": 0,
        }
        self._tx_frames = 0
        self._tx_bytes = 0
        self._tx_dropped = 0
        self._decimation = 0
        for code in NackCode:
            self._counts[f"nack_{code.name}"] = 0
        for fault in Fault:
            if fault is not Fault.NONE:
                self._counts[f"fault_{fault.name}"] = 0
        self._set_decimation(tel.decimation)
        # The shared state in the arrays of the compiled tick (firmware_model/tick.py):
        # the constants once here, the rest by _pack / _unpack around each compiled call.
        self._fi = np.zeros(ftick.N_FI, dtype=np.int64)
        s = params.safety
        fs, fi = self._fs, self._fi
        fs[ftick.FS_DT], fs[ftick.FS_TOL] = self.dt_s, params.limits.in_position_deg
        fs[ftick.FS_OC_THR], fs[ftick.FS_OVER_SPEED] = s.over_current_a, s.over_speed_dps
        fs[ftick.FS_STUCK_MIN_VEL] = s.encoder_stuck_min_vel_dps
        fi[ftick.FI_WATCHDOG], fi[ftick.FI_OC_SAMPLES] = self._watchdog_ticks, s.over_current_ticks
        fi[ftick.FI_JUMP], fi[ftick.FI_STUCK] = s.encoder_jump_counts, s.encoder_stuck_ticks
        lim = params.limits
        fs[ftick.FS_TRAVEL_MIN], fs[ftick.FS_TRAVEL_MAX] = lim.travel_min_deg, lim.travel_max_deg
        fs[ftick.FS_EDGE_DECEL] = lim.a_max_dps2
        fs[ftick.FS_SUPPLY_V], fs[ftick.FS_MM_WINDOW] = self._supply_v, s.sensor_mismatch_window_s
        fs[ftick.FS_MM_TOL] = s.sensor_mismatch_tolerance_dps
        fs[ftick.FS_MM_RATIO], fs[ftick.FS_MM_DEG] = (
            s.sensor_mismatch_tolerance_ratio, s.sensor_mismatch_deg,
        )  # fmt: skip
        fi[ftick.FI_DIAG_TICKS] = s.encoder_diag_ticks
        # The bus trips' thresholds in counts of the bus reading (safety.bus_voltage_screen).
        v_per_count = params.current.v_per_bus_adc
        self._set_bus_thresholds(s.bus_over_voltage_v, s.bus_under_voltage_v)
        fi[ftick.FI_BUS_SAMPLES] = s.bus_voltage_samples if s.bus_voltage_check else 0
        fs[ftick.FS_MM_V_PER_BUS] = v_per_count if s.sensor_mismatch_measured_bus else 0.0
        fs[ftick.FS_MM_SENSE_SPREAD] = s.sensor_mismatch_sense_spread
        # With the offset calibrated at every enable (the axis never drives before), the
        # back-EMF check's offset allowance is the one for a calibrated board.
        offset_counts = (
            s.sensor_mismatch_calibrated_offset_counts
            if params.current.sense_calibration
            else s.sensor_mismatch_offset_counts
        )
        fs[ftick.FS_MM_OFFSET_A] = offset_counts * params.current.a_per_adc
        fs[ftick.FS_MM_R_SPREAD] = s.sensor_mismatch_r_spread
        fs[ftick.FS_MM_RESTART_W] = fs[ftick.FS_MM_RESTART_H] = s.sensor_mismatch_restart_rise_k
        fs[ftick.FS_BUS_V_PER_COUNT] = v_per_count
        fs[ftick.FS_BRAKE_CAP] = s.brake_current_limit_a
        self._prof = np.zeros((0, 5))
        self._prof_of: Any = None  # the (profile, start time) packed into _prof

    # ------------------------------------------------------------------ public API
    def servo_tick(
        self, encoder_counts: Any, rx_bytes: bytes, tx_free: int, encoder_spi: Any = None
    ) -> bytes:
        """One 500 Hz servo tick; returns the bytes written into the UART TX FIFO.

        Args:
            encoder_counts: AS5048 reading(s), int in [0, 16383] (``(N,)`` in batch).
            rx_bytes: bytes the UART received from the PC since the last tick.
            tx_free: free bytes in the TX FIFO; only whole frames that fit are written.
            encoder_spi: the AS5048's SPI frames of this reading, ``(angle_frames,
                diag_frames)`` (int ``(N,)`` each, ``firmware_model/as5048.py``), or None
                for valid frames from a healthy chip (what the simulation passes while no
                encoder fault is injected).
        """
        law = self.law
        if self._scalar:
            self._raw[0] = encoder_counts
            encoder_counts = self._raw
        elif not (
            isinstance(encoder_counts, np.ndarray)
            and encoder_counts.dtype == np.int64
            and encoder_counts.shape == (self._n,)
        ):
            encoder_counts = np.broadcast_to(np.asarray(encoder_counts, dtype=np.int64), (self._n,))
        if encoder_spi is None:
            as5048.clear_diag(self._diag_ticks, self._diag_errors)
        else:
            encoder_counts = encoder_counts.copy()  # a bad angle is replaced (the caller's kept)
            angle, diag = (np.asarray(f, dtype=np.int64).reshape(self._n) for f in encoder_spi)
            as5048.check_reading(angle, diag, encoder_counts, law.C, self._diag_ticks,
                                 self._diag_errors, self._booted)  # fmt: skip
        if not self._booted:
            self._boot(encoder_counts)
        law.estimate(encoder_counts)
        if rx_bytes:
            self._receive(rx_bytes)
        elif self.decoder._buf and self.tick - self._last_byte_tick >= self._silence_ticks:
            self._silence()
        self._pack()
        hit = ftick.servo_stage(
            law.P, law.C, law.S, law.G, law.K, self._fs, self._fi, self._enabled, self._prof,
            self._sf,
        )  # fmt: skip
        self._unpack()
        if hit:
            self._check()
        self.tick += 1
        return self._transmit(tx_free)

    def current_tick(self, adc_counts: Any, bus_adc_counts: Any = None) -> tuple[Any, Any]:
        """One current-loop period: ``(duty, enable)`` for the bridge.

        Args:
            adc_counts: the IS-pin reading(s), int in [0, 4095] (``(N,)`` in batch).
            bus_adc_counts: the bus-voltage channel's reading(s) (through the divider of
                ``[controller.current] bus_divider_ratio``); None keeps the last one (at
                power-on the configured supply's).

        Returns:
            ``duty`` in [-1, 1] on the timer's ARR grid, applied by the bridge for the next
            current-loop period, and ``enable`` (False: bridge off, the motor coasts); while
            ``bridge_high_sides`` is nonzero the bridge has both high sides on instead.
        """
        law = self.law
        if bus_adc_counts is not None:
            law.C[C_BUS_ADC] = bus_adc_counts
        if self._scalar:
            adc = self._raw
            adc[0] = adc_counts
        else:
            adc = np.asarray(adc_counts, dtype=np.int64)
        enabled = self._enabled.copy()
        fi = self._fi
        fi[ftick.FI_OC_ANY] = self._oc_s
        trip = ftick.current_stage(
            adc, enabled, law.P, law.C, law.S, law.G, law.K, self._fs, fi, self._oc_ticks,
            self._bus_ticks,
        )  # fmt: skip
        self._oc_s = int(fi[ftick.FI_OC_ANY])
        if trip:
            self._current_trips()
            enabled = self._enabled.copy()
        # duty 0 with the bridge on (or off while a capped brake holds off)
        safety.brake_enable(
            enabled, self._brake_ticks, law.P[P_VEL], self._r_ohm, self._emf_v_per_dps,
            law.P[P_R_RISE], law.P[P_EMF_RISE], self._fs[ftick.FS_BRAKE_CAP],
        )  # fmt: skip
        if self._scalar:
            return float(law.duty[0]), bool(enabled[0])
        # Copies: the caller may keep them; the law's arrays change next period.
        return law.duty.copy(), enabled

    def signals(self) -> dict[str, Any]:
        """The firmware's view of this tick (floats, or ``(N,)`` arrays in batch).

        Keys: ``sp_pos_deg, sp_vel_dps, sp_acc_dps2`` (shared setpoint, floats), ``pos_deg,
        vel_dps`` (estimated), ``vel_raw_dps`` (plain differencing), ``current_meas_a``,
        ``current_ref_a``, ``duty``, ``state``, ``fault``. Batch arrays are not updated in
        place (each tick makes new ones); ``state`` and ``fault`` arrays are read-only.
        """
        return dict(zip(SIGNAL_NAMES, self.signal_row(), strict=True))

    def signal_row(self) -> tuple[Any, ...]:
        """``signals()`` as a tuple in the order of :data:`SIGNAL_NAMES` (the simulation
        loop logs one per tick; a tuple costs a third of the dict)."""
        p = self.law.P
        if self._scalar:
            return (
                self.sp_pos_deg, self.sp_vel_dps, self.sp_acc_dps2, float(p[P_POS, 0]),
                float(p[P_VEL, 0]), float(p[P_VEL_RAW, 0]), float(p[P_IMEAS, 0]),
                float(p[P_IREF, 0]), float(p[P_DUTY, 0]), self.state, self._fault_s,
            )  # fmt: skip
        return (
            self.sp_pos_deg, self.sp_vel_dps, self.sp_acc_dps2, p[P_POS].copy(),
            p[P_VEL].copy(), p[P_VEL_RAW].copy(), p[P_IMEAS].copy(), p[P_IREF].copy(),
            p[P_DUTY].copy(), self.state, self.fault,
        )  # fmt: skip

    @property
    def state(self) -> Any:
        """``State`` code (int; ``(N,)`` int array in batch)."""
        motion = _MOVING if self._moving else (_HOLDING if self._moved else _IDLE)
        if self._scalar:
            if self._fault_s:
                return _FAULT
            return motion if self._enabled_s else _DISABLED
        key = (self._flags_version, motion)
        if self._state_cache[0] != key:
            st = np.where(self._enabled, motion, _DISABLED)
            st = np.where(self._fault != 0, _FAULT, st)
            st.setflags(write=False)
            self._state_cache = (key, st)
        return self._state_cache[1]

    @property
    def fault(self) -> Any:
        """Latched ``Fault`` code (int; ``(N,)`` array in batch)."""
        if self._scalar:
            return self._fault_s
        if self._fault_cache[0] != self._flags_version:
            fault = self._fault.copy()
            fault.setflags(write=False)
            self._fault_cache = (self._flags_version, fault)
        return self._fault_cache[1]

    @property
    def bridge_high_sides(self) -> np.ndarray:
        """Per member (int64 ``(N,)``, a view read after ``current_tick``): nonzero while
        the IS-offset calibration wants both high sides of the bridge on for the next
        period (``[controller.current] sense_calibration``); its parity picks the IS pin
        the ADC reads then (even: the positive half-bridge's; ``sim.bridge.apply_bridge``)."""
        return self.law.C[C_CAL_LEFT]

    @property
    def thermal_estimate_c(self) -> Any:
        """The thermal protection's estimate of the winding temperature (degC; ``(N,)`` in
        batch): from the measured current and the firmware's constants only."""
        est = self._thermal_est[:, 0].copy()
        return float(est[0]) if self._scalar else est

    @property
    def current_limit_derated_a(self) -> Any:
        """The current limit in effect after the thermal protection's derating (A;
        ``(N,)`` in batch)."""
        lim = self.law.i_limit_a * (1.0 - self.law.P[P_DERATE])
        return float(lim[0]) if self._scalar else lim

    @property
    def telemetry_decimation(self) -> int:
        """Ticks between telemetry frames actually used (0 = off); see ``counters``."""
        return self._decimation

    @property
    def counters(self) -> dict[str, int]:
        """A snapshot of the counters (see the class docstring)."""
        out = dict(self._counts)
        out["tx_frames"] = self._tx_frames
        out["tx_bytes"] = self._tx_bytes
        out["tx_telemetry_dropped"] = self._tx_dropped
        out["telemetry_decimation"] = self._decimation
        return out

    # ------------------------------------------------------------------ compiled state
    def _pack(self) -> None:
        """The attributes the compiled tick reads and writes, into ``_fs`` / ``_fi``."""
        fs, fi = self._fs, self._fi
        fs[ftick.FS_SP_POS] = self.sp_pos_deg
        fs[ftick.FS_SP_VEL] = self.sp_vel_dps
        fs[ftick.FS_SP_ACC] = self.sp_acc_dps2
        fs[ftick.FS_TARGET] = self._target_deg
        fs[ftick.FS_V_CLAMP] = self._v_clamp_dps
        fs[ftick.FS_I_LIMIT] = self.current_limit_a
        fs[ftick.FS_FOLLOWING] = self.following_error_deg
        fs[ftick.FS_POS_LO], fs[ftick.FS_POS_HI] = self._pos_lo_deg, self._pos_hi_deg
        fs[ftick.FS_OC_THR] = self._oc_thr_a
        fi[ftick.FI_TICK] = self.tick
        fi[ftick.FI_HEARTBEAT] = self._heartbeat_ticks
        fi[ftick.FI_JOG_TIMEOUT] = self._jog_timeout_ticks
        mode = self._mode
        fi[ftick.FI_MODE] = _MODES[mode]
        fi[ftick.FI_MOVING] = self._moving
        fi[ftick.FI_MOVED] = self._moved
        fi[ftick.FI_SEQ] = self._seq
        fi[ftick.FI_DECIMATION] = self._decimation
        fi[ftick.FI_LAST_RX] = self._last_rx_tick
        fi[ftick.FI_OC_ANY] = self._oc_s
        fi[ftick.FI_TX_FRAMES] = self._tx_frames
        fi[ftick.FI_TX_BYTES] = self._tx_bytes
        fi[ftick.FI_TX_DROPPED] = self._tx_dropped
        if mode == "plan":
            planner = self._planners[self._kind]
            profile, t_start_s = planner.profile, planner.t_start_s
            if (
                self._prof_of is None
                or self._prof_of[0] is not profile
                or (self._prof_of[1] != t_start_s)
            ):
                self._pack_profile(profile, t_start_s)

    def _pack_profile(self, profile: Any, t_start_s: float) -> None:
        """The planner's active profile (``planner.profile.Profile``; the firmware plans
        before it enters ``plan`` mode, so there is one) as the compiled tick's arrays."""
        fs = self._fs
        self._prof_of = (profile, t_start_s)
        rows = (profile.t0, profile.p, profile.v, profile.a, profile.j)
        self._prof = np.array(rows, dtype=float).T.reshape(-1, 5).copy()
        fs[ftick.FS_PROF_T0], fs[ftick.FS_PROF_DURATION] = t_start_s, profile.duration
        fs[ftick.FS_PROF_P0], fs[ftick.FS_PROF_V0] = profile.p0, profile.v0
        fs[ftick.FS_PROF_P1], fs[ftick.FS_PROF_V1] = profile.p1, profile.v1

    def _unpack(self) -> None:
        """What the compiled tick changed, back into the attributes."""
        fs, fi = self._fs, self._fi
        self.sp_pos_deg = float(fs[ftick.FS_SP_POS])
        self.sp_vel_dps = float(fs[ftick.FS_SP_VEL])
        self.sp_acc_dps2 = float(fs[ftick.FS_SP_ACC])
        self.tick = int(fi[ftick.FI_TICK])
        self._moving = bool(fi[ftick.FI_MOVING])
        self._seq = int(fi[ftick.FI_SEQ])
        self._oc_s = int(fi[ftick.FI_OC_ANY])
        self._tx_frames = int(fi[ftick.FI_TX_FRAMES])
        self._tx_bytes = int(fi[ftick.FI_TX_BYTES])
        self._tx_dropped = int(fi[ftick.FI_TX_DROPPED])

    # ------------------------------------------------------------------ boot and state
    def _boot(self, encoder_counts: Any) -> None:
        self.law.reset(encoder_counts)
        self._booted = True
        pos = self._pos0()
        self.sp_pos_deg = pos
        if self.params.servo.start_enabled:
            self._enable()

    def _pos0(self) -> float:
        return float(self.law.pos_deg[0])

    def _enable(self, only: Any = True) -> None:
        ok = (self._fault == 0) & only
        self._enabled = ok.copy()
        self._brake_ticks[ok] = 0  # the loops take over from the brake
        self._flags_version += 1
        self._enabled_s = bool(ok[0])
        self.law.reset_control()
        self.law.resync()
        self._set_position_window()
        self._hold_here()
        self._moved = False
        if self.params.current.sense_calibration:
            self._start_calibration(ok)

    # ------------------------------------------------------------------ IS-offset calibration
    def _start_calibration(self, mask: Any) -> None:
        """Both high sides on for the members in ``mask`` (they are enabled, their control
        output held at zero) for ``sense_calibration_samples`` current-loop periods and the
        one in which the bridge switches (``firmware_model.sense_calibration``)."""
        c = self.law.C
        c[C_CAL_LEFT, mask] = self.params.current.sense_calibration_samples + 1
        c[C_CAL_SUM_A, mask] = 0
        c[C_CAL_SUM_B, mask] = 0
        self._calibrating |= mask

    def _stop_calibration(self, mask: Any, code: NackCode) -> None:
        """The members in ``mask`` stop calibrating (disabled, tripped): their bridge leaves
        the both-high-sides state; a pending ``SetEnable`` with nobody left calibrating is
        refused with ``code``."""
        mask = np.asarray(mask, dtype=bool) & self._calibrating
        if not mask.any():
            return
        self.law.C[C_CAL_LEFT, mask] = 0
        self._calibrating &= ~mask
        if not self._calibrating.any():
            self._answer_enable(code, 0.0)

    def _calibration_done(self) -> None:
        """The members whose calibration ended this period (``calibration_step`` said so):
        keep the offsets of those that passed (``C_SENSE_OFFSET_A`` / ``_B``, one per IS pin),
        latch a fault on the others (``_calibration_failed``), and answer the ``SetEnable``
        once no member calibrates any more: ACK if one passed, else NACK ``BUSY`` (the axis
        turned; limit: the speed bound in deg/s) or ``SENSE_OFFSET`` (an offset implausible;
        limit: the ceiling, A)."""
        c = self.law.C
        done = self._calibrating & (c[C_CAL_LEFT] == 0)
        if not done.any():
            return
        cur = self.params.current
        offset_a, offset_b, reason = sense_calibration.judge(
            c[C_CAL_SUM_A], c[C_CAL_SUM_B], cur.sense_calibration_samples,
            cur.sense_calibration_pin_counts, cur.sense_offset_max_counts,
        )  # fmt: skip
        good = done & (reason == 0)
        c[C_SENSE_OFFSET_A, good] = offset_a[good]
        c[C_SENSE_OFFSET_B, good] = offset_b[good]
        self._calibrating &= ~done
        self._calibration_failed(done & (reason != 0), reason, offset_a, offset_b)
        if self._calibrating.any():
            return
        first = int(np.flatnonzero(done)[0])
        if good.any():
            self._answer_enable()
        elif reason[first] == sense_calibration.MOVED:
            self._answer_enable(NackCode.BUSY, cur.sense_calibration_max_speed_dps)
        else:
            self._answer_enable(NackCode.SENSE_OFFSET,
                                cur.sense_offset_max_counts * cur.a_per_adc)  # fmt: skip

    def _calibration_failed(self, bad: Any, reason: Any, offset_a: Any, offset_b: Any) -> None:
        """A failed calibration is a latched fault (bridge off, no brake: the axis was held
        at rest by the both-high-sides state; ``ClearFault`` then ``SetEnable`` to retry),
        so that a member refused (one of a batch, or the axis after the ``SetEnable``'s
        NACK) says why when asked later (``Status``, ``GetFault``, ``FaultReport``):

        * ``SENSE_OFFSET``: a pin's offset above ``sense_offset_max_counts``; value the
          larger pin's offset, threshold the ceiling (A of load current);
        * ``CALIBRATION_MOTION``: the axis turned, in deg/s of the axis: abandoned on the
          encoder's speed (value that speed, threshold ``sense_calibration_max_speed_dps``),
          or the pins apart by more than ``sense_calibration_pin_counts`` (value the speed
          whose back-EMF drives that loop current, ``dI R / K_e`` with the firmware's R and
          K_e; threshold the same of the pin bound)."""
        if not bad.any():
            return
        cur = self.params.current
        a = cur.a_per_adc
        c = self.law.C
        high = bad & (reason == sense_calibration.IMPLAUSIBLE)
        self._trip(high, Fault.SENSE_OFFSET, np.maximum(offset_a, offset_b) * a,
                   cur.sense_offset_max_counts * a)  # fmt: skip
        moved = bad & (reason == sense_calibration.MOVED)
        abandoned = moved & (c[C_CAL_SUM_A] < 0)
        self._trip(abandoned, Fault.CALIBRATION_MOTION, np.abs(self.law.vel_dps),
                   cur.sense_calibration_max_speed_dps)  # fmt: skip
        dps_per_count = a * self._r_ohm / self._emf_v_per_dps
        apart = np.abs(offset_a - offset_b) * dps_per_count
        self._trip(moved & ~abandoned, Fault.CALIBRATION_MOTION, apart,
                   float(cur.sense_calibration_pin_counts * dps_per_count[0]))  # fmt: skip

    def _answer_enable(self, code: NackCode | None = None, limit: float = 0.0) -> None:
        """The answer of the ``SetEnable`` that started the calibration (none for the
        power-up's): ACK, or NACK ``code`` with ``limit``; a retry of it now gets this."""
        msg, self._cal_command = self._cal_command, None
        if msg is None:
            return
        if code is None:
            reply: Ack | Nack = Ack(cmd_id=msg.cmd_id, msg_type=int(msg.MSG_TYPE))
            self._counts["commands_applied"] += 1
        else:
            reply = self._nack(msg, code, None, limit)
        if self._last_cmd is msg:
            self._last_reply = reply
        self._queue(reply)

    def _set_position_window(self) -> None:
        """The hard position trip's window: the travel widened by the margin, and widened
        further to where the axis is (an axis enabled outside the travel may be moved back,
        as a planned trajectory may; it trips only if it goes further out)."""
        lim = self.params.limits
        margin = self.params.safety.position_limit_margin_deg
        lo, hi = lim.travel_min_deg, lim.travel_max_deg
        if self._booted:
            pos = np.asarray(self.law.pos_deg, dtype=float)
            lo, hi = min(lo, float(pos.min())), max(hi, float(pos.max()))
        self._pos_lo_deg, self._pos_hi_deg = float(lo - margin), float(hi + margin)

    def _disable(self) -> None:
        self._stop_calibration(self._calibrating, NackCode.BUSY)
        self._enabled[:] = False
        self._flags_version += 1
        self._enabled_s = False
        self._hold_here()

    def _hold_here(self) -> None:
        self.program.clear()
        self.stream.clear()
        self._jog_timeout_ticks = 0
        self._mode = "hold"
        self._moving = False
        self.sp_pos_deg = self._pos0()
        self.sp_vel_dps = self.sp_acc_dps2 = 0.0
        self._v_clamp_dps = self.v_max_dps

    def _planner_from_axis(self, kind: str, t_s: float) -> OnlinePlanner:
        """A planner whose commanded state at ``t_s`` is the measured state of the axis
        (member 0): a planned move that takes over from a STEP move (no planner, the axis
        may be at full speed) starts from where the axis is and how fast it moves."""
        planner = OnlinePlanner(kind)
        pos = self._pos0()
        vel = _first(self.law.vel_dps)
        planner.reset(pos)
        planner.profile = build_profile(kind, "hold", pos, vel, 0.0, [], pos, vel)
        planner.t_start_s = t_s
        return planner

    def _in_position(self) -> bool:
        # Settled: within in_position_deg and slower than in_position_deg per 0.1 s.
        tol = self.params.limits.in_position_deg
        law = self.law
        ok = (np.abs(law.pos_deg - self._target_deg) <= tol) & (np.abs(law.vel_dps) <= 10 * tol)
        live = self._enabled
        return bool(np.all(ok[live])) if live.any() else True

    # ------------------------------------------------------------------ safety
    def _check(self) -> None:
        law, s = self.law, self.params.safety
        if self._jog_timeout_ticks and self.tick - self._last_rx_tick > self._jog_timeout_ticks:
            self._jog_expired()
        following = self._mode != "step"
        watchdog = bool(self._watchdog_ticks) and (
            self.tick - self._last_rx_tick > self._watchdog_ticks
        )
        # firmware_model.tick.servo_stage screened the members and updated the sensor
        # checks' state (self._sf): here the masks and trips.
        innov = np.abs(law.innovation_counts)
        stuck = law.stuck_ticks
        vel = law.vel_dps
        err = self.sp_pos_deg - law.pos_deg
        live = self._enabled.copy()
        bad = self._diag_ticks >= s.encoder_diag_ticks
        self._trip(live & bad, Fault.ENCODER_DIAG, self._diag_errors.astype(float),
                   float(s.encoder_diag_ticks))  # fmt: skip
        live &= ~bad
        enc = (innov > s.encoder_jump_counts) | (
            (stuck >= s.encoder_stuck_ticks)
            & (np.abs(law.vel_ref_dps) > s.encoder_stuck_min_vel_dps)
        )
        self._trip(live & enc, Fault.ENCODER, law.raw_counts.astype(float),
                   float(s.encoder_jump_counts))  # fmt: skip
        live &= ~enc
        runaway = self._mismatch_deg > s.sensor_mismatch_deg
        self._trip(live & runaway, Fault.SENSOR_MISMATCH, self._mismatch_deg.copy(),
                   float(s.sensor_mismatch_deg))  # fmt: skip
        live &= ~runaway
        if s.thermal_protection:
            trip_c = self.thermal_thresholds_c[1]
            hot = self._thermal_est[:, 0] >= trip_c
            self._trip(live & hot, Fault.THERMAL, self._thermal_est[:, 0].copy(), trip_c)
            live &= ~hot
        over = np.abs(vel) > s.over_speed_dps
        self._trip(live & over, Fault.OVER_SPEED, vel, s.over_speed_dps)
        live &= ~over
        beyond = ~((self._pos_lo_deg <= law.pos_deg) & (law.pos_deg <= self._pos_hi_deg))
        end_deg = self._pos_hi_deg if law.pos_deg[0] > self._pos_hi_deg else self._pos_lo_deg
        self._trip(live & beyond, Fault.TRAVEL, law.pos_deg, float(end_deg))
        live &= ~beyond
        if following:
            fe = np.abs(err) > self.following_error_deg
            self._trip(live & fe, Fault.FOLLOWING_ERROR, err, self.following_error_deg)
            live &= ~fe
        if watchdog:
            ticks = float(self.tick - self._last_rx_tick)
            self._trip(live, Fault.WATCHDOG, np.full(self._n, ticks), float(self._watchdog_ticks))

    def _current_trips(self) -> None:
        """The trips of the current-loop screens (``firmware_model.tick.current_stage``):
        over-current, and the bus over/under-voltage (over if the reading is above the
        over threshold, else under), with the measured bus in volts as the value; and the
        end of an IS-offset calibration."""
        if self._calibrating.any():
            self._calibration_done()
        self._trip(
            self._oc_ticks >= self._oc_samples, Fault.OVER_CURRENT,
            self.law.current_meas_a.copy(), self._oc_thr_a,
        )  # fmt: skip
        s = self.params.safety
        hit = self._bus_ticks >= s.bus_voltage_samples
        if s.bus_voltage_check and hit.any():
            reading = self.law.C[C_BUS_ADC]
            bus_v = reading * self.params.current.v_per_bus_adc
            over = hit & (reading > self._bus_over_counts)
            self._trip(over, Fault.BUS_OVER_VOLTAGE, bus_v, self.bus_over_voltage_v)
            self._trip(hit & ~over, Fault.BUS_UNDER_VOLTAGE, bus_v, self.bus_under_voltage_v)

    def _trip(self, mask: Any, fault: Fault, value: Any, threshold: float = 0.0) -> None:
        """Latch ``fault`` on the members in ``mask``: bridge off, report, abandon motion.

        ``value`` is what tripped it (scalar or ``(N,)``), ``threshold`` the bound crossed;
        both are reported (``FaultReport``, ``GetFault``) in the fault's unit."""
        mask = np.asarray(mask, dtype=bool) & (self._fault == 0)
        if not mask.any():
            return
        self._fault[mask] = int(fault)
        self._stop_calibration(mask, NackCode.FAULT_ACTIVE)
        flag = int(FAULT_FLAG[fault])
        self._flags[mask] |= flag
        self._enabled[mask] = False
        self._flags_version += 1
        self._enabled_s = bool(self._enabled[0])
        self._fault_s = int(self._fault[0])
        hits = int(mask.sum())
        self._counts["faults"] += hits
        self._counts[f"fault_{fault.name}"] += hits
        self.law.reset_control(mask)
        if fault not in _NO_BRAKE and self._brake_ticks_setting:
            # The fault reaction: dynamic braking (both low sides on, duty 0) for brake_s,
            # then the bridge off. An over-current (a short, perhaps) turns it off at once,
            # as a failed IS-offset calibration does (the axis was held, never driven).
            self._brake_ticks[mask] = self._brake_ticks_setting
        if mask[0]:
            v = float(value) if np.ndim(value) == 0 else float(np.asarray(value)[0])
            self._fault_info[flag.bit_length() - 1] = (self.tick, v, float(threshold))
            self._queue(FaultReport(tick=self.tick, fault=fault, value=v,
                                    fault_flags=int(self._flags[0]),
                                    threshold=float(threshold)))  # fmt: skip
        if not self._enabled.any():
            self._hold_here()

    # ------------------------------------------------------------------ receive
    def _receive(self, rx_bytes: bytes) -> None:
        """The bytes of one tick: the silence rule, the receive ring, the decoder."""
        if self.decoder._buf and self.tick - self._last_byte_tick >= self._silence_ticks:
            self._silence()
        self._last_byte_tick = self.tick
        ring = self._rx_ring_bytes
        if len(rx_bytes) > ring:
            # The DMA ring holds that much per tick: the rest is lost, counted.
            self._rx_overflow_bytes += len(rx_bytes) - ring
            rx_bytes = rx_bytes[:ring]
        for msg in self.decoder.feed(rx_bytes):
            self._handle(msg)

    def _silence(self) -> None:
        """``RX_SILENCE_S`` without a byte: give up the partial frame (a whole frame found in
        the held-back bytes is still handled)."""
        for msg in self.decoder.flush():
            self._handle(msg)

    # ------------------------------------------------------------------ commands
    def _queue(self, msg: Any) -> None:
        if len(self._replies) >= self.params.telemetry.reply_queue_frames:
            self._replies.popleft()
            self._counts["tx_replies_dropped"] += 1
        self._replies.append(msg)

    def _nack(
        self, msg: Any, code: NackCode, field: str | int | None = None, limit: float = 0.0
    ) -> Nack:
        """Count and build the ``Nack`` of ``msg`` naming ``field`` (a name or an index)."""
        self._counts["nacks"] += 1
        self._counts[f"nack_{code.name}"] += 1
        if isinstance(msg, Malformed):
            msg_type, index = msg.msg_type, msg.field
        else:
            msg_type = int(msg.MSG_TYPE)
            if field is None:
                index = NO_FIELD
            elif isinstance(field, int):
                index = field
            else:
                try:
                    index = frame.field_index(type(msg), field)
                except KeyError:  # a refusal naming another message's field: never raise
                    index = NO_FIELD
        return Nack(msg.cmd_id, msg_type, code, index, float(limit))

    def _handle(self, msg: Any) -> None:
        """One decoded frame: NACK what cannot be a command, check the session, then
        answer (queries), apply once (commands) or just feed the watchdog (heartbeats)."""
        if isinstance(msg, Malformed) and msg.msg_type < 0x80:
            self._counts["rx_malformed"] += 1
            self._queue(self._nack(msg, NackCode(msg.code)))
            return
        if isinstance(msg, Malformed):
            # A type 0x80..0xFF is NOT_A_COMMAND whatever its payload (docs section 3: the
            # board never decodes board -> PC payloads, so their length and enums are moot).
            self._counts["rx_malformed"] += 1
            self._queue(Nack(msg.cmd_id, msg.msg_type, NackCode.NOT_A_COMMAND))
            self._counts["nacks"] += 1
            self._counts["nack_NOT_A_COMMAND"] += 1
            return
        self._counts["rx_messages"] += 1
        if type(msg) not in _COMMAND_CLASSES:
            # A board -> PC type (our own frames echoed back, a confused peer): never fed
            # to the watchdog, never applied.
            self._queue(Nack(getattr(msg, "cmd_id", 0), int(msg.MSG_TYPE),
                             NackCode.NOT_A_COMMAND))  # fmt: skip
            self._counts["nacks"] += 1
            self._counts["nack_NOT_A_COMMAND"] += 1
            return
        if isinstance(msg, Hello):
            self._queue(self._hello(msg))
            return
        if msg.session != self.session or not self.session:
            code = NackCode.NO_SESSION if not self.session else NackCode.STALE_SESSION
            self._queue(self._nack(msg, code, "session", float(self.session)))
            return
        self._last_rx_tick = self.tick  # a frame of the session: feeds the watchdog
        if isinstance(msg, Heartbeat):
            self._counts["heartbeats"] += 1
            return
        if isinstance(msg, _MUTATING):
            # A retry is the same command again: same type and payload (cmd_id included).
            if msg == self._last_cmd:
                self._counts["duplicates"] += 1
                if self._last_reply is not _PENDING:
                    self._queue(self._last_reply)
                return
            # time's bookkeeping first (a stream that ran dry), so that a refused command
            # changes nothing
            self.stream.update(self.tick * self.dt_s)
            reply = self._apply(msg)
            self._last_cmd, self._last_reply = msg, reply
            if isinstance(reply, Ack):
                self._counts["commands_applied"] += 1
            if reply is not _PENDING:  # (a SetEnable calibrating: answered when done)
                self._queue(reply)
            return
        self._queue(self._query(msg))

    def _hello(self, msg: Hello) -> HelloReply | Nack:
        """Open session ``msg.session``: forget the previous session's duplicate memory.
        Motion, enable, faults and telemetry settings are not touched."""
        if not msg.version_min <= PROTOCOL_VERSION <= msg.version_max:
            return self._nack(msg, NackCode.UNSUPPORTED_VERSION, "version_min",
                              float(PROTOCOL_VERSION))  # fmt: skip
        if msg.session == 0:
            return self._nack(msg, NackCode.TOO_LOW, "session", 1.0)
        self.session = msg.session
        self._last_cmd = self._last_reply = None
        self._last_rx_tick = self.tick
        self._counts["sessions"] += 1
        major, minor, patch = FW_VERSION
        p = self.params
        return HelloReply(
            cmd_id=msg.cmd_id, session=msg.session, protocol_version=PROTOCOL_VERSION,
            fw_major=major, fw_minor=minor, fw_patch=patch, tick_hz=round(p.servo.tick_hz),
            counts_per_rev=16384, command_mask=COMMAND_MASK,
            max_payload_bytes=frame.MAX_PAYLOAD_BYTES,
            rx_buffer_bytes=min(65535, self._rx_ring_bytes),
            reply_queue_frames=p.telemetry.reply_queue_frames,
            telemetry_min_decimation=self._auto_decimation,
            heartbeat_ms=min(65535, round(p.telemetry.heartbeat_s * 1000)),
            watchdog_ms=min(65535, round(p.safety.watchdog_s * 1000)),
            rx_silence_ms=round(frame.RX_SILENCE_S * 1000), baud=p.telemetry.baud,
            queue_blocks=self.program.capacity, stream_points=self.stream.capacity,
            stream_period_min_ms=round(stream.PERIOD_MIN_S * 1000),
            stream_period_max_ms=round(stream.PERIOD_MAX_S * 1000),
        )  # fmt: skip

    def _query(self, msg: Any) -> Any:
        if isinstance(msg, GetStatus):
            return Status(
                cmd_id=msg.cmd_id, tick=self.tick, state=State(self._state0()),
                fault=Fault(int(self._fault[0])), pos_deg=safety.wire_pos(self._pos0()),
                vel_dps=safety.wire_pos(float(self.law.vel_dps[0])),
                target_deg=safety.wire_pos(self._target_deg if self._moved else self.sp_pos_deg),
                fault_flags=int(self._flags[0]), session=self.session,
                sense_offset_a=float(self.law.C[C_SENSE_OFFSET_A, 0]) * self.law.a_per_adc,
                sense_offset_neg_a=float(self.law.C[C_SENSE_OFFSET_B, 0]) * self.law.a_per_adc,
            )  # fmt: skip
        if isinstance(msg, GetGains):
            kp_name, ki_name = _LOOP_GAINS[Loop(msg.loop)]
            g = self.law.gains
            ki = _first(g[ki_name]) if ki_name else 0.0
            return Gains(cmd_id=msg.cmd_id, loop=msg.loop, kp=_first(g[kp_name]), ki=ki, kd=0.0)
        if isinstance(msg, GetLimits):
            lim, s = self.params.limits, self.params.safety
            derate_c, trip_c = self.thermal_thresholds_c
            return Limits(
                cmd_id=msg.cmd_id, v_max_dps=self.v_max_dps, a_max_dps2=self.a_max_dps2,
                current_limit_a=self.current_limit_a,
                following_error_deg=self.following_error_deg,
                over_current_trip_a=self._oc_thr_a, travel_min_deg=lim.travel_min_deg,
                travel_max_deg=lim.travel_max_deg, over_speed_dps=s.over_speed_dps,
                over_current_max_a=s.over_current_a,
                bus_over_voltage_v=self.bus_over_voltage_v if s.bus_voltage_check else 0.0,
                bus_under_voltage_v=self.bus_under_voltage_v if s.bus_voltage_check else 0.0,
                thermal_trip_c=trip_c if s.thermal_protection else 0.0,
                winding_estimate_c=(
                    float(self._thermal_est[0, 0]) if s.thermal_protection else 0.0
                ),
                thermal_derate_c=derate_c if s.thermal_protection else 0.0,
                brake_current_limit_a=float(self._fs[ftick.FS_BRAKE_CAP]),
            )  # fmt: skip
        if isinstance(msg, GetFault):
            if not 0 <= msg.bit <= 31:
                return self._nack(msg, NackCode.TOO_HIGH, "bit", 31.0)
            info = self._fault_info.get(msg.bit)
            if info is None or not int(self._flags[0]) >> msg.bit & 1:
                return FaultInfo(msg.cmd_id, msg.bit, False, 0, 0.0, 0.0)
            return FaultInfo(msg.cmd_id, msg.bit, True, *info)
        raise AssertionError(f"no handler for {msg!r}")  # every command class is handled

    def fault_flags(self) -> Any:
        """Latched ``FaultFlag`` bits (int; ``(N,)`` int array in batch)."""
        if self._scalar:
            return int(self._flags[0])
        return self._flags.copy()

    def link_status(self) -> BoardHeartbeat:
        """The board's heartbeat now: state, faults and the receiver's counters."""
        return _HEARTBEAT_FROM_WIRE(self._link_wire())

    def _link_wire(self) -> tuple[int, ...]:
        """The ``BoardHeartbeat`` of now as its wire values, in wire order: what
        ``link_status`` decodes and what the compiled tick's heartbeat frames
        (``_pack_link``; ``firmware_model.tick.frame_heartbeat``)."""
        d = self.decoder
        w = 0xFFFFFFFF
        t_s = self.tick * self.dt_s
        stream = self.stream
        return (
            self.tick & w, self.session, self._state0(), int(self._flags[0]) & w,
            d.frames & w, d.crc_errors & w, d.header_errors & w, d.bytes_dropped & w,
            d.seq_gaps & w, self._rx_overflow_bytes & w, d.partial_discards & w,
            self._counts["nacks"] & w, self._tx_dropped & w, self.program.free(t_s),
            stream.free(t_s), int(stream.state), stream.underruns & w, self._bus_mv(),
        )  # fmt: skip

    def _pack_link(self) -> None:
        """The heartbeat's fields into ``fi[FI_HB:]`` for the compiled tick, which frames
        the heartbeat itself (it writes the tick, state, fault flags, telemetry dropped and
        bus voltage; the rest changes only in this Python: commands, the receiver, trips).
        ``FI_LINK`` 0 while the program queue or the point stream is active: their flow
        control changes with time in their Python bookkeeping, ``_transmit`` sends that
        heartbeat."""
        fi = self._fi
        if not self._heartbeat_ticks or self.program.active() or self.stream.active():
            fi[ftick.FI_LINK] = 0
            return
        fi[ftick.FI_LINK] = 1
        fi[ftick.FI_HB :] = self._link_wire()

    def _bus_mv(self) -> int:
        """Member 0's bus voltage as the firmware reads it, in mV (the ADC reading times
        volts per count, ``[controller.current] bus_divider_ratio``), at most 65535: the
        wire value of ``BoardHeartbeat.bus_voltage_v``."""
        volts = int(self.law.C[C_BUS_ADC, 0]) * self.params.current.v_per_bus_adc
        return min(round(volts * 1000.0), 0xFFFF)

    @property
    def bus_voltage_v(self) -> float:
        """Member 0's bus voltage as the firmware reads it (V: the ADC reading times volts
        per count, ``[controller.current] bus_divider_ratio``), in the 1 mV steps and
        range of ``BoardHeartbeat.bus_voltage_v`` (at most 65.535 V)."""
        return self._bus_mv() / 1000.0

    def _state0(self) -> int:
        """The state of member 0 (the one replies and telemetry describe)."""
        if self._fault[0]:
            return _FAULT
        if not self._enabled[0]:
            return _DISABLED
        return _MOVING if self._moving else (_HOLDING if self._moved else _IDLE)

    def _apply(self, msg: Any) -> Ack | Nack:
        """Validate completely, then apply; a NACKed command changes nothing."""
        handler = {
            Move: self._cmd_move,
            Stop: self._cmd_stop,
            SetGains: self._cmd_set_gains,
            SetLimits: self._cmd_set_limits,
            ClearFault: self._cmd_clear_fault,
            SetEnable: self._cmd_set_enable,
            SetTelemetry: self._cmd_set_telemetry,
            QueueSegment: self._cmd_queue_segment,
            QueueControl: self._cmd_queue_control,
            StreamControl: self._cmd_stream_control,
            StreamPoints: self._cmd_stream_points,
            Jog: self._cmd_jog,
        }[type(msg)]
        refusal = handler(msg)
        if refusal is _PENDING:
            return _PENDING
        if refusal is not None:
            return self._nack(msg, *refusal)
        if isinstance(msg, QueueSegment | QueueControl):
            return self.queue_status(msg.cmd_id)
        if isinstance(msg, StreamControl | StreamPoints):
            return self.stream_status(msg.cmd_id)
        return Ack(cmd_id=msg.cmd_id, msg_type=int(msg.MSG_TYPE))

    def _motion_refused(self) -> _Refusal | None:
        if (self._fault != 0).all():
            return NackCode.FAULT_ACTIVE, None, 0.0
        if not self._enabled.any():
            return NackCode.DISABLED, None, 0.0
        return None

    def _cmd_move(self, m: Move) -> _Refusal | None:
        lim = self.params.limits
        profile = Profile(m.profile)
        checks = [
            ("target_deg", m.target_deg, lim.travel_min_deg, lim.travel_max_deg),
            ("v_max_dps", m.v_max_dps, MIN_POSITIVE, self.v_max_dps),
            ("a_max_dps2", m.a_max_dps2, MIN_POSITIVE, self.a_max_dps2),
        ]
        if profile is Profile.SCURVE:
            checks.append(("j_max_dps3", m.j_max_dps3, MIN_POSITIVE, math.inf))
        elif not math.isfinite(m.j_max_dps3):
            return NackCode.NOT_FINITE, "j_max_dps3", 0.0
        refusal = _check_ranges(checks)
        if refusal is not None:
            return refusal
        kind = _PROFILE_KIND.get(profile)
        refused = self._motion_refused()
        if refused is not None:
            return refused
        t_s = self.tick * self.dt_s
        if kind is None:  # Profile.STEP: no planning, the setpoint jumps to the target
            self._end_other_motion()
            self._mode = "step"
            self._v_clamp_dps = m.v_max_dps
        else:
            # Planned on a copy, checked over its whole extent, committed only if accepted.
            if self._mode == "plan":
                # From the commanded state, switching the profile kind on the way if asked
                # (OnlinePlanner.command(kind=...): no jump in position or velocity).
                planner = copy.copy(self._planners[self._kind])
            elif self._mode == "step":
                planner = self._planner_from_axis(kind, t_s)
            else:  # from hold: from rest where the axis is held
                planner = OnlinePlanner(kind)
                planner.reset(self.sp_pos_deg)
            j_max = m.j_max_dps3 if kind == "scurve" else None
            try:
                profile = planner.command(t_s, m.target_deg, v_max=m.v_max_dps,
                                          a_max=m.a_max_dps2, j_max=j_max,
                                          kind=kind)  # fmt: skip
            except ValueError:
                return NackCode.OUT_OF_RANGE, None, 0.0
            refusal = self._travel_refusal(profile, None)
            if refusal is not None:
                return refusal
            self._planners[kind] = planner
            self._end_other_motion()  # a Move replaces a running program, stream or jog
            self._mode, self._kind, self._j_max = "plan", kind, m.j_max_dps3
            self._move_limits = (m.v_max_dps, m.a_max_dps2)
            self._v_clamp_dps = self.v_max_dps
        self._target_deg = m.target_deg
        self._moving = True
        self._moved = True
        return None

    def _cmd_stop(self, m: Stop) -> _Refusal | None:
        if m.a_max_dps2 != 0.0:  # 0: the configured a_max
            refusal = _check_ranges([("a_max_dps2", m.a_max_dps2, MIN_POSITIVE, self.a_max_dps2)])
            if refusal is not None:
                return refusal
        a_max = m.a_max_dps2 or self.a_max_dps2
        t_s = self.tick * self.dt_s
        if self._mode == "hold":
            return None
        if self._mode == "plan":
            kind = self._kind
            planner = copy.copy(self._planners[kind])
        else:  # a STEP move has no planner: brake from the measured state
            kind = "trapezoid"
            planner = self._planner_from_axis(kind, t_s)
        j_max = self._j_max if kind == "scurve" else None
        profile = planner.stop(t_s, a_max=a_max, j_max=j_max)
        refusal = self._travel_refusal(profile, "a_max_dps2")
        if refusal is not None:
            return refusal  # too soft to stop within the travel
        if self._mode == "step":
            self._mode, self._kind = "plan", kind
            self._move_limits = (self.v_max_dps, a_max)
            self._v_clamp_dps = self.v_max_dps
            self._moving = True
        self._planners[kind] = planner
        self._target_deg = profile.p1
        self._end_other_motion()  # Stop aborts a program (QueueControl HOLD keeps it)
        return None

    # ------------------------------------------------------------------ programs
    def _cmd_queue_segment(self, m: QueueSegment) -> _Refusal | None:
        lim = self.params.limits
        refusal = _check_ranges([
            ("target_deg", m.target_deg, lim.travel_min_deg, lim.travel_max_deg),
            ("v_max_dps", m.v_max_dps, MIN_POSITIVE, self.v_max_dps),
            ("dwell_s", m.dwell_s, 0.0, MAX_DWELL_S),
        ])  # fmt: skip
        if refusal is not None:
            return refusal
        refused = self._motion_refused()
        if refused is not None:
            return refused
        prog = self.program
        if not prog.active() and self._mode != "hold" and self._moving:
            return NackCode.BUSY, None, 0.0  # a Move in progress: the program starts at rest
        if self.stream.active():
            return NackCode.BUSY, None, 0.0  # a stream in progress
        t_s = self.tick * self.dt_s
        if prog.free(t_s) == 0:
            return NackCode.QUEUE_FULL, None, float(prog.capacity)
        trial = copy.deepcopy(prog)  # planned on a copy, committed only if it plans
        try:
            profile = trial.append(
                t_s, self.sp_pos_deg, m.target_deg, m.v_max_dps, m.dwell_s,
                v_limit_dps=self.v_max_dps, a_max_dps2=self.a_max_dps2,
            )  # fmt: skip
        except ValueError:
            return NackCode.OUT_OF_RANGE, None, 0.0
        # the whole program's profile, checked as a Move's (its targets are in the travel
        # and its blocks monotone, so this holds; the check keeps it so)
        refusal = self._travel_refusal(profile, "target_deg")
        if refusal is not None:
            return refusal
        self.program = trial
        if not trial.held:
            self._follow_program(profile, trial.t_start_s)
        return None

    def _cmd_queue_control(self, m: QueueControl) -> _Refusal | None:
        action = QueueAction(m.action)
        prog = self.program
        t_s = self.tick * self.dt_s
        prog.finish(t_s)
        if action is QueueAction.OVERRIDE:
            refusal = _check_ranges([("override_pct", m.override_pct, 10.0, 200.0)])
            if refusal is not None:
                return refusal
            trial = copy.deepcopy(prog)
            try:
                profile = trial.set_override(t_s, m.override_pct)
            except ValueError:
                return NackCode.OUT_OF_RANGE, None, 0.0
            self.program = trial
            if profile is not None:
                self._follow_program(profile, trial.t_start_s)
            return None
        if action is QueueAction.STATUS or not prog.active():
            return None
        if action is QueueAction.ABORT:
            return self._cmd_stop(Stop(m.cmd_id, 0.0))  # which empties the queue
        if action is QueueAction.HOLD:
            if prog.held or self._mode != "plan":
                return None
            planner = copy.copy(self._planners[self._kind])
            profile = planner.stop(t_s, a_max=self.a_max_dps2, kind="trapezoid")
            refusal = self._travel_refusal(profile, None)
            if refusal is not None:
                return refusal
            prog.hold(t_s, profile.p1)
            self._planners[self._kind] = planner
            self._target_deg = profile.p1
            return None
        # RESUME
        if not prog.held:
            return None
        if self._moving:
            return NackCode.BUSY, "action", 0.0  # still braking from the hold
        trial = copy.deepcopy(prog)
        try:
            profile = trial.resume(t_s, self.sp_pos_deg)
        except ValueError:
            return NackCode.OUT_OF_RANGE, None, 0.0
        self.program = trial
        if profile is not None:
            self._follow_program(profile, trial.t_start_s)
        return None

    def _follow_program(self, profile: Any, t_start_s: float) -> None:
        """Follow a program's or a stream's profile through the trapezoid planner (as a
        Move)."""
        self._jog_timeout_ticks = 0
        planner = OnlinePlanner("trapezoid")
        planner.reset(profile.p0)
        planner.profile, planner.t_start_s = profile, t_start_s
        planner.moving = True
        self._planners["trapezoid"] = planner
        self._mode, self._kind = "plan", "trapezoid"
        self._move_limits = (self.v_max_dps, self.a_max_dps2)
        self._v_clamp_dps = self.v_max_dps
        self._target_deg = profile.p1
        self._moving = True
        self._moved = True

    def _end_other_motion(self) -> None:
        """A Move, Stop or Jog takes over: the program, the stream and a jog's timeout end."""
        self.program.clear()
        self.stream.clear()
        self._jog_timeout_ticks = 0

    # ------------------------------------------------------------------ streams
    def _cmd_stream_control(self, m: StreamControl) -> _Refusal | None:
        action = StreamAction(m.action)
        t_s = self.tick * self.dt_s
        st = self.stream
        st.update(t_s)
        if action is StreamAction.STATUS:
            return None
        if action is StreamAction.START:
            refusal = _check_ranges([
                ("period_s", m.period_s, stream.PERIOD_MIN_S, stream.PERIOD_MAX_S),
                ("prefill", m.prefill, 1, st.capacity),
            ])  # fmt: skip
            if refusal is not None:
                return refusal
            refused = self._motion_refused()
            if refused is not None:
                return refused
            self.program.finish(t_s)
            if self._moving or self.program.active() or st.active():
                return NackCode.BUSY, None, 0.0  # a stream starts from rest
            lim = self.params.limits
            st.start(self.sp_pos_deg, float(m.period_s), m.interp, int(m.prefill),
                     v_max_dps=self.v_max_dps, a_max_dps2=self.a_max_dps2,
                     travel_deg=(lim.travel_min_deg, lim.travel_max_deg))  # fmt: skip
            return None
        if action is StreamAction.END:
            if st.state in (StreamState.FILLING, StreamState.RUNNING):
                followed = st.end(t_s)
                if followed is not None:
                    self._follow_program(*followed)
            return None
        # ABORT: the board's Stop (which closes the stream)
        if not st.active():
            return None
        refusal = self._cmd_stop(Stop(m.cmd_id, 0.0))
        if refusal is None:
            return None
        # The Stop's refusal names a Stop field (its a_max_dps2), which StreamControl does
        # not have: the NACK keeps the code and the bound and names no field.
        code, _, limit = refusal
        return code, None, limit

    def _cmd_stream_points(self, m: StreamPoints) -> _Refusal | None:
        refusal = _check_ranges([("count", m.count, 1, STREAM_POINTS_PER_FRAME)])
        if refusal is not None:
            return refusal
        points = m.points
        for k, (_, v) in enumerate(points):
            if not math.isfinite(v):
                return NackCode.NOT_FINITE, f"vel{k}_dps", 0.0
        refused = self._motion_refused()
        if refused is not None:
            return refused
        t_s = self.tick * self.dt_s
        refusal = self.stream.check(t_s, m.first_index, points)
        if refusal is not None:
            return refusal
        followed = self.stream.add(t_s, points)
        if followed is not None:
            self._follow_program(*followed)
        return None

    def stream_status(self, cmd_id: int = 0) -> StreamStatus:
        """The point stream's state now (the answer to the stream commands)."""
        st = self.stream
        t_s = self.tick * self.dt_s
        free = st.free(t_s)
        w = 0xFFFFFFFF
        return StreamStatus(cmd_id, st.state, free, st.next_index & w, st.underruns & w,
                            safety.wire_pos(st.start_pos_deg))  # fmt: skip

    # ------------------------------------------------------------------ jog
    def _cmd_jog(self, m: Jog) -> _Refusal | None:
        refusal = _check_ranges([
            ("vel_dps", m.vel_dps, -self.v_max_dps, self.v_max_dps),
            ("a_max_dps2", m.a_max_dps2, MIN_POSITIVE, self.a_max_dps2),
            ("timeout_ms", m.timeout_ms, 0, 60000),
        ])  # fmt: skip
        if refusal is not None:
            return refusal
        refused = self._motion_refused()
        if refused is not None:
            return refused
        t_s = self.tick * self.dt_s
        if self._mode == "plan":
            planner = copy.copy(self._planners[self._kind])
        elif self._mode == "step":
            planner = self._planner_from_axis("trapezoid", t_s)
        else:
            planner = OnlinePlanner("trapezoid")
            planner.reset(self.sp_pos_deg)
        a_max = float(m.a_max_dps2)
        lim = self.params.limits
        try:
            if m.vel_dps == 0.0:
                profile = planner.stop(t_s, a_max=a_max, kind="trapezoid")
            else:
                # a move to the travel end at |vel|: the stop there is planned with it
                end = lim.travel_max_deg if m.vel_dps > 0.0 else lim.travel_min_deg
                profile = planner.command(t_s, end, v_max=abs(m.vel_dps), a_max=a_max,
                                          kind="trapezoid")  # fmt: skip
        except ValueError:
            return NackCode.OUT_OF_RANGE, None, 0.0
        refusal = self._travel_refusal(profile, "a_max_dps2")
        if refusal is not None:
            return refusal  # moving too fast towards an end to stop there at a_max_dps2
        self._end_other_motion()
        self._planners["trapezoid"] = planner
        self._mode, self._kind = "plan", "trapezoid"
        self._move_limits = (max(abs(m.vel_dps), MIN_POSITIVE), a_max)
        self._v_clamp_dps = self.v_max_dps
        self._target_deg = profile.p1
        self._moving = self._moved = True
        ticks = math.ceil(m.timeout_ms * 1e-3 * self.params.servo.tick_hz - 1e-9)
        self._jog_timeout_ticks = max(1, ticks) if m.timeout_ms else 0
        self._jog_a_max_dps2 = a_max
        return None

    def _jog_expired(self) -> None:
        """No frame of the session within the jog's timeout: decelerate to rest at the
        jog's acceleration (within the travel: the jog's own stop at the end is at it)."""
        self._jog_timeout_ticks = 0
        self._counts["jog_timeouts"] += 1
        if self._mode != "plan":
            return
        t_s = self.tick * self.dt_s
        planner = self._planners[self._kind]
        profile = planner.stop(t_s, a_max=self._jog_a_max_dps2, kind="trapezoid")
        self._planners["trapezoid"] = planner
        self._kind = "trapezoid"
        self._target_deg = profile.p1

    def queue_status(self, cmd_id: int = 0) -> QueueStatus:
        """The program queue's state now (the answer to the queue commands)."""
        prog = self.program
        t_s = self.tick * self.dt_s
        queued = prog.queued(t_s)
        state = QueueState.HELD if prog.held else (
            QueueState.RUNNING if prog.active() else QueueState.EMPTY)  # fmt: skip
        return QueueStatus(cmd_id, state, prog.capacity - queued, queued,
                           prog.done & 0xFFFFFFFF, prog.override_pct)  # fmt: skip

    def _travel_refusal(self, profile: Any, field: str | None) -> _Refusal | None:
        """``NackCode.TRAVEL`` naming ``field`` and the travel end ``profile`` would cross
        (``safety.travel_end_crossed``), or None if it stays within the travel."""
        lim = self.params.limits
        end = safety.travel_end_crossed(profile, lim.travel_min_deg, lim.travel_max_deg)
        return None if end is None else (NackCode.TRAVEL, field, end)

    def _cmd_set_gains(self, m: SetGains) -> _Refusal | None:
        loop = Loop(m.loop)
        kp_name, ki_name = _LOOP_GAINS[loop]
        # No D terms in these loops, no integrator in the position loop: those are [0, 0].
        refusal = _check_ranges([
            ("kp", m.kp, 0.0, math.inf),
            ("ki", m.ki, 0.0, math.inf if ki_name is not None else 0.0),
            ("kd", m.kd, 0.0, 0.0),
        ])  # fmt: skip
        if refusal is not None:
            return refusal
        new = {kp_name: float(m.kp)}
        if ki_name is not None:
            new[ki_name] = float(m.ki)
        trial = {k: _first(v) for k, v in self.law.gains.items()}
        trial.update(new)
        if self._gain_check(self.params, trial) is not None:
            return NackCode.UNSTABLE_GAINS, None, 0.0
        self.law.set_gains(**new)
        return None

    def _cmd_set_limits(self, m: SetLimits) -> _Refusal | None:
        s = self.params.safety
        # 0 keeps the present trip threshold; the clamp may not exceed the trip.
        trip_a = m.over_current_trip_a if m.over_current_trip_a != 0.0 else self._oc_thr_a
        refusal = _check_ranges([
            ("v_max_dps", m.v_max_dps, MIN_POSITIVE, s.over_speed_dps),
            ("a_max_dps2", m.a_max_dps2, MIN_POSITIVE, math.inf),
            ("current_limit_a", m.current_limit_a, MIN_POSITIVE,
             trip_a if math.isfinite(trip_a) else math.inf),
            ("following_error_deg", m.following_error_deg, MIN_POSITIVE, math.inf),
            ("over_current_trip_a", trip_a, MIN_POSITIVE, s.over_current_a),
        ]) or self._threshold_refusal(m)  # fmt: skip
        if refusal is not None:
            return refusal
        v_max, a_max = float(m.v_max_dps), float(m.a_max_dps2)
        if self._mode == "plan" and self._moving:
            # Limits lowered below those of the move in progress: replan the rest of it from
            # the commanded state (the planner brakes down to the new v_max first).
            move_v, move_a = self._move_limits
            if v_max < move_v or a_max < move_a:
                new_v, new_a = min(v_max, move_v), min(a_max, move_a)
                planner = copy.copy(self._planners[self._kind])
                j_max = self._j_max if self._kind == "scurve" else None
                try:
                    profile = planner.command(self.tick * self.dt_s, self._target_deg,
                                              v_max=new_v, a_max=new_a, j_max=j_max)  # fmt: skip
                except ValueError:
                    return NackCode.OUT_OF_RANGE, None, 0.0
                refusal = self._travel_refusal(profile, None)
                if refusal is not None:
                    return refusal  # the move could not brake within the travel
                self._planners[self._kind] = planner
                self._move_limits = (new_v, new_a)
        self.v_max_dps, self.a_max_dps2 = v_max, a_max
        self.current_limit_a = float(m.current_limit_a)
        self.following_error_deg = float(m.following_error_deg)
        self._oc_thr_a = float(trip_a)
        self._apply_thresholds(m)
        if self._mode == "step":
            self._v_clamp_dps = min(self._v_clamp_dps, v_max)
        else:
            self._v_clamp_dps = v_max
        return None

    @property
    def over_current_trip_a(self) -> float:
        """The over-current trip threshold in A (``SetLimits.over_current_trip_a``)."""
        return self._oc_thr_a

    def _set_bus_thresholds(self, over_v: float, under_v: float) -> None:
        """The bus trips' thresholds (V), and in counts of the bus reading for the compiled
        screen (``safety.bus_voltage_screen``)."""
        v_per_count = self.params.current.v_per_bus_adc
        self.bus_over_voltage_v, self.bus_under_voltage_v = float(over_v), float(under_v)
        self._bus_over_counts = math.floor(over_v / v_per_count)
        self._bus_under_counts = math.ceil(under_v / v_per_count)
        self._fi[ftick.FI_BUS_OVER] = self._bus_over_counts
        self._fi[ftick.FI_BUS_UNDER] = self._bus_under_counts

    @property
    def thermal_thresholds_c(self) -> tuple[float, float]:
        """The thermal protection's derating start and trip (degC) in force."""
        at = ftick.FS_THERMAL
        return float(self._fs[at + TP_DERATE_C]), float(self._fs[at + TP_TRIP_C])

    def _threshold_refusal(self, m: SetLimits) -> _Refusal | None:
        """The appended thresholds of ``m`` (0 = keep): the bus trips within the band
        between the configured supply and the BTN7971B's lock-out, the thermal ones in
        ``[safety]``'s range with the derating below the trip; a check the configuration
        turned off takes only 0 (``TOO_HIGH``, limit 0)."""
        s, cur = self.params.safety, self.params.current
        supply_v = float(cur.supply_v)
        checks = []
        for name, low, high, on in (
            # Above the supply (else it trips on enable), at most where the chip may have
            # locked its outputs out already (the trip would come after it).
            ("bus_over_voltage_v", supply_v, float(cur.bus_hold_v), s.bus_voltage_check),
            # Below the supply (else it trips on enable).
            ("bus_under_voltage_v", MIN_POSITIVE, supply_v, s.bus_voltage_check),
            ("thermal_derate_c", THERMAL_MIN_C, THERMAL_MAX_C, s.thermal_protection),
            ("thermal_trip_c", THERMAL_MIN_C, THERMAL_MAX_C, s.thermal_protection),
            # Any brake may be capped (the cap is off by default, not a check turned off).
            ("brake_current_limit_a", MIN_POSITIVE, BRAKE_CAP_MAX_A, True),
        ):
            value = getattr(m, name)
            if value != 0.0:  # NaN too: refused as NOT_FINITE
                checks.append((name, value, low, high) if on else (name, value, 0.0, 0.0))
        refusal = _check_ranges(checks)
        if refusal is not None:
            return refusal
        derate, trip = self.thermal_thresholds_c
        new_derate = m.thermal_derate_c if m.thermal_derate_c != 0.0 else derate
        new_trip = m.thermal_trip_c if m.thermal_trip_c != 0.0 else trip
        if not new_derate < new_trip:
            if m.thermal_derate_c != 0.0:
                return NackCode.TOO_HIGH, "thermal_derate_c", new_trip
            return NackCode.TOO_LOW, "thermal_trip_c", new_derate
        return None

    def _apply_thresholds(self, m: SetLimits) -> None:
        """Apply ``_threshold_refusal``'s accepted thresholds (0 keeps each)."""
        over = m.bus_over_voltage_v if m.bus_over_voltage_v != 0.0 else self.bus_over_voltage_v
        under = (
            m.bus_under_voltage_v if m.bus_under_voltage_v != 0.0 else self.bus_under_voltage_v
        )
        self._set_bus_thresholds(over, under)
        at = ftick.FS_THERMAL
        if m.thermal_derate_c != 0.0:
            self._fs[at + TP_DERATE_C] = float(m.thermal_derate_c)
        if m.thermal_trip_c != 0.0:
            self._fs[at + TP_TRIP_C] = float(m.thermal_trip_c)
        if m.brake_current_limit_a != 0.0:
            self._fs[ftick.FS_BRAKE_CAP] = float(m.brake_current_limit_a)

    def _cmd_clear_fault(self, m: ClearFault) -> _Refusal | None:
        # Without a latched fault: ACKed, nothing changes (the bridge stays as it is).
        if (self._fault != 0).any() or (self._flags != 0).any():
            self._fault[:] = 0
            self._flags[:] = 0
            self._fault_info.clear()
            self._flags_version += 1
            self._fault_s = 0
            self._oc_ticks[:] = 0
            self._oc_s = 0
            self._disable()
        return None

    def _cmd_set_enable(self, m: SetEnable) -> _Refusal | None:
        if m.enable:
            if (self._fault != 0).all():
                return NackCode.FAULT_ACTIVE, None, 0.0
            if np.array_equal(self._enabled, self._fault == 0):
                return None  # already enabled: the motion in progress goes on undisturbed
            cur = self.params.current
            if cur.sense_calibration:
                # The offset is measured with the motor at rest: a turning motor drives a
                # current around the both-high-sides loop.
                still = np.abs(self.law.vel_dps) <= cur.sense_calibration_max_speed_dps
                if not (still & (self._fault == 0)).any():
                    return NackCode.BUSY, None, cur.sense_calibration_max_speed_dps
                self._enable(still)
                self._cal_command = m
                return _PENDING
            self._enable()
        else:
            self._disable()
        return None

    def _cmd_set_telemetry(self, m: SetTelemetry) -> _Refusal | None:
        if 0 < m.decimation < self._auto_decimation:
            # Refused, not raised: the PC learns the floor (HelloReply states it too).
            return NackCode.TOO_LOW, "decimation", float(self._auto_decimation)
        self._set_decimation(m.decimation)
        return None

    def _set_decimation(self, requested: int) -> None:
        self._requested_decimation = requested
        used = 0 if requested == 0 else max(requested, self._auto_decimation)
        self._decimation = used

    # ------------------------------------------------------------------ transmit
    def _transmit(self, tx_free: int) -> bytes:
        hb = self._heartbeat_ticks
        if hb and self.tick % hb == 0:
            self._queue(self.link_status())
        replies = self._replies
        dec = self._decimation
        if not replies and dec == 1:  # the common case: one telemetry frame per tick
            if frame.TELEMETRY_FRAME_BYTES <= tx_free:
                data = self._telemetry()
                self._seq = (self._seq + 1) & 0xFF
                self._tx_frames += 1
                self._tx_bytes += len(data)
                return data
            self._tx_dropped += 1
            return b""
        out = b""
        free = tx_free
        while replies:
            data = frame.encode(replies[0], self._seq)
            if len(data) > free:
                break  # stays queued for the next tick
            replies.popleft()
            out += data
            free -= len(data)
            self._seq = (self._seq + 1) & 0xFF
            self._tx_frames += 1
        if dec and (self.tick - 1) % dec == 0:
            if frame.TELEMETRY_FRAME_BYTES <= free:
                out += self._telemetry()
                self._seq = (self._seq + 1) & 0xFF
                self._tx_frames += 1
            else:
                self._tx_dropped += 1
        self._tx_bytes += len(out)
        return out

    def _telemetry(self) -> bytes:
        """The telemetry frame of this tick (member 0), framed with the next sequence."""
        p = self.law.P
        pos, vel = float(p[P_POS, 0]), float(p[P_VEL, 0])
        cur, duty = float(p[P_IMEAS, 0]), float(p[P_DUTY, 0])
        state, fault = self._state0(), int(self._fault[0])
        if not self._enabled[0]:
            duty = 0.0  # the bridge is off for the next period, whatever the law last said
        return frame.encode_telemetry_fields(
            self._seq, self.tick - 1, self.sp_pos_deg, self.sp_vel_dps, pos, vel, cur, duty,
            state, fault, int(self._flags[0]) if fault else 0, self._bus_mv() / frame.BUS_SCALE,
        )  # fmt: skip


def _check_ranges(checks: list[tuple[str, float, float, float]]) -> _Refusal | None:
    """The first ``(name, value, low, high)`` whose value is not finite or not in
    ``[low, high]``, as a refusal; None if all pass."""
    for name, value, low, high in checks:
        if not math.isfinite(value):
            return NackCode.NOT_FINITE, name, 0.0
        if value < low:
            return NackCode.TOO_LOW, name, low
        if value > high:
            return NackCode.TOO_HIGH, name, high
    return None


def _first(x: Any) -> float:
    return float(np.asarray(x).reshape(-1)[0])
