"""The duty-cycle experiment of docs/model.md, "Heat": Fig. 6's step move (3000 deg, no
planning, 5 A) repeated back and forth, with the plant's heat model on and the firmware's
thermal protection at its defaults; writes docs/img/heat_duty.png and prints the table of
docs/model.md (winding temperature, derating, trip), and the effect of the heat model on
Fig. 6 and Fig. 8.

    python3 docs/heat_duty.py [--minutes 30] [--leg-s 4] [--set safety.thermal_ff_back_emf=false]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from serial_protocol.messages import Fault  # noqa: E402
from sim import loop  # noqa: E402
from sim.config import ScriptedCommand  # noqa: E402
from sim.reproduce import experiments  # noqa: E402

HEAT = {"thermal.model": True}


def back_and_forth(minutes: float, leg_s: float) -> loop.Experiment:
    """Fig. 6's move to 3000 deg and back to 0, a new leg every ``leg_s``."""
    base = experiments.load("fig6")
    move = next(c for c in base.commands if c.type == "move")
    cmds = [c for c in base.commands if c.type != "move"]
    k = 0
    while k * leg_s < minutes * 60.0:
        fields = dict(move.fields)
        fields["target_mdeg"] = 3e6 if k % 2 == 0 else 0.0
        cmds.append(ScriptedCommand(k * leg_s, "move", tuple(fields.items())))
        k += 1
    cmds.sort(key=lambda c: c.t_s)
    return dataclasses.replace(base, commands=tuple(cmds), duration_s=minutes * 60.0)


def run_sampled(exp: loop.Experiment, overrides: dict) -> tuple[loop.RunResult, dict]:
    """``loop.run`` with the firmware's estimate, its derated limit and the plant's housing
    sampled after every chunk the run steps."""
    samples: dict[str, list[float]] = {"t_s": [], "est_c": [], "limit_a": [], "housing_c": []}
    saved = loop.Simulation

    class Sampled(saved):  # type: ignore[misc, valid-type]
        def step(self, n_ticks: int = 1) -> None:
            super().step(n_ticks)
            samples["t_s"].append(self.t_s)
            samples["est_c"].append(float(self.fw.thermal_estimate_c))
            samples["limit_a"].append(float(self.fw.current_limit_derated_a))
            samples["housing_c"].append(float(self.heat.temps[0, 1]))

    loop.Simulation = Sampled
    try:
        result = loop.run(exp, seed=0, overrides=overrides)
    finally:
        loop.Simulation = saved
    return result, {k: np.array(v) for k, v in samples.items()}


