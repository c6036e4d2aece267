"""The board's safety logic as pure functions: is a trajectory within the travel, what can
the board's wire fields hold, does the encoder agree with the motor's back-EMF.

The firmware (``firmware_model/firmware.py``) calls these from its command handling; they
hold no state of their own, so a test can call them directly. The per-tick checks
(:func:`sensor_mismatch_step`, the fault reaction's brake) are compiled, once for N members,
and called from ``firmware_model.tick.servo_stage`` and the bridge stage: the same code in
the firmware's Python tick and in the simulation's compiled tick (``sim/tick.py``).

Travel (docs/model.md, "Safety"): every trajectory the board is asked to execute — a
``Move``, a ``Stop``, the replan of a ``SetLimits`` that lowers the limits of a move in
progress, an interrupting ``Move`` — is planned first and checked over its *whole* extent,
not only at its end. A trajectory that would leave ``[travel_min_deg, travel_max_deg]`` is
refused (NACK ``OUT_OF_RANGE``) and the motion in progress goes on unchanged (it was checked
when it was accepted). The board never brakes at a rate other than the one asked for: a
Stop too soft to stop within the travel is refused, with the deceleration that would do
(:func:`min_stop_decel_dps2`) in the reason, and ``Stop(a_max_dps2 = 0)`` (the configured
a_max) always stops within the travel of a trajectory that was itself accepted.

An axis already outside the travel (pushed there by hand, or enabled there) may be moved
back: the allowed range is widened to include the position the new trajectory starts from,
so a trajectory may start outside and come back but never go further out than it started.
"""

from __future__ import annotations

import math

from firmware_model.kernel_cache import kernel
from planner.profile import Profile

__all__ = [
    "TRAVEL_TOL_DEG",
    "WIRE_POS_MAX_DEG",
    "brake_countdown",
    "brake_enable",
    "brake_shorts",
    "bus_voltage_screen",
    "edge_speed_dps",
    "wire_pos",
    "min_stop_decel_dps2",
    "profile_extent",
    "sensor_mismatch_step",
    "travel_end_crossed",
    "travel_refusal",
]

#: How far beyond a travel end a planned trajectory may reach and still count as within it
#: (deg; docs/protocol.md, NACK TRAVEL). It absorbs only the float64 rounding of a profile
#: evaluated in closed form: a move planned to end exactly at a travel end, interrupting
#: a motion, evaluated 1.4e-17 to 2.9e-11 deg beyond it in 87 of the 600 trajectories of
#: 300 random pairs of a move and an interrupt to a travel end
#: (travel ends 0.1 to 1e5 deg). 1e-6 deg is far above that rounding and 100 times below
#: the wire's 1e-4 deg step, so no target the wire can carry gets through because of it.
#: The targets themselves are range-checked exactly.
TRAVEL_TOL_DEG = 1e-6

#: The largest |position| an int32 wire field in 1e-4 deg can carry (docs/protocol.md).
WIRE_POS_MAX_DEG = (2**31 - 1) / 10_000.0


def wire_pos(value: float) -> float:
    """``value`` saturated to what an int32 field in 1e-4 units carries (positions in deg,
    velocities in deg/s), as the telemetry frame saturates: a reply that reports a measured
    value beyond the field's range says "at least this much" instead of failing to encode.
    """
    return min(max(value, -WIRE_POS_MAX_DEG), WIRE_POS_MAX_DEG)


def profile_extent(profile: Profile) -> tuple[float, float]:
    """The lowest and highest position ``profile`` reaches, ``(lo, hi)``, exactly.

    Positions are extreme at the phase boundaries, at the end state and where the velocity
    changes sign inside a phase (the velocity of a phase is quadratic in time, so its zeros
    come from one quadratic each). A profile that ends moving (``v1 != 0``) continues for
    ever: its extent is infinite on that side.
    """
    lo = hi = profile.p0
    ends = profile.t0[1:] + (profile.duration,) if profile.t0 else ()
    for t0, t1, p, v, a, j in zip(
        profile.t0, ends, profile.p, profile.v, profile.a, profile.j, strict=True
    ):
        dt = t1 - t0
        for tau in _velocity_zeros(v, a, j, dt):
            pos = p + tau * (v + tau * (0.5 * a + tau * j / 6.0))
            lo, hi = min(lo, pos), max(hi, pos)
        pos = p + dt * (v + dt * (0.5 * a + dt * j / 6.0))
        lo, hi = min(lo, pos), max(hi, pos)
    lo, hi = min(lo, profile.p1), max(hi, profile.p1)
    if profile.v1 > 0.0:
        hi = math.inf
    elif profile.v1 < 0.0:
        lo = -math.inf
    return lo, hi


