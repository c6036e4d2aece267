"""Durations checked against ruckig, which computes the time-optimal profile.

With ``max_jerk = inf`` ruckig solves the velocity- and acceleration-limited problem that
plan_trapezoid solves (including a brake when |v0| > v_max); with a finite jerk it solves the
jerk-limited one that plan_scurve solves (here for a0 = 0 and |v0| <= v_max).
"""

import math
import random

import ruckig  # the test extra installs it; a missing oracle must fail, not skip

from planner import plan_scurve, plan_trapezoid


def ruckig_duration(p0, p1, v0, v1, v_max, a_max, j_max=math.inf, a0=0.0):
    inp = ruckig.InputParameter(1)
    inp.current_position = [p0]
    inp.current_velocity = [v0]
    inp.current_acceleration = [a0]
    inp.target_position = [p1]
    inp.target_velocity = [v1]
    inp.target_acceleration = [0.0]
    inp.max_velocity = [v_max]
    inp.max_acceleration = [a_max]
    inp.max_jerk = [j_max]
    traj = ruckig.Trajectory(1)
    result = ruckig.Ruckig(1).calculate(inp, traj)
    assert result == ruckig.Result.Working, result
    return traj.duration


def random_state(rng, *, v0_range, with_v1):
    v_max = 10 ** rng.uniform(-1, 3)
    a_max = 10 ** rng.uniform(-1, 3)
    p0 = rng.uniform(-1e3, 1e3)
    p1 = p0 + rng.uniform(-1e3, 1e3) * 10 ** rng.uniform(-4, 0)
    v0 = rng.uniform(-v0_range, v0_range) * v_max if rng.random() < 0.9 else 0.0
    v1 = rng.uniform(-1.0, 1.0) * v_max if with_v1 and rng.random() < 0.5 else 0.0
    return p0, p1, v0, v1, v_max, a_max


def test_trapezoid_is_time_optimal_on_10000_random_states():
    rng = random.Random(10_000)
    worst = 0.0
    for _ in range(10_000):
        p0, p1, v0, v1, v_max, a_max = random_state(rng, v0_range=1.5, with_v1=True)
        ours = plan_trapezoid(p0, p1, v_max=v_max, a_max=a_max, v0=v0, v1=v1).duration
        theirs = ruckig_duration(p0, p1, v0, v1, v_max, a_max)
        worst = max(worst, abs(ours - theirs) / theirs)
    assert worst <= 1e-9


def test_scurve_matches_ruckig_from_rest_and_from_any_v0_with_a0_zero():
    rng = random.Random(7)
    worst = 0.0
    for k in range(3000):
        p0, p1, v0, _, v_max, a_max = random_state(rng, v0_range=1.0, with_v1=False)
        j_max = 10 ** rng.uniform(-1, 3)
        if k % 3 == 0:
            v0 = 0.0  # every third one starts at rest
        ours = plan_scurve(p0, p1, v_max=v_max, a_max=a_max, j_max=j_max, v0=v0).duration
        theirs = ruckig_duration(p0, p1, v0, 0.0, v_max, a_max, j_max)
        worst = max(worst, abs(ours - theirs) / theirs)
    assert worst <= 1e-6


def test_scurve_with_start_acceleration_matches_ruckig_when_limits_can_hold():
    """a0 != 0: not required to be optimal, but it is where the start state lets the speed
    stay within v_max (elsewhere ruckig's brake pre-profile differs by design)."""
    rng = random.Random(11)
    compared = 0
    worst = 0.0
    while compared < 600:
        p0, p1, v0, _, v_max, a_max = random_state(rng, v0_range=1.0, with_v1=False)
        j_max = 10 ** rng.uniform(-1, 3)
        a0 = rng.uniform(-1.0, 1.0) * a_max
        if abs(v0 + a0 * abs(a0) / (2 * j_max)) > v_max:
            continue
        try:
            theirs = ruckig_duration(p0, p1, v0, 0.0, v_max, a_max, j_max, a0=a0)
        except ruckig.RuckigError:
            continue  # ruckig gives up on a few extreme states
        ours = plan_scurve(p0, p1, v_max=v_max, a_max=a_max, j_max=j_max, v0=v0, a0=a0)
        worst = max(worst, abs(ours.duration - theirs) / theirs)
        compared += 1
    assert worst <= 1e-6


def test_scurve_from_above_v_max_is_never_slower_than_ruckig():
    """|v0| > v_max (a replan that lowered v_max): ruckig runs a brake pre-profile that is not
    time-optimal, so durations differ; plan_scurve (which must also be back within v_max no
    later than the fastest settled brake, tested in test_scurve.py) is never slower."""
    rng = random.Random(13)
    compared = 0
    while compared < 150:
        v_max = 10 ** rng.uniform(-1, 2)
        a_max = 10 ** rng.uniform(-1, 2)
        j_max = 10 ** rng.uniform(-1, 3)
        d = rng.uniform(-1.0, 1.0) * 10 ** rng.uniform(-3, 3)
        v0 = rng.choice([-1.0, 1.0]) * rng.uniform(1.001, 2.0) * v_max
        a0 = rng.uniform(-1.0, 1.0) * a_max if rng.random() < 0.5 else 0.0
        try:
            theirs = ruckig_duration(0.0, d, v0, 0.0, v_max, a_max, j_max, a0=a0)
        except ruckig.RuckigError:
            continue
        ours = plan_scurve(0.0, d, v_max=v_max, a_max=a_max, j_max=j_max, v0=v0, a0=a0)
        assert ours.duration <= theirs * (1 + 1e-6)
        compared += 1
