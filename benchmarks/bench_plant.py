"""The tick before and after issue 13 (plant fidelity, round 2), paired.

Issue 13's target: the tick stays within 25 % of its speed before the issue. The reference
``REF`` is the tree before the issue's commits (default: the merge base with main, i.e.
main without this branch).

1. the plant alone, in one process: ``REF``'s ``sim/plant.py`` and ``sim/plant_kernel.py``
   loaded from git as private modules next to the working tree's, both stepping the
   15,000 recorded inputs of a 30 s Fig. 8 run (N = 1), runs alternating;
2. the whole 20 s Fig. 8 run (``sim.loop.run``: the compiled tick, firmware, encoder,
   UART), N = 1 and N = 64 (2 s): ``REF``'s tree (``git archive``) and the working tree,
   each timed inside a fresh process, the processes alternating.

Medians and the ratio new / reference, with the load average (the machine is shared).

Usage::

    python3 benchmarks/bench_plant.py [--repeat 5] [--ref REV]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim import loop  # noqa: E402
from sim.plant import Plant  # noqa: E402
from sim.reproduce import experiments  # noqa: E402

# One timed run in a fresh process of a tree (its root first on sys.path).
CHILD = """
import sys, time
sys.path.insert(0, sys.argv[1])
from sim.loop import run
from sim.reproduce import experiments
exp = experiments.with_duration(experiments.load("fig8"), float(sys.argv[2]))
batch = int(sys.argv[3]) or None
run(experiments.with_duration(exp, 0.1), batch=batch)  # compile / load the kernels
wall = time.perf_counter()
run(exp, batch=batch)
print(time.perf_counter() - wall)
"""


def load_reference(ref: str) -> type:
    """``Plant`` of commit ``ref``: its plant.py and plant_kernel.py as private modules."""
    tmp = Path(tempfile.mkdtemp(prefix="bench_plant_"))
    for name in ("plant_kernel", "plant"):
        text = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{ref}:sim/{name}.py"],
            check=True, capture_output=True, text=True,
        ).stdout  # fmt: skip
        text = text.replace(
            "from sim import plant_kernel", "import _ref_plant_kernel as plant_kernel"
        )
        (tmp / f"_ref_{name}.py").write_text(text)
    sys.path.insert(0, str(tmp))
    for name in ("_ref_plant_kernel", "_ref_plant"):
        spec = importlib.util.spec_from_file_location(name, tmp / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules["_ref_plant"].Plant


def recorded_inputs(duration_s: float) -> tuple[np.ndarray, np.ndarray, object]:
    exp = experiments.with_duration(experiments.load("fig8"), duration_s)
    holder = {}

    class Recording(loop.Simulation):
        def __init__(self, *a, **k):
            k["record_inputs"] = True
            super().__init__(*a, **k)
            holder["sim"] = self

    saved, loop.Simulation = loop.Simulation, Recording
    try:
        loop.run(exp, seed=0)
    finally:
        loop.Simulation = saved
    duty, enable = holder["sim"].inputs()
    return duty, enable, exp.bench.plant


def time_plant(plant_cls: type, params, duty, enable) -> float:
    plant = plant_cls(params, 1, 0.002)
    x = np.zeros((1, 5))
    d1, e1 = np.empty(1), np.empty(1, dtype=bool)
    wall = time.perf_counter()
    for k in range(len(duty)):
        d1[0], e1[0] = duty[k], enable[k]
        x = plant.update(0.0, x, (d1.copy(), e1.copy()))
    return time.perf_counter() - wall


def time_run(tree: Path, duration_s: float, batch: int) -> float:
    """Wall time of one Fig. 8 run of ``tree`` in a fresh process (kernels loaded first)."""
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(tree), str(duration_s), str(batch)],
        check=True, capture_output=True, text=True, cwd=tree,
    ).stdout  # fmt: skip
    return float(out.strip().splitlines()[-1])


def export_tree(ref: str) -> Path:
    """``ref``'s tree in a temporary directory."""
    tmp = Path(tempfile.mkdtemp(prefix="bench_plant_tree_"))
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", ref], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(tmp)], input=archive, check=True)
    return tmp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--ref", default=None, help="default: git merge-base HEAD main")
    args = ap.parse_args()
    ref = args.ref or subprocess.run(
        ["git", "-C", str(ROOT), "merge-base", "HEAD", "main"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    ref_plant = load_reference(ref)
    ref_tree = export_tree(ref)
    duty, enable, params = recorded_inputs(30.0)
    cases = [
        ("plant, 15,000 Fig. 8 steps, N = 1", lambda new: time_plant(
            Plant if new else ref_plant, params, duty, enable)),
        ("fig8 20 s run, N = 1", lambda new: time_run(ROOT if new else ref_tree, 20.0, 0)),
        ("fig8 2 s run, N = 64", lambda new: time_run(ROOT if new else ref_tree, 2.0, 64)),
    ]  # fmt: skip
    time_plant(ref_plant, params, duty, enable)  # compile / load both plant kernels
    time_plant(Plant, params, duty, enable)
    print(f"reference {ref[:10]}; load average {os.getloadavg()[0]:.2f} at the start")
    for label, fn in cases:
        ref_s, new_s = [], []
        for _ in range(args.repeat):
            ref_s.append(fn(False))
            new_s.append(fn(True))
        r, n = statistics.median(ref_s), statistics.median(new_s)
        ratios = [b / a for a, b in zip(ref_s, new_s, strict=True)]
        print(
            f"{label}: reference {r:.3f} s, issue 13 {n:.3f} s (medians of {args.repeat}); "
            f"new/ref {n / r:.3f} (paired ratios {min(ratios):.3f}-{max(ratios):.3f})"
        )
    print(f"load average {os.getloadavg()[0]:.2f} at the end (2 cores, shared)")


if __name__ == "__main__":
    main()
