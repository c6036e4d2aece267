"""The back-EMF check's R spread and offset allowance once the IS offset is calibrated at
enable (issue 13 §2.3; figures go to docs/model.md, "Safety"): false trips over a grid of
healthy boards and the detection of real faults, for each setting. Not a test: the suite
pins the chosen setting's outcome (tests/firmware_model/test_sensor_spread.py).

* False trips: Fig. 6 (the step, 6 s) and Fig. 8 (20 s) as batches, the plant's heat model
  on, every member a healthy board: k_ILIS 3k-14k (the firmware assumes 8.5k) x R x0.7 /
  x1.0 / x1.3 (at its 20 degC reference) x the motor's temperature at power-up (cold: at
  the lab's 25 degC; warm: a restart with the winding +55 K, the housing +30 K; hot: a
  restart at the firmware's thermal trip, the winding at 120 degC, +95 K, the housing
  +70 K), plus IS offsets (50 uA, and 70 / 30 uA per pin). A member counts as a false trip
  if it latches SENSOR_MISMATCH (k_ILIS 3k-6k may trip OVER_CURRENT: the chip reads up to
  2.8x the current, a different fault, listed). Then the heat duty (Fig. 6's move back and
  forth, docs/heat_duty.py) until the THERMAL trip: boards warmed by running, which the
  firmware's estimate follows.
* Detection: a noisy (+-1 count) freeze of the encoder cruising at 30 / 60 / 100 / 130
  deg/s (benchmarks/sensor_check.py's); the IS pin shorted (the ADC reads 0 V) and stuck
  (its reading frozen) while cruising at 100 deg/s (3 s in); an open winding (R 1 kOhm)
  from a move's start; the freeze at 100 deg/s again in moves 10 / 30 / 60 min after
  power-up. Ticks from the fault to the first trip, which trip, the axis travel.

    python3 benchmarks/sensor_spread.py [--only NAME ...] [--no-heat]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "firmware_model"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "docs"))

from uart_fuzz import paper_bench  # noqa: E402

from serial_protocol import frame  # noqa: E402
from serial_protocol.messages import Fault, FaultReport, Hello, Move, Profile  # noqa: E402
from sim import loop  # noqa: E402
from sim.reproduce.experiments import load, with_duration  # noqa: E402

CAL = {"controller.current.sense_calibration": True}
OFF = {"safety.sensor_mismatch_restart_rise_k": 0.0}  # no warm-restart allowance


def _cal(counts: int, r_spread: float = 0.3, restart_k: float = 0.0) -> dict:
    return {**CAL, "safety.sensor_mismatch_calibrated_offset_counts": counts,
            "safety.sensor_mismatch_r_spread": r_spread,
            "safety.sensor_mismatch_restart_rise_k": restart_k}  # fmt: skip


# Offset allowance (counts), R spread, warm-restart allowance; the sense spread 0.65.
SETTINGS = {
    "uncalibrated, 62, 0.3 (the default before)": {**OFF},
    "calibrated, 62, 0.3": _cal(62),
    "calibrated, 2, 0.3": _cal(2),
    "calibrated, 2, 0.45": _cal(2, 0.45),
    "calibrated, 2, 0.5": _cal(2, 0.5),
    "calibrated, 2, 0.3, restart 80 K (the default, calibrated)": _cal(2, 0.3, 80.0),
    "calibrated, 2, 0.3, restart 100 K": _cal(2, 0.3, 100.0),
    "uncalibrated, 62, 0.3, restart 80 K (the default)": {},
}

R_NOMINAL_OHM = 1.2  # bench_configs/paper_bench.toml [motor] r_ohm (at 20 degC)
K_ILIS = (3000.0, 6000.0, 8500.0, 10000.0, 12000.0, 14000.0)
STARTS = {"cold": (0.0, 0.0), "warm": (55.0, 30.0), "hot": (95.0, 70.0)}
HEAT = {"thermal.model": True}


def grid() -> list[tuple[str, dict]]:
    rows = []
    for start, (w, h) in STARTS.items():
        for k in K_ILIS:
            for r in (0.7, 1.0, 1.3):
                rows.append((f"{k / 1000:g}k R x{r} {start}", {
                    "current_sense.k_ilis": k, "motor.r_ohm": R_NOMINAL_OHM * r,
                    "thermal.initial_winding_rise_k": w, "thermal.initial_housing_rise_k": h,
                    "current_sense.is_offset_ua": 0.0, "current_sense.is_offset_mismatch_ua": 0.0,
                }))  # fmt: skip
    for o, m in ((50.0, 0.0), (50.0, 40.0), (50.0, -40.0)):
        for k, r in ((8500.0, 1.0), (14000.0, 1.3)):
            rows.append((f"{k / 1000:g}k R x{r} warm, IS {o + m / 2:g}/{o - m / 2:g} uA", {
                "current_sense.k_ilis": k, "motor.r_ohm": R_NOMINAL_OHM * r,
                "thermal.initial_winding_rise_k": 55.0, "thermal.initial_housing_rise_k": 30.0,
                "current_sense.is_offset_ua": o, "current_sense.is_offset_mismatch_ua": m,
            }))  # fmt: skip
    return rows


def batch_run(exp, rows, overrides):
    """``exp`` as one batch, member m with ``rows[m]``: per member the first fault (0: none),
    its time (s), and the check's largest excess (deg)."""
    holder = {}

    class Keep(loop.Simulation):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            holder["sim"] = self

    ov = {key: [row[key] for row in rows] for key in rows[0]}
    saved, loop.Simulation = loop.Simulation, Keep
    try:
        log = loop.run(exp, batch=len(rows), overrides={**ov, **HEAT, **overrides}).log
    finally:
        loop.Simulation = saved
    faults = np.atleast_2d(log.fault)
    first, when = [], []
    for f in faults:
        k = np.flatnonzero(f)
        first.append(int(f[k[0]]) if k.size else 0)
        when.append(float(log.t_s[k[0]]) if k.size else float("nan"))
    return first, when, holder["sim"].fw.sensor_mismatch_peak_deg.copy()


