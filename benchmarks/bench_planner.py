"""Planner benchmark: microseconds per plan and per 10,000-sample ``at(t)``, ruckig alongside.

Run: ``python3 benchmarks/bench_planner.py`` (about half a minute). Prints a Markdown table
of medians over repeated batches (host wall clock, ``wall_s``), plus how the S-curve's
durations compare with ruckig's for starts with a0 != 0 (where plan_scurve is valid but
not proven time-optimal). Targets: trapezoid plan <= 10 us, S-curve plan <= 50 us,
10,000 samples <= 1 ms.
"""

from __future__ import annotations

import math
import os
import random
import statistics
import time

import numpy as np

from planner import OnlinePlanner, plan_scurve, plan_trapezoid

try:
    import ruckig
except ImportError:  # ruckig is a test extra
    ruckig = None

N_STATES = 500
REPEATS = 15


def states(seed: int, *, with_a0: bool = False) -> list[tuple[float, ...]]:
    rng = random.Random(seed)
    out = []
    for _ in range(N_STATES):
        v_max = 10 ** rng.uniform(0, 3)
        a_max = 10 ** rng.uniform(0, 3)
        j_max = 10 ** rng.uniform(0, 3)
        p0 = rng.uniform(-1e3, 1e3)
        p1 = p0 + rng.uniform(-1e3, 1e3)
        v0 = rng.uniform(-1.0, 1.0) * v_max
        a0 = rng.uniform(-1.0, 1.0) * a_max if with_a0 else 0.0
        out.append((p0, p1, v0, a0, v_max, a_max, j_max))
    return out


def median_us_per_call(fn, items) -> tuple[float, float]:
    """(median, min) over REPEATS batches of the wall time per item, in microseconds."""
    per_call = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        for item in items:
            fn(item)
        per_call.append((time.perf_counter() - start) / len(items) * 1e6)
    return statistics.median(per_call), min(per_call)


def median_us(fn, repeats: int = REPEATS * 4) -> tuple[float, float]:
    """(median, min) wall time of ``fn()`` over ``repeats`` calls, in microseconds."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1e6)
    return statistics.median(times), min(times)


def ruckig_input(state, j_max: float):
    p0, p1, v0, a0, v_max, a_max, _ = state
    inp = ruckig.InputParameter(1)
    inp.current_position = [p0]
    inp.current_velocity = [v0]
    inp.current_acceleration = [a0]
    inp.target_position = [p1]
    inp.target_velocity = [0.0]
    inp.target_acceleration = [0.0]
    inp.max_velocity = [v_max]
    inp.max_acceleration = [a_max]
    inp.max_jerk = [j_max]
    return inp


def main() -> None:
    rows: list[tuple[str, tuple[float, float], str]] = []
    rest = states(1)
    moving = states(2, with_a0=True)

    def trap(s):
        return plan_trapezoid(s[0], s[1], v_max=s[4], a_max=s[5], v0=s[2])

    def scurve(s):
        return plan_scurve(s[0], s[1], v_max=s[4], a_max=s[5], j_max=s[6], v0=s[2], a0=s[3])

    rows.append(("plan_trapezoid (random v0)", median_us_per_call(trap, rest), "<= 10 us"))
    rows.append(("plan_scurve, a0 = 0", median_us_per_call(scurve, rest), "<= 50 us"))
    rows.append(("plan_scurve, a0 != 0 (grid search)", median_us_per_call(scurve, moving), "-"))

    t10k = None
    prof_t = plan_trapezoid(0.0, 10_000.0, v_max=990.0, a_max=148.0, v0=400.0)
    prof_s = plan_scurve(0.0, 10_000.0, v_max=990.0, a_max=148.0, j_max=300.0, v0=400.0)
    t10k = np.linspace(-1.0, prof_s.duration + 1.0, 10_000)
    prof_t.at(t10k)
    prof_s.at(t10k)  # build the cached arrays outside the timing
    rows.append(("trapezoid at(t), 10,000 samples", median_us(lambda: prof_t.at(t10k)), "<= 1 ms"))
    rows.append(("S-curve at(t), 10,000 samples", median_us(lambda: prof_s.at(t10k)), "<= 1 ms"))
    ts = [float(x) for x in t10k[:1000]]
    rows.append(("trapezoid at(float), per call", median_us_per_call(prof_t.at, ts), "-"))

    op = OnlinePlanner("scurve")
    op.reset(0.0)
    op.command(0.0, 10_000.0, v_max=990.0, a_max=148.0, j_max=300.0)
    ticks = [k * 0.002 for k in range(1000)]
    rows.append(
        ("OnlinePlanner.sample (S-curve), per tick", median_us_per_call(op.sample, ticks), "-")
    )

    ratio_lines = []
    if ruckig is not None:
        otg = ruckig.Ruckig(1)
        traj = ruckig.Trajectory(1)
        inputs_inf = [ruckig_input(s, math.inf) for s in rest]
        inputs_j = [ruckig_input(s, s[6]) for s in rest]
        inputs_a0 = []
        for s in moving:  # keep the states ruckig solves (it fails on a few extreme ones)
            try:
                otg.calculate(ruckig_input(s, s[6]), traj)
            except ruckig.RuckigError:
                continue
            inputs_a0.append((s, ruckig_input(s, s[6])))
        rows.append(
            (
                "ruckig, max_jerk = inf",
                median_us_per_call(lambda i: otg.calculate(i, traj), inputs_inf),
                "-",
            )
        )
        rows.append(
            (
                "ruckig, finite jerk, a0 = 0",
                median_us_per_call(lambda i: otg.calculate(i, traj), inputs_j),
                "-",
            )
        )
        rows.append(
            (
                "ruckig, finite jerk, a0 != 0",
                median_us_per_call(lambda i: otg.calculate(i, traj), [i for _, i in inputs_a0]),
                "-",
            )
        )
        otg.calculate(inputs_j[0], traj)
        ruckig_ts = [float(x) for x in np.linspace(0.0, traj.duration, 10_000)]
        rows.append(
            (
                "ruckig at_time, 10,000 samples (Python loop)",
                median_us(lambda: [traj.at_time(x) for x in ruckig_ts], repeats=7),
                "-",
            )
        )
        # S-curve durations against ruckig for a0 != 0 and the velocity reachable within
        # limits (elsewhere ruckig's brake pre-profile makes the two incomparable).
        ratios = []
        for s, inp in inputs_a0:
            p0, p1, v0, a0, v_max, a_max, j_max = s
            if abs(v0 + a0 * abs(a0) / (2 * j_max)) > v_max:
                continue
            otg.calculate(inp, traj)
            ratios.append(scurve(s).duration / traj.duration)
        ratios.sort()
        slower = sum(r > 1 + 1e-6 for r in ratios)
        ratio_lines.append(
            f"S-curve duration / ruckig duration for a0 != 0 ({len(ratios)} states): "
            f"median {statistics.median(ratios):.6f}, max {ratios[-1]:.4f}, "
            f"slower by > 1e-6 in {slower} ({100 * slower / len(ratios):.1f} %)"
        )

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average (1 min) at the end: {load:.2f}; {os.cpu_count()} CPUs")
    print()
    print("| operation | median | min | target |")
    print("|---|---:|---:|---|")
    for name, (med, low), target in rows:
        print(f"| {name} | {med:,.2f} us | {low:,.2f} us | {target} |")
    for line in ratio_lines:
        print()
        print(line)


if __name__ == "__main__":
    main()
