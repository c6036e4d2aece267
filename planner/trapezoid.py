"""Time-optimal trapezoid (velocity- and acceleration-limited) from any start velocity.

Seed 000 (Du et al. 2022): the classic zero-to-zero trapezoid and triangle (eqs. 1-7) and the
"trapezoid-like" profile from a non-zero start velocity v0 over the distance
S'_b = S_b - S_0 with its four strategies (eqs. 8-19):

====  ===============================  ==========================================
case  condition (0 <= v0 <= v_max)      shape
====  ===============================  ==========================================
a     S'_b > S_2 = (2 v_max^2 - v0^2)/(2 a_max)  accelerate, cruise at v_max, decelerate
b     S_3 = v0^2/(2 a_max) <= S'_b <= S_2        accelerate to v' < v_max, decelerate
c     -S_2 <= S'_b < S_3                          decelerate through 0 to -v', back to 0
d     S'_b < -S_2                                 decelerate, cruise at -v_max, decelerate
====  ===============================  ==========================================

(The seed prints the lower bound of case c with S_0^2 where v0^2 is meant, and eq. (18) with
S_b where S'_b is meant; both are read the second way here. Its triangle, eqs. (5)-(7), writes
v_max for the peak speed; the peak is v' = sqrt(a_max S_a), so t1 = t2 = v'/a_max and
t3 = 2 v'/a_max.)

What the paper leaves out is handled too: a negative v0 is the mirror image (the case letter
is that of the mirrored move, so "a" always means "keep going the way you were going"); a
start with |v0| > v_max first brakes at a_max down to v_max (case prefixed ``"brake+"``);
p1 == p0 with v0 != 0 is case c; a non-zero end velocity v1 (|v1| <= v_max, used by the
look-ahead) gives the same four shapes. With v0 == v1 == 0 the cases are named after eqs. 1-7:
``"classic"`` (with cruise) and ``"triangle"``; a zero-length move is ``"hold"``.

The general rule behind the four cases: with d the distance left and
d_direct = (v0 + v1) |v1 - v0| / (2 a_max) the distance of a single ramp from v0 to v1, the
fastest profile first accelerates (+a_max, then -a_max) if d >= d_direct, and first
decelerates (-a_max, then +a_max) otherwise; the peak speed is capped at v_max by a cruise.
"""

from __future__ import annotations

import math

from planner._checks import check_finite, check_positive
from planner.profile import Profile, build_profile

__all__ = ["plan_trapezoid", "plan_stop", "time_optimal_segments"]


def time_optimal_segments(
    x0: float, x1: float, v0: float, v1: float, v_max: float, a_max: float
) -> tuple[list[tuple[float, float]], bool, int, bool]:
    """The time-optimal double-integrator move from ``(x0, v0)`` to ``(x1, v1)``.

    The limits are ``|v| <= v_max`` (after an initial brake if ``|v0| > v_max``) and
    ``|a| <= a_max``; ``|v1| <= v_max`` is required. Used for positions (the trapezoid) and,
    one order down, for velocities (an acceleration-limited, jerk-limited velocity change).

    Returns:
        ``(segments, braked, sigma, cruise)``: ``segments`` is a list of ``(dt, a)``;
        ``braked`` tells whether a brake phase to v_max comes first; ``sigma`` is +1 if the
        main part accelerates first (peak above both end velocities), -1 if it decelerates
        first; ``cruise`` tells whether there is a cruise at ``sigma * v_max``.
    """
    segments: list[tuple[float, float]] = []
    braked = False
    v = v0
    d = x1 - x0
    if abs(v0) > v_max:
        s = 1.0 if v0 > 0.0 else -1.0
        dt = (abs(v0) - v_max) / a_max
        segments.append((dt, -s * a_max))
        v = s * v_max
        d -= (v0 + v) * 0.5 * dt
        braked = True
    # Distance covered by a single ramp from v to v1.
    d_direct = (v + v1) * abs(v1 - v) / (2.0 * a_max)
    # At d == d_direct the single ramp is the answer; it belongs to the "accelerate first"
    # family only if v + v1 >= 0 (otherwise that family's root is the far, slow one).
    sigma = 1 if d > d_direct or (d == d_direct and v + v1 >= 0.0) else -1
    # The peak satisfies peak^2 = sigma a d + (v^2 + v1^2)/2 >= m^2, m the end velocity
    # nearer the peak; clamp only against rounding.
    m = max(v, v1) if sigma > 0 else min(v, v1)
    peak_sq = max(sigma * a_max * d + 0.5 * (v * v + v1 * v1), m * m)
    vp = sigma * math.sqrt(peak_sq)
    cruise = abs(vp) >= v_max
    t_cruise = 0.0
    if cruise:
        vp = sigma * v_max
        ramps = sigma * (2.0 * v_max * v_max - v * v - v1 * v1) / (2.0 * a_max)
        t_cruise = max((d - ramps) / vp, 0.0)
        t_up = max(sigma * (vp - v), 0.0) / a_max
        t_down = max(sigma * (vp - v1), 0.0) / a_max
    else:
        # |vp| - sigma v without the cancellation of two near-equal speeds:
        # (peak^2 - v^2) / (|vp| + sigma v), with peak^2 - v^2 = sigma a d + (v1^2 - v^2)/2.
        rise = sigma * a_max * d + 0.5 * (v1 - v) * (v1 + v)
        fall = sigma * a_max * d + 0.5 * (v - v1) * (v + v1)
        abs_vp = abs(vp)
        sv, sv1 = sigma * v, sigma * v1
        up = rise / (abs_vp + sv) if sv > 0.0 else abs_vp - sv
        down = fall / (abs_vp + sv1) if sv1 > 0.0 else abs_vp - sv1
        t_up = max(up, 0.0) / a_max
        t_down = max(down, 0.0) / a_max
    segments.append((t_up, sigma * a_max))
    segments.append((t_cruise, 0.0))
    segments.append((t_down, -sigma * a_max))
    return segments, braked, sigma, t_cruise > 0.0


