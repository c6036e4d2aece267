"""The firmware's numeric servo tick, compiled: setpoint, position and velocity loops, trip
screen, current loop with its over-current screen, and telemetry framing, for N members.

``Firmware.servo_tick`` / ``current_tick`` (one tick at a time, Python in between) and the
simulation's compiled run of many ticks (``sim/tick.py``) call these same functions; Python
keeps what is rare and rich: commands, planning, the trips themselves (a screen hit hands
over to ``Firmware._check``), replies.

The firmware's shared state lives in two small arrays, ``fs`` (float64, ``FS_*``) and
``fi`` (int64, ``FI_*``), which ``Firmware._pack`` / ``_unpack`` fill from and copy back to
its attributes; the active motion profile in ``prof`` (``(n_phases, 5)``: start time, p, v,
a, j of each phase, as ``planner.profile.Profile`` holds them) and ``fs``'s ``FS_PROF_*``.
"""

from __future__ import annotations

import math

import numpy as np

from firmware_model import safety
from firmware_model.kernel_cache import kernel
from firmware_model.laws import dispatch as law
from firmware_model.laws.layout import (
    C_BUS_ADC,
    C_INNOV,
    C_STUCK,
    K_BUS_HOLD,
    P_DERATE,
    P_DUTY,
    P_EMF_RISE,
    P_IMEAS,
    P_POS,
    P_R_RISE,
    P_VEL,
    P_VREF,
)  # fmt: skip
from firmware_model.sense_calibration import calibration_step
from firmware_model.thermal import (
    N_TP,
    TP_ALPHA,
    TP_AMBIENT_C,
    TP_ON,
    network_advance,
    thermal_protection,
)
from serial_protocol import frame
from serial_protocol.messages import BoardHeartbeat, State, Telemetry

__all__ = [
    "HEARTBEAT_TABLES", "TABLES", "bus_mv", "current_stage", "frame_heartbeat",
    "frame_telemetry", "frame_wire", "framer_ok", "heartbeat_wire", "live_state", "member_state",
    "servo_stage", "state_of", "trip_screen",
]  # fmt: skip

