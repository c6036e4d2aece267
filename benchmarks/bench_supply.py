"""The bus model's cost (issue 13 §2.1): Fig. 6 (10 s, N = 1) and a batch of 16 members
(2 s) with ``[supply] bus_model`` off and on, alternating in one process; prints the
medians and the paired ratio (on / off) of whole ``loop.run`` calls (wall time).

Run: ``python3 benchmarks/bench_supply.py [repeats]``. The machine's load average is
printed with the figures (the project's machine is shared).
"""

from __future__ import annotations

import os
import statistics
import sys
import time

from sim import loop
from sim.reproduce import experiments


def _time(exp, batch, overrides) -> float:
    t = time.perf_counter()
    loop.run(exp, seed=0, batch=batch, overrides=overrides)
    return time.perf_counter() - t


def main(repeats: int = 7) -> None:
    cases = {
        "fig6 10 s, N = 1": (experiments.load("fig6"), None),
        "fig6 2 s, N = 16": (experiments.with_duration(experiments.load("fig6"), 2.0), 16),
    }
    for name, (exp, batch) in cases.items():
        _time(exp, batch, None)  # load the kernels and the mode tables
        _time(exp, batch, {"supply.bus_model": True})
        off, on = [], []
        for _ in range(repeats):
            off.append(_time(exp, batch, None))
            on.append(_time(exp, batch, {"supply.bus_model": True}))
        ratios = [b / a for a, b in zip(off, on, strict=True)]
        print(
            f"{name}: off median {statistics.median(off):.3f} s, on {statistics.median(on):.3f}"
            f" s, paired ratio on/off median {statistics.median(ratios):.2f} "
            f"(min {min(ratios):.2f}, max {max(ratios):.2f}), load {os.getloadavg()[0]:.1f}"
        )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 7)