def plan_trapezoid(
    p0: float,
    p1: float,
    *,
    v_max: float,
    a_max: float,
    v0: float = 0.0,
    v1: float = 0.0,
) -> Profile:
    """Plan the fastest move from ``(p0, v0)`` to ``(p1, v1)`` with |v| <= v_max, |a| <= a_max.

    Args:
        p0, p1: start and target position (any unit, used consistently).
        v_max: velocity limit, > 0. a_max: acceleration limit, > 0.
        v0: start velocity, any finite value (|v0| > v_max brakes first).
        v1: end velocity, |v1| <= v_max.

    Returns:
        A trapezoid :class:`Profile` whose ``case`` names the shape (see the module
        docstring) and whose duration is the minimum time of the move.

    Raises:
        ValueError: an argument is not finite, a limit is not > 0, or |v1| > v_max.
    """
    isfinite = math.isfinite
    if not (
        isfinite(p0)
        and isfinite(p1)
        and isfinite(v0)
        and isfinite(v1)
        and isfinite(v_max)
        and isfinite(a_max)
        and v_max > 0.0
        and a_max > 0.0
    ):  # the slow path names the bad argument
        check_finite(p0=p0, p1=p1, v0=v0, v1=v1)
        check_positive(v_max=v_max, a_max=a_max)
    if abs(v1) > v_max:
        raise ValueError(f"v1 = {v1!r}: |v1| must be <= v_max = {v_max!r}")
    p0, p1, v0, v1 = float(p0), float(p1), float(v0), float(v1)
    v_max, a_max = float(v_max), float(a_max)
    segments, braked, sigma, cruise = time_optimal_segments(p0, p1, v0, v1, v_max, a_max)
    # The last three segments are ramp, cruise, ramp; a brake phase is never empty.
    if not (braked or segments[-1][0] > 0.0 or segments[-2][0] > 0.0 or segments[-3][0] > 0.0):
        case = "hold"
    else:
        # The case letter is read in the frame where the start velocity is >= 0 (the seed's
        # frame); from rest, in the frame where the move goes forward.
        if v0 != 0.0:
            frame = 1 if v0 > 0.0 else -1
        elif p1 != p0:
            frame = 1 if p1 > p0 else -1
        else:
            frame = 1 if v1 >= 0.0 else -1
        forward = sigma * frame > 0
        if v0 == 0.0 and v1 == 0.0:
            case = "classic" if cruise else "triangle"
        elif forward:
            case = "a" if cruise else "b"
        else:
            case = "d" if cruise else "c"
        if braked:
            case = "brake+" + case
    return build_profile("trapezoid", case, p0, v0, 0.0, segments, p1, v1)


def plan_stop(p0: float, *, a_max: float, v0: float = 0.0) -> Profile:
    """The shortest stop from ``(p0, v0)``: decelerate at ``a_max`` to rest.

    The end position is wherever the stop ends, ``p0 + v0 |v0| / (2 a_max)``; case ``"stop"``
    (``"hold"`` if already at rest).
    """
    check_finite(p0=p0, v0=v0)
    check_positive(a_max=a_max)
    p0, v0, a_max = float(p0), float(v0), float(a_max)
    dt = abs(v0) / a_max
    p1 = p0 + 0.5 * v0 * dt
    acc = -a_max if v0 > 0.0 else a_max
    case = "stop" if dt > 0.0 else "hold"
    return build_profile("trapezoid", case, p0, v0, 0.0, [(dt, acc)], p1, 0.0)