def _velocity_zeros(v: float, a: float, j: float, dt: float) -> list[float]:
    """The times in ``(0, dt)`` where ``v + a t + j t^2 / 2`` is zero."""
    if j == 0.0:
        if a == 0.0:
            return []
        roots = [-v / a]
    else:
        disc = a * a - 2.0 * j * v
        if disc < 0.0:
            return []
        sq = math.sqrt(disc)
        roots = [(-a - sq) / j, (-a + sq) / j]
    return [t for t in roots if 0.0 < t < dt]


def travel_end_crossed(
    profile: Profile, travel_min_deg: float, travel_max_deg: float
) -> float | None:
    """The travel end ``profile`` would cross (``travel_max_deg`` or ``travel_min_deg``),
    or None if it stays within the travel: the one travel check of every trajectory.

    The allowed range is ``[travel_min_deg, travel_max_deg]`` widened to include the
    profile's start ``profile.p0`` (an axis outside the travel may come back, not go further
    out) and by :data:`TRAVEL_TOL_DEG` on each side, so that a trajectory planned to end
    exactly at a travel end is not refused for the rounding of its evaluation. Units: axis
    degrees.
    """
    lo, hi = profile_extent(profile)
    if hi > max(travel_max_deg, profile.p0) + TRAVEL_TOL_DEG:
        return travel_max_deg
    if lo < min(travel_min_deg, profile.p0) - TRAVEL_TOL_DEG:
        return travel_min_deg
    return None


def travel_refusal(profile: Profile, travel_min_deg: float, travel_max_deg: float) -> str | None:
    """Why ``profile`` may not be executed within the travel, or None if it may
    (:func:`travel_end_crossed`, in words)."""
    end = travel_end_crossed(profile, travel_min_deg, travel_max_deg)
    if end is None:
        return None
    lo, hi = profile_extent(profile)
    if end == travel_max_deg and hi > travel_max_deg:
        return f"the trajectory reaches {hi:.6g} deg > travel_max_deg {travel_max_deg:.6g}"
    return f"the trajectory reaches {lo:.6g} deg < travel_min_deg {travel_min_deg:.6g}"


def min_stop_decel_dps2(
    p_deg: float, v_dps: float, travel_min_deg: float, travel_max_deg: float
) -> float:
    """The smallest constant deceleration that stops ``(p_deg, v_dps)`` within the travel
    (trapezoid braking, ``v^2 / (2 d)`` with ``d`` the room left ahead), in deg/s^2.

    ``inf`` if there is no room left ahead (already at or beyond the limit while moving
    towards it); 0 at rest. The S-curve needs a little more (its jerk phases): this is the
    bound quoted in a NACK's reason, the planner's own stop is what is checked.
    """
    if v_dps == 0.0:
        return 0.0
    room = (travel_max_deg - p_deg) if v_dps > 0.0 else (p_deg - travel_min_deg)
    if room <= 0.0:
        return math.inf
    return v_dps * v_dps / (2.0 * room)


def edge_speed_dps(
    pos_deg: float,
    target_deg: float,
    travel_min_deg: float,
    travel_max_deg: float,
    decel_dps2: float,
) -> float:
    """The highest speed at ``pos_deg`` from which braking at ``decel_dps2`` still stops
    before the travel end that a move towards ``target_deg`` heads for:
    ``sqrt(2 * decel * room)`` (deg/s).

    A STEP move (no planner, the setpoint jumps to the target) clamps its velocity reference
    to this, so that however it is commanded it slows down as it nears an end of the travel
    instead of overshooting it; far from the ends the clamp is far above ``v_max_dps`` and
    changes nothing.
    """
    room = travel_max_deg - pos_deg if target_deg >= pos_deg else pos_deg - travel_min_deg
    return math.sqrt(2.0 * decel_dps2 * max(room, 0.0))


