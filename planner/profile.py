"""The one profile type every planner returns: piecewise-polynomial, immutable, vectorised.

A :class:`Profile` is a list of phases; in each phase the jerk is constant, so position is
a cubic in time. A trapezoid profile has zero jerk everywhere and its ``phases`` report the
(constant) acceleration of each phase; an S-curve profile reports the jerk.

Time ``t`` is relative to the start of the profile (``t = 0`` is the start state). Units are
whatever the caller used consistently (positions p, velocities v = dp/dt, accelerations a,
jerks j); the firmware uses axis degrees and seconds.

Outside ``[0, duration]`` the profile is still defined, so that a sampler never needs to
special-case the ends:

* before 0 it holds the start position and velocity with zero acceleration:
  ``at(t < 0) = (p0, v0, 0)`` (the state the profile was planned from, frozen);
* from ``duration`` on it continues at the end velocity from the end position with zero
  acceleration: ``at(t >= T) = (p1 + v1 * (t - T), v1, 0)``. The end state is stored exactly
  (the requested target), so ``at(T)`` returns ``p1`` bit-for-bit.
"""

from __future__ import annotations

import math
from bisect import bisect_right as _bisect_right
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

__all__ = ["Profile", "build_profile"]

FloatOrArray = float | npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Profile:
    """An immutable motion profile from ``(p0, v0, a0)`` to ``(p1, v1, 0)``.

    Attributes:
        kind: ``"trapezoid"`` (piecewise-constant acceleration) or ``"scurve"``
            (piecewise-constant jerk).
        case: which shape the planner chose, explained in the planner's docstring:
            ``"classic"``, ``"triangle"``, ``"a"``..``"d"`` (seed 000), ``"brake+<case>"``
            (|v0| > v_max), ``"stop"``, ``"hold"`` (no motion), ``"1"``..``"7"`` (seed 001
            segments).
        t0: start time of each phase, shape ``(n,)`` as a tuple; ``t0[0] == 0``.
        p, v, a: state at the start of each phase, tuples of length ``n``.
        j: jerk in each phase (all zero for a trapezoid), tuple of length ``n``.
        duration: end time ``T`` of the last phase (0 for an empty profile).
        p0, v0, a0: start state. p1, v1: end state (the end acceleration is 0).
    """

    kind: str
    case: str
    t0: tuple[float, ...]
    p: tuple[float, ...]
    v: tuple[float, ...]
    a: tuple[float, ...]
    j: tuple[float, ...]
    duration: float
    p0: float
    v0: float
    a0: float
    p1: float
    v1: float

    @property
    def phases(self) -> tuple[tuple[float, float, float], ...]:
        """``(t_start, t_end, value)`` per phase; value is the acceleration of a trapezoid
        phase or the jerk of an S-curve phase (see ``kind``)."""
        if not self.t0:
            return ()
        ends = self.t0[1:] + (self.duration,)
        values = self.a if self.kind == "trapezoid" else self.j
        return tuple(zip(self.t0, ends, values, strict=True))

    @cached_property
    def _arrays(self) -> tuple[npt.NDArray[np.float64], ...]:
        # Built once, on the first array evaluation; plain tuples keep planning cheap.
        return tuple(np.asarray(x, dtype=float) for x in (self.t0, self.p, self.v, self.a, self.j))

    def at(self, t: FloatOrArray) -> tuple[FloatOrArray, FloatOrArray, FloatOrArray]:
        """Position, velocity and acceleration at time ``t`` (relative to the start).

        Args:
            t: a float, or an array of any shape of times.

        Returns:
            ``(p, v, a)``: floats for a float (or 0-d) input, arrays of ``t``'s shape for an
            array input. No Python loop runs over the samples.
        """
        if isinstance(t, float | int) and not isinstance(t, bool):
            return self._at_scalar(float(t))
        t_arr = np.asarray(t, dtype=float)
        if t_arr.ndim == 0:
            return self._at_scalar(float(t_arr))
        return self._at_array(t_arr)

    def jerk(self, t: FloatOrArray) -> FloatOrArray:
        """The piecewise-constant jerk at ``t`` (0 outside ``[0, duration)`` and for a
        trapezoid, whose acceleration steps are not represented as jerk)."""
        t_arr = np.asarray(t, dtype=float)
        if not self.t0:
            out = np.zeros_like(t_arr)
        else:
            t0, _, _, _, j = self._arrays
            i = np.clip(np.searchsorted(t0, t_arr, side="right") - 1, 0, len(self.t0) - 1)
            out = np.where((t_arr < 0.0) | (t_arr >= self.duration), 0.0, j[i])
        return float(out) if out.ndim == 0 else out

    @cached_property
    def _rows(self) -> tuple[tuple[float, float, float, float], ...]:
        return tuple(zip(self.p, self.v, self.a, self.j, strict=True))

    def _at_scalar(self, t: float) -> tuple[float, float, float]:
        # The firmware's per-tick path: one bisect and one row of coefficients.
        duration = self.duration
        if 0.0 <= t < duration:
            t0 = self.t0
            i = _bisect_right(t0, t) - 1
            tau = t - t0[i]
            p, v, a, j = self._rows[i]
            jt = j * tau
            return (
                p + tau * (v + tau * (0.5 * a + jt / 6.0)),
                v + tau * (a + 0.5 * jt),
                a + jt,
            )
        if t < 0.0:
            return self.p0, self.v0, 0.0
        return self.p1 + self.v1 * (t - duration), self.v1, 0.0

    def _at_array(
        self, t: npt.NDArray[np.float64]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        n = len(self.t0)
        big_t = self.duration
        if n == 0:
            after = t >= 0.0
            pos = np.where(after, self.p1 + self.v1 * (t - big_t), self.p0)
            vel = np.where(after, self.v1, self.v0)
            return pos, vel.astype(float), np.zeros_like(t)
        t0, p, v, a, j = self._arrays
        i = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, n - 1)
        tau = t - t0[i]
        ai, ji, vi = a[i], j[i], v[i]
        pos = p[i] + tau * (vi + tau * (0.5 * ai + tau * ji / 6.0))
        vel = vi + tau * (ai + 0.5 * tau * ji)
        acc = ai + tau * ji
        before = t < 0.0
        after = t >= big_t
        pos = np.where(before, self.p0, np.where(after, self.p1 + self.v1 * (t - big_t), pos))
        vel = np.where(before, self.v0, np.where(after, self.v1, vel))
        acc = np.where(before | after, 0.0, acc)
        return pos, vel, acc


