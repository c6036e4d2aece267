"""Regenerate the closed-loop tables of docs/model.md that describe the default bench.

Each table is a list of rows; each row is the default bench (``bench_configs/paper_bench.toml``
with the firmware's defaults, today's: the feed-forward R following the winding estimate)
with a few overrides, run through ``sim.loop.run`` (the scripted PC, the emulated UART, the
compiled tick), seed 0. The runs are deterministic: the machine's load does not enter the
numbers, only the time it takes. The script prints every table as markdown, in the form
docs/model.md quotes it; each table of the page names the table of this script that makes it.

    python3 benchmarks/model_tables.py                  # every table (~2 min on a quiet machine)
    python3 benchmarks/model_tables.py effects switching   # some of them
    python3 benchmarks/model_tables.py --list           # the tables and where they go
    python3 benchmarks/model_tables.py --check          # does docs/model.md hold them?
    python3 benchmarks/model_tables.py --set safety.thermal_ff_resistance=false
                                                        # every row with one more override
                                                        # (here: the nominal-R feed-forward)

Metrics (every one from the run's log, ``sim.loop.RunLog``; axis degrees):

* Fig. 8 (``bench_configs/fig8.toml`` cut to 20 s, or its whole 30 s where a table says so):
  largest following error ``|sp_pos_deg - true_pos_deg|`` (true axis) or
  ``|sp_pos_deg - pos_deg|`` (the firmware's estimate), largest true ``|current_a|``, largest
  ``|vel_raw_dps - true_vel_dps|`` (the raw differenced velocity against the true one),
  largest velocity error ``|sp_vel_dps - vel_dps|``.
* Fig. 6 (``bench_configs/fig6.toml``, 10 s, the step without planning to 3000 deg):
  overshoot ``max(true_pos_deg) - 3000`` and its time, the error ``|true_pos_deg - 3000|`` at
  4 s, largest true ``|current_a|``, the first fault and its time.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from serial_protocol.messages import Fault, State  # noqa: E402
from sim import loop  # noqa: E402
from sim.reproduce import experiments  # noqa: E402

TARGET_DEG = 3000.0  # Fig. 6's step
DT_S = 0.002

STICTION = {
    "motor.stiction_nm": 0.005,
    "motor.stribeck_rad_s": 1.0,
    "platter.stiction_nm": 0.45,
    "platter.stribeck_rad_s": 0.01,
}
INL = {"encoder.inl_h1_deg": 0.5, "encoder.inl_h2_deg": 0.1}
DRAG_OFF = {"gearbox.drag_nm": 0.0, "gearbox.drag_viscous_nm_s_rad": 0.0}
BUS = {"supply.bus_model": True}
HEAT = {"thermal.model": True}
WARM = {**HEAT, "thermal.initial_winding_rise_k": 60.0, "thermal.initial_housing_rise_k": 55.0}
SWITCHING = {
    "bridge.pulse_shift_with_current_us": -0.7,
    "bridge.pulse_shift_against_current_us": 2.7,
}

Overrides = Mapping[str, Any]


@dataclasses.dataclass(frozen=True)
class Runs:
    """The runs of one process, each made once (``key`` -> log); ``extra`` is added to every
    row's overrides (``--set``; a row's own override of the same key wins)."""

    extra: Overrides
    cache: dict = dataclasses.field(default_factory=dict)

    def log(self, name: str, overrides: Overrides, duration_s: float) -> loop.RunLog:
        over = {**self.extra, **overrides}
        key = (name, duration_s, tuple(sorted(over.items())))
        if key not in self.cache:
            exp = dataclasses.replace(experiments.load(name), duration_s=duration_s)
            self.cache[key] = loop.run(exp, seed=0, overrides=over or None).log
        return self.cache[key]

    def fig8(self, overrides: Overrides, duration_s: float = 20.0) -> loop.RunLog:
        return self.log("fig8", overrides, duration_s)

    def fig6(self, overrides: Overrides) -> loop.RunLog:
        return self.log("fig6", overrides, 10.0)


def _at(log: loop.RunLog, t_s: float) -> int:
    return int(round(t_s / DT_S))


def overshoot(log: loop.RunLog) -> tuple[float, float]:
    """``(overshoot deg, its time s)`` of Fig. 6's step."""
    k = int(np.argmax(log.true_pos_deg))
    return float(log.true_pos_deg[k] - TARGET_DEG), float(log.t_s[k])


