"""``turntable-sim reproduce`` as a user runs it: the whole command in fresh processes, this
tree against a reference tree (not a test; the numbers go to docs/benchmarks.md,
"reproduce").

Each round runs the command once in each tree, alternating (which tree goes first alternates
too), so that both see the same machine load; printed: every run's wall time and CPU time
(user + sys of the process and of the worker it draws with), the medians, the median of the
per-round ratios, and the load average around each round.

Usage::

    python3 benchmarks/bench_reproduce.py --ref /tmp/ref_tree [--rounds 5] [-- --quick]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def _load() -> str:
    return "load average " + " ".join(f"{x:.1f}" for x in os.getloadavg())


def run_once(tree: str, extra: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds of one ``python3 -m sim.cli reproduce`` in ``tree``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, PYTHONPATH=tree, MPLBACKEND="Agg")
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "sim.cli", "reproduce", "--out", tmp, "--quiet", *extra],
            cwd=tree, env=env, check=True, capture_output=True,
        )  # fmt: skip
        wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ref", required=True, help="the reference tree (a checkout)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("extra", nargs="*", help="more arguments for reproduce (after --)")
    args = ap.parse_args(argv)
    trees = {"reference": args.ref, "this tree": str(HERE)}
    for tree in trees.values():  # warm numba's cache of each tree (not timed)
        run_once(tree, args.extra)
    walls: dict[str, list[float]] = {n: [] for n in trees}
    cpus: dict[str, list[float]] = {n: [] for n in trees}
    for k in range(args.rounds):
        order = list(trees) if k % 2 == 0 else list(reversed(trees))
        text = []
        for name in order:
            wall, cpu = run_once(trees[name], args.extra)
            walls[name].append(wall)
            cpus[name].append(cpu)
            text.append(f"{name} {wall:.2f} s wall, {cpu:.2f} s CPU")
        print(f"round {k + 1}: " + "; ".join(text) + f" ({_load()})", flush=True)
    for label, data in (("wall", walls), ("CPU", cpus)):
        ratios = [b / a for a, b in zip(data["reference"], data["this tree"], strict=True)]
        print(
            f"{label}: reference median {statistics.median(data['reference']):.2f} s "
            f"({min(data['reference']):.2f}-{max(data['reference']):.2f}), this tree median "
            f"{statistics.median(data['this tree']):.2f} s ({min(data['this tree']):.2f}-"
            f"{max(data['this tree']):.2f}), this / reference {statistics.median(ratios):.2f}x "
            "(median of per-round ratios)"
        )


if __name__ == "__main__":
    main()
