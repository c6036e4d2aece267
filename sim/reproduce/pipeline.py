"""Everything ``turntable-sim reproduce`` does, callable from Python: run the experiments,
draw the figures, write REPORT.md.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim.reproduce import (
    band,
    fig6,
    fig7,
    fig8,
    lookahead_demo,
    programs_demo,
    report,
    scurve_extras,
    seed002,
)
from sim.reproduce.drawing import Drawer
from sim.reproduce.experiments import Runner, load, write_telemetry_csv

__all__ = ["FIGURES", "TELEMETRY_DIR", "ReproduceOutput", "reproduce"]

FIGURES = (
    "fig6.png",
    "fig7.png",
    "fig8.png",
    "fig7_scurve.png",
    "fig8_scurve.png",
    "lookahead.png",
    "programs.png",
    "stream.png",
    "fig6_band.png",
)
# The decoded telemetry of the paper's runs, as CSV (the columns of `monitor --csv`).
TELEMETRY_DIR = "telemetry"
# fig6 (2) + fig7 (4) + fig8 (1) + seed 002 (1) + S-curve fig7 (4) + fig8 (1) + look-ahead (2)
# + programs and streams (3)
_RUNS_ALL = 20
_RUNS_PAPER = 9


@dataclass(frozen=True)
class ReproduceOutput:
    """What was written (``paths``), the results behind it (``inputs``) and the wall time."""

    out_dir: Path
    paths: tuple[Path, ...]
    inputs: report.ReportInputs
    wall_s: float
    simulated_s: float


def reproduce(
    out_dir: str | Path,
    *,
    quick: bool = False,
    extras: bool = True,
    show_progress: bool = True,
    stream: Any = None,
    sensitivity: bool = False,
    retune: str = "classic",
    noise_copies: int | None = None,
) -> ReproduceOutput:
    """Run every experiment and write the figures and REPORT.md into ``out_dir``.

    Args:
        quick: the time-scaled forms (``experiments.scale_quick``), four times shorter.
        extras: also seed 002's tables, the S-curve runs and the look-ahead program.
        show_progress: a progress display per run on ``stream`` (default stderr).
        sensitivity: the full sensitivity study (``sim.reproduce.band.run_sensitivity``
            with ``full=True``) instead of its cheap form.
        retune: how each motor of the study is re-tuned, ``"classic"`` or ``"de"``.
        noise_copies: noise realisations of every run and of the study's nominal members
            and variants (default 3, or 5 with ``sensitivity``; the runs take at least 2):
            REPORT.md's error bars.
    """
    wall0 = time.monotonic()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    copies = band.default_noise_copies(sensitivity) if noise_copies is None else noise_copies
    runner = Runner(
        quick=quick,
        show_progress=show_progress,
        total_runs=_RUNS_ALL if extras else _RUNS_PAPER,
        stream=stream,
        # every run in its noise realisations, one batch each (at least 2 for a spread)
        copies=max(copies, 2),
    )
    bench = load("fig8").bench
    limit_a = bench.firmware.limits.current_limit_a
    paths: list[Path] = []
    # Each figure is drawn by a second process as soon as its runs are done (drawing
    # and saving PNGs is about half of the command's work), overlapping what follows.
    with Drawer() as drawer:
        r6 = fig6.run(runner)
        r7 = fig7.run(runner)
        r8 = fig8.run(runner)
        r8c = fig8.run_choices(runner)  # a_max per move; no feed-forward (section 3)
        drawer.submit(fig6.plot, r6, out / "fig6.png", limit_a)
        drawer.submit(fig7.plot, r7, out / "fig7.png", limit_a)
        drawer.submit(fig8.plot, r8, out / "fig8.png", limit_a)
        paths += [out / "fig6.png", out / "fig7.png", out / "fig8.png"]
        tel = out / TELEMETRY_DIR
        traces = [("fig6_step", r6.step), ("fig6_trapezoid", r6.planned), ("fig8", r8.trace)]
        traces += [(f"fig7_{r.name}", r.trace) for r in r7.runs]
        for stem, trace in traces:
            drawer.submit(write_telemetry_csv, trace, tel / f"{stem}.csv")
            paths.append(tel / f"{stem}.csv")
        if show_progress:
            print(
                f"[sensitivity] {'full' if sensitivity else 'cheap'} study, {retune} re-tune...",
                file=stream if stream is not None else sys.stderr,
            )
        sens = band.run_sensitivity(
            quick=quick, full=sensitivity, retune_how=retune, noise_copies=noise_copies
        )
        drawer.submit(band.plot, sens.band, out / "fig6_band.png")
        s2 = sc = la = pg = None
        if extras:
            s2 = seed002.run(runner)
            sc = scurve_extras.run(runner, r7, r8)
            k = sc.fig7.time_scale
            drawer.submit(
                fig7.plot,
                sc.fig7,
                out / "fig7_scurve.png",
                limit_a,
                # the run's jerk: the time scaling multiplies it by k
                title=f"Fig. 7 with the S-curve planner ($j_{{max}}$ {sc.j_max_dps3 * k:g} "
                "°/s$^3$)",
                acceleration=True,
            )
            drawer.submit(fig8.plot, sc.fig8, out / "fig8_scurve.png", limit_a)
            la = lookahead_demo.run(runner)
            drawer.submit(lookahead_demo.plot, la, out / "lookahead.png", limit_a)
            pg = programs_demo.run(runner)
            drawer.submit(programs_demo.plot_programs, pg, out / "programs.png", limit_a)
            drawer.submit(programs_demo.plot_stream, pg, out / "stream.png")
            paths += [out / "fig7_scurve.png", out / "fig8_scurve.png", out / "lookahead.png",
                      out / "programs.png", out / "stream.png"]  # fmt: skip
        paths.append(out / "fig6_band.png")
    # Error bars: every run's metrics over its noise realisations (REPORT.md, sections 1-7).
    from sim.reproduce.metrics import measure  # not at the top: python -m runs sensitivity
    from sim.reproduce.sensitivity import metric_spread

    measured = [(r6.step, None), (r6.planned, None), (r8.trace, None)]
    measured += [(r.trace, None) for r in r8c]
    measured += [(r.trace, r.trace.command_t_s[-1]) for r in r7.runs]
    if sc is not None:  # measured as scurve_extras measures them (Fig. 7 from the interrupt)
        measured += [(r.trace, r.trace.command_t_s[-1]) for r in sc.fig7.runs]
        measured += [(sc.fig8.trace, None)]
    copy_traces = dict(runner.copies_of)
    copy_metrics = {
        t.name: tuple(measure(c, limit_a, from_t) for c in copy_traces[t.name])
        for t, from_t in measured
    }
    noise = {name: metric_spread(rows) for name, rows in copy_metrics.items()}
    wall_s = time.monotonic() - wall0
    inputs = report.ReportInputs(
        fig6=r6,
        fig7=r7,
        fig8=r8,
        fig8_choices=r8c,
        seed002=s2,
        scurve=sc,
        lookahead=la,
        baud=int(bench.firmware.telemetry.baud),
        tick_hz=float(bench.firmware.servo.tick_hz),
        current_limit_a=limit_a,
        acc_ff_a_per_dps2=float(bench.firmware.velocity.acc_ff_a_per_dps2),
        quick=quick,
        wall_s=wall_s,
        figures=tuple(p.name for p in paths if p.suffix == ".png"),
        programs=pg,
        sensitivity=sens,
        noise=noise,
        noise_traces=copy_traces,
        copy_metrics=copy_metrics,
    )
    report_path = out / "REPORT.md"
    report.write_report(inputs, report_path)
    paths.append(report_path)
    simulated_s = runner.ticks * bench.dt_s
    return ReproduceOutput(out, tuple(paths), inputs, wall_s, simulated_s)