def error_at(log: loop.RunLog, t_s: float) -> float:
    return float(abs(log.true_pos_deg[_at(log, t_s)] - TARGET_DEG))


def first_fault(log: loop.RunLog) -> tuple[str, float] | None:
    k = np.flatnonzero(log.fault != 0)
    if not k.size:
        return None
    return Fault(int(log.fault[k[0]])).name, float(log.t_s[k[0]])


def follow_true(log: loop.RunLog) -> float:
    return float(np.abs(log.sp_pos_deg - log.true_pos_deg).max())


def follow_est(log: loop.RunLog) -> float:
    return float(np.abs(log.sp_pos_deg - log.pos_deg).max())


def peak_current(log: loop.RunLog) -> float:
    return float(np.abs(log.current_a).max())


def _os_cell(log: loop.RunLog, digits: int = 2) -> str:
    os_deg, t_s = overshoot(log)
    fault = first_fault(log)
    cell = f"{os_deg:.{digits}f} ° at {t_s:.3f} s"
    if fault is not None:
        cell += f", `{fault[0]}` at {fault[1]:.3f} s"
    return cell


# --- the tables --------------------------------------------------------------------------


def table_effects(runs: Runs) -> list[str]:
    """docs/model.md section 6, first table: issue 13 §2.2 and §2.5 (drag, INL, stiction)."""
    rows = (
        ("bench (gearbox drag on)", {}),
        ("drag off (the model before)", DRAG_OFF),
        ("+ INL 0.5° / 0.1°", INL),
        ("+ stiction (motor 5 mN·m, platter 0.45 N·m)", STICTION),
        ("+ stiction, supply 26 V", {**STICTION, "supply.voltage_v": 26.0}),
        ("supply 26 V without stiction", {"supply.voltage_v": 26.0}),
    )
    out = [
        "| run | Fig. 8 max following error | Fig. 8 max \\|i\\| | Fig. 8 max \\|v_raw − v\\| "
        "| Fig. 6 overshoot | Fig. 6 \\|error\\| at 4 s |",
        "|---|---|---|---|---|---|",
    ]
    for name, over in rows:
        f8, f6 = runs.fig8(over), runs.fig6(over)
        vraw = float(np.abs(f8.vel_raw_dps - f8.true_vel_dps).max())
        out.append(
            f"| {name} | {follow_true(f8):.3f} ° | {peak_current(f8):.3f} A | {vraw:.2f} °/s "
            f"| {_os_cell(f6)} | {error_at(f6, 4.0):.3f} ° |"
        )
    return out


