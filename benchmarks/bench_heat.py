"""The heat model's and the thermal protection's cost (issue 13 §2.6): Fig. 8 (20 s, N = 1)
and Fig. 6 (2 s, N = 16) with ``[thermal] model`` off and on, and with the firmware's
``[safety] thermal_protection`` off (the tick before the protection), alternating in one
process; prints CPU-time medians and paired ratios of whole ``loop.run`` calls.

Run: ``python3 benchmarks/bench_heat.py [repeats]``. The machine's load average is printed
with the figures (the project's machine is shared; CPU time is less sensitive to it).
"""

from __future__ import annotations

import os
import statistics
import sys
import time

from sim import loop
from sim.reproduce import experiments

VARIANTS = {
    "protection off": {"safety.thermal_protection": False},
    "default (protection on)": None,
    "heat model on": {"thermal.model": True},
}


def _time(exp, batch, overrides) -> float:
    t = time.process_time()
    loop.run(exp, seed=0, batch=batch, overrides=overrides)
    return time.process_time() - t


def main(repeats: int = 7) -> None:
    cases = {
        "fig8 20 s, N = 1": (experiments.with_duration(experiments.load("fig8"), 20.0), None),
        "fig6 2 s, N = 16": (experiments.with_duration(experiments.load("fig6"), 2.0), 16),
    }
    for name, (exp, batch) in cases.items():
        for over in VARIANTS.values():  # load the kernels and the mode tables
            _time(exp, batch, over)
        times: dict[str, list[float]] = {v: [] for v in VARIANTS}
        for _ in range(repeats):
            for v, over in VARIANTS.items():
                times[v].append(_time(exp, batch, over))
        base = times["protection off"]
        parts = []
        for v, ts in times.items():
            ratios = [b / a for a, b in zip(base, ts, strict=True)]
            parts.append(
                f"{v} {statistics.median(ts) * 1e3:.1f} ms (x{statistics.median(ratios):.2f})"
            )
        print(f"{name}: " + ", ".join(parts) + f"; load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 7)
