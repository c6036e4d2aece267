"""Fixed-period interpolation (seed 002): sample a profile every ``dt`` as a controller does.

Seed 002 (Zhang et al. 2013) plans by time ("time-based"): each segment is cut into equal
periods and the setpoint is computed at every period boundary. Its Table 1 (trapezoid) and
Table 2 (S-curve) list, per period k, the position, velocity and acceleration at ``t = k dt``;
the acceleration column of Table 1 and the jerk column of Table 2 are the value *held over
the period that ends at row k* (row 0: 0), which is what :attr:`FixedPeriodSamples.a_held` and
:attr:`FixedPeriodSamples.j_held` hold.

Sampled here, both tables come out row by row to the printed digits, except four printed
positions that are not the rounding of the exact value: Table 1 rows 1 and 3 are truncated
(0.9375 printed 0.93, 8.4375 printed 8.43) and row 19 prints 119.07 for 119.0625 (all within
one unit of the last digit); Table 2 row 8 prints 26.820 for 26.319 (a 3 misprinted as 8:
eqs. (3)-(5) give 13.125 + 11.25 + 2.5 - 0.556). tests/planner/test_sampling.py asserts each.

The paper's own parameterisation ("accelerate for n periods") is accepted by
:func:`trapezoid_from_periods` and :func:`planner.scurve.scurve_from_periods`; otherwise any
profile from :func:`planner.plan_trapezoid` / :func:`planner.plan_scurve` can be sampled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from planner._checks import check_positive
from planner.profile import Profile
from planner.trapezoid import plan_trapezoid

__all__ = ["FixedPeriodSamples", "sample_fixed_period", "trapezoid_from_periods"]

Array = npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class FixedPeriodSamples:
    """Samples ``k = 0..n`` of a profile at ``t = k dt``; every array has shape ``(n + 1,)``.

    Attributes:
        t, p, v, a: time and state at each sample.
        a_held: acceleration held over the period ending at sample k (its midpoint value).
        j_held: jerk held over the period ending at sample k (0 for a trapezoid).
    """

    dt: float
    t: Array
    p: Array
    v: Array
    a: Array
    a_held: Array
    j_held: Array


def sample_fixed_period(profile: Profile, dt: float, *, n: int | None = None) -> FixedPeriodSamples:
    """Sample ``profile`` every ``dt`` from 0.

    Args:
        dt: the period (> 0).
        n: number of periods; default the fewest that reach the end of the profile
            (``ceil(duration / dt)``, ignoring a rounding excess of 1e-9 period).
    """
    check_positive(dt=dt)
    if n is None:
        n = max(0, math.ceil(profile.duration / dt - 1e-9))
    elif not (isinstance(n, int) and n >= 0):
        raise ValueError(f"n = {n!r}: must be an integer >= 0")
    k = np.arange(n + 1, dtype=float)
    t = k * dt
    p, v, a = profile.at(t)
    mid = t - 0.5 * dt
    a_held = np.asarray(profile.at(mid)[2], dtype=float)
    j_held = np.asarray(profile.jerk(mid), dtype=float)
    a_held[0] = 0.0
    j_held[0] = 0.0
    return FixedPeriodSamples(dt=float(dt), t=t, p=p, v=v, a=a, a_held=a_held, j_held=j_held)


def trapezoid_from_periods(
    length: float, v: float, dt: float, *, n_acc: int, p0: float = 0.0
) -> Profile:
    """Seed 002's trapezoid: reach ``v`` in ``n_acc`` periods of ``dt``, stop the same way.

    That is ``a_max = v / (n_acc dt)``; the cruise takes whatever time the length leaves
    (Table 1: L = 120, v = 50, dt = 0.15, n_acc = 4 gives a 12-period cruise).
    """
    if not (isinstance(n_acc, int) and n_acc >= 1):
        raise ValueError(f"n_acc = {n_acc!r}: must be an integer >= 1")
    check_positive(v=v, dt=dt)
    return plan_trapezoid(p0, p0 + length, v_max=v, a_max=v / (n_acc * dt))
