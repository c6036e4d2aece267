"""``turntable-sim run CONFIG --out DIR``: run a scripted experiment, write log.csv and
plot.png."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from sim.commands._common import integer, output_dir

HELP = "run a scripted experiment (TOML) and write log.csv and plot.png"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", type=Path, help="experiment TOML file (see README)")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument(
        "--seed", type=integer(0, 2**63 - 1), default=0, help="noise and line-fault seed (>= 0)"
    )
    parser.add_argument("--no-plot", action="store_true", help="skip plot.png")
    parser.add_argument("--quiet", action="store_true", help="no progress bar or summary")


def main(args: argparse.Namespace) -> int:
    from sim.config import load_experiment

    exp = load_experiment(args.config)
    with output_dir(args.out, ("log.csv", "plot.png")):
        return _run(exp, args)


def _run(exp: Any, args: argparse.Namespace) -> int:
    from sim.csvlog import write_csv
    from sim.loop import run, warm_up
    from sim.progress import Progress

    # The compiled tick loads once per process (numba's start-up): timed apart, so that
    # the real-time factor below is the simulation's.
    load0 = time.perf_counter()
    warm_up(exp.bench)
    load_s = time.perf_counter() - load0
    n_ticks = max(1, round(exp.duration_s / exp.bench.dt_s))
    wall0 = time.perf_counter()
    # The project's progress display: a bar with ETA on a terminal, a few lines in a log.
    with Progress(args.config.name, n_ticks, enabled=not args.quiet) as bar:
        result = run(exp, seed=args.seed, progress=bar.callback)
    wall_s = time.perf_counter() - wall0
    log = result.log
    csv_path = write_csv(log, args.out / "log.csv")
    outputs = [csv_path]
    if not args.no_plot:
        from sim.plot import plot_run

        plot_run(log, args.out / "plot.png", exp.title or args.config.stem)
        outputs.append(args.out / "plot.png")
    if not args.quiet:
        faults = sorted({int(f) for f in log.fault if f})
        print(
            f"{args.config}: {len(log)} ticks ({exp.duration_s:g} s simulated) in "
            f"{wall_s:.2f} s wall ({exp.duration_s / wall_s:.0f}x real time; compiled kernels "
            f"loaded before it in {load_s:.2f} s)\n"
            f"final axis position {log.pos_deg[-1]:.3f} deg (true {log.true_pos_deg[-1]:.3f}), "
            f"faults {faults or 'none'}, "
            f"telemetry frames at the PC {len(result.telemetry_arrays()['tick'])}, "
            f"replies {len(result.replies)}"
        )
        for p in outputs:
            print(f"wrote {p}")
    return 0