@kernel
def sensor_mismatch_step(
    duty, current_a, vel_dps, live, supply_v, r_ohm, emf_v_per_dps, dt_s, window_s,
    tolerance_dps, tolerance_ratio, step_max_deg, excess_deg, bus_adc, v_per_bus_count,
    bus_hold_counts, sense_spread, sense_offset_a, r_spread, winding_c, alpha_per_k,
    ambient_c,
):  # fmt: skip
    """One tick of the frozen / implausible sensor (runaway) check, for N members; updates
    ``excess_deg`` in place and returns its largest value over the live members.

    The motor's terminal equation gives a speed that needs no encoder: the back-EMF
    ``duty * supply_v - r_ohm * current_a`` over the EMF constant ``emf_v_per_dps`` (V per
    axis deg/s). Its difference from the encoder's velocity estimate ``vel_dps`` is allowed
    ``tolerance_dps + tolerance_ratio * max(|emf speed|, |vel_dps|)`` (the model's errors:
    the supply voltage, which this firmware does not measure, scales with the duty, the
    resistance with the current); what exceeds it is integrated over a leaky window of
    ``window_s`` (``e = max(0, e * (1 - dt / window) + dt * (|diff| - tolerance))``): the
    degrees the axis moved, by its back-EMF, beyond what the encoder and the tolerance
    explain; one tick adds at most ``step_max_deg`` (the firmware passes a third of the
    threshold: no single sample, e.g. one current reading of a spike, can trip it). A
    frozen encoder (with or without noise on it) reads 0 deg/s while the motor
    turns; a runaway (the position not following the current the way the model says) shows
    the same way. Integrating lets the short inductive and compute-delay transients of the
    terminal equation pass. Members not ``live`` (bridge off: the terminal voltage is not
    the duty's) restart at 0. A current against the duty (or with a duty of 0) is not a
    measurement (the high-side sense is blind to it; the law reports its model's value):
    the back-EMF speed is then the interval between the ends of 0 A and that value, and
    only a speed outside it counts.

    The bridge's voltage is ``duty`` times the bus: ``supply_v`` as configured, or, with
    ``v_per_bus_count`` > 0 (``[safety] sensor_mismatch_measured_bus``), the firmware's
    own reading of the bus in the last period, ``bus_adc * v_per_bus_count`` (a rail lifted
    by braking is then no error of the model). In either case a reading at
    ``bus_hold_counts`` or above (the BTN7971B may have locked its outputs out: the terminal
    voltage is not the duty's and the IS pin reads nothing) holds the member's excess where
    it is for that tick: a lock-out is not a sensor fault (the bus trip names it, if on).

    What the firmware does not know makes the back-EMF speed an interval, not a value
    (docs/model.md, "Safety"): the true current is the reading less the IS pin's offset,
    times the chip's k_ILIS over the firmware's ``sense_ratio`` — the offset within
    ``±sense_offset_a`` (A, as the firmware reads it), the ratio within ``1 ± sense_spread``
    — and a reading the offset alone explains may be a current against the duty the
    high-side sense cannot see (the interval is then open on that side); the winding's
    resistance lies within ``r_ohm * (1 ± r_spread)``, its upper end raised by the rise
    the firmware's thermal estimate saw since power-up (``1 + alpha_per_k * (T_est -
    ambient_c)``, ``T_est = winding_c[j]``; ``alpha_per_k = 0``: none). Only an
    encoder speed outside the interval counts, beyond the tolerance. With the three spreads
    0 the interval of a measured current is the single value of before.

    Args: ``duty, current_a, vel_dps`` float ``(N,)`` (the duty applied in the last period,
    the measured current in A); ``live`` bool ``(N,)``; ``r_ohm, emf_v_per_dps`` float
    ``(N,)``; ``excess_deg`` float ``(N,)``; ``bus_adc`` int ``(N,)`` (counts);
    ``winding_c`` float ``(N,)`` (degC, the thermal protection's winding estimate).
    """
    worst = 0.0
    keep = 1.0 - dt_s / window_s
    # The common case without the interval's two divisions: a member with no excess carried
    # whose encoder speed is within tolerance_dps of the back-EMF speed of the measured
    # current, |v - emf_dps| <= tolerance_dps, ends the tick at excess 0.0 exactly as the
    # full computation does. Why, in floating point (IEEE rounding is monotone): with the
    # spreads, the offset and alpha >= 0 and R > 0, the current's interval holds i and R's
    # holds R (their computed ends too), so the computed ri_min <= fl(R i) <= ri_max and
    # lo <= emf_dps <= hi; the computed diff is then at most fl(|v - emf_dps|) in every
    # branch; tol >= tolerance_dps (ratio >= 0): diff - tol <= 0, dt > 0, and e = 0.0.
    screen = (
        sense_spread >= 0.0 and sense_offset_a >= 0.0 and r_spread >= 0.0
        and alpha_per_k >= 0.0 and tolerance_ratio >= 0.0 and dt_s > 0.0
    )  # fmt: skip
    for j in range(duty.shape[0]):
        if not live[j] or not emf_v_per_dps[j] > 0.0:  # off, or no EMF model to check by
            excess_deg[j] = 0.0
            continue
        # The board reads the bus whichever voltage the check takes: from the lock-out
        # level up the BTN7971B may have turned its outputs off (the terminal voltage is
        # not the duty's, the IS pin reads nothing), so there is no terminal equation
        # this tick; the bus trip, if on, names the cause.
        if bus_adc[j] >= bus_hold_counts:
            continue
        bus_v = bus_adc[j] * v_per_bus_count if v_per_bus_count > 0.0 else supply_v
        v = vel_dps[j]
        ke = emf_v_per_dps[j]
        i = current_a[j]
        drive_dps = duty[j] * bus_v / ke
        emf_dps = drive_dps - r_ohm[j] * i / ke
        if screen and excess_deg[j] == 0.0 and r_ohm[j] > 0.0 and abs(v - emf_dps) <= tolerance_dps:
            excess_deg[j] = 0.0
            continue
        # The true current's interval [i_lo, i_hi] (A; open below or above if unbounded).
        open_lo = open_hi = False
        if i * duty[j] > 0.0:
            m = abs(i)
            top = (m + sense_offset_a) * (1.0 + sense_spread)
            blind = m <= sense_offset_a  # the offset alone may be all the pin reads
            bottom = 0.0 if blind else (m - sense_offset_a) * (1.0 - sense_spread)
            if i > 0.0:
                i_lo, i_hi, open_lo = bottom, top, blind
            else:
                i_lo, i_hi, open_hi = -top, -bottom, blind
        else:
            # A high-side sense cannot see a current against the duty (or with none): the
            # law's value is its model's, the true current is only known to lie between
            # 0 and about that value.
            i_lo, i_hi = min(0.0, i), max(0.0, i)
        rise = 1.0 + alpha_per_k * max(winding_c[j] - ambient_c, 0.0)
        r_lo = r_ohm[j] * (1.0 - r_spread)
        r_hi = r_ohm[j] * (1.0 + r_spread) * rise
        # R * i over both intervals (R > 0): its ends give the back-EMF speed's.
        ri_max = r_hi * i_hi if i_hi >= 0.0 else r_lo * i_hi
        ri_min = r_lo * i_lo if i_lo >= 0.0 else r_hi * i_lo
        if open_hi:  # the current unbounded above (R * i too): the speed has no lower end
            diff = v - (drive_dps - ri_min / ke)
            diff = diff if diff > 0.0 else 0.0
        elif open_lo:  # ... unbounded below: the speed has no upper end
            diff = (drive_dps - ri_max / ke) - v
            diff = diff if diff > 0.0 else 0.0
        else:
            lo, hi = drive_dps - ri_max / ke, drive_dps - ri_min / ke
            diff = lo - v if v < lo else (v - hi if v > hi else 0.0)
        tol = tolerance_dps + tolerance_ratio * max(abs(emf_dps), abs(v))
        e = excess_deg[j] * keep + min((diff - tol) * dt_s, step_max_deg)
        e = e if e > 0.0 else 0.0
        excess_deg[j] = e
        if e > worst:
            worst = e
    return worst


