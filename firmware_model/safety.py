"""The board's safety logic as pure functions: is a trajectory within the travel, and what
can the board's wire fields hold.

The firmware (``firmware_model/firmware.py``) calls these from its command handling; they
hold no state of their own, so a test can call them directly.

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

from planner.profile import Profile

__all__ = [
    "WIRE_POS_MAX_DEG",
    "edge_speed_dps",
    "wire_pos",
    "min_stop_decel_dps2",
    "profile_extent",
    "travel_refusal",
]

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


def travel_refusal(profile: Profile, travel_min_deg: float, travel_max_deg: float) -> str | None:
    """Why ``profile`` may not be executed within the travel, or None if it may.

    The allowed range is ``[travel_min_deg, travel_max_deg]`` widened to include the
    profile's start ``profile.p0`` (an axis outside the travel may come back, not go further
    out). Units: axis degrees.
    """
    lo_allowed = min(travel_min_deg, profile.p0)
    hi_allowed = max(travel_max_deg, profile.p0)
    lo, hi = profile_extent(profile)
    if hi > hi_allowed:
        return f"the trajectory reaches {hi:.6g} deg > travel_max_deg {travel_max_deg:.6g}"
    if lo < lo_allowed:
        return f"the trajectory reaches {lo:.6g} deg < travel_min_deg {travel_min_deg:.6g}"
    return None


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