# fs: floats.
(
    FS_SP_POS, FS_SP_VEL, FS_SP_ACC, FS_TARGET, FS_V_CLAMP, FS_I_LIMIT, FS_FOLLOWING, FS_DT,
    FS_TOL, FS_OC_THR, FS_STUCK_MIN_VEL, FS_OVER_SPEED, FS_PROF_T0, FS_PROF_DURATION,
    FS_PROF_P0, FS_PROF_V0, FS_PROF_P1, FS_PROF_V1, FS_POS_LO, FS_POS_HI, FS_TRAVEL_MIN,
    FS_TRAVEL_MAX, FS_EDGE_DECEL, FS_SUPPLY_V, FS_MM_WINDOW, FS_MM_TOL, FS_MM_RATIO, FS_MM_DEG,
    FS_MM_V_PER_BUS, FS_MM_SENSE_SPREAD, FS_MM_OFFSET_A, FS_MM_R_SPREAD, FS_BUS_V_PER_COUNT,
    FS_BRAKE_CAP, FS_MM_RESTART_W, FS_MM_RESTART_H,
) = range(36)  # fmt: skip
N_FS = 36
# FS_BUS_V_PER_COUNT: volts per count of the bus reading (what BoardHeartbeat reports).
# FS_BRAKE_CAP: the fault reaction's brake current cap (A; 0 = none: the full short).
# The thermal protection's block at the end of fs (Firmware sizes fs to hold it):
# fs[FS_THERMAL:FS_THERMAL + thermal.N_TP] its constants, then (T_w, T_h) of each member
# (its estimate, degC). Not in sf: growing that tuple made every compiled tick ~0.4 us
# slower (measured: 10,000 Fig. 8 ticks 4.9 -> 8.7 ms in run_ticks), fs costs nothing.
FS_THERMAL = N_FS
# FS_MM_V_PER_BUS: volts per count of the bus reading for the back-EMF check, 0 = it takes
# the configured supply voltage (FS_SUPPLY_V). FS_MM_SENSE_SPREAD, _OFFSET_A, _R_SPREAD: what
# the check does not know of its current reading's gain and offset and of the winding's R.
# FS_MM_RESTART_W / _H: the warm restart's excess over the thermal estimate the check still
# allows for (K, winding and housing; [safety] sensor_mismatch_restart_rise_k at power-up),
# decaying through the protection's network with no heat in (the same for every member).
# fi: integers.
(
    FI_TICK, FI_MODE, FI_MOVING, FI_MOVED, FI_SEQ, FI_DECIMATION, FI_LAST_RX, FI_WATCHDOG,
    FI_OC_ANY, FI_OC_SAMPLES, FI_TX_FRAMES, FI_TX_BYTES, FI_TX_DROPPED, FI_JUMP, FI_STUCK,
    FI_HEARTBEAT, FI_JOG_TIMEOUT, FI_DIAG_TICKS, FI_BUS_OVER, FI_BUS_UNDER, FI_BUS_SAMPLES,
    FI_LINK,
) = range(22)  # fmt: skip
# FI_LINK: 1 while the BoardHeartbeat's fields are in fi (FI_HB on), 0 while the heartbeat is
# Python's (the program queue or the point stream is active: their flow control changes with
# time in their Python bookkeeping). FI_HB: the BoardHeartbeat's wire values in wire order
# (frame_wire's input): the compiled tick writes the tick, state, fault flags, telemetry
# dropped and bus voltage (_HB_OWN); Firmware._pack_link the rest (the receiver's counters,
# the session, the queue's and the stream's flow control).
FI_HB = 22
N_FI = FI_HB + len(frame.wire_fields(BoardHeartbeat))
# FI_BUS_OVER / _UNDER: the bus trips' thresholds in counts of the bus reading (a reading
# above / below trips); FI_BUS_SAMPLES: readings in a row that trip, 0 = the check off.
MODE_HOLD, MODE_PLAN, MODE_STEP = 0, 1, 2
_DISABLED, _IDLE, _MOVING, _HOLDING, _FAULT = (
    int(State.DISABLED),
    int(State.IDLE),
    int(State.MOVING),
    int(State.HOLDING),
    int(State.FAULT),
)


# The STEP move's speed limit near the travel ends: safety's function, compiled.
_edge_speed_dps = kernel(safety.edge_speed_dps)


@kernel
def profile_at(prof, fs, t):
    """``Profile._at_scalar(t)`` of the packed profile (the same operations in order)."""
    duration = fs[FS_PROF_DURATION]
    if 0.0 <= t < duration:
        # bisect_right over the phase start times, minus one
        lo, hi = 0, prof.shape[0]
        while lo < hi:
            mid = (lo + hi) // 2
            if t < prof[mid, 0]:
                hi = mid
            else:
                lo = mid + 1
        i = lo - 1
        tau = t - prof[i, 0]
        p, v, a, j = prof[i, 1], prof[i, 2], prof[i, 3], prof[i, 4]
        jt = j * tau
        return (
            p + tau * (v + tau * (0.5 * a + jt / 6.0)),
            v + tau * (a + 0.5 * jt),
            a + jt,
        )
    if t < 0.0:
        return fs[FS_PROF_P0], fs[FS_PROF_V0], 0.0
    return fs[FS_PROF_P1] + fs[FS_PROF_V1] * (t - duration), fs[FS_PROF_V1], 0.0


@kernel
def _in_position(P, fs, enabled):
    """Every live member within ``in_position_deg`` of the target and slower than that
    per 0.1 s (True with no live member)."""
    tol = fs[FS_TOL]
    target = fs[FS_TARGET]
    for j in range(enabled.shape[0]):
        if enabled[j] and not (abs(P[P_POS, j] - target) <= tol and abs(P[P_VEL, j]) <= 10 * tol):
            return False
    return True


