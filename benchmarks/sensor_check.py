"""The back-EMF sensor check (``SENSOR_MISMATCH``) against its two failure modes: false trips
in normal runs and late detection of a frozen encoder (issue #11 §3; figures go to
docs/model.md, "Safety"). Not a test: the suite checks the settings' outcome on a few runs
(tests/firmware_model/test_safety.py).

* False alarms: every scenario ``reproduce`` and ``tune`` run, with encoder noise on
  (the paper bench's 1 LSB rms), the check disarmed (``sensor_mismatch_deg = 1e5``):
  Fig. 6 (step) at 20 / 24 / 26 V and over noise seeds, Fig. 7, Fig. 8 over noise seeds, Table
  1's a_max per move and no feed-forward (``reproduce``'s sensitivity runs), step_demo,
  lookahead_program, and ``tune``'s robustness spread (33 plants: inertia, friction, supply
  20 / 26 V, noise 0 / 1 LSB, belt) on Fig. 8 as one batch. Prints the firmware's own
  ``sensor_mismatch_peak_deg`` per scenario (largest over the members that latched no
  other fault) against the threshold.
* Detection: a noisy (+-1 count) freeze of the encoder while cruising at each speed, with
  the configured settings (check and brake on): the detection tick, the axis travel from
  the freeze to the trip and to rest; ``--set safety.KEY=VALUE`` changes the firmware's
  settings for it (e.g. the check's spreads: ``--set safety.sensor_mismatch_sense_spread=0``).

    python3 benchmarks/sensor_check.py [--seeds 5] [--no-spread] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "firmware_model"))

from uart_fuzz import paper_bench  # noqa: E402

import bench_configs  # noqa: E402
from serial_protocol import frame  # noqa: E402
from serial_protocol.messages import FaultReport, Hello, Move, Profile  # noqa: E402
from sim import loop  # noqa: E402
from sim.config import load_experiment  # noqa: E402
from sim.reproduce.experiments import load, with_duration  # noqa: E402
from sim.reproduce.sensitivity import FF_OFF, table1_experiment  # noqa: E402
from sim.tuning.robust import plant_spread  # noqa: E402

DISARMED = {"safety.sensor_mismatch_deg": 1e5}


def _peak(exp, *, seed=0, batch=None, overrides=None):
    """``(largest peak over the members with no fault, members faulted)`` of one run with the
    check disarmed."""
    holder = {}

    class Keep(loop.Simulation):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            holder["sim"] = self

    saved, loop.Simulation = loop.Simulation, Keep
    try:
        res = loop.run(exp, seed=seed, batch=batch, overrides={**DISARMED, **(overrides or {})})
    finally:
        loop.Simulation = saved
    peak = holder["sim"].fw.sensor_mismatch_peak_deg
    fault = np.atleast_2d(res.log.fault)[:, -1]
    ok = fault == 0
    return (float(peak[ok].max()) if ok.any() else float("nan")), int((~ok).sum())


def false_alarms(seeds: int, spread: bool, overrides: dict | None = None) -> float:
    over = overrides or {}
    rows = []
    fig6, fig7, fig8 = load("fig6"), load("fig7"), load("fig8")
    fig6 = with_duration(fig6, 6.0)
    for v in (20.0, 24.0, 26.0):
        for s in range(seeds):
            rows.append((f"fig6 step, {v:g} V, seed {s}", _peak(fig6, seed=s,
                         overrides={**over, "supply.voltage_v": v})))  # fmt: skip
    for s in range(seeds):
        rows.append((f"fig7, seed {s}", _peak(fig7, seed=s, overrides=over)))
        rows.append((f"fig8, seed {s}", _peak(fig8, seed=s, overrides=over)))
        rows.append((f"fig8 Table 1 a_max, seed {s}",
                     _peak(table1_experiment(), seed=s, overrides=over)))  # fmt: skip
        rows.append((f"fig8 no feed-forward, seed {s}",
                     _peak(fig8, seed=s, overrides={**over, **FF_OFF})))  # fmt: skip
    for name in ("step_demo", "lookahead_program"):
        exp = load_experiment(bench_configs.path(name + ".toml"))
        rows.append((name, _peak(exp, overrides=over)))
    if spread:
        plants = plant_spread(fig8)
        ov = {key: [p[key] for p in plants] for key in plants[0]}
        rows.append((f"tune spread on fig8 ({len(plants)} plants)",
                     _peak(fig8, batch=len(plants), overrides={**over, **ov})))  # fmt: skip
    thr = fig8.bench.firmware.safety.sensor_mismatch_deg
    worst = 0.0
    print(f"False alarms (check disarmed; threshold {thr:g} deg): peak integrated excess")
    for name, (peak, faulted) in rows:
        worst = max(worst, peak) if peak == peak else worst
        extra = f"  ({faulted} member(s) latched another fault)" if faulted else ""
        print(f"  {name:42s} {peak:8.3f} deg{extra}")
    print(f"  worst {worst:.3f} deg = {worst / thr:.2f} x the threshold")
    return worst


def freeze(
    v_dps: float, *, brake: bool = True, seed: int = 3, overrides: dict | None = None
) -> dict[str, float]:
    """A +-1 count noisy freeze while cruising at ``v_dps`` (3 s after the start)."""
    over = {**(overrides or {}), **({} if brake else {"safety.brake_s": 0.0})}
    sim = loop.Simulation(paper_bench(**over), seed=seed)
    sim.pc_write(frame.encode(Hello(0, session=1), 0))
    sim.pc_write(frame.encode(Move(1, 30000.0, v_dps, 2000.0, 0.0, Profile.TRAPEZOID, 1), 1))
    k0 = 1500
    sim.step(k0)
    sim.encoder.inject("freeze", x=sim.plant_state)
    sim.step(1500)
    reports = [m for m in frame.Decoder().feed(sim.pc_read()) if isinstance(m, FaultReport)]
    log = sim.log()
    k = reports[0].tick if reports else -1
    pos = log.true_pos_deg
    return {
        "fault": reports[0].fault.name if reports else "none",
        "ticks": k - k0,
        "to_trip_deg": pos[k] - pos[k0] if reports else float("nan"),
        "to_rest_deg": pos[-1] - pos[k0],
        "speed_at_trip": log.true_vel_dps[k] if reports else float("nan"),
        "rest": abs(log.true_vel_dps[-1]) < 0.5,
    }


def detection(overrides: dict | None = None) -> None:
    print(f"Detection of a noisy freeze (+-1 count) while cruising, settings as configured"
          f"{' with ' + str(overrides) if overrides else ''}:")  # fmt: skip
    print("  speed deg/s | fault | ticks to trip | travel to trip deg | speed at trip | to rest")
    for v in (30.0, 60.0, 100.0, 130.0, 200.0, 400.0, 700.0, 990.0):
        r = freeze(v, overrides=overrides)
        print(f"  {v:11.0f} | {r['fault']} | {r['ticks']:13d} | {r['to_trip_deg']:18.2f} | "
              f"{r['speed_at_trip']:13.1f} | {r['to_rest_deg']:.2f} deg"
              f"{'' if r['rest'] else ' (still moving)'}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--no-spread", action="store_true")
    ap.add_argument("--no-false-alarms", action="store_true")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a setting for every run (e.g. safety.brake_s=0, "
        "controller.current.sense_calibration=true)",
    )
    args = ap.parse_args()
    overrides = {}
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            ap.error(f"--set {item!r}: expected KEY=VALUE")
        if value in ("true", "false"):  # a switch, e.g. controller.current.sense_calibration
            overrides[key] = value == "true"
            continue
        try:
            overrides[key] = int(value) if value.lstrip("-").isdigit() else float(value)
        except ValueError:
            ap.error(f"--set {item!r}: {value!r} is not a number, true or false")
    wall0 = time.perf_counter()
    detection(overrides)
    if not args.no_false_alarms:
        false_alarms(args.seeds, not args.no_spread, overrides)
    print(f"{time.perf_counter() - wall0:.0f} s wall, load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