def build_profile(
    kind: str,
    case: str,
    p0: float,
    v0: float,
    a0: float,
    segments: list[tuple[float, float]],
    p1: float,
    v1: float,
) -> Profile:
    """Integrate ``segments`` from the start state into a :class:`Profile`.

    Args:
        kind: ``"trapezoid"`` (segment values are accelerations) or ``"scurve"``
            (segment values are jerks, starting from acceleration ``a0``).
        segments: ``(dt, value)`` pairs; phases with ``dt <= 0`` are dropped.
        p1, v1: the exact end state stored for ``t >= duration``.
    """
    t0: list[float] = []
    ps: list[float] = []
    vs: list[float] = []
    as_: list[float] = []
    t, p, v, a = 0.0, p0, v0, a0
    if kind == "trapezoid":
        # The hot path of plan_trapezoid: kept free of the jerk terms.
        for dt, a in segments:
            if dt > 0.0:
                t0.append(t)
                ps.append(p)
                vs.append(v)
                as_.append(a)
                p += dt * (v + 0.5 * a * dt)
                v += a * dt
                t += dt
        js = (0.0,) * len(t0)
    else:
        js = []
        a_scale = abs(a0)
        for dt, j in segments:
            if not dt > 0.0:
                continue
            # A phase that starts where the planner brought the acceleration to zero must
            # start at exactly zero: a rounding residue would grow as t^2 over a long cruise.
            if abs(a) <= 1e-12 * a_scale:
                a = 0.0
            t0.append(t)
            ps.append(p)
            vs.append(v)
            as_.append(a)
            js.append(j)
            p += dt * (v + dt * (0.5 * a + dt * j / 6.0))
            v += dt * (a + 0.5 * dt * j)
            a += dt * j
            a_scale = max(a_scale, abs(a))
            t += dt
    if not math.isfinite(t):
        raise ValueError(f"duration = {t!r}: the profile is not finite")
    # The frozen dataclass's __init__ sets its 13 fields one object.__setattr__ at a time
    # (about 5 us on the target host, half a plan); filling __dict__ at once gives the
    # same immutable object.
    prof = object.__new__(Profile)
    prof.__dict__.update(
        kind=kind,
        case=case,
        t0=tuple(t0),
        p=tuple(ps),
        v=tuple(vs),
        a=tuple(as_),
        j=tuple(js),
        duration=t,
        p0=p0,
        v0=v0,
        a0=a0,
        p1=p1,
        v1=v1,
    )
    return prof