@kernel(inline="always")
def brake_shorts(j, brake_ticks, vel_dps, r_ohm, emf_v_per_dps, r_rise, emf_rise, cap_a):
    """Whether member ``j``'s fault-reaction brake shorts the motor now: it is braking
    (``brake_ticks[j] > 0``) and either the brake current is not capped (``cap_a <= 0``) or
    the firmware's model predicts the short's current at or below the cap, ``|k_emf,T v| <=
    R_T cap_a`` (``k_emf,T = emf_v_per_dps (1 + emf_rise)``, ``R_T = r_ohm (1 + r_rise)``:
    the current loop's model at its winding estimate; ``v``: the velocity estimate, deg/s).
    A short's current is the back-EMF over R and can only fall as the motor slows, so the
    brake holds off (the bridge off: the motor coasts) until the speed allows the cap."""
    if brake_ticks[j] <= 0:
        return False
    if cap_a <= 0.0:
        return True
    emf = abs(vel_dps[j] * emf_v_per_dps[j] * (1.0 + emf_rise[j]))
    return emf <= cap_a * r_ohm[j] * (1.0 + r_rise[j])


@kernel
def brake_countdown(brake_ticks, vel_dps, r_ohm, emf_v_per_dps, r_rise, emf_rise, cap_a):
    """One servo tick of the fault reaction's dynamic braking: each member's remaining
    braking ticks (int64 ``(N,)``, set by a trip to ``brake_s`` worth) count down to 0 while
    it shorts the motor (``brake_shorts``); a brake holding off for its current cap keeps
    them (the ``brake_s`` of shorting starts when the speed allows the cap)."""
    for j in range(brake_ticks.shape[0]):
        if brake_shorts(j, brake_ticks, vel_dps, r_ohm, emf_v_per_dps, r_rise, emf_rise, cap_a):
            brake_ticks[j] -= 1


