"""Live plot benchmark (``monitor --plot``): frames per second drawn off screen (Agg), and
the whole monitor against ``serve --tcp`` in real time, telemetry counted.

    python3 benchmarks/bench_liveplot.py [--frames 200] [--duration 8]

1. Rendering: a 10 s window at 500 Hz of telemetry (5000 frames in the buffer), 20 new
   frames per redraw (25 fps at 500 Hz). Medians of the time per frame of ``LivePlot.draw``
   (lines over a cached background; the whole figure only when a y range changes), paired
   frame by frame with a reference: rendering the whole figure every frame (what a plain
   ``canvas.draw()`` per frame costs), alternating in the same process.
2. End to end: ``turntable-sim serve --tcp 0`` in another process, ``monitor --plot-save``
   in this one for ``--duration`` s with a move and an interrupt; frames drawn per second of
   wall time, telemetry frames received against the board's sequence gaps.

Wall-clock figures: they move with the machine's load (printed with them).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from serial_protocol.messages import Fault, State, Telemetry  # noqa: E402
from sim.liveplot import LiveBuffer, LivePlot  # noqa: E402


def load() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def feeder(buffer: LiveBuffer):
    """Telemetry of a turntable sweeping ±100 °/s, with encoder noise on the estimate."""
    rng = np.random.default_rng(0)
    tick = 0

    def feed(n: int) -> None:
        nonlocal tick
        for _ in range(n):
            t = tick / 500.0
            v = 100.0 * np.sin(0.8 * t)
            buffer.append(
                Telemetry(tick, -125.0 * np.cos(0.8 * t), v, -125.0 * np.cos(0.8 * t) + 0.01,
                          v + 0.3 * rng.standard_normal(), 0.4 * np.cos(0.8 * t), 0.1,
                          State.MOVING, Fault.NONE)
            )  # fmt: skip
            tick += 1

    return feed


def bench_render(frames: int) -> None:
    buffer = LiveBuffer(10_000)
    feed = feeder(buffer)
    feed(5000)
    plot = LivePlot(buffer, 10.0, title="bench")
    plot.draw()
    full_before = plot.full_redraws
    blit_s, full_s = [], []
    for _ in range(frames):
        feed(20)
        t0 = time.perf_counter()
        plot.draw()
        blit_s.append(time.perf_counter() - t0)
        feed(20)
        t0 = time.perf_counter()
        plot.update()
        plot.fig.canvas.draw()  # the reference: the whole figure every frame
        full_s.append(time.perf_counter() - t0)
    ratios = [f / b for b, f in zip(blit_s, full_s, strict=True)]
    med_b, med_f = statistics.median(blit_s), statistics.median(full_s)
    print("## Live plot: rendering (Agg, off screen)\n")
    print(f"{frames} frames each, 10 s window of 500 Hz telemetry; {load()}\n")
    print("| frame | median ms | frames/s |")
    print("|---|---|---|")
    print(f"| LivePlot.draw (lines over a cached background) | {med_b * 1e3:.1f} | "
          f"{1 / med_b:.0f} |")  # fmt: skip
    print(f"| reference: whole figure every frame | {med_f * 1e3:.1f} | {1 / med_f:.0f} |")
    print(f"\npaired ratio reference / LivePlot.draw: median {statistics.median(ratios):.1f}x; "
          f"{plot.full_redraws - full_before} of the {frames} live frames rendered the whole "
          "figure (a y range changed)")  # fmt: skip


def bench_end_to_end(duration_s: float) -> None:
    import argparse as ap

    from sim.commands import monitor

    serve = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "serve", "--tcp", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        url = serve.stdout.readline().strip()
        with tempfile.TemporaryDirectory() as tmp:
            parser = ap.ArgumentParser()
            monitor.add_arguments(parser)
            args = parser.parse_args([
                url, "--enable", "--move", "300", "--v-max", "400", "--a-max", "600",
                "--interrupt", str(duration_s / 3), "-200", "--duration", str(duration_s),
                "--plot-save", f"{tmp}/live.png", "--quiet", "--ack-timeout", "0.5",
            ])  # fmt: skip
            from contextlib import redirect_stdout
            from io import StringIO

            out = StringIO()
            wall0 = time.perf_counter()
            with redirect_stdout(out):
                monitor.main(args)
            wall_s = time.perf_counter() - wall0
        text = out.getvalue()
    finally:
        serve.terminate()
        serve.wait(timeout=10)
    drawn = int(text.split("live plot: ")[1].split(" frames drawn")[0])
    received = int(text.split("received telemetry ")[1].split(",")[0])
    gaps = text.split("sequence gaps ")[1].split(")")[0] + ")"
    print("\n## Live plot: monitor --plot-save against serve --tcp (real time)\n")
    print(f"{load()}\n")
    print(f"- wall time of monitor.main: {wall_s:.2f} s (listening {duration_s:g} s after the "
          "commands)")  # fmt: skip
    print(f"- frames drawn: {drawn}, {drawn / duration_s:.1f} per second of listening "
          "(the plot is paced at 25 per second)")  # fmt: skip
    print(f"- telemetry frames received: {received}; sequence gaps {gaps}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--duration", type=float, default=8.0)
    args = parser.parse_args()
    bench_render(args.frames)
    bench_end_to_end(args.duration)


if __name__ == "__main__":
    main()
