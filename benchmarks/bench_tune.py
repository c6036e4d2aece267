"""Tuning benchmark: wall time of tuning the three loops on the Fig. 8 scenario, and what one
generation costs.

Run: ``python3 benchmarks/bench_tune.py`` (about 2 minutes; ``--full`` adds the tune on the
uncompressed 30 s scenario, several minutes more). Prints a Markdown table (host wall clock,
``wall_s``). Target: the staged tune of the three loops under 60 s on the 2-core machine.

Measured:

* the simulator's lock-step batch: microseconds per servo tick for N = 1, 24 and 96 members
  (one generation costs about ticks x that);
* the linear gate: milliseconds per candidate (margins of the three loops);
* ``sim.tuning.optimise.tune`` with the command's defaults (staged, popsize 10, maxiter 4)
  on Fig. 8 compressed 4x (8.5 s simulated with the tail), and with ``--full`` at scale 1.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import bench_configs
from sim.config import load_bench
from sim.reproduce.experiments import QUICK_TIME_SCALE
from sim.tuning import linear
from sim.tuning.cost import CostWeights
from sim.tuning.evaluate import evaluate
from sim.tuning.gains import GainSet
from sim.tuning.optimise import TuneSettings, tune
from sim.tuning.scenarios import scenario


def per_tick_us(exp, gains: GainSet, n: int, duration_s: float = 1.0, repeats: int = 3) -> float:
    """Median wall time per tick of ``repeats`` evaluations of ``n`` members (us)."""
    short = dataclasses.replace(exp, duration_s=duration_s)
    ticks = int(round(duration_s / exp.bench.dt_s))
    walls = []
    for _ in range(repeats):
        wall0 = time.perf_counter()
        evaluate([short], [gains] * n, weights=CostWeights())
        walls.append(time.perf_counter() - wall0)
    return statistics.median(walls) / ticks * 1e6


def gate_ms(bench, gains: GainSet, repeats: int = 20) -> float:
    spec = linear.MarginSpec()
    linear.rejection_reasons(bench, gains, spec)
    wall0 = time.perf_counter()
    for _ in range(repeats):
        linear.rejection_reasons(bench, gains, spec)
    return (time.perf_counter() - wall0) / repeats * 1e3


def tune_wall_s(bench, time_scale: float) -> tuple[float, float, float, int]:
    exp = scenario("fig8", bench, time_scale=time_scale, tail_s=1.0)
    start = GainSet.from_bench(bench)
    settings = TuneSettings()
    wall0 = time.perf_counter()
    result = tune([exp], start, settings)
    wall_s = time.perf_counter() - wall0
    ev = evaluate([exp], [start, result.gains], weights=settings.weights)
    sims = sum(s.simulated for s in result.stages)
    return wall_s, float(ev.cost[0]), float(ev.cost[1]), sims


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="also tune at time scale 1")
    args = parser.parse_args()
    bench = load_bench(bench_configs.path("paper_bench"))
    gains = GainSet.from_bench(bench)
    exp = scenario("fig8", bench, time_scale=QUICK_TIME_SCALE, tail_s=1.0)
    # One untimed run first: loading the compiled kernels (numba's start-up, ~0.3 s) is a
    # cost per process, not per tick.
    per_tick_us(exp, gains, 1, duration_s=0.1, repeats=1)
    rows = []
    for n in (1, 24, 96):
        rows.append((f"batch tick, N = {n}", f"{per_tick_us(exp, gains, n):,.0f}", "us"))
    rows.append(("linear gate per candidate (3 loops)", f"{gate_ms(bench, gains):.1f}", "ms"))
    scales = [QUICK_TIME_SCALE] + ([1.0] if args.full else [])
    for k in scales:
        wall_s, before, after, sims = tune_wall_s(bench, k)
        label = f"tune 3 loops, Fig. 8 at time scale 1/{k:g}"
        rows.append((label, f"{wall_s:.1f}", f"s ({sims} candidates simulated)"))
        rows.append((f"  cost before -> after (scale 1/{k:g})", f"{before:.3f} -> {after:.3f}", ""))
    print("| measurement | value | unit |")
    print("|---|---:|---|")
    for name, value, unit in rows:
        print(f"| {name} | {value} | {unit} |")


if __name__ == "__main__":
    main()