@kernel
def brake_enable(enable, brake_ticks, vel_dps, r_ohm, emf_v_per_dps, r_rise, emf_rise, cap_a):
    """The bridge enable of one current-loop period: a member still braking after a trip
    keeps its bridge on (``enable`` bool ``(N,)``, in place) with the duty 0 the law gives
    a disabled member: both low-side switches on, the motor's back-EMF drives a braking
    current through its own resistance — unless the brake current is capped and the short
    would pass the cap (``brake_shorts``): then the bridge stays off and the motor coasts."""
    for j in range(enable.shape[0]):
        if brake_shorts(j, brake_ticks, vel_dps, r_ohm, emf_v_per_dps, r_rise, emf_rise, cap_a):
            enable[j] = True


@kernel
def bus_voltage_screen(bus_adc, live, over_counts, under_counts, samples, bus_ticks):
    """One current-loop period of the bus over/under-voltage screen, for N members: a live
    member whose bus reading (``bus_adc``, int ``(N,)``, counts of the divider's ADC
    channel) is above ``over_counts`` or below ``under_counts`` counts one more period in
    ``bus_ticks`` (int64 ``(N,)``, in place), any other restarts at 0. Returns True if a
    member reached ``samples`` periods in a row (the firmware then trips it:
    ``Firmware._current_trips``, which tells over from under by the reading).

    The thresholds are in counts, as a firmware without an FPU compares them:
    ``over_counts = floor(V_over / V_per_count)``, ``under_counts = ceil(V_under /
    V_per_count)``, so that ``reading > over_counts`` is exactly ``reading * V_per_count >
    V_over`` (and likewise under)."""
    trip = False
    for j in range(bus_adc.shape[0]):
        c = bus_adc[j]
        if live[j] and (c > over_counts or c < under_counts):
            bus_ticks[j] += 1
            if bus_ticks[j] >= samples:
                trip = True
        else:
            bus_ticks[j] = 0
    return trip
