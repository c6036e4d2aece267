"""Continuous-path (CP) velocity look-ahead over a polyline (seed 001), batch and streaming.

Seed 001 gives each junction i (between segments i and i+1) a speed V_i, the minimum of

1. the forward limit ``V_i <= sqrt(V_{i-1}^2 + 2 a l_i)`` (what acceleration can reach);
2. the corner limit ``2 V_i sin(alpha_i / 2) <= a T`` (alpha_i the change of direction, T the
   interpolation period: the direction turns within one period at bounded acceleration);
3. the backward limit ``V_i <= sqrt(V_{i+1}^2 + 2 a l_{i+1})``, taken over as many segments as
   it takes to stop (``v_max^2 / (2 a)``), i.e. a full backward pass from the end at rest;
4. ``V_i <= v_max``;
5. optionally the contour-error limit ``V_i <= 2 e / (T tan(theta_i / 2))``.

Then each segment is planned from (V_b, V_e, V_m, l) (:func:`plan_segment`): time-optimally
by default, or in the seed's seven literal cases with ``optimal=False``. The corner and
contour caps are computed from ``|u2 - u1| = 2 sin(alpha/2)`` and
``|u2 + u1| = 2 cos(alpha/2)`` (u the unit directions), accurate at every angle.

Because the forward and backward passes bound every junction by its neighbours, every
segment has ``l >= |V_e^2 - V_b^2| / (2 a)``: the seed's "l < l_i, the look-ahead was wrong,
stop the machine" cannot happen (the segment planner still checks and raises ``ValueError``
if handed such a segment directly).

In one dimension (the turntable's multi-waypoint programs) the velocity is one continuous
number, so a reversal (a 180-degree corner) must pass through zero: the junction speed there
is 0. Same-direction waypoints are passed through without slowing down.

The streaming form, :class:`LookaheadQueue`, keeps a bounded window of segments, like grbl's
block buffer or Klipper's look-ahead queue: it always assumes the path stops at the end of
what it holds, so the machine can always stop; a segment is released once the path queued
after it is long enough to stop from v_max (its end speed can no longer change), or when the
window is full (then with the conservative speed), or on :meth:`LookaheadQueue.flush`. When
the window holds the whole path it gives exactly the batch result.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from planner._checks import check_finite, check_positive
from planner.profile import Profile, build_profile

__all__ = [
    "LookaheadQueue",
    "PathPlan",
    "PathSegment",
    "junction_speeds",
    "plan_path",
    "plan_program",
    "plan_segment",
]

Array = npt.NDArray[np.float64]

# Relative tolerance for rounding in l >= |V_e^2 - V_b^2| / (2 a).
_ROUND = 1e-9


def plan_segment(
    length: float, v_b: float, v_e: float, v_m: float, a_max: float, *, optimal: bool = True
) -> Profile:
    """Seed 001, section 4: plan one segment of ``length`` from speed v_b to v_e.

    With ``l_e = (2 V_m^2 - V_b^2 - V_e^2) / (2 a)`` and ``l_i = |V_b^2 - V_e^2| / (2 a)``:

    ====  =====================================  ============================
    case  condition                              shape
    ====  =====================================  ============================
    6     l >= l_e, V_e < V_m                    accelerate to V_m, cruise, decelerate
    5     l >= l_e, V_e == V_m                   accelerate to V_m, cruise
    4     l_i < l < l_e, V_b > V_e               cruise at V_b, decelerate
    3     l_i < l < l_e, V_b < V_e               accelerate to V_e, cruise
    2     l == l_i, V_b > V_e                    decelerate all the way
    1     l == l_i, V_b < V_e                    accelerate all the way
    7     l_i < l < l_e, V_b == V_e == 0         accelerate, decelerate (peak < V_m)
    ====  =====================================  ============================

    The seed leaves out ``l < l_e`` with ``V_b == V_e > 0``: that is a cruise (case 4 with no
    deceleration). Speeds are >= 0 along the path; the profile's position is the arc length
    from 0 to ``length``. Its ``case`` is ``"1"``..``"7"``.

    ``optimal=True`` (the default) plans the time-optimal segment: the seed's cases 3 and 4
    crawl the whole segment at the lower end speed (a corner capped at 0.2 speed units makes
    a 1-unit segment at a_max = 1 take 5 s instead of 2), so every segment with
    ``l_i < l < l_e`` is planned as case 7 for any end speeds: accelerate to the peak
    ``sqrt(a l + (V_b^2 + V_e^2) / 2)`` (above both ends, below V_m) and decelerate.
    Cases 1, 2, 5 and 6 are already time-optimal. ``optimal=False`` keeps the seed's
    literal cases 3, 4 and 7.

    Raises:
        ValueError: ``l < l_i`` (beyond rounding): the end speed cannot be reached, which a
            correct look-ahead never produces.
    """
    check_finite(length=length, v_b=v_b, v_e=v_e)
    check_positive(v_m=v_m, a_max=a_max)
    if (
        length < 0.0
        or v_b < 0.0
        or v_e < 0.0
        or v_b > v_m * (1 + _ROUND)
        or v_e > v_m * (1 + _ROUND)
    ):
        raise ValueError(
            f"segment (length, v_b, v_e, v_m) = {(length, v_b, v_e, v_m)!r}: need length >= 0 "
            "and 0 <= v_b, v_e <= v_m"
        )
    v_b, v_e = min(v_b, v_m), min(v_e, v_m)
    two_a = 2.0 * a_max
    l_e = (2.0 * v_m * v_m - v_b * v_b - v_e * v_e) / two_a
    l_i = abs(v_b * v_b - v_e * v_e) / two_a
    # Rounding of the squared speeds (which the look-ahead's sqrt chain cannot avoid) and of
    # the lengths: within this, l == l_i.
    tol = _ROUND * max(length, l_i) + 8.0 * math.ulp(max(v_b * v_b, v_e * v_e)) / two_a
    if length < l_i - tol:
        raise ValueError(
            f"length = {length!r}: shorter than l_i = {l_i!r} needed to go from "
            f"v_b = {v_b!r} to v_e = {v_e!r}; the look-ahead was wrong, stop the machine"
        )
    segments: list[tuple[float, float]]
    if optimal and l_i + tol < length < l_e:
        # peak^2 - V^2 without cancelling two near-equal squares: a l + (V_o^2 - V^2) / 2.
        peak = math.sqrt(a_max * length + 0.5 * (v_b * v_b + v_e * v_e))
        rise = (a_max * length + 0.5 * (v_e - v_b) * (v_e + v_b)) / (peak + v_b)
        fall = (a_max * length + 0.5 * (v_b - v_e) * (v_b + v_e)) / (peak + v_e)
        segments = [(max(rise, 0.0) / a_max, a_max), (max(fall, 0.0) / a_max, -a_max)]
        return build_profile("trapezoid", "7", 0.0, v_b, 0.0, segments, length, v_e)
    if length >= l_e:
        t_up = (v_m - v_b) / a_max
        t_down = (v_m - v_e) / a_max
        t_cruise = (length - l_e) / v_m
        segments = [(t_up, a_max), (t_cruise, 0.0), (t_down, -a_max)]
        case = "5" if v_e == v_m else "6"
    elif v_b == v_e == 0.0:
        peak = math.sqrt(a_max * length)
        segments = [(peak / a_max, a_max), (peak / a_max, -a_max)]
        case = "7"
    elif length <= l_i + tol:
        acc = a_max if v_e > v_b else -a_max
        segments = [(abs(v_e - v_b) / a_max, acc)]
        case = "1" if v_e > v_b else "2"
    elif v_b >= v_e:
        # Cruise at v_b, then decelerate (so that a stop is at the very end).
        t_down = (v_b - v_e) / a_max
        t_cruise = (length - l_i) / v_b
        segments = [(t_cruise, 0.0), (t_down, -a_max)]
        case = "4"
    else:
        t_up = (v_e - v_b) / a_max
        t_cruise = (length - l_i) / v_e
        segments = [(t_up, a_max), (t_cruise, 0.0)]
        case = "3"
    return build_profile("trapezoid", case, 0.0, v_b, 0.0, segments, length, v_e)


def _corner_cap(
    u_in: Array, u_out: Array, a_max: float, period: float, contour_error: float | None
) -> float:
    """Speed cap at a junction from the corner limit (and the contour-error limit).

    ``2 sin(alpha/2) = |u_out - u_in|`` and ``2 cos(alpha/2) = |u_out + u_in|`` for unit
    directions: both are accurate to rounding for every angle, where ``sqrt((1 -+ cos)/2)``
    loses all digits near a straight line (a 3e-7 rad kink was capped 0.04 % too fast) and
    near a hairpin (a 1e-9 residue instead of 0 made a streaming plan crawl for years).
    """
    chord = float(np.linalg.norm(u_out - u_in))  # 2 sin(alpha / 2)
    if u_in.shape[0] == 1:
        # One dimension: same direction passes, a reversal must stop.
        return math.inf if chord == 0.0 else 0.0
    if chord == 0.0:
        return math.inf
    cap = a_max * period / chord
    if contour_error is not None:
        # V <= 2 e / (T tan(alpha/2)), tan(alpha/2) = |u_out - u_in| / |u_out + u_in|.
        cap = min(cap, 2.0 * contour_error * float(np.linalg.norm(u_out + u_in)) / (period * chord))
    return cap


def junction_speeds(
    lengths: list[float] | Array,
    caps: list[float] | Array,
    *,
    v_max: float,
    a_max: float,
    v_start: float = 0.0,
    v_end: float = 0.0,
) -> list[float]:
    """Junction speeds ``V_0..V_M`` for segments of ``lengths`` (M of them).

    Args:
        lengths: segment lengths, shape ``(M,)``, each > 0.
        caps: the corner/contour cap at each inner junction, shape ``(M - 1,)``.
        v_start, v_end: speed at the first and last point (<= v_max).

    Returns:
        ``M + 1`` speeds: the minimum of the seed's limits (forward, corner, backward over the
        whole rest of the path, v_max, contour).
    """
    m = len(lengths)
    if m == 0:
        return [v_start]  # a single point: nothing to plan
    two_a = 2.0 * a_max
    speeds = [v_start] + [min(v_max, float(c)) for c in caps] + [v_end]
    if len(speeds) != m + 1:
        raise ValueError(f"caps has {len(caps)} entries: need len(lengths) - 1 = {m - 1}")
    for i in range(m - 1, -1, -1):  # backward: able to stop at the end
        speeds[i] = min(speeds[i], math.sqrt(speeds[i + 1] ** 2 + two_a * lengths[i]))
    for i in range(1, m + 1):  # forward: reachable from the start
        speeds[i] = min(speeds[i], math.sqrt(speeds[i - 1] ** 2 + two_a * lengths[i - 1]))
    return speeds


@dataclass(frozen=True, eq=False)
class PathSegment:
    """One planned segment: ``start + direction * s(t)`` for ``t`` in ``[t_start, t_end]``.

    ``profile`` is the arc-length profile ``s(t - t_start)`` (from 0 to ``length``).
    """

    start: Array
    direction: Array
    length: float
    t_start: float
    profile: Profile

    @property
    def t_end(self) -> float:
        return self.t_start + self.profile.duration


@dataclass(frozen=True, eq=False)
class PathPlan:
    """A planned polyline: segments back to back in time, speed continuous at junctions."""

    segments: tuple[PathSegment, ...]
    speeds: tuple[float, ...]
    end: Array

    @property
    def duration(self) -> float:
        return self.segments[-1].t_end if self.segments else 0.0

    def at(self, t: float | Array) -> tuple[Array, Array, Array]:
        """Position, velocity and acceleration vectors at time(s) ``t``.

        Returns arrays of shape ``t.shape + (N,)``. Before 0 the path holds its first point,
        after the end its last one. Across a corner the direction (not the speed) jumps.
        """
        t_arr = np.asarray(t, dtype=float)
        n_dim = self.end.shape[0]
        pos = np.broadcast_to(self.end, t_arr.shape + (n_dim,)).copy()
        vel = np.zeros(t_arr.shape + (n_dim,))
        acc = np.zeros(t_arr.shape + (n_dim,))
        if not self.segments:
            return pos, vel, acc
        starts = np.array([seg.t_start for seg in self.segments])
        idx = np.clip(np.searchsorted(starts, t_arr, side="right") - 1, 0, len(starts) - 1)
        inside = (t_arr >= 0.0) & (t_arr < self.duration)
        for k, seg in enumerate(self.segments):
            mask = inside & (idx == k)
            if not np.any(mask):
                continue
            s, ds, dds = seg.profile.at(t_arr[mask] - seg.t_start)
            pos[mask] = seg.start + np.multiply.outer(s, seg.direction)
            vel[mask] = np.multiply.outer(ds, seg.direction)
            acc[mask] = np.multiply.outer(dds, seg.direction)
        pos[t_arr < 0.0] = self.segments[0].start
        return pos, vel, acc


def _as_points(points: Array | list) -> Array:
    pts = np.asarray(points, dtype=float)
    if pts.ndim == 1:
        pts = pts[:, None]
    if pts.ndim != 2 or pts.shape[0] < 1:
        raise ValueError(f"points shape = {pts.shape!r}: need (M + 1, N) with M >= 0")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points: must all be finite")
    # Repeated points (or points so close that the length underflows) make zero-length
    # segments with no direction: drop them.
    kept = [pts[0]]
    for p in pts[1:]:
        if float(np.linalg.norm(p - kept[-1])) > 0.0:
            kept.append(p)
    return np.array(kept)


def _geometry(pts: Array) -> tuple[Array, Array]:
    diffs = np.diff(pts, axis=0)
    lengths = np.linalg.norm(diffs, axis=1)
    dirs = diffs / lengths[:, None] if len(lengths) else diffs
    return lengths, dirs


def _assemble(
    pts: Array,
    lengths: Array,
    dirs: Array,
    speeds: list[float],
    v_max: float,
    a_max: float,
    optimal: bool,
) -> list[PathSegment]:
    segs = []
    t = 0.0
    for i in range(len(lengths)):
        prof = plan_segment(
            float(lengths[i]), speeds[i], speeds[i + 1], v_max, a_max, optimal=optimal
        )
        segs.append(PathSegment(pts[i].copy(), dirs[i].copy(), float(lengths[i]), t, prof))
        t += prof.duration
    return segs


def _check_limits(v_max: float, a_max: float, period: float, contour_error: float | None) -> None:
    check_positive(v_max=v_max, a_max=a_max, period=period)
    if contour_error is not None:
        check_positive(contour_error=contour_error)


def plan_path(
    points: Array | list,
    *,
    v_max: float,
    a_max: float,
    period: float,
    contour_error: float | None = None,
    optimal: bool = True,
) -> PathPlan:
    """Batch look-ahead and per-segment planning of a polyline, at rest at both ends.

    Args:
        points: waypoints, shape ``(M + 1, N)`` (or ``(M + 1,)`` for one dimension).
        v_max, a_max: path speed and acceleration limits. period: the interpolation
            period T of the corner limit. contour_error: e of the optional contour limit.
        optimal: plan segments time-optimally (the default) or in the seed's literal cases
            3, 4 and 7 (``False``; see :func:`plan_segment`); the junction speeds are the
            same either way.
    """
    _check_limits(v_max, a_max, period, contour_error)
    pts = _as_points(points)
    lengths, dirs = _geometry(pts)
    caps = [
        _corner_cap(dirs[i], dirs[i + 1], a_max, period, contour_error)
        for i in range(len(lengths) - 1)
    ]
    speeds = junction_speeds(lengths, caps, v_max=v_max, a_max=a_max)
    segs = _assemble(pts, lengths, dirs, speeds, v_max, a_max, optimal)
    return PathPlan(tuple(segs), tuple(speeds), pts[-1].copy())


def plan_program(
    waypoints: list[float] | Array,
    *,
    v_max: float,
    a_max: float,
    period: float = 0.002,
    optimal: bool = True,
) -> PathPlan:
    """A 1-D turntable program: visit ``waypoints`` in order, stopping only at reversals.

    Same-direction waypoints are passed at speed; where the direction reverses the
    turntable comes to rest. ``period`` only matters in more than one dimension.
    """
    return plan_path(
        np.asarray(waypoints, dtype=float)[:, None],
        v_max=v_max,
        a_max=a_max,
        period=period,
        optimal=optimal,
    )


class LookaheadQueue:
    """Streaming look-ahead over a bounded window of segments.

    ``append(point)`` adds the segment from the previous point; ``pop_ready()`` returns the
    segments whose speeds are final; ``flush()`` ends the path (at rest) and returns the rest.
    The queue always plans as if the path stopped at the end of its window, so whatever it
    has released can be followed by a stop.

    Args:
        start: the first point, shape ``(N,)`` (or a float for one dimension).
        window: the most segments held (>= 1).
        optimal: plan segments time-optimally (default) or in the seed's literal cases
            (see :func:`plan_segment`).
    """

    def __init__(
        self,
        start: Array | list | float,
        *,
        v_max: float,
        a_max: float,
        period: float,
        window: int = 32,
        contour_error: float | None = None,
        optimal: bool = True,
    ) -> None:
        _check_limits(v_max, a_max, period, contour_error)
        if not (isinstance(window, int) and window >= 1):
            raise ValueError(f"window = {window!r}: must be an integer >= 1")
        self.v_max, self.a_max, self.period = float(v_max), float(a_max), float(period)
        self.contour_error = contour_error
        self.optimal = optimal
        self.window = window
        self._last = np.atleast_1d(np.asarray(start, dtype=float)).copy()
        if not np.all(np.isfinite(self._last)):
            raise ValueError(f"start = {start!r}: must be finite")
        # (start, dir, length, the segment's speed limit, at rest at its end)
        self._pending: deque[tuple[Array, Array, float, float, bool]] = deque()
        self._v_in = 0.0  # speed at the start of the first pending segment (final)
        self._t = 0.0
        self._stop_distance = v_max * v_max / (2.0 * a_max)

    def __len__(self) -> int:
        return len(self._pending)

    @property
    def v_in(self) -> float:
        """The speed the first pending segment starts with (final: the released segments
        end at it). A queue that takes over a path already moving (the board replanning
        the block in progress) sets it before appending; it must be >= 0 and reachable."""
        return self._v_in

    @v_in.setter
    def v_in(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"v_in = {value!r}: must be finite and >= 0")
        self._v_in = value

    def append(
        self, point: Array | list | float, *, v_max: float | None = None, stop: bool = False
    ) -> list[PathSegment]:
        """Queue the segment to ``point``; returns segments forced out by a full window.

        Args:
            v_max: this segment's own speed limit (None: the queue's ``v_max``; never above
                it); its junctions are capped at the lower of the two segments' limits.
            stop: come to rest at ``point`` (a dwell there), whatever follows.
        """
        p = np.atleast_1d(np.asarray(point, dtype=float))
        if p.shape != self._last.shape or not np.all(np.isfinite(p)):
            raise ValueError(f"point = {point!r}: need a finite point of shape {self._last.shape}")
        v_seg = self.v_max if v_max is None else float(v_max)
        if not 0.0 < v_seg < math.inf:
            raise ValueError(f"v_max = {v_max!r}: must be positive and finite")
        v_seg = min(v_seg, self.v_max)
        diff = p - self._last
        length = float(np.linalg.norm(diff))
        if length == 0.0:
            return []
        self._pending.append((self._last.copy(), diff / length, length, v_seg, bool(stop)))
        self._last = p.copy()
        out = []
        while len(self._pending) > self.window:
            out.extend(self._release(1))
        return out

    def _speeds(self) -> list[float]:
        pend = self._pending
        lengths = [seg[2] for seg in pend]
        dirs = [seg[1] for seg in pend]
        caps = [
            0.0
            if pend[i][4]
            else min(
                _corner_cap(dirs[i], dirs[i + 1], self.a_max, self.period, self.contour_error),
                pend[i][3],
                pend[i + 1][3],
            )
            for i in range(len(dirs) - 1)
        ]
        return junction_speeds(
            lengths, caps, v_max=self.v_max, a_max=self.a_max, v_start=self._v_in, v_end=0.0
        )

    def _release(self, count: int) -> list[PathSegment]:
        speeds = self._speeds()
        out = []
        for k in range(count):
            start, direction, length, v_seg, _ = self._pending.popleft()
            prof = plan_segment(
                length, speeds[k], speeds[k + 1], v_seg, self.a_max, optimal=self.optimal
            )
            out.append(PathSegment(start, direction, length, self._t, prof))
            self._t += prof.duration
        self._v_in = speeds[count]
        return out

    def pop_ready(self) -> list[PathSegment]:
        """Release the segments whose end speed can no longer change.

        A junction's speed is final once the path queued after it is at least the stopping
        distance ``v_max^2 / (2 a_max)`` long: no later segment can lower it.
        """
        after = sum(seg[2] for seg in self._pending)
        ready = 0
        for _, _, length, _, _ in self._pending:
            after -= length
            if after >= self._stop_distance:
                ready += 1
            else:
                break
        return self._release(ready) if ready else []

    def release(self, count: int = 1) -> list[PathSegment]:
        """Release the first ``count`` pending segments now, with the speeds planned for
        stopping at the end of the window (what a machine entering them must commit to)."""
        count = min(count, len(self._pending))
        return self._release(count) if count > 0 else []

    def preview(self) -> list[Profile]:
        """The pending segments' arc-length profiles as :meth:`flush` would plan them (at
        rest at the end of the window), without releasing anything."""
        if not self._pending:
            return []
        speeds = self._speeds()
        return [
            plan_segment(seg[2], speeds[k], speeds[k + 1], seg[3], self.a_max,
                         optimal=self.optimal)
            for k, seg in enumerate(self._pending)
        ]  # fmt: skip

    def pending(self) -> list[tuple[Array, float, bool]]:
        """The pending segments as ``(end point, speed limit, stop at the end)``."""
        return [(seg[0] + seg[1] * seg[2], seg[3], seg[4]) for seg in self._pending]

    def flush(self) -> list[PathSegment]:
        """End the path at rest at the last point; release every pending segment."""
        return self._release(len(self._pending)) if self._pending else []

    @property
    def end_point(self) -> Array:
        return self._last.copy()
