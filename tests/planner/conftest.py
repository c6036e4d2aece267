"""Shared checks for planner tests: a profile's validity, judged by sampling it densely.

The checks use only ``Profile.at`` and the phase boundaries, not the planner's internals.
Tolerance: limits may be exceeded by at most 1e-9 relative (rounding), documented in the
README; continuity is checked across every phase boundary.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

# A bounded profile so that the planner's property tests stay well under the time budget;
# applied per test (``@settings(settings.get_profile("planner"))``), not loaded globally, so
# that it does not change other packages' tests.
settings.register_profile(
    "planner", max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)

REL = 1e-9


def _scale(*xs):
    return max(1.0, *(abs(x) for x in xs if math.isfinite(x)))


def check_profile(prof, *, v_max, a_max, j_max=None, v_start_max=None):
    """Assert ``prof`` respects the limits, is continuous and ends exactly where it says.

    v_start_max: the speed the profile may start at (a brake may start above v_max).
    """
    big_t = prof.duration
    assert big_t >= 0.0 and math.isfinite(big_t)
    p_scale = _scale(prof.p0, prof.p1, v_max * big_t, *prof.p)
    v_lim = max(v_max, abs(prof.v0) if v_start_max is None else v_start_max)
    # Start state.
    p, v, _ = prof.at(0.0)
    assert p == pytest.approx(prof.p0, rel=REL, abs=REL * p_scale)
    assert v == pytest.approx(prof.v0, rel=REL, abs=REL * v_lim)
    # End state (from the last phase's polynomial, just before T, and exactly at T).
    p_end, v_end, a_end = prof.at(big_t)
    assert (p_end, v_end, a_end) == (prof.p1, prof.v1, 0.0)
    if big_t > 0.0:
        i = len(prof.t0) - 1
        tau = big_t - prof.t0[i]
        p_poly = prof.p[i] + tau * (prof.v[i] + tau * (prof.a[i] / 2 + tau * prof.j[i] / 6))
        v_poly = prof.v[i] + tau * (prof.a[i] + tau * prof.j[i] / 2)
        a_poly = prof.a[i] + tau * prof.j[i]
        assert p_poly == pytest.approx(prof.p1, rel=REL, abs=REL * p_scale)
        # Phase times are absolute, so the rounding of T (its ulp) bounds what can match.
        t_ulp = 4 * math.ulp(big_t)
        assert v_poly == pytest.approx(prof.v1, abs=1e-8 * v_lim + t_ulp * a_max)
        if prof.kind == "scurve":
            assert abs(a_poly) <= 1e-8 * a_max + t_ulp * j_max
    # Dense samples plus both sides of every boundary.
    knots = np.array(prof.t0[1:] + (big_t,))
    eps = 1e-9 * max(big_t, 1e-300)
    ts = np.concatenate([np.linspace(0.0, big_t, 2001), knots - eps, knots + eps])
    ts = np.clip(ts, 0.0, big_t)
    ps, vs, accs = prof.at(ts)
    assert np.all(np.abs(vs) <= v_lim * (1 + REL) + 1e-12)
    if prof.kind == "trapezoid":
        assert np.all(np.abs(accs) <= a_max * (1 + REL) + 1e-12)
    else:
        # An S-curve may start above a_max only if a0 is; it never grows past max(a0, a_max).
        a_lim = max(a_max, abs(prof.a0))
        assert np.all(np.abs(accs) <= a_lim * (1 + REL) + 1e-12)
        assert all(abs(j) <= j_max * (1 + REL) for j in prof.j)
    # Continuity across boundaries: the jump over 2 eps is bounded by the derivative.
    if len(knots) > 1:
        inner = knots[:-1]
        pl, vl, al = prof.at(np.maximum(inner - eps, 0.0))
        pr, vr, ar = prof.at(np.minimum(inner + eps, big_t))
        assert np.all(np.abs(pr - pl) <= 2 * eps * v_lim * 1.01 + REL * p_scale)
        assert np.all(np.abs(vr - vl) <= 2 * eps * max(a_max, abs(prof.a0)) * 1.01 + REL * v_lim)
        if prof.kind == "scurve":
            assert np.all(np.abs(ar - al) <= 2 * eps * j_max * 1.01 + REL * a_max)
    # The position is the integral of the velocity (checks at() against itself).
    t_fine = np.linspace(0.0, big_t, 4001)
    pf, vf, af = prof.at(t_fine)
    if big_t > 0.0:
        dt = t_fine[1] - t_fine[0]
        # Trapezoid rule with its end correction: exact where v is a quadratic; an interval
        # holding a phase boundary is off by at most dt^2 * |jump of a| (bounded below).
        dp = dt * (vf[1:] + vf[:-1]) / 2 - dt**2 * (af[1:] - af[:-1]) / 12
        a_lim = max(a_max, abs(prof.a0))
        assert np.allclose(pf[1:] - pf[:-1], dp, rtol=0.0, atol=dt**2 * a_lim + REL * p_scale)


@pytest.fixture(scope="session")
def check():
    return check_profile