# sf: the sensor checks' and the fault reaction's state, per member (Firmware._sf).
# SF_BUS_TICKS: the bus voltage screen's readings in a row beyond a threshold.
(
    SF_MISMATCH, SF_R, SF_EMF, SF_BRAKE, SF_DIAG_TICKS, SF_DIAG_ERRORS, SF_PEAK, SF_BUS_TICKS,
) = range(8)  # fmt: skip


@kernel
def servo_stage(P, C, S, G, K, fs, fi, enabled, prof, sf):
    """The fault reaction's brake countdown, the back-EMF check
    (``safety.sensor_mismatch_step``), the setpoint of this tick (hold, the profile, or a
    STEP move's raw target), then, if any member is enabled, the position and velocity loops
    (``servo``: the law's step) and the trip screen. Returns True if a member meets a trip
    condition (encoder jump or stuck, AS5048 errors, back-EMF mismatch, over-speed, travel,
    following error, watchdog): ``Firmware._check`` takes it from there. ``fi[FI_TICK]`` is
    not advanced here. ``sf``: ``(mismatch_deg, r_ohm, emf_v_per_dps, brake_ticks,
    diag_ticks, diag_errors, mismatch_peak_deg, bus_ticks)``, ``(N,)`` each (the ``SF_*``
    rows); the thermal protection (``firmware_model.thermal.thermal_protection``) keeps its
    constants and estimate in ``fs`` from ``FS_THERMAL``."""
    mismatch, brake, diag_ticks = sf[SF_MISMATCH], sf[SF_BRAKE], sf[SF_DIAG_TICKS]
    safety.brake_countdown(
        brake, P[P_VEL], sf[SF_R], sf[SF_EMF], P[P_R_RISE], P[P_EMF_RISE], fs[FS_BRAKE_CAP]
    )
    # The duty applied in the last current period, the current it measured, the encoder's
    # speed: the check needs no law step of this tick.
    # R's rise with the thermal protection's winding estimate (none when it is off), plus
    # what a warm restart may still add to it: the rise is counted from the ambient less
    # that excess, which decays as the motor would cool (a linear network: the truth is the
    # estimate plus the initial excess's free response).
    alpha, rise_from_c = 0.0, fs[FS_THERMAL + TP_AMBIENT_C]
    if fs[FS_THERMAL + TP_ON] != 0.0:
        alpha = fs[FS_THERMAL + TP_ALPHA]
        rise_from_c -= fs[FS_MM_RESTART_W]
        fs[FS_MM_RESTART_W], fs[FS_MM_RESTART_H] = network_advance(
            fs[FS_MM_RESTART_W], fs[FS_MM_RESTART_H], 0.0, 0.0, 0.0, fs, FS_THERMAL
        )
    worst = safety.sensor_mismatch_step(
        P[P_DUTY], P[P_IMEAS], P[P_VEL], enabled, fs[FS_SUPPLY_V], sf[SF_R], sf[SF_EMF],
        fs[FS_DT], fs[FS_MM_WINDOW], fs[FS_MM_TOL], fs[FS_MM_RATIO], fs[FS_MM_DEG] / 3.0,
        mismatch, C[C_BUS_ADC], fs[FS_MM_V_PER_BUS], K[K_BUS_HOLD], fs[FS_MM_SENSE_SPREAD],
        fs[FS_MM_OFFSET_A], fs[FS_MM_R_SPREAD], fs[FS_THERMAL + N_TP :: 2], alpha,
        rise_from_c,
    )  # fmt: skip
    sensor = worst > fs[FS_MM_DEG]
    peak = sf[SF_PEAK]
    for j in range(peak.shape[0]):
        peak[j] = max(peak[j], mismatch[j])
    for j in range(diag_ticks.shape[0]):
        if enabled[j] and diag_ticks[j] >= fi[FI_DIAG_TICKS]:
            sensor = True
    # The thermal protection (its estimate, the derating of this tick's current limit).
    if fs[FS_THERMAL + TP_ON] != 0.0 and thermal_protection(
        P[P_IMEAS], P[P_VEL], enabled, sf[SF_R], sf[SF_EMF], fs, FS_THERMAL, P[P_DERATE],
        P[P_R_RISE], P[P_EMF_RISE],
    ):
        sensor = True
    t_s = fi[FI_TICK] * fs[FS_DT]
    mode = fi[FI_MODE]
    v_clamp = fs[FS_V_CLAMP]
    if mode == MODE_PLAN:
        tau = t_s - fs[FS_PROF_T0]
        fi[FI_MOVING] = 1 if tau < fs[FS_PROF_DURATION] else 0
        p, v, a = profile_at(prof, fs, tau)
    elif mode == MODE_STEP:
        p, v, a = fs[FS_TARGET], 0.0, 0.0
        if fi[FI_MOVING]:
            fi[FI_MOVING] = 0 if _in_position(P, fs, enabled) else 1
        # Slow down near the travel end the move heads for (Firmware._step_edge_speed_dps:
        # from the outermost member).
        up = p >= P[P_POS, 0]
        pos = P[P_POS, 0]
        for j in range(P.shape[1]):
            pos = max(pos, P[P_POS, j]) if up else min(pos, P[P_POS, j])
        edge = _edge_speed_dps(pos, p, fs[FS_TRAVEL_MIN], fs[FS_TRAVEL_MAX], fs[FS_EDGE_DECEL])
        v_clamp = min(v_clamp, edge)
    else:
        p, v, a = fs[FS_SP_POS], 0.0, 0.0
    fs[FS_SP_POS], fs[FS_SP_VEL], fs[FS_SP_ACC] = p, v, a
    live = False
    for j in range(enabled.shape[0]):
        if enabled[j]:
            live = True
            break
    if not live:
        return False
    law.servo(p, v, a, v_clamp, fs[FS_I_LIMIT], P, C, S, G, K)
    return trip_screen(P, C, fs, fi, enabled) or sensor


