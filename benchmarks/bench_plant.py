"""The tick before and after issue 13 (plant fidelity, round 2), paired in one process.

Issue 13's target: the tick stays within 25 % of its speed before the issue. The reference
is the plant of ``REF`` (the last commit before the issue's changes to ``sim/plant.py`` and
``sim/plant_kernel.py``), loaded from git into this process next to the working tree's; the
runs alternate (reference, new, reference, ...) so that the machine's load hits both alike,
and the ratio of the medians is quoted, with the load average.

1. the plant alone: the 15,000 recorded inputs of a 30 s Fig. 8 run, N = 1 (``Plant.update``);
2. the whole 20 s Fig. 8 run (``sim.loop.run``, firmware, encoder, UART), N = 1, with the
   reference plant swapped into ``sim.loop`` and the encoder's INL off (the tick before the
   issue) against the working tree's plant with ``paper_bench.toml``'s INL on;
3. the same at N = 64 (2 s), parameters shared.

Usage::

    python3 benchmarks/bench_plant.py [--repeat 5] [--ref c2ce113]
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

INL_OFF = {"encoder.inl_h1_deg": 0.0, "encoder.inl_h2_deg": 0.0}


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


def time_run(plant_cls: type, duration_s: float, batch: int | None, overrides) -> float:
    exp = experiments.with_duration(experiments.load("fig8"), duration_s)
    saved, loop.Plant = loop.Plant, plant_cls
    try:
        wall = time.perf_counter()
        loop.run(exp, seed=0, batch=batch, overrides=overrides)
        return time.perf_counter() - wall
    finally:
        loop.Plant = saved


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--ref", default="c2ce113")
    args = ap.parse_args()
    ref_plant = load_reference(args.ref)
    duty, enable, params = recorded_inputs(30.0)
    cases = [
        ("plant, 15,000 Fig. 8 steps, N = 1", lambda cls, o: time_plant(cls, params, duty, enable)),
        ("fig8 20 s run, N = 1", lambda cls, o: time_run(cls, 20.0, None, o)),
        ("fig8 2 s run, N = 64", lambda cls, o: time_run(cls, 2.0, 64, o)),
    ]
    # Warm-up: compile or load both kernels, fill the matrix caches.
    for _, fn in cases:
        fn(ref_plant, INL_OFF)
        fn(Plant, None)
    print(f"reference {args.ref}; load average {os.getloadavg()[0]:.2f} at the start")
    for label, fn in cases:
        ref_s, new_s = [], []
        for _ in range(args.repeat):
            ref_s.append(fn(ref_plant, INL_OFF))
            new_s.append(fn(Plant, None))
        r, n = statistics.median(ref_s), statistics.median(new_s)
        ratios = [b / a for a, b in zip(ref_s, new_s, strict=True)]
        print(
            f"{label}: reference {r:.3f} s, issue 13 {n:.3f} s (medians of {args.repeat}); "
            f"new/ref {n / r:.3f} (paired ratios {min(ratios):.3f}-{max(ratios):.3f})"
        )
    print(f"load average {os.getloadavg()[0]:.2f} at the end (2 cores, shared)")


if __name__ == "__main__":
    main()