def figure_effects() -> None:
    """Fig. 6 and Fig. 8 with the heat model off, on from 25 degC, on from a warm motor."""
    warm = {**HEAT, "thermal.initial_winding_rise_k": 60.0, "thermal.initial_housing_rise_k": 55.0}
    print("| run | Fig. 6 overshoot | Fig. 6 peak |i| | Fig. 6 winding end | Fig. 8 max "
          "following error | Fig. 8 max |i| | Fig. 8 winding end |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for name, over in (("heat off (20 degC)", {}), ("on, from 25 degC", HEAT),
                       ("on, warm (85 / 80 degC)", warm)):  # fmt: skip
        f6 = loop.run(experiments.load("fig6"), seed=0, overrides=over or None).log
        f8 = loop.run(experiments.load("fig8"), seed=0, overrides=over or None).log
        k = int(np.argmax(f6.true_pos_deg))
        err8 = np.abs(f8.sp_pos_deg - f8.pos_deg).max()
        print(
            f"| {name} | {f6.true_pos_deg[k] - 3000:.2f} deg at {f6.t_s[k]:.3f} s | "
            f"{np.abs(f6.current_a).max():.3f} A | {f6.winding_c[-1]:.2f} degC | {err8:.3f} deg | "
            f"{np.abs(f8.current_a).max():.3f} A | {f8.winding_c[-1]:.2f} degC |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--leg-s", type=float, default=4.0)
    ap.add_argument("--out", default=str(Path(__file__).parent / "img" / "heat_duty.png"))
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a configuration override of the duty run (true/false or a number)",
    )
    args = ap.parse_args()
    over = dict(HEAT)
    for item in args.set:
        key, _, value = item.partition("=")
        over[key] = {"true": True, "false": False}.get(value.lower()) if value.lower() in (
            "true", "false") else float(value)  # fmt: skip
    exp = back_and_forth(args.minutes, args.leg_s)
    result, s = run_sampled(exp, over)
    log = result.log
    t_min = log.t_s / 60.0
    derate = np.flatnonzero(s["limit_a"] < 5.0 - 1e-9)
    trips = np.flatnonzero(log.fault == int(Fault.THERMAL))
    other = set(log.fault.tolist()) - {0, int(Fault.THERMAL)}
    print(f"{args.minutes:g} min of Fig. 6 legs every {args.leg_s:g} s (plant ambient 25 degC, "
          f"firmware assumes 40 degC)")  # fmt: skip
    for minute in (1, 5, 10, 15, 20, 25, 30, 35, 40):
        k = min(int(minute * 60 / 0.002), len(log) - 1)
        j = min(np.searchsorted(s["t_s"], minute * 60.0), len(s["t_s"]) - 1)
        if minute <= args.minutes:
            print(f"  {minute:2d} min: winding {log.winding_c[k]:6.1f} degC, housing "
                  f"{s['housing_c'][j]:6.1f}, firmware estimate {s['est_c'][j]:6.1f}, "
                  f"limit {s['limit_a'][j]:.2f} A")  # fmt: skip
    if derate.size:
        print(f"  derating from {s['t_s'][derate[0]]:.0f} s")
    if trips.size:
        k = trips[0]
        print(f"  THERMAL trip at {log.t_s[k]:.1f} s, the winding then {log.winding_c[k]:.1f} "
              f"degC (max {log.winding_c.max():.1f})")  # fmt: skip
    else:
        print(f"  no trip; winding max {log.winding_c.max():.1f} degC")
    print(f"  other faults: {sorted(other) or 'none'}")
    # The true current against the limit in force: each leg's current reference is clamped
    # to the (derated) limit and reaches it, so a leg's largest |reference| is that limit
    # (legs up to a trip: its brake is not the loops' current).
    ticks = int(round(args.leg_s / 0.002))
    worst, at = -np.inf, 0.0
    end = trips[0] if trips.size else len(log)
    for k0 in range(0, end - ticks + 1, ticks):
        leg = slice(k0, k0 + ticks)
        excess = np.abs(log.current_a[leg]).max() - np.abs(log.current_ref_a[leg]).max()
        if excess > worst:
            worst, at = excess, log.t_s[k0]
    print(f"  largest |true current| above its leg's clamped reference: {worst:+.3f} A "
          f"(leg from {at / 60.0:.1f} min)")  # fmt: skip

    fig, (ax_t, ax_i) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    ax_t.plot(t_min, log.winding_c, lw=0.8, label="plant winding")
    ax_t.plot(s["t_s"] / 60.0, s["housing_c"], lw=1.2, label="plant housing")
    ax_t.plot(s["t_s"] / 60.0, s["est_c"], lw=1.2, ls="--", label="firmware estimate")
    fw = exp.bench.firmware.safety
    ax_t.axhline(fw.thermal_derate_c, color="orange", lw=0.8, ls=":", label="derating from")
    ax_t.axhline(fw.thermal_trip_c, color="red", lw=0.8, ls=":", label="trip")
    if trips.size:
        for ax in (ax_t, ax_i):
            ax.axvline(t_min[trips[0]], color="red", lw=0.8)
    ax_t.set_ylabel("temperature (°C)")
    ax_t.legend(loc="lower right", fontsize=8)
    ax_t.grid(alpha=0.3)
    ax_t.set_title(f"Fig. 6's step move back and forth every {args.leg_s:g} s: heat and protection")
    ax_i.plot(t_min, np.abs(log.current_a), lw=0.3, color="0.6", label="|true current|")
    ax_i.plot(s["t_s"] / 60.0, s["limit_a"], lw=1.5, color="C3", label="firmware current limit")
    if trips.size:
        ax_i.annotate(
            "trip: 0.4 s of dynamic braking, then off", (t_min[trips[0]], 7.2),
            xytext=(4, 0), textcoords="offset points", fontsize=8, color="red",
        )  # fmt: skip
    ax_i.set_ylim(0.0, 8.0)
    ax_i.set_ylabel("current (A)")
    ax_i.set_xlabel("time (min)")
    ax_i.legend(loc="lower left", fontsize=8)
    ax_i.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")
    figure_effects()


if __name__ == "__main__":
    main()