@kernel
def trip_screen(P, C, fs, fi, enabled):
    """Whether an enabled member meets a trip condition after this tick's servo step
    (encoder jump or stuck, over-speed, position outside ``[FS_POS_LO, FS_POS_HI]``,
    following error against ``fs[FS_SP_POS]``), or the watchdog or a jog's timeout fired.
    A disabled member (tripped, or off) is not screened: ``Firmware._check`` trips only
    enabled ones, and a tripped member of a batch would stop the compiled run every tick."""
    if fi[FI_WATCHDOG] and fi[FI_TICK] - fi[FI_LAST_RX] > fi[FI_WATCHDOG]:
        return True
    # a jog's dead-man timeout (Firmware._check plans the stop)
    if fi[FI_JOG_TIMEOUT] and fi[FI_TICK] - fi[FI_LAST_RX] > fi[FI_JOG_TIMEOUT]:
        return True
    p = fs[FS_SP_POS]
    following = fs[FS_FOLLOWING] if fi[FI_MODE] != MODE_STEP else math.inf
    jump, stuck_limit = fi[FI_JUMP], fi[FI_STUCK]
    stuck_vel, over_speed = fs[FS_STUCK_MIN_VEL], fs[FS_OVER_SPEED]
    lo, hi = fs[FS_POS_LO], fs[FS_POS_HI]
    for j in range(C.shape[1]):
        if enabled[j] and (
            abs(C[C_INNOV, j]) > jump
            or (C[C_STUCK, j] >= stuck_limit and abs(P[P_VREF, j]) > stuck_vel)
            or abs(P[P_VEL, j]) > over_speed
            or not lo <= P[P_POS, j] <= hi
            or abs(p - P[P_POS, j]) > following
        ):
            return True
    return False


