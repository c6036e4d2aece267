"""The board's point stream (issue #14 §1, seed 002): positions at a fixed period.

The PC opens a stream (``StreamControl`` START: the period ``h``, the interpolation, the
prefill) and sends points ``k = 1, 2, ...`` (``StreamPoints``); point 0 is where the axis
rests at START. Once ``prefill`` points are held the axis starts moving at board time
``t0``: point k is due at ``t0 + k h`` and between two points the setpoint is

* ``Interp.LINEAR``: the straight line, one constant-velocity phase per period
  (``v = (p_{k+1} - p_k) / h``; the velocity steps at each point, as a CANopen drive's
  linear interpolated-position mode);
* ``Interp.CUBIC`` (PVT): the cubic Hermite through both points' positions and velocities,
  one constant-jerk phase per period (``a_k = (6 dp - h (4 v_k + 2 v_{k+1})) / h^2``,
  ``j = (a_{k+1}^- - a_k) / h``). A trajectory whose phases are at most cubic and change at
  the points (seed 002's trapezoid and S-curve sampled every period) is reproduced exactly.

What the axis follows is one :class:`planner.profile.Profile`: the periods from the one in
progress to the last point held, then a deceleration to rest at ``a_max`` from the last
point's velocity. So the setpoint source is the one the compiled tick evaluates for a
``Move`` (no per-tick Python), and the axis can always stop: if the next point comes too
late (an *underrun*: the time of the last point held has passed before END), the stop
already planned is what happens; the stream is closed, the underrun counted and
``StreamState.UNDERRUN`` reported (``StreamStatus``, ``BoardHeartbeat``). END asks for the
same stop without the flag.

Every point is checked before any of a frame is taken (field-level refusals): the travel,
|velocity| <= v_max and |acceleration| <= a_max of the segment it ends (LINEAR: the velocity
change from the previous segment, at most ``a_max h``; CUBIC: the cubic's accelerations at
both ends), each with the allowance of the wire's position step (1e-4 deg: ``q / h`` in
velocity, ``6 q / h^2`` in acceleration, q = half a step), and the whole profile, stop
included, within the travel. Between two CUBIC points the velocity may exceed the larger of
the points' by at most ``a_max h / 4`` (the acceleration is linear there); the points
themselves are held to v_max.

Pure bookkeeping: no I/O, no exceptions escape to the board.
"""

from __future__ import annotations

import math

from firmware_model import safety
from planner.profile import Profile
from serial_protocol.messages import Interp, NackCode, StreamState

__all__ = ["PERIOD_MAX_S", "PERIOD_MIN_S", "STREAM_CAPACITY", "PointStream"]

#: Points the board holds ahead of the axis (HelloReply.stream_points).
STREAM_CAPACITY = 64
#: Shortest and longest period between points (s): one 500 Hz tick to 1 s.
PERIOD_MIN_S = 0.002
PERIOD_MAX_S = 1.0
# Half the wire's position step (deg): the quantisation the checks allow for.
_Q_DEG = 0.5e-4
# Relative rounding allowance of the checks.
_REL = 1e-9

# A refusal: (code, field name or None, limit in the field's unit).
Refusal = tuple[NackCode, str | None, float]


