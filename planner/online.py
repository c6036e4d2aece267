"""Online interruption and replanning (seed 000, section 4 and Fig. 8 / Table 1).

The firmware keeps one :class:`OnlinePlanner`, asks it for the setpoint every servo tick and
hands it new targets (and limits) at any time. A new command replans from the *commanded*
state at that instant (position, velocity and, for the S-curve, acceleration), so the
setpoint has no jump in position or velocity (nor in acceleration for the S-curve); this is
the paper's "record the current position as S_0 and the velocity as v_0 and replan".

The profile kind of a moving axis can be switched at any command (trapezoid <-> S-curve):
the new profile starts from the commanded state like any replan, so position and velocity
never jump; switching to the S-curve also keeps the acceleration (it starts from the
trapezoid's), switching to the trapezoid sets its own (a trapezoid has no jerk limit).

The object holds only the active profile and its start time. A sample is O(number of
phases) and allocates no arrays; a trapezoid replan costs ~8 us, an S-curve replan from any
state a compiled search (median ~15 us, worst under 80 us: ``benchmarks/bench_planner.py``), both
well inside a 2 ms tick. An S-curve planner loads the compiled kernel when it is created
(0.3-0.9 s once per process, see :func:`planner.warm_up`), not in the middle of a move.
"""

from __future__ import annotations

import math

from planner._kernel import warm_up
from planner.profile import Profile
from planner.scurve import plan_scurve, plan_scurve_stop
from planner.trapezoid import plan_stop, plan_trapezoid

__all__ = ["OnlinePlanner"]

_KINDS = ("trapezoid", "scurve")


class OnlinePlanner:
    """A stateful setpoint generator that replans on command without jumps.

    Args:
        kind: ``"trapezoid"`` (velocity and acceleration limited) or ``"scurve"`` (also jerk
            limited; ``j_max`` then required in :meth:`command` and :meth:`stop`); the
            kind of the first profile, switched by the ``kind`` argument of a command.

    Attributes:
        profile: the active :class:`Profile`, or None after :meth:`reset`.
        t_start_s: the time at which ``profile`` starts (``profile.at(t_s - t_start_s)``).
        moving: True if the last :meth:`sample` fell before the end of the active profile.
    """

    def __init__(self, kind: str = "trapezoid") -> None:
        self._check_kind(kind)
        if kind == "scurve":
            warm_up()
        self.kind = kind
        self.profile: Profile | None = None
        self.t_start_s = 0.0
        self.moving = False
        self._p_rest = 0.0

    def reset(self, p0: float) -> None:
        """Forget any profile; hold still at ``p0``."""
        if not math.isfinite(p0):
            raise ValueError(f"p0 = {p0!r}: must be finite")
        self.profile = None
        self.t_start_s = 0.0
        self.moving = False
        self._p_rest = float(p0)

    def _state(self, t_s: float) -> tuple[float, float, float]:
        if not math.isfinite(t_s):
            raise ValueError(f"t_s = {t_s!r}: must be finite")
        if self.profile is None:
            return self._p_rest, 0.0, 0.0
        if t_s < self.t_start_s:
            raise ValueError(
                f"t_s = {t_s!r}: before the start of the active profile ({self.t_start_s!r})"
            )
        p, v, a = self.profile.at(t_s - self.t_start_s)
        return float(p), float(v), float(a)

    @staticmethod
    def _check_kind(kind: str) -> None:
        if kind not in _KINDS:
            raise ValueError(f"kind = {kind!r}: must be one of {_KINDS}")

    def _resolve(self, kind: str | None, j_max: float | None) -> str:
        """The kind of the next profile; checked before anything changes."""
        kind = self.kind if kind is None else kind
        self._check_kind(kind)
        if kind == "scurve" and j_max is None:
            raise ValueError("j_max = None: an S-curve planner needs a jerk limit")
        return kind

    def command(
        self,
        t_s: float,
        target: float,
        *,
        v_max: float,
        a_max: float,
        j_max: float | None = None,
        d_max: float | None = None,
        kind: str | None = None,
    ) -> Profile:
        """Replan at ``t_s`` from the commanded state to ``target`` (at rest there).

        If the commanded speed exceeds a lowered ``v_max`` the new profile brakes down to
        ``v_max`` first. Returns the new active profile (which starts at ``t_s``).

        Args:
            d_max: deceleration limit (None: ``a_max``), see :func:`planner.plan_trapezoid`.
            kind: switch the profile kind from here on (None: keep it); allowed while moving.

        Raises:
            ValueError: bad limits, kind or target (named, with the value), or ``t_s``
                earlier than the start of the active profile. Nothing changes then.
        """
        if not math.isfinite(target):
            raise ValueError(f"target = {target!r}: must be finite")
        new_kind = self._resolve(kind, j_max)
        p, v, a = self._state(t_s)
        if new_kind == "trapezoid":
            profile = plan_trapezoid(p, target, v_max=v_max, a_max=a_max, v0=v, d_max=d_max)
        else:
            profile = plan_scurve(
                p, target, v_max=v_max, a_max=a_max, j_max=j_max, v0=v, a0=a, d_max=d_max
            )
        self.kind = new_kind
        self.profile = profile
        self.t_start_s = float(t_s)
        self.moving = profile.duration > 0.0
        return profile

    def stop(
        self, t_s: float, *, a_max: float, j_max: float | None = None, kind: str | None = None
    ) -> Profile:
        """Replan at ``t_s`` to the shortest stop from the commanded state (``a_max`` is the
        deceleration of the stop); ``kind`` as in :meth:`command`."""
        new_kind = self._resolve(kind, j_max)
        p, v, a = self._state(t_s)
        if new_kind == "trapezoid":
            profile = plan_stop(p, a_max=a_max, v0=v)
        else:
            profile = plan_scurve_stop(p, a_max=a_max, j_max=j_max, v0=v, a0=a)
        self.kind = new_kind
        self.profile = profile
        self.t_start_s = float(t_s)
        self.moving = profile.duration > 0.0
        return profile

    def sample(self, t_s: float) -> tuple[float, float, float]:
        """The setpoint ``(p, v, a)`` at ``t_s``; updates :attr:`moving`."""
        if self.profile is None:
            self.moving = False
            return self._p_rest, 0.0, 0.0
        profile = self.profile
        tau = float(t_s) - self.t_start_s
        self.moving = tau < profile.duration
        # The scalar evaluator directly: this runs every 2 ms tick (about half the cost of
        # going through at()'s type dispatch); it returns plain floats.
        return profile._at_scalar(tau)