@kernel
def current_stage(adc, enabled, P, C, S, G, K, fs, fi, oc_ticks, bus_ticks):
    """One current-loop period (the law's step), the over-current screen (a member counts
    the periods its |sensed current| stays above the threshold while enabled) and the bus
    voltage screen (``safety.bus_voltage_screen``, with ``[safety] bus_voltage_check``).
    Returns True if one reached its trip count (``oc_ticks``, ``bus_ticks`` say which) or
    finished its IS-offset calibration (``sense_calibration.calibration_step``: a member
    calibrating has its control output held at zero)."""
    law.current(adc, enabled, P, C, S, G, K)
    bus = calibration_step(adc, P, C, S, K)
    if fi[FI_BUS_SAMPLES]:
        bus = safety.bus_voltage_screen(
            C[C_BUS_ADC], enabled, fi[FI_BUS_OVER], fi[FI_BUS_UNDER], fi[FI_BUS_SAMPLES],
            bus_ticks,
        ) or bus  # fmt: skip
    thr = fs[FS_OC_THR]
    over_any = False
    for j in range(adc.shape[0]):
        if abs(P[P_IMEAS, j]) > thr:
            over_any = True
            break
    if not over_any:  # the common case
        if fi[FI_OC_ANY]:
            oc_ticks[:] = 0
            fi[FI_OC_ANY] = 0
        return bus
    fi[FI_OC_ANY] = 1
    trip = False
    for j in range(adc.shape[0]):
        if enabled[j] and abs(P[P_IMEAS, j]) > thr:
            oc_ticks[j] += 1
            if oc_ticks[j] >= fi[FI_OC_SAMPLES]:
                trip = True
        else:
            oc_ticks[j] = 0
    return trip or bus


@kernel(inline="always")
def live_state(fi):
    """The ``State`` code of an enabled member without a fault (the board's motion state:
    the same for every member, so a member loop reads it once)."""
    if fi[FI_MOVING]:
        return _MOVING
    return _HOLDING if fi[FI_MOVED] else _IDLE


@kernel(inline="always")
def member_state(j, enabled, fault, live):
    """The ``State`` code of member ``j``, ``live`` being ``live_state(fi)``."""
    if fault[j]:
        return _FAULT
    return live if enabled[j] else _DISABLED


@kernel(inline="always")
def state_of(j, fi, enabled, fault):
    """The ``State`` code of member ``j``."""
    return member_state(j, enabled, fault, live_state(fi))


# ---------------------------------------------------------------- framing
# The board's frames of every tick written in compiled code: the Telemetry
# (frame_telemetry) and the BoardHeartbeat (frame_heartbeat, through frame_wire), built from
# serial_protocol's own tables and checked against its encoder at first use (framer_ok); a
# format these framers do not know leaves the framing to serial_protocol.frame (framer_ok()
# False: the simulation hands every tick's transmit to Python).
_FMT = frame._TELEMETRY.fmt
_HEAD_BYTES = frame.HEADER_BYTES
_CRC_BYTES = frame.TELEMETRY_FRAME_BYTES - frame.HEADER_BYTES - frame._TELEMETRY_LEN
_SIZES = {"I": 4, "i": 4, "h": 2, "H": 2, "B": 1, "b": 1}
# Per payload field after the tick: byte size, scale, lowest and highest wire value.
_SAT = {name: (scale, lo, hi) for name, scale, lo, hi in frame._TELEMETRY_SATURATION}
_NAMES = ("sp_pos_deg", "sp_vel_dps", "pos_deg", "vel_dps", "current_a", "duty")


def _crc_table(width: int) -> np.ndarray:
    table = np.zeros(256, dtype=np.int64)
    for byte in range(256):
        if width == 16:  # CRC-16/CCITT, not reflected (binascii.crc_hqx)
            crc = byte << 8
            for _ in range(8):
                crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
        else:  # CRC-32/ISO-HDLC, reflected (zlib.crc32)
            crc = byte
            for _ in range(8):
                crc = (crc >> 1) ^ 0xEDB88320 if crc & 1 else crc >> 1
        table[byte] = crc
    return table