def table_effects13(runs: Runs) -> list[str]:
    """docs/model.md section 6, second table: issue 13 §2.1, §2.3, §2.4, §2.6 (bus, sense,
    switching, heat), each on the default bench."""
    rows = (
        ("bench", {}),
        ("+ bus, 2,200 µF, no brake", BUS),
        ("+ bus + chopper 10 Ω at 26.5 V", {**BUS, "supply.brake_resistor_ohm": 10.0}),
        ("+ chip k_ILIS 14k (firmware 8.5k)", {"current_sense.k_ilis": 14000.0}),
        ("+ IS offset 50 µA (0.425 A), uncalibrated", {"current_sense.is_offset_ua": 50.0}),
        (
            "+ IS offset 50 µA, calibrated at enable",
            {"current_sense.is_offset_ua": 50.0, "controller.current.sense_calibration": True},
        ),
        (
            "+ IS offset 50 µA, `sense_offset_counts` = 62",
            {"current_sense.is_offset_ua": 50.0, "controller.current.sense_offset_counts": 62},
        ),
        ("+ ADC sampled at the ripple's valley", {"current_sense.sample_point": 0.0}),
        ("+ switching times (typical)", SWITCHING),
        ("+ heat model (§2.6), motor from 25 °C", HEAT),
        ("+ heat model, motor warm (winding 85 °C, housing 80 °C)", WARM),
    )
    out = [
        "| run | Fig. 8 max following error | Fig. 8 max \\|i\\| | Fig. 6 overshoot "
        "| Fig. 6 \\|error\\| at 4 s | Fig. 6 max \\|i\\| |",
        "|---|---|---|---|---|---|",
    ]
    for name, over in rows:
        f8, f6 = runs.fig8(over), runs.fig6(over)
        out.append(
            f"| {name} | {follow_est(f8):.3f} ° | {peak_current(f8):.3f} A | {_os_cell(f6)} "
            f"| {error_at(f6, 4.0):.3f} ° | {peak_current(f6):.3f} A |"
        )
    return out


