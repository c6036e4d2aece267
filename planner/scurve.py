"""Jerk-limited 7-segment S-curve (seed 002, eqs. 2-5) from any start velocity and acceleration.

Seed 002 (Zhang et al. 2013) writes the S-curve as seven phases of constant jerk
``+J, 0, -J, 0, -J, 0, +J`` (jerk-up, constant acceleration, jerk-down, cruise, and the mirror
image to stop). Two end values of its eq. (5) are misprinted and are read here as:
``s_04 = s_03 + v_03 T_4`` (the paper repeats the s_03 line, ``s_03 + v_02 T_1 + J T_1^3/3``)
and ``s_07 = s_06 + v_06 T_7 - J T_5 T_7^2 / 2 + J T_7^3 / 6`` (printed
``s_06 + v_06 T_5 - J T_7^3 / 2``, which does not end at L); with these readings the
per-phase formulas (3)-(5) agree with this module (tests/planner/test_sampling.py) and
reproduce the paper's Table 2. Here the same shape is planned time-optimally for given limits
``|v| <= v_max``, ``|a| <= a_max``, ``|j| <= j_max`` from any start state ``(p0, v0, a0)`` to
``(p1, v1, 0)`` (``v1 != 0``: a jerk-limited segment of a queue that does not stop there):

* A *velocity pulse* is the time-optimal acceleration-limited, jerk-limited velocity change:
  the trapezoid of :mod:`planner.trapezoid` one order down (velocity in place of position,
  acceleration in place of velocity, jerk in place of acceleration), the same code. It has a
  constant-acceleration phase only if the change is large enough, so the degenerate shapes
  (no constant acceleration, no cruise, very short moves) come out by themselves; phases of
  zero length are dropped.
* The candidates (all in ``planner._kernel``, compiled with numba): family A, a pulse from
  ``(v0, a0)`` to a peak velocity ``vp`` with zero acceleration, a cruise at ``vp`` (only if
  ``|vp| == v_max``) and a pulse from ``(vp, 0)`` to ``(v1, 0)``, with ``vp`` every root of
  ``distance(vp) = p1 - p0`` bracketed on a grid of ``[-v_max, v_max]`` (plus 0, v0, v1 and
  the velocity where a0 runs out) and refined by Illinois regula falsi; family B, a first
  phase of jerk +-j_max (the acceleration dips or grows first), then one pulse to v1; family
  C (for starts beyond the limits), two opposite jerk phases, then one pulse; and for those
  starts also ruckig's brake pre-profile followed by the fastest profile from where it ends.
  The fastest candidate that passes the filter below is taken. Family A from a0 = 0 is the
  classic S-curve; the search is not a proof of optimality, so ruckig is the oracle in the
  tests: durations agree to 1e-6 (in practice to ~1e-12) on thousands of random states with
  a0 = 0 and a0 != 0, v1 = 0 and v1 != 0, and the plan is never slower than ruckig's.
* A start above v_max (a replan that lowered it) or one whose acceleration makes an excess
  unavoidable may exceed v_max only while braking back: never faster than the start's
  unavoidable excess, and within v_max for good no later than the fastest settled brake to
  v_max. ruckig's brake pre-profile is not time-optimal, so here the plan is often faster.
* ``d_max`` (a deceleration limit, as ODrive's): ``|a| <= a_max`` while the speed grows,
  ``|a| <= d_max`` while it falls. Each pulse takes the limit of what it does; a pulse that
  reverses the direction keeps the smaller limit throughout, because the acceleration is
  continuous through v = 0 where both apply (valid; not time-optimal for such pulses: the
  time-optimal pulse would change its plateau at v = 0).
* Cost: a plan is one call of the compiled search, median ~15 us and at most 47-78 us
  across runs on the loaded 2-core development machine (``benchmarks/bench_planner.py``),
  inside a 2 ms tick. The kernel loads from numba's cache once per process
  (:func:`planner.warm_up`).

"""

from __future__ import annotations

import math

from planner._checks import check_finite, check_positive, check_reaches
from planner._kernel import pulse_phases, scurve_phases
from planner.profile import Profile, build_profile

__all__ = ["plan_scurve", "plan_scurve_stop", "scurve_from_periods", "velocity_pulse"]


def velocity_pulse(
    v0: float, a0: float, v1: float, a_max: float, j_max: float
) -> list[tuple[float, float]]:
    """Fastest change of velocity from ``(v0, a0)`` to ``(v1, 0)``: ``(dt, jerk)`` segments.

    ``|a| <= a_max`` (after bringing ``|a0| > a_max`` back first), ``|j| <= j_max``.
    """
    segments, _, _ = pulse_phases(float(v0), float(a0), float(v1), float(a_max), float(j_max))
    return segments


def _cruise_of(segments: list[tuple[float, float]], v: float, a: float) -> tuple[float, float]:
    """(velocity, duration) of the zero-jerk, zero-acceleration phase in ``segments``, or
    (velocity at the last a = 0 before the end, 0) when there is none; for naming the case."""
    v_last = v
    live = [(dt, j) for dt, j in segments if dt > 0.0]
    a_scale = abs(a)
    for k, (dt, j) in enumerate(live):
        if j == 0.0 and a == 0.0:
            return v, dt
        if j != 0.0 and 0.0 < -a / j < dt:
            tau = -a / j
            v_last = v + tau * (a + 0.5 * tau * j)
        v += dt * (a + 0.5 * dt * j)
        a += dt * j
        a_scale = max(a_scale, abs(a))
        # The jerk turns round where the acceleration passes zero: a phase boundary.
        if k < len(live) - 1 and abs(a) <= 1e-12 * a_scale:
            v_last = v
    return v_last, 0.0


