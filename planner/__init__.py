"""Motion planners from the three seeds: pure functions, immutable profiles, no I/O.

Unit-free: any consistent units (the firmware uses axis degrees and seconds).

* :func:`plan_trapezoid` - time-optimal velocity/acceleration-limited move from any start
  velocity to any end velocity (seed 000, eqs. 1-19).
* :func:`plan_scurve` - jerk-limited 7-segment S-curve from any (v0, a0) (seed 002).
* :func:`plan_stop`, :func:`plan_scurve_stop` - the shortest stop.
* :class:`OnlinePlanner` - per-tick setpoints with interrupt-and-replan (seed 000, Fig. 8).
* :func:`sample_fixed_period` - fixed-period interpolation (seed 002, Tables 1 and 2).
* :func:`plan_path`, :func:`plan_program`, :class:`LookaheadQueue` - continuous-path
  look-ahead over a polyline, batch and streaming (seed 001).
* :class:`Profile` - what every planner returns: ``duration``, ``at(t)``, ``phases``.
* :func:`warm_up` - load the compiled S-curve kernel ahead of a real-time loop.
"""

from planner._kernel import warm_up
from planner.lookahead import (
    LookaheadQueue,
    PathPlan,
    PathSegment,
    junction_speeds,
    plan_path,
    plan_program,
    plan_segment,
)
from planner.online import OnlinePlanner
from planner.profile import Profile
from planner.sampling import FixedPeriodSamples, sample_fixed_period, trapezoid_from_periods
from planner.scurve import plan_scurve, plan_scurve_stop, scurve_from_periods, velocity_pulse
from planner.trapezoid import plan_stop, plan_trapezoid

__all__ = [
    "FixedPeriodSamples",
    "LookaheadQueue",
    "OnlinePlanner",
    "PathPlan",
    "PathSegment",
    "Profile",
    "junction_speeds",
    "plan_path",
    "plan_program",
    "plan_scurve",
    "plan_scurve_stop",
    "plan_segment",
    "plan_stop",
    "plan_trapezoid",
    "sample_fixed_period",
    "scurve_from_periods",
    "trapezoid_from_periods",
    "velocity_pulse",
    "warm_up",
]
