"""Planner benchmark: microseconds per plan and per 10,000-sample ``at(t)``, ruckig alongside,
and the S-curve replan's worst case over 10,000 random moving states.

Run: ``python3 benchmarks/bench_planner.py`` (about a minute). Prints a Markdown table of
medians over repeated batches (host wall clock, ``wall_s``), the replan distribution, and
how the S-curve's durations compare with ruckig's for starts with a0 != 0. Targets: trapezoid
plan <= 10 us, S-curve plan <= 50 us, 10,000 samples <= 1 ms, every S-curve replan (worst
case over >= 10,000 random replan states) <= 200 us, inside the 2 ms tick.

The machine is shared (2 cores, other work running): the load average is printed, and each
replan state is timed once as it comes (what a tick would see, preemption included) and as
the least of 5 runs (the planner's own cost, without the scheduler's interruptions).
"""

from __future__ import annotations

import gc
import math
import os
import random
import statistics
import time

import numpy as np

from planner import OnlinePlanner, plan_scurve, plan_trapezoid, warm_up

try:
    import ruckig
except ImportError:  # ruckig is a test extra
    ruckig = None

N_STATES = 500
REPEATS = 15
N_REPLAN = 10_000


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


def replan_states(seed: int) -> list[tuple[float, ...]]:
    """Random replan states: limits over three decades, a moving start (|v0| up to 1.2 v_max,
    i.e. also after a lowered v_max; |a0| up to a_max), a target anywhere from 1e-3 to 1e3
    away, and one in five with a non-zero end velocity (a queue segment)."""
    rng = random.Random(seed)
    out = []
    for k in range(N_REPLAN):
        v_max = 10 ** rng.uniform(0, 3)
        a_max = 10 ** rng.uniform(0, 3)
        j_max = 10 ** rng.uniform(0, 3)
        p0 = rng.uniform(-1e3, 1e3)
        p1 = p0 + rng.uniform(-1.0, 1.0) * 10 ** rng.uniform(-3, 3)
        v0 = rng.uniform(-1.2, 1.2) * v_max
        a0 = rng.uniform(-1.0, 1.0) * a_max
        v1 = rng.uniform(-1.0, 1.0) * v_max if k % 5 == 0 else 0.0
        out.append((p0, p1, v0, a0, v_max, a_max, j_max, v1))
    return out


def replan_table() -> list[str]:
    """Wall and CPU time of plan_scurve over N_REPLAN states, the trapezoid replan on the same
    states as the same-process reference. The main table runs after ``gc.freeze()`` (the
    objects made so far are out of the collector's way, as a real-time loop would arrange);
    one row first measures the S-curve with the collector as it is."""
    warm_up()
    states = replan_states(3)

    def scurve(s):
        return plan_scurve(
            s[0], s[1], v_max=s[4], a_max=s[5], j_max=s[6], v0=s[2], a0=s[3], v1=s[7]
        )

    def trap(s):
        return plan_trapezoid(s[0], s[1], v_max=s[4], a_max=s[5], v0=s[2], v1=s[7])

    def row(name: str, xs: list[float]) -> str:
        xs = sorted(xs)
        over = sum(x > 200.0 for x in xs)
        return (
            f"| {name} | {statistics.median(xs):,.1f} | {xs[int(0.99 * len(xs))]:,.1f} | "
            f"{xs[-1]:,.1f} | {over} |"
        )

    load_before = os.getloadavg()[0]
    cpu_gc = []
    for s in states:
        cpu_start = time.thread_time()
        scurve(s)
        cpu_gc.append((time.thread_time() - cpu_start) * 1e6)
    lines = [row("plan_scurve (replan), once, thread CPU time, GC not frozen", cpu_gc)]
    gc.collect()
    gc.freeze()
    for name, fn in (("plan_scurve (replan)", scurve), ("plan_trapezoid (reference)", trap)):
        once, least, cpu = [], [], []
        for s in states:
            # The thread's CPU time of the first run: what the call costs without the time
            # the scheduler gave to other processes in the middle of it.
            cpu_start = time.thread_time()
            start = time.perf_counter()
            fn(s)
            runs = [(time.perf_counter() - start) * 1e6]
            cpu.append((time.thread_time() - cpu_start) * 1e6)
            for _ in range(4):
                start = time.perf_counter()
                fn(s)
                runs.append((time.perf_counter() - start) * 1e6)
            once.append(runs[0])
            least.append(min(runs))
        lines.append(row(f"{name}, once", once))
        lines.append(row(f"{name}, once, thread CPU time", cpu))
        lines.append(row(f"{name}, least of 5", least))
    gc.unfreeze()
    load_after = os.getloadavg()[0]
    return [
        f"S-curve replan over {N_REPLAN:,} random states (load average {load_before:.2f} "
        f"before, {load_after:.2f} after; target: max <= 200 us):",
        "",
        "| operation | median (us) | p99 (us) | max (us) | > 200 us |",
        "|---|---:|---:|---:|---:|",
        *lines,
    ]


def main() -> None:
    rows: list[tuple[str, tuple[float, float], str]] = []
    warm_up()
    rest = states(1)
    moving = states(2, with_a0=True)

    def trap(s):
        return plan_trapezoid(s[0], s[1], v_max=s[4], a_max=s[5], v0=s[2])

    def scurve(s):
        return plan_scurve(s[0], s[1], v_max=s[4], a_max=s[5], j_max=s[6], v0=s[2], a0=s[3])

    rows.append(("plan_trapezoid (random v0)", median_us_per_call(trap, rest), "<= 10 us"))
    rows.append(("plan_scurve, a0 = 0", median_us_per_call(scurve, rest), "<= 50 us"))
    rows.append(("plan_scurve, a0 != 0", median_us_per_call(scurve, moving), "<= 200 us"))

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
        # S-curve durations against ruckig for a0 != 0: where the velocity can stay within
        # the limits (equal expected) and where the start is beyond them (never slower).
        for within in (True, False):
            ratios = []
            for s, inp in inputs_a0:
                p0, p1, v0, a0, v_max, a_max, j_max = s
                if (abs(v0 + a0 * abs(a0) / (2 * j_max)) <= v_max) != within:
                    continue
                otg.calculate(inp, traj)
                ratios.append(scurve(s).duration / traj.duration)
            if not ratios:
                continue
            ratios.sort()
            slower = sum(r > 1 + 1e-9 for r in ratios)
            faster = sum(r < 1 - 1e-9 for r in ratios)
            where = "within the limits" if within else "beyond the limits"
            ratio_lines.append(
                f"S-curve duration / ruckig duration, a0 != 0, {where} ({len(ratios)} states): "
                f"min {ratios[0]:.6f}, median {statistics.median(ratios):.9f}, max "
                f"{ratios[-1]:.9f}; slower by > 1e-9 in {slower}, faster in {faster}"
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
    print()
    for line in replan_table():
        print(line)


if __name__ == "__main__":
    main()