def false_trips(name: str, overrides: dict) -> list[str]:
    rows = grid()
    labels, values = [r[0] for r in rows], [r[1] for r in rows]
    out = []
    for fig, exp in (("fig6", with_duration(load("fig6"), 6.0)), ("fig8", load("fig8"))):
        first, when, peak = batch_run(exp, values, overrides)
        mm = [f"{lab} at {t:.3f} s" for lab, f, t in zip(labels, first, when, strict=True)
              if f == Fault.SENSOR_MISMATCH]  # fmt: skip
        other = sorted({(Fault(f).name, lab.split(" ")[0]) for lab, f in
                        zip(labels, first, strict=True) if f not in (0, Fault.SENSOR_MISMATCH)})
        ok = [p for f, p in zip(first, peak, strict=True) if f == 0]
        out.append(f"  {fig}: SENSOR_MISMATCH {len(mm)} of {len(rows)}"
                   f"{': ' + '; '.join(mm) if mm else ''}; other faults {other or 'none'}; "
                   f"largest excess of the untripped {max(ok):.3f} deg")  # fmt: skip
    return out


def heat_duty(overrides: dict, minutes: float) -> str:
    from heat_duty import back_and_forth

    rows = [{"current_sense.k_ilis": k, "motor.r_ohm": R_NOMINAL_OHM * r}
            for k in (8500.0, 14000.0) for r in (0.7, 1.0, 1.3)]  # fmt: skip
    first, when, peak = batch_run(back_and_forth(minutes, 4.0), rows, overrides)
    desc = ", ".join(
        f"{row['current_sense.k_ilis'] / 1000:g}k x{row['motor.r_ohm'] / R_NOMINAL_OHM:.1f}: "
        f"{Fault(f).name if f else 'none'}{f' {t / 60:.1f} min' if f else ''}"
        for row, f, t in zip(rows, first, when, strict=True)
    )
    return f"  heat duty {minutes:g} min: {desc}; largest excess {peak.max():.3f} deg"


def _first_report(sim):
    reports = [m for m in frame.Decoder().feed(sim.pc_read()) if isinstance(m, FaultReport)]
    return reports[0] if reports else None


def _moving(overrides, target_deg, v_dps, **plant):
    sim = loop.Simulation(paper_bench(**overrides, **plant), seed=3)
    sim.pc_write(frame.encode(Hello(0, session=1), 0))
    sim.pc_write(frame.encode(Move(1, target_deg, v_dps, 2000.0, 0.0, Profile.TRAPEZOID, 1), 1))
    return sim


