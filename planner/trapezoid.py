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

from planner._checks import check_finite, check_positive, check_reaches
from planner._kernel import trapezoid_phases
from planner.profile import Profile, build_profile

__all__ = ["plan_trapezoid", "plan_stop"]


def plan_trapezoid(
    p0: float,
    p1: float,
    *,
    v_max: float,
    a_max: float,
    v0: float = 0.0,
    v1: float = 0.0,
    d_max: float | None = None,
) -> Profile:
    """Plan the fastest move from ``(p0, v0)`` to ``(p1, v1)`` with |v| <= v_max, |a| <= a_max.

    Args:
        p0, p1: start and target position (any unit, used consistently).
        v_max: velocity limit, > 0. a_max: acceleration limit, > 0.
        v0: start velocity, any finite value (|v0| > v_max brakes first, at d_max).
        v1: end velocity, |v1| <= v_max.
        d_max: deceleration limit, > 0 (None: a_max). With it ``|a| <= a_max`` while the
            speed |v| grows and ``|a| <= d_max`` while it falls, as ODrive's accel_limit and
            decel_limit; a ramp through zero velocity slows at d_max down to 0 and speeds
            up at a_max after (two phases). Still time-optimal.

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
    if d_max is None:
        d_max = a_max
    elif not (isfinite(d_max) and d_max > 0.0):
        check_positive(d_max=d_max)
    if abs(v1) > v_max:
        raise ValueError(f"v1 = {v1!r}: |v1| must be <= v_max = {v_max!r}")
    p0, p1, v0, v1 = float(p0), float(p1), float(v0), float(v1)
    v_max, a_max, d_max = float(v_max), float(a_max), float(d_max)
    segments, sigma, cruise, braked = trapezoid_phases(p0, p1, v0, v1, v_max, a_max, d_max)
    if not (braked or max(segments)[0] > 0.0):  # max() compares the durations first
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
    prof = build_profile("trapezoid", case, p0, v0, 0.0, segments, p1, v1)
    check_reaches(prof)
    return prof


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
