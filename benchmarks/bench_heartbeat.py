"""What the board's heartbeat costs a compiled run (not a test; docs/benchmarks.md,
"Simulation"): the 20 s Fig. 8 run at N = 1, decoded by the simulated PC, with the default
``BoardHeartbeat`` every 200 ms and with ``telemetry.heartbeat_s = 0``, alternated in one
process (median of 7 pairs, CPU time of the process: what a loaded machine disturbs least);
with ``--ref TREE`` the same in the reference tree, the trees alternated process by process.

Usage::

    python3 benchmarks/bench_heartbeat.py [--ref /tmp/ref_tree] [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

_MEASURE = r"""
import dataclasses, json, resource, statistics, sys, warnings
warnings.simplefilter("ignore")
tree = {tree!r}
sys.path.insert(0, tree)
from pathlib import Path
from sim.config import load_experiment
from sim.loop import run
fig8 = load_experiment(Path(tree) / "bench_configs" / "fig8.toml")
one = dataclasses.replace(fig8, duration_s=20.0)
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
def timed(overrides):
    t0 = cpu()
    run(one, overrides=overrides).telemetry_arrays()
    return cpu() - t0
run(dataclasses.replace(fig8, duration_s=0.1))  # load the kernels
timed({{}}); timed({{"telemetry.heartbeat_s": 0.0}})
on, off = [], []
for _ in range(7):
    on.append(timed({{}}))
    off.append(timed({{"telemetry.heartbeat_s": 0.0}}))
print(json.dumps({{"on_ms": statistics.median(on) * 1e3, "off_ms": statistics.median(off) * 1e3}}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", help="a reference tree (e.g. a checkout of the previous commit)")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    here = str(Path(__file__).resolve().parents[1])
    trees = {"this tree": here, "reference": args.ref} if args.ref else {"this tree": here}
    for r in range(args.rounds):
        for name, tree in trees.items():
            out = subprocess.run(
                [sys.executable, "-c", _MEASURE.format(tree=tree)],
                capture_output=True, text=True, check=True,
            )  # fmt: skip
            m = json.loads(out.stdout.strip().splitlines()[-1])
            load = " ".join(f"{v:.1f}" for v in os.getloadavg())
            print(
                f"round {r + 1} {name}: with heartbeats {m['on_ms']:.2f} ms, without "
                f"{m['off_ms']:.2f} ms CPU ({100 * (m['on_ms'] / m['off_ms'] - 1):+.0f} %) "
                f"(load average {load})",
                flush=True,
            )


if __name__ == "__main__":
    main()