def _head_tables(cls: type) -> tuple[np.ndarray, np.ndarray]:
    """``frame.frame_heads(cls)`` as arrays: ``(256, 6)`` header bytes, ``(256,)`` CRCs."""
    heads = frame.frame_heads(cls)
    return (
        np.array([list(h) for h, _ in heads], dtype=np.uint8),
        np.array([c for _, c in heads], dtype=np.int64),
    )


_CRC_TABLE = _crc_table(16 if _CRC_BYTES == 2 else 32)
_FIELD_SIZE = np.array([_SIZES.get(c, 0) for c in _FMT[1:7]], dtype=np.int64)
_FIELD_SCALE = np.array([_SAT.get(n, (1.0, 0, 0))[0] for n in _NAMES])
_FIELD_LO = np.array([float(_SAT.get(n, (1.0, 0, 0))[1]) for n in _NAMES])
_FIELD_HI = np.array([float(_SAT.get(n, (1.0, 0, 0))[2]) for n in _NAMES])


@kernel(inline="always")
def _put(out, at, value, size):
    for b in range(size):
        out[at + b] = (value >> (8 * b)) & 0xFF
    return at + size


@kernel(inline="always")
def _put_head(out, at, head, head_bytes):
    for b in range(head_bytes):
        out[at + b] = head[b]
    return at + head_bytes


@kernel(inline="always")
def _put_crc(out, start, pos, crc, crc_table, crc_bytes):
    """The frame's CRC over ``out[start:pos]`` (the payload), continued from ``crc`` (the
    register after the header), written at ``pos``; returns the index after it."""
    if crc_bytes == 2:
        for b in range(start, pos):
            crc = ((crc << 8) & 0xFFFF) ^ crc_table[((crc >> 8) ^ out[b]) & 0xFF]
    else:
        crc = ~crc & 0xFFFFFFFF
        for b in range(start, pos):
            crc = crc_table[(crc ^ out[b]) & 0xFF] ^ (crc >> 8)
        crc = ~crc & 0xFFFFFFFF
    return _put(out, pos, crc, crc_bytes)


@kernel
def frame_telemetry(out, at, seq, tick, values, state, fault, fault_flags, bus, tables):
    """Write the telemetry frame of ``(tick, values = (sp_pos_deg, sp_vel_dps, pos_deg,
    vel_dps, current_a, duty), state, fault, fault_flags, bus)`` (``bus``: the bus
    voltage's wire value, mV, :func:`bus_mv`) with sequence ``seq`` into ``out[at:]``
    (values beyond the wire range saturate, as ``frame.encode_telemetry_fields``).
    ``tables``: :data:`TABLES`, serial_protocol's (passed in, not frozen into the compiled
    code, so that a new frame format is never served from numba's cache). Returns the
    index after the frame, or -1 for a NaN (which ``frame`` refuses)."""
    heads, head_crc, crc_table, size, scale, lo, hi, widths = tables
    head_bytes, crc_bytes, flag_bytes, bus_bytes = widths[0], widths[1], widths[2], widths[3]
    start = _put_head(out, at, heads[seq], head_bytes)
    pos = _put(out, start, tick & 0xFFFFFFFF, 4)
    for f in range(6):
        x = values[f] * scale[f]
        if x != x:
            return -1
        x = min(max(x, lo[f]), hi[f])
        pos = _put(out, pos, np.int64(np.rint(x)), size[f])
    out[pos] = state
    out[pos + 1] = fault
    pos = _put(out, pos + 2, fault_flags & 0xFFFFFFFF, flag_bytes)
    pos = _put(out, pos, min(max(bus, 0), 0xFFFF), bus_bytes)
    return _put_crc(out, start, pos, head_crc[seq], crc_table, crc_bytes)


# frame_wire's and frame_heartbeat's layout array (HEARTBEAT_TABLES[4]).
L_HEAD, L_CRC, L_FRAME, L_TICK, L_STATE, L_FLAGS, L_DROPPED, L_BUS = range(8)