def table_switching(runs: Runs) -> list[str]:
    """docs/model.md section 2, "Bridge switching": the typical shifts against the ideal
    bridge (Fig. 6's step and its holding at rest 5-10 s, Fig. 8's 20 s)."""
    out = [
        "| bridge | Fig. 6 overshoot | holding 5–10 s: median \\|duty\\| "
        "| ticks without a pulse | max \\|i\\| | max \\|position − 3000\\| "
        "| Fig. 8 max following error | Fig. 8 max \\|i\\| |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, over in (("ideal (default)", {}), ("typical shifts (−0.7 / +2.7 µs)", SWITCHING)):
        f6, f8 = runs.fig6(over), runs.fig8(over)
        hold = slice(_at(f6, 5.0), _at(f6, 10.0))
        duty = np.abs(f6.duty[hold])
        # Ticks whose bridge applied no voltage at all: a pulse shortened to nothing (the
        # minimum pulse width) is not switched (the ideal bridge: only a duty of exactly 0).
        silent = int(np.count_nonzero(f6.voltage_v[hold] == 0.0))
        out.append(
            f"| {name} | {overshoot(f6)[0]:.2f} ° | {100 * np.median(duty):.2f} % "
            f"| {silent} of {duty.size} | {np.abs(f6.current_a[hold]).max():.2f} A "
            f"| {np.abs(f6.true_pos_deg[hold] - TARGET_DEG).max():.3f} ° "
            f"| {follow_est(f8):.3f} ° | {peak_current(f8):.2f} A |"
        )
    return out


def table_gains(runs: Runs) -> list[str]:
    """docs/model.md "Default gains": the closed-loop check of the default gains (Fig. 8's
    whole 30 s and Fig. 6's step)."""
    f8, f6 = runs.fig8({}, duration_s=30.0), runs.fig6({})
    vel_err = float(np.abs(f8.sp_vel_dps - f8.vel_dps).max())
    brake = np.flatnonzero(np.sign(f6.current_ref_a) < 0)
    held = np.flatnonzero(f6.state == int(State.HOLDING))
    t_rise = np.flatnonzero(f6.true_vel_dps >= 980.0)
    fault = first_fault(f6) or first_fault(f8)
    return [
        "| run | figure |",
        "|---|---|",
        f"| Fig. 8 (30 s) max following error (estimate) | {follow_est(f8):.3f} ° |",
        f"| Fig. 8 max velocity error \\|v_sp − v̂\\| | {vel_err:.2f} °/s |",
        f"| Fig. 8 max \\|i\\| | {peak_current(f8):.3f} A |",
        f"| Fig. 6 980 °/s reached at | {f6.t_s[t_rise[0]]:.3f} s |"
        if t_rise.size
        else "| Fig. 6 980 °/s | never |",
        f"| Fig. 6 braking from (first negative current reference) | {f6.t_s[brake[0]]:.3f} s |"
        if brake.size
        else "| Fig. 6 braking | never |",
        f"| Fig. 6 overshoot | {_os_cell(f6)} |",
        f"| Fig. 6 HOLDING from | {f6.t_s[held[0]]:.3f} s |"
        if held.size
        else "| Fig. 6 HOLDING | never |",
        f"| Fig. 6 max \\|i\\| (true, at the servo ticks) | {peak_current(f6):.3f} A |",
        f"| faults | {fault[0] + ' at ' + format(fault[1], '.3f') + ' s' if fault else 'none'} |",
    ]


def table_regen(runs: Runs) -> list[str]:
    """docs/model.md "The current loop", the regenerative clamp: Fig. 6's true current at the
    servo ticks on the bench and on plants that differ from the firmware's model."""
    rows = (
        ("bench", {}),
        ("supply 26 V", {"supply.voltage_v": 26.0}),
        ("supply 25 V", {"supply.voltage_v": 25.0}),
        ("motor K_e = K_t = 0.0135", {"motor.kt_nm_a": 0.0135, "motor.ke_v_s_rad": 0.0135}),
        ("motor R 1.0 Ω (firmware 1.2 Ω)", {"motor.r_ohm": 1.0}),
    )
    out = [
        "| plant | max \\|i\\| | regenerative peak (current against the duty) | Fig. 6 overshoot |",
        "|---|---|---|---|",
    ]
    for name, over in rows:
        f6 = runs.fig6(over)
        against = np.sign(f6.current_a) * np.sign(f6.duty) < 0
        regen = float(np.abs(f6.current_a[against]).max()) if against.any() else 0.0
        out.append(f"| {name} | {peak_current(f6):.2f} A | {regen:.2f} A | {_os_cell(f6, 1)} |")
    return out


def table_ff(runs: Runs) -> list[str]:
    """docs/model.md "The feed-forward R follows the estimate": Fig. 6 with the feed-forward
    R and k_emf nominal, with R following the winding estimate (k_emf nominal: the rows of
    that table), and with both following it (today's default); the differences are the point."""
    r_ff, emf_ff = "safety.thermal_ff_resistance", "safety.thermal_ff_back_emf"
    columns = (
        ("both nominal", {r_ff: False, emf_ff: False}),
        ("R on the estimate", {r_ff: True, emf_ff: False}),
        ("R and k_emf on the estimate", {r_ff: True, emf_ff: True}),
    )
    rows = (
        ("Fig. 6, default bench (10 s)", {}),
        ("Fig. 6, plant heat model from 25 °C", HEAT),
        (
            "Fig. 6, warm motor (winding +55 K, housing +30 K)",
            {
                **HEAT,
                "thermal.initial_winding_rise_k": 55.0,
                "thermal.initial_housing_rise_k": 30.0,
            },
        ),
    )
    out = ["| run | " + " | ".join(name for name, _ in columns) + " |", "|---|---|---|---|"]
    for name, over in rows:
        cells = []
        for _, switch in columns:
            log = runs.fig6({**over, **switch})
            cells.append(f"{_os_cell(log)}, peak {peak_current(log):.3f} A")
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    return out


def table_fixed(runs: Runs) -> list[str]:
    """docs/model.md "Fixed point": the same run (Fig. 8, 20 s, seed 0) in float and in the
    fixed-point law, largest differences over the run."""
    a, b = runs.fig8({}), runs.fig8({"servo.arithmetic": "fixed"})
    count_deg = 360.0 / (16384 * 80)
    arr = 3600  # 72 MHz / 20 kHz
    return [
        "| signal | largest \\|float − fixed\\| |",
        "|---|---|",
        f"| position estimate | {np.abs(a.pos_deg - b.pos_deg).max() / count_deg:.0f} counts "
        f"({np.abs(a.pos_deg - b.pos_deg).max():.1e} °) |",
        f"| velocity estimate | {np.abs(a.vel_dps - b.vel_dps).max():.3f} °/s |",
        f"| current reference | {np.abs(a.current_ref_a - b.current_ref_a).max():.4f} A |",
        f"| duty | {np.abs(a.duty - b.duty).max() * arr:.0f} ARR steps |",
        f"| largest following error (estimate) | float {follow_est(a):.4f} °, "
        f"fixed {follow_est(b):.4f} ° |",
    ]


TABLES: dict[str, tuple[Callable[[Runs], list[str]], str]] = {
    "effects": (table_effects, "section 6, first table (drag, INL, stiction)"),
    "effects13": (table_effects13, "section 6, second table (bus, sense, switching, heat)"),
    "switching": (table_switching, 'section 2, "Bridge switching", measured'),
    "gains": (table_gains, '"Default gains", the closed-loop check (quoted in its prose)'),
    "regen": (table_regen, '"The current loop", the regenerative clamp'),
    "fixed": (table_fixed, '"Fixed point", float against fixed on Fig. 8 (quoted in its prose)'),
    "ff": (table_ff, '"The feed-forward R follows the estimate" (its first rows, and today)'),
}
# The tables docs/model.md holds exactly as printed (``--check`` compares them line by line).
VERBATIM = ("effects", "effects13", "switching", "regen")
MODEL_MD = Path(__file__).resolve().parents[1] / "docs" / "model.md"


def check(runs: Runs, names: list[str]) -> int:
    """Print every row of the ``VERBATIM`` tables among ``names`` that docs/model.md does not
    hold exactly; 0 if there is none, else 1."""
    doc = set(MODEL_MD.read_text(encoding="utf-8").splitlines())
    missing = 0
    for name in names:
        if name not in VERBATIM:
            continue
        for line in TABLES[name][0](runs):
            if line not in doc:
                missing += 1
                print(f"{name}: docs/model.md lacks: {line}")
    print(f"{missing} row(s) of {', '.join(n for n in names if n in VERBATIM)} differ")
    return 1 if missing else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tables", nargs="*", help=f"which tables (default all): {', '.join(TABLES)}")
    ap.add_argument("--list", action="store_true", help="list the tables and where they go")
    ap.add_argument(
        "--check",
        action="store_true",
        help=f"compare the tables docs/model.md holds as printed ({', '.join(VERBATIM)}) "
        "with a new run; exit status 1 if a row differs",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="TABLE.KEY=VALUE",
        help="one more override for every row (repeatable)",
    )
    args = ap.parse_args(argv)
    if args.list:
        for name, (_, where) in TABLES.items():
            print(f"{name:10s} docs/model.md {where}")
        return 0
    unknown = [t for t in args.tables if t not in TABLES]
    if unknown:
        ap.error(f"unknown table {unknown[0]!r}; choose from {', '.join(TABLES)}")
    extra: dict[str, Any] = {}
    for item in args.set:
        key, sep, text = item.partition("=")
        try:
            value = tomllib.loads(f"v = {text.strip()}")["v"] if sep and "." in key else None
        except tomllib.TOMLDecodeError:
            value = None
        if value is None or isinstance(value, list | dict):
            ap.error(f"--set {item!r}: expected TABLE.KEY=VALUE with one TOML value")
        extra[key.strip()] = value
    runs = Runs(extra)
    if args.check:
        return check(runs, args.tables or list(TABLES))
    for name in args.tables or list(TABLES):
        fn, where = TABLES[name]
        wall0 = time.perf_counter()
        lines = fn(runs)
        wall = time.perf_counter() - wall0
        print(f"### `{name}`: docs/model.md {where}")
        if extra:
            print(f"(every row with {extra})")
        print()
        print("\n".join(lines))
        print(f"\n({wall:.1f} s)\n", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