def detect(kind: str, overrides: dict, v_dps: float = 100.0, when: str = "cruise") -> str:
    """``kind`` (freeze, short, stuck, open winding) injected 3 s into a cruise at ``v_dps``
    (``when`` "cruise"; the move's deceleration begins 1.5 s later), or at rest before a
    move at the 5 A clamp (``when`` "rest"; the short and the stuck pin) or from power-up
    (the open winding): the ticks from the fault (or the move's start) to the first trip."""
    k0 = 1500
    if kind == "open winding":
        sim = _moving(overrides, 450.0, v_dps, **{"motor.r_ohm": 1000.0})
        k0 = 2  # the move's start
        sim.step(3000)
    elif when == "rest":
        sim = loop.Simulation(paper_bench(**overrides), seed=3)
        sim.pc_write(frame.encode(Hello(0, session=1), 0))
        sim.step(k0 - 2)
        sim.inject_sense(kind)
        sim.pc_write(frame.encode(Move(1, 3000.0, 990.0, 2000.0, 0.0, Profile.STEP, 1), 1))
        sim.step(1502)
    else:
        target = 0.05 + v_dps * 4.5  # decelerating 4.5 s after the start
        sim = _moving(overrides, target, v_dps)
        sim.step(k0)
        if kind == "freeze":
            sim.encoder.inject("freeze", x=sim.plant_state)
        else:
            sim.inject_sense(kind)
        sim.step(1500)
    rep = _first_report(sim)
    log = sim.log()
    pos = log.true_pos_deg
    what = f"{kind} ({when}, {v_dps:g} deg/s)" if kind != "open winding" else kind
    peak = np.abs(log.current_a[k0:]).max()
    if rep is None:
        return f"{what}: no trip in {len(pos) - k0} ticks (peak true current {peak:.2f} A)"
    k = rep.tick
    return (f"{what}: {rep.fault.name} after {k - k0} ticks, {pos[k] - pos[k0]:.1f} deg, "
            f"peak true current {np.abs(log.current_a[k0:k + 1]).max():.2f} A")  # fmt: skip


def freeze_after_uptime(overrides: dict, minutes: float, v_dps: float = 100.0) -> str:
    """The freeze of ``detect`` in a move that starts ``minutes`` after power-up (at rest
    until then): the warm restart's allowance decays with the estimate's network."""
    sim = loop.Simulation(paper_bench(**overrides), seed=3)
    sim.pc_write(frame.encode(Hello(0, session=1), 0))
    sim.step(round(minutes * 60 * 500) + 1)
    sim.pc_write(frame.encode(Move(1, 30000.0, v_dps, 2000.0, 0.0, Profile.TRAPEZOID, 1), 1))
    sim.step(1500)
    k0 = sim.tick
    sim.encoder.inject("freeze", x=sim.plant_state)
    sim.step(1500)
    rep = _first_report(sim)
    return f"{rep.fault.name} after {rep.tick - k0} ticks" if rep else "no trip"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", action="append", default=[], help="a setting's name (repeat)")
    ap.add_argument("--no-heat", action="store_true")
    ap.add_argument("--no-detect", action="store_true")
    ap.add_argument("--minutes", type=float, default=45.0)
    args = ap.parse_args()
    wall0 = time.perf_counter()
    for name, over in SETTINGS.items():
        if args.only and name not in args.only:
            continue
        print(f"== {name}", flush=True)
        for line in false_trips(name, over):
            print(line, flush=True)
        if not args.no_heat:
            print(heat_duty(over, args.minutes), flush=True)
        if not args.no_detect:
            for v in (30.0, 60.0, 100.0, 130.0):
                print("  " + detect("freeze", over, v), flush=True)
            for kind in ("short", "stuck"):
                for when in ("cruise", "rest"):
                    print("  " + detect(kind, over, when=when), flush=True)
            print("  " + detect("open winding", over), flush=True)
            for minutes in (10.0, 30.0, 60.0):
                print(f"  freeze (cruise, 100 deg/s) {minutes:g} min after power-up: "
                      f"{freeze_after_uptime(over, minutes)}", flush=True)  # fmt: skip
    print(f"{time.perf_counter() - wall0:.0f} s wall, load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