@kernel
def frame_wire(out, at, seq, wire, tables):
    """Write the frame of a message of integer fields with sequence ``seq`` into
    ``out[at:]``: ``wire`` (int64, ``(n_fields,)``) holds the wire values in wire order (what
    ``struct.pack`` takes; each is written in its field's size, two's complement, little
    endian). ``tables``: ``(heads, head_crc, crc_table, sizes, layout)`` of the message
    (:data:`HEARTBEAT_TABLES`; ``layout[L_HEAD]``, ``layout[L_CRC]``: header and CRC
    bytes). Returns the index after the frame."""
    heads, head_crc, crc_table, size, layout = tables
    start = _put_head(out, at, heads[seq], layout[L_HEAD])
    pos = start
    for f in range(size.shape[0]):
        pos = _put(out, pos, wire[f], size[f])
    return _put_crc(out, start, pos, head_crc[seq], crc_table, layout[L_CRC])


@kernel(inline="always")
def bus_mv(C, fs):
    """Member 0's bus reading in mV (its ADC counts times ``fs[FS_BUS_V_PER_COUNT]``,
    rounded, at most 65535): ``Firmware.bus_voltage_v`` on the wire."""
    mv = np.rint(float(C[C_BUS_ADC, 0]) * fs[FS_BUS_V_PER_COUNT] * 1000.0)
    return np.int64(min(mv, 65535.0))


_HB_FIELDS = frame.wire_fields(BoardHeartbeat)
HB_FRAME_BYTES = frame.frame_bytes(BoardHeartbeat)
# HEARTBEAT_TABLES[4]: header and CRC bytes, frame bytes, then where the fields the compiled
# tick writes sit in the wire values (the rest: Firmware._pack_link).
_HB_OWN = ("tick", "state", "fault_flags", "tx_telemetry_dropped", "bus_voltage_v")


@kernel
def frame_heartbeat(out, at, free, seq, fs, fi, enabled, fault, fault_flags, C, tables):
    """The ``BoardHeartbeat`` of this tick (``Firmware.link_status``) into ``out[at:]`` if
    it fits in ``free`` bytes: the fields ``Firmware._pack_link`` put in ``fi[FI_HB:]``,
    with the tick, member 0's state and fault flags, the telemetry frames dropped and the
    bus voltage of now. ``tables``: :data:`HEARTBEAT_TABLES`. Returns the index after the
    frame, or -1 if it does not fit."""
    layout = tables[4]
    if layout[L_FRAME] > free:
        return -1
    wire = fi[FI_HB:]
    wire[layout[L_TICK]] = fi[FI_TICK] & 0xFFFFFFFF
    wire[layout[L_STATE]] = state_of(0, fi, enabled, fault)
    wire[layout[L_FLAGS]] = fault_flags[0] & 0xFFFFFFFF
    wire[layout[L_DROPPED]] = fi[FI_TX_DROPPED] & 0xFFFFFFFF
    wire[layout[L_BUS]] = bus_mv(C, fs)
    return frame_wire(out, at, seq, wire, tables)


#: The tables ``frame_telemetry`` takes, from ``serial_protocol.frame``.
TABLES = (
    *_head_tables(Telemetry), _CRC_TABLE, _FIELD_SIZE, _FIELD_SCALE, _FIELD_LO, _FIELD_HI,
    np.array(
        [_HEAD_BYTES, _CRC_BYTES, 4 if "BBI" in _FMT else 0, 2 if _FMT.endswith("BBIH") else 0],
        dtype=np.int64,
    ),
)  # fmt: skip
#: The tables ``frame_wire`` takes for a ``BoardHeartbeat``, from ``serial_protocol.frame``.
HEARTBEAT_TABLES = (
    *_head_tables(BoardHeartbeat), _CRC_TABLE,
    np.array([_SIZES.get(f.fmt, 0) for f in _HB_FIELDS], dtype=np.int64),
    np.array(
        [_HEAD_BYTES, _CRC_BYTES, HB_FRAME_BYTES]
        + [frame.field_index(BoardHeartbeat, name) for name in _HB_OWN],
        dtype=np.int64,
    ),
)  # fmt: skip