class PointStream:
    """The stream's points and state; see the module docstring.

    Attributes:
        state: the ``StreamState``.
        underruns: underruns since boot.
        start_pos_deg: point 0 (where the axis rested at START).
        t0_s: board time of point 0 once moving (None while filling).
    """

    def __init__(self, capacity: int = STREAM_CAPACITY) -> None:
        self.capacity = capacity
        self.underruns = 0
        self.state = StreamState.IDLE
        self.start_pos_deg = 0.0
        self.t0_s: float | None = None
        self.period_s = PERIOD_MIN_S
        self.interp = Interp.LINEAR
        self._prefill = 1
        self._v_max = self._a_max = 0.0
        self._travel = (-math.inf, math.inf)
        self._pos: list[float] = []  # points base .. base + len - 1
        self._vel: list[float] = []
        self._base = 0
        self._t_end_s = math.inf  # when the axis is at rest after END

    # ------------------------------------------------------------------ state
    def active(self) -> bool:
        """True while the stream is open (filling, running or ended and still moving)."""
        return self.state in (StreamState.FILLING, StreamState.RUNNING, StreamState.ENDED)

    @property
    def next_index(self) -> int:
        """The index the next point must carry."""
        return self._base + len(self._pos)

    def _segment(self, t_s: float) -> int:
        """Index of the point that starts the period in progress at ``t_s``."""
        if self.t0_s is None:
            return self._base
        return max(self._base, int(math.floor((t_s - self.t0_s) / self.period_s + 1e-9)))

    def update(self, t_s: float) -> None:
        """Account for time: an underrun if the last point's time has passed before END;
        points already passed are forgotten."""
        if self.state is StreamState.ENDED and t_s >= self._t_end_s:
            self.state = StreamState.IDLE
        if self.t0_s is None or not self._pos:
            return
        last = self.next_index - 1
        if self.state is StreamState.RUNNING and t_s > self.t0_s + last * self.period_s + 1e-9:
            self.state = StreamState.UNDERRUN
            self.underruns += 1
        # keep the point before the period in progress too (LINEAR checks the next point
        # against the last segment's velocity)
        s = min(self._segment(t_s), last) - 1
        if s > self._base:
            drop = s - self._base
            del self._pos[:drop], self._vel[:drop]
            self._base = s

    def held(self, t_s: float) -> int:
        """Points held that the axis has not reached yet."""
        self.update(t_s)
        if not self.active() or not self._pos:
            return 0
        if self.t0_s is None:
            return len(self._pos) - 1
        return max(0, self.next_index - 1 - self._segment(t_s))

    def free(self, t_s: float) -> int:
        """Points that may be sent now (0 unless the stream takes points)."""
        self.update(t_s)
        if self.state not in (StreamState.FILLING, StreamState.RUNNING):
            return 0
        return max(0, self.capacity - self.held(t_s))

    def clear(self) -> None:
        """Close the stream (the caller stops the axis): Stop, Move, disable, a fault."""
        self.state = StreamState.IDLE
        self._pos, self._vel, self._base, self.t0_s = [], [], 0, None
        self._t_end_s = math.inf

    # ------------------------------------------------------------------ commands
    def start(
        self,
        p_deg: float,
        period_s: float,
        interp: Interp,
        prefill: int,
        *,
        v_max_dps: float,
        a_max_dps2: float,
        travel_deg: tuple[float, float],
    ) -> None:
        """Open a stream from rest at ``p_deg`` (the caller checked the fields)."""
        self.clear()
        self.state = StreamState.FILLING
        self.start_pos_deg = p_deg
        self.period_s, self.interp, self._prefill = period_s, Interp(interp), prefill
        self._v_max, self._a_max = v_max_dps, a_max_dps2
        self._travel = travel_deg
        self._pos, self._vel, self._base = [p_deg], [0.0], 0

    def check(self, t_s: float, first_index: int, points: tuple[tuple[float, float], ...]
              ) -> Refusal | None:  # fmt: skip
        """Why the points may not be taken now (a refusal naming the field), or None."""
        self.update(t_s)
        if self.state not in (StreamState.FILLING, StreamState.RUNNING):
            return NackCode.NO_STREAM, None, float(self.state)
        n = len(points)
        if first_index != self.next_index:
            code = NackCode.TOO_LOW if first_index < self.next_index else NackCode.TOO_HIGH
            return code, "first_index", float(self.next_index)
        if n > self.free(t_s):
            return NackCode.QUEUE_FULL, "count", float(self.capacity)
        h = self.period_s
        p_prev, v_prev = self._pos[-1], self._vel[-1]
        seg_prev = self._last_segment_velocity()
        lo_t, hi_t = self._travel
        v_max, a_max = self._v_max, self._a_max
        v_tol = v_max * (1 + _REL) + _Q_DEG / h
        for k, (p, v) in enumerate(points):
            pos_f, vel_f = f"pos{k}_deg", f"vel{k}_dps"
            if p < lo_t:
                return NackCode.TOO_LOW, pos_f, lo_t
            if p > hi_t:
                return NackCode.TOO_HIGH, pos_f, hi_t
            if self.interp is Interp.LINEAR:
                seg = (p - p_prev) / h
                # the reachable band: |v| <= v_max and |v - v_prev_segment| <= a_max h
                dv = a_max * h * (1 + _REL) + 2 * _Q_DEG / h
                v_hi = min(v_tol, seg_prev + dv)
                v_lo = max(-v_tol, seg_prev - dv)
                if seg > v_hi:
                    return NackCode.TOO_HIGH, pos_f, p_prev + v_hi * h
                if seg < v_lo:
                    return NackCode.TOO_LOW, pos_f, p_prev + v_lo * h
                seg_prev, v = seg, 0.0
            else:
                if not math.isfinite(v):
                    return NackCode.NOT_FINITE, vel_f, 0.0
                if v > v_max * (1 + _REL):
                    return NackCode.TOO_HIGH, vel_f, v_max
                if v < -v_max * (1 + _REL):
                    return NackCode.TOO_LOW, vel_f, -v_max
                # |a| <= a_max at both ends of the cubic: a band of positions
                a_tol = a_max * (1 + _REL) + 6 * _Q_DEG / (h * h)
                c0 = p_prev + h * (4 * v_prev + 2 * v) / 6
                c1 = p_prev + h * (2 * v_prev + 4 * v) / 6
                band = a_tol * h * h / 6
                hi, lo = min(c0, c1) + band, max(c0, c1) - band
                if p > hi:
                    return NackCode.TOO_HIGH, pos_f, hi
                if p < lo:
                    return NackCode.TOO_LOW, pos_f, lo
            p_prev, v_prev = p, v
        trial = self._profile_with(points, t_s)
        end = None if trial is None else safety.travel_end_crossed(trial[0], lo_t, hi_t)
        if end is not None:
            return NackCode.TRAVEL, f"pos{n - 1}_deg", end
        return None

    def add(self, t_s: float, points: tuple[tuple[float, float], ...]
            ) -> tuple[Profile, float] | None:  # fmt: skip
        """Take checked points; returns the profile to follow and its start time once the
        stream moves (None while it is still filling)."""
        for p, v in points:
            self._pos.append(float(p))
            self._vel.append(float(v) if self.interp is Interp.CUBIC else 0.0)
        if self.state is StreamState.FILLING and len(self._pos) - 1 >= self._prefill:
            self.state, self.t0_s = StreamState.RUNNING, t_s
        return self._followed()

    def _followed(self) -> tuple[Profile, float] | None:
        if self.t0_s is None:
            return None
        prof, t_start_s = self.profile()
        self._t_end_s = t_start_s + prof.duration
        return prof, t_start_s

    def end(self, t_s: float) -> tuple[Profile, float] | None:
        """END: no more points; a filling stream starts with what it holds (None if it
        holds no point: closed at once)."""
        self.update(t_s)
        if self.state is StreamState.FILLING:
            if len(self._pos) == 1:
                self.clear()
                return None
            self.t0_s = t_s
        if self.state in (StreamState.FILLING, StreamState.RUNNING):
            self.state = StreamState.ENDED
        return self._followed()

    # ------------------------------------------------------------------ the profile
    def _last_segment_velocity(self) -> float:
        """LINEAR: the velocity of the last period held (0 from point 0, at rest)."""
        if len(self._pos) < 2:
            return 0.0
        return (self._pos[-1] - self._pos[-2]) / self.period_s

    def _profile_with(self, points: tuple[tuple[float, float], ...], t_s: float
                      ) -> tuple[Profile, float] | None:  # fmt: skip
        """The profile as it would be with ``points`` added (for the travel check)."""
        saved = (self._pos[:], self._vel[:], self.state, self.t0_s)
        try:
            for p, v in points:
                self._pos.append(float(p))
                self._vel.append(float(v) if self.interp is Interp.CUBIC else 0.0)
            return self.profile(t_s if self.t0_s is None else None)
        finally:
            self._pos, self._vel, self.state, self.t0_s = saved

    def profile(self, t_s: float | None = None) -> tuple[Profile, float]:
        """The periods from the first point held to the last, then the stop at a_max:
        ``(profile, board time of its start)``. ``t_s`` is the start time if the stream has
        not started moving (a trial)."""
        h = self.period_s
        t0 = self.t0_s if self.t0_s is not None else (t_s or 0.0)
        pos, vel = self._pos, self._vel
        linear = self.interp is Interp.LINEAR
        ts: list[float] = []
        ps: list[float] = []
        vs: list[float] = []
        accs: list[float] = []
        js: list[float] = []
        v_end = 0.0
        for i in range(len(pos) - 1):
            dp = pos[i + 1] - pos[i]
            ts.append(i * h)
            ps.append(pos[i])
            if linear:
                v_end = dp / h
                vs.append(v_end)
                accs.append(0.0)
                js.append(0.0)
            else:
                v0, v1 = vel[i], vel[i + 1]
                a0 = (6 * dp - h * (4 * v0 + 2 * v1)) / (h * h)
                a1 = (-6 * dp + h * (2 * v0 + 4 * v1)) / (h * h)
                vs.append(v0)
                accs.append(a0)
                js.append((a1 - a0) / h)
                v_end = v1
        t = (len(pos) - 1) * h
        p_end = pos[-1]
        if v_end != 0.0:
            # the stop: decelerate at a_max from the last point's velocity
            a = -math.copysign(self._a_max, v_end)
            dt = abs(v_end) / self._a_max
            ts.append(t)
            ps.append(p_end)
            vs.append(v_end)
            accs.append(a)
            js.append(0.0)
            p_end = p_end + v_end * dt + 0.5 * a * dt * dt
            t += dt
        v0 = vs[0] if vs else 0.0
        prof = Profile(
            "trapezoid", "stream", tuple(ts), tuple(ps), tuple(vs), tuple(accs), tuple(js),
            t, pos[0], v0, accs[0] if accs else 0.0, p_end, 0.0,
        )  # fmt: skip
        return prof, t0 + self._base * h
