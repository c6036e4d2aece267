"""Programs and streams on the board (issue #14): what a command costs the board's Python,
and what a 2 ms stream costs a simulated run against the same motion as one Move.

Prints, with the machine's load average:

1. per ``StreamPoints`` frame (5 points, 50 held ahead, a 2 ms period: the frame a PC sends
   every 10 ms), ``PointStream.check`` + ``add`` for LINEAR and CUBIC; per ``QueueSegment``
   appended to a program holding 16 blocks; the replan of a ``Move`` while moving as the
   same-process reference (``OnlinePlanner.command``), medians and p99 of 2,000 each;
2. a 2.4 s run of the paper's bench (emulated UART, compiled tick) following a 2 ms PVT
   stream of a 10 deg rest-to-rest cosine against the same run with one ``Move`` of the
   same length: wall time of each (median of 3, interleaved) and their ratio.

Run: ``PYTHONPATH=. python3 benchmarks/bench_stream.py``.
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from firmware_model.programs import ProgramQueue
from firmware_model.stream import PointStream
from planner.online import OnlinePlanner
from serial_protocol.messages import Interp


def _frames(n_frames: int, interp: Interp) -> list[float]:
    h = 0.002
    s = PointStream()
    s.start(0.0, h, interp, 32, v_max_dps=1000.0, a_max_dps2=2000.0,
            travel_deg=(-1e5, 1e5))  # fmt: skip

    def pt(k: int) -> tuple[float, float]:
        t = k * h
        return round(100.0 * (1.0 - np.cos(t)), 4), 100.0 * np.sin(t)

    k, t_s, out = 1, 0.0, []
    while k < 50:
        pts = tuple(pt(k + i) for i in range(5))
        s.check(t_s, k, pts)
        s.add(t_s, pts)
        k += 5
    for _ in range(n_frames):
        pts = tuple(pt(k + i) for i in range(5))
        w0 = time.perf_counter()
        refusal = s.check(t_s, k, pts)
        s.add(t_s, pts)
        out.append(time.perf_counter() - w0)
        assert refusal is None, refusal
        k += 5
        t_s += 5 * h
    return out


def _segments(n: int) -> list[float]:
    out = []
    for _ in range(n):
        q = ProgramQueue()
        for j in range(16):
            q.append(0.0, 0.0, 10.0 * (j + 1), 200.0, 0.0, v_limit_dps=1000.0,
                     a_max_dps2=2000.0)  # fmt: skip
        w0 = time.perf_counter()
        q.append(0.0, 0.0, 170.0, 200.0, 0.0, v_limit_dps=1000.0, a_max_dps2=2000.0)
        out.append(time.perf_counter() - w0)
    return out


def _replans(n: int) -> list[float]:
    out = []
    for k in range(n):
        p = OnlinePlanner("trapezoid")
        p.reset(0.0)
        p.command(0.0, 3000.0, v_max=990.0, a_max=148.0)
        w0 = time.perf_counter()
        p.command(1.0 + 1e-4 * k, -8000.0, v_max=990.0, a_max=148.0)
        out.append(time.perf_counter() - w0)
    return out


def _us(xs: list[float]) -> str:
    xs = sorted(xs)
    return (
        f"median {statistics.median(xs) * 1e6:7.1f} us, p99 {xs[int(0.99 * len(xs))] * 1e6:8.1f} us"
    )


def _runs() -> tuple[float, float]:
    from pathlib import Path

    from sim.config import Experiment, ScriptedCommand, load_bench, stream_commands
    from sim.loop import run, warm_up

    bench = load_bench(Path(__file__).resolve().parents[1] / "bench_configs" / "paper_bench.toml")
    warm_up(bench)
    n = 1000
    t = np.arange(1, n + 1) * 0.002
    pos = 10.0 * (1.0 - np.cos(np.pi * t / 2.0)) / 2.0
    vel = 10.0 * np.pi / 4.0 * np.sin(np.pi * t / 2.0)
    stream = Experiment(bench, 2.4, tuple(stream_commands(0.1, pos, vel, 0.002, Interp.CUBIC, 48)))
    move = Experiment(bench, 2.4, (ScriptedCommand(0.1, "move", (
        ("target_deg", 10.0), ("v_max_dps", 10.0), ("a_max_dps2", 20.0))),))  # fmt: skip
    walls: dict[str, list[float]] = {"stream": [], "move": []}
    for _ in range(3):
        for name, exp in (("stream", stream), ("move", move)):
            w0 = time.perf_counter()
            run(exp)
            walls[name].append(time.perf_counter() - w0)
    return statistics.median(walls["stream"]), statistics.median(walls["move"])


def main() -> None:
    print(f"load average {os.getloadavg()[0]:.1f} (2 cores, shared)")
    for interp in (Interp.LINEAR, Interp.CUBIC):
        label = f"StreamPoints frame ({interp.name:6s}, 5 points, 50 held):"
        print(f"{label} {_us(_frames(2000, interp))}")
    print(f"QueueSegment append (16 blocks held):           {_us(_segments(2000))}")
    print(f"Move replan while moving (reference):           {_us(_replans(2000))}")
    s, m = _runs()
    print(f"2.4 s run, 2 ms PVT stream: {s:.3f} s wall; one Move: {m:.3f} s; ratio {s / m:.2f}")


if __name__ == "__main__":
    main()