def _framer_ok() -> bool:
    """Whether ``frame_telemetry`` writes what ``frame.encode_telemetry_fields`` writes."""
    formats = ("IiiiihhBB", "IiiiihhBBI", "IiiiihhBBIH")
    if _FMT not in formats or _CRC_BYTES not in (2, 4) or len(_SAT) != 6:
        return False
    flags, bus = "BBI" in _FMT, _FMT.endswith("H")
    rng = np.random.default_rng(1)
    out = np.zeros(frame.TELEMETRY_FRAME_BYTES, dtype=np.uint8)
    for k in range(64):
        values = rng.normal(0.0, [1e3, 1e3, 1e3, 1e3, 3.0, 0.5]) * (1e6 if k % 9 == 0 else 1)
        seq, tick, state, fault = k * 37 % 256, int(rng.integers(0, 1 << 33)), k % 5, k % 6
        bits = int(rng.integers(0, 1 << 32)) if flags else 0
        mv = int(rng.integers(0, 1 << 16)) if bus else 0
        end = frame_telemetry(out, 0, seq, tick, values, state, fault, bits, mv, TABLES)
        extra = (bits, mv / frame.BUS_SCALE)[: flags + bus]
        want = frame.encode_telemetry_fields(seq, tick, *values.tolist(), state, fault, *extra)
        if end != len(want) or bytes(out[:end]) != want:
            return False
    return True


def heartbeat_wire(msg: BoardHeartbeat) -> np.ndarray:
    """``msg``'s wire values in wire order (``frame_wire``'s input), as the codec packs
    them."""
    return np.array(frame.wire_values(msg), dtype=np.int64)


def _heartbeat_framer_ok() -> bool:
    """Whether ``frame_wire`` with :data:`HEARTBEAT_TABLES` writes ``frame.encode``'s
    ``BoardHeartbeat`` (every field an integer on the wire)."""
    if any(f.fmt not in _SIZES for f in _HB_FIELDS) or _CRC_BYTES not in (2, 4):
        return False
    rng = np.random.default_rng(2)
    out = np.zeros(HB_FRAME_BYTES, dtype=np.uint8)
    for k in range(64):
        msg = frame.from_wire_values(BoardHeartbeat, _random_wire(BoardHeartbeat, rng))
        want = frame.encode(msg, k * 37 % 256)
        end = frame_wire(out, 0, k * 37 % 256, heartbeat_wire(msg), HEARTBEAT_TABLES)
        if end != len(want) or bytes(out[:end]) != want:
            return False
    return True


def _random_wire(cls: type, rng: np.random.Generator) -> tuple[int, ...]:
    """Random wire values of a message of integer fields: a defined code for a code
    field, any value of its wire type for the others (bounds included often)."""
    values = []
    for f in frame.wire_fields(cls):
        if f.enum is not None:
            codes = [0, 1] if f.enum is bool else [int(m) for m in f.enum]
            values.append(codes[int(rng.integers(len(codes)))])
            continue
        bits = 8 * _SIZES[f.fmt]
        lo, hi = (
            (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if f.fmt.islower() else (0, (1 << bits) - 1)
        )
        pick = int(rng.integers(4))
        values.append(lo if pick == 0 else hi if pick == 1 else int(rng.integers(lo, hi + 1)))
    return tuple(values)


_FRAMER_OK: list[bool] = []


def framer_ok() -> bool:
    """True if the compiled framers reproduce ``serial_protocol.frame``'s telemetry and
    heartbeat bytes (checked once per process, on first use)."""
    if not _FRAMER_OK:
        _FRAMER_OK.append(_framer_ok() and _heartbeat_framer_ok())
    return _FRAMER_OK[0]