def plan_scurve(
    p0: float,
    p1: float,
    *,
    v_max: float,
    a_max: float,
    j_max: float,
    v0: float = 0.0,
    a0: float = 0.0,
    v1: float = 0.0,
    d_max: float | None = None,
) -> Profile:
    """Plan a jerk-limited move from ``(p0, v0, a0)`` to ``(p1, v1, 0)``.

    Args:
        p0, p1: start and target position. v0, a0: start velocity and acceleration.
        v1: end velocity, |v1| <= v_max (a segment of a queue that does not stop).
        v_max, a_max, j_max: limits, each finite and > 0.
        d_max: deceleration limit, > 0 (None: a_max): ``|a| <= a_max`` while the speed grows,
            ``|a| <= d_max`` while it falls; a velocity pulse that reverses the direction
            keeps the smaller one throughout (the acceleration is continuous through v = 0,
            where both apply).

    Returns:
        An ``"scurve"`` :class:`Profile`; its ``phases`` carry the jerk of each phase.

    Raises:
        ValueError: an argument is not finite, a limit is not > 0, or |v1| > v_max.
    """
    isfinite = math.isfinite
    if not (
        isfinite(p0)
        and isfinite(p1)
        and isfinite(v0)
        and isfinite(a0)
        and isfinite(v1)
        and isfinite(v_max)
        and isfinite(a_max)
        and isfinite(j_max)
        and v_max > 0.0
        and a_max > 0.0
        and j_max > 0.0
    ):  # the slow path names the bad argument
        check_finite(p0=p0, p1=p1, v0=v0, a0=a0, v1=v1)
        check_positive(v_max=v_max, a_max=a_max, j_max=j_max)
    if d_max is None:
        d_max = a_max
    elif not (isfinite(d_max) and d_max > 0.0):
        check_positive(d_max=d_max)
    if abs(v1) > v_max:
        raise ValueError(f"v1 = {v1!r}: |v1| must be <= v_max = {v_max!r}")
    p0, p1, v0, a0, v1 = float(p0), float(p1), float(v0), float(a0), float(v1)
    v_max, a_max, j_max, d_max = float(v_max), float(a_max), float(j_max), float(d_max)
    d = p1 - p0
    out, n, _ = scurve_phases(d, v0, a0, v1, v_max, a_max, d_max, j_max)
    segments = list(zip(out[0, :n].tolist(), out[1, :n].tolist(), strict=True))
    if all(dt <= 0.0 for dt, _ in segments):
        case = "hold"
    else:
        vp, t_cruise = _cruise_of(segments, v0, a0)
        if v0 != 0.0:
            frame = 1.0 if v0 > 0.0 else -1.0
        else:
            frame = 1.0 if d >= 0.0 else -1.0
        cruise = abs(vp) == v_max and t_cruise > 0.0
        forward = vp * frame > 0.0
        if v0 == 0.0 and a0 == 0.0 and v1 == 0.0:
            case = "classic" if cruise else "triangle"
        elif forward:
            case = "a" if cruise else "b"
        else:
            case = "d" if cruise else "c"
    prof = build_profile("scurve", case, p0, v0, a0, segments, p1, v1)
    check_reaches(prof)
    return prof


def plan_scurve_stop(
    p0: float, *, a_max: float, j_max: float, v0: float = 0.0, a0: float = 0.0
) -> Profile:
    """The shortest jerk-limited stop from ``(p0, v0, a0)``; ends at rest wherever it stops."""
    check_finite(p0=p0, v0=v0, a0=a0)
    check_positive(a_max=a_max, j_max=j_max)
    p0, v0, a0 = float(p0), float(v0), float(a0)
    segments, dist, dur = pulse_phases(v0, a0, 0.0, float(a_max), float(j_max))
    case = "stop" if dur > 0.0 else "hold"
    return build_profile("scurve", case, p0, v0, a0, segments, p0 + dist, 0.0)


def scurve_from_periods(
    length: float, v: float, dt: float, *, n_jerk: int, n_const: int, p0: float = 0.0
) -> Profile:
    """Seed 002's parameterisation: reach ``v`` in ``n_jerk`` periods of jerk-up, ``n_const``
    of constant acceleration and ``n_jerk`` of jerk-down (period ``dt``), and stop the same way.

    Gives ``j_max = v / (T_j (T_j + T_a))`` and ``a_max = j_max T_j`` with ``T_j = n_jerk dt``,
    ``T_a = n_const dt``, and plans ``plan_scurve(p0, p0 + length, ...)`` with them.
    """
    if not (isinstance(n_jerk, int) and n_jerk >= 1):
        raise ValueError(f"n_jerk = {n_jerk!r}: must be an integer >= 1")
    if not (isinstance(n_const, int) and n_const >= 0):
        raise ValueError(f"n_const = {n_const!r}: must be an integer >= 0")
    check_positive(v=v, dt=dt)
    t_j = n_jerk * dt
    t_a = n_const * dt
    j_max = v / (t_j * (t_j + t_a))
    return plan_scurve(p0, p0 + length, v_max=v, a_max=j_max * t_j, j_max=j_max)
