"""The bus model's cost (issue 13 §2.1): Fig. 6 (10 s) and Fig. 8 (30 s) at N = 1, and a
batch of 16 members (Fig. 6, 2 s), with ``[supply] bus_model`` off, on with the adaptive
step (``bus_quiet_v`` = 1 mV, the default) and on with the sub-steps everywhere
(``bus_quiet_v = 0``, the model before the adaptive step), alternating in one process;
prints the medians of whole ``loop.run`` calls (CPU time) and the paired ratios to "off",
and the share of the member-periods taken whole (and of those, the share that needed the
second pass).

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
from sim.supply import SUB_QUIET, SUB_SECOND

VARIANTS = {
    "off": None,
    "adaptive": {"supply.bus_model": True},
    "sub-steps": {"supply.bus_model": True, "supply.bus_quiet_v": 0.0},
}


class _Keep(loop.Simulation):
    last: loop.Simulation | None = None

    def __init__(self, *a, **k) -> None:
        super().__init__(*a, **k)
        _Keep.last = self


def _time(exp, batch, overrides) -> float:
    """CPU time (user + system) of one whole run: the shared machine's load disturbs it
    far less than wall time."""
    t = time.process_time()
    loop.run(exp, seed=0, batch=batch, overrides=overrides)
    return time.process_time() - t


def main(repeats: int = 7) -> None:
    cases = {
        "fig6 10 s, N = 1": (experiments.load("fig6"), None),
        "fig8 30 s, N = 1": (experiments.load("fig8"), None),
        "fig6 2 s, N = 16": (experiments.with_duration(experiments.load("fig6"), 2.0), 16),
    }
    loop.Simulation = _Keep
    for name, (exp, batch) in cases.items():
        whole, second = {}, {}
        for label, overrides in VARIANTS.items():
            _time(exp, batch, overrides)  # load the kernels and the mode tables
            sim = _Keep.last
            if overrides:
                periods = len(sim.log().t_s) * sim.multiple * (batch or 1)
                whole[label] = int(sim.bus.sub[SUB_QUIET]) / periods
                second[label] = int(sim.bus.sub[SUB_SECOND]) / max(1, int(sim.bus.sub[SUB_QUIET]))
        times: dict[str, list[float]] = {label: [] for label in VARIANTS}
        for _ in range(repeats):
            for label, overrides in VARIANTS.items():
                times[label].append(_time(exp, batch, overrides))
        off = times["off"]
        parts = [f"off {statistics.median(off):.3f} s"]
        for label in ("adaptive", "sub-steps"):
            ratios = [b / a for a, b in zip(off, times[label], strict=True)]
            med = statistics.median(times[label])
            parts.append(
                f"{label} {med:.3f} s = x{statistics.median(ratios):.2f}"
                f" ({min(ratios):.2f}-{max(ratios):.2f}; {100 * whole[label]:.0f} % whole, "
                f"{100 * second[label]:.0f} % of them twice)"
            )
        print(f"{name}: " + ", ".join(parts) + f"; load {os.getloadavg()[0]:.1f}", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 7)
