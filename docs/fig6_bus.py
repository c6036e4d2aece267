"""Fig. 6 (the step without planning) with and without the bus model: docs/img/fig6_bus.png
and the table of docs/model.md's section "Supply and bus".

Each variant is ``bench_configs/fig6.toml`` (10 s, seed 0) with overrides of the bench's
``[supply]`` / ``[bridge]`` / ``[controller.current]`` tables. Prints one row per variant:
overshoot, the first lock-out, how long the bridge was locked out, the bus peak, the
braking energy returned to the bus and its peak power, the position at the end, the
firmware's first trip (``[safety] bus_voltage_check``; nan: none).
Run: ``python3 docs/fig6_bus.py`` (about 10 s after the kernels are compiled).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sim import loop  # noqa: E402
from sim.reproduce import experiments  # noqa: E402

BUS = {"supply.bus_model": True}
VARIANTS: dict[str, dict[str, object]] = {
    "stiff 24 V supply (bus model off: the bench so far)": {},
    "bus: 2,200 µF, no brake (the paper's bench as assumed)": BUS,
    "bus + brake chopper 10 Ω at 26.5 V": {**BUS, "supply.brake_resistor_ohm": 10.0},
    "bus + chopper + firmware duty from the measured bus": {
        **BUS,
        "supply.brake_resistor_ohm": 10.0,
        "controller.current.bus_compensation": True,
    },
    "bus + firmware regenerative limit 0.05 A (no chopper)": {
        **BUS,
        "controller.current.regen_bus_current_limit_a": 0.05,
    },
    "bus + TVS, V_BR 26.7 V, R_d 0.7 Ω (no chopper)": {**BUS, "supply.tvs_breakdown_v": 26.7},
    "bus + firmware bus trip at 27 V (no chopper)": {
        **BUS,
        "safety.bus_voltage_check": True,
    },
    "bus + firmware bus trip at 26 V (no chopper)": {
        **BUS,
        "safety.bus_voltage_check": True,
        "safety.bus_over_voltage_v": 26.0,
    },
}


def _metrics(log: loop.RunLog, dt_s: float) -> dict[str, float]:
    t, p, v = log.t_s, log.true_pos_deg, log.bus_v
    locked = (log.voltage_v == 0.0) & (log.duty != 0.0)
    first = t[np.argmax(locked)] if locked.any() else float("nan")
    # Power into the bridge from the bus: its mean output voltage times the current
    # (the bridge draws duty * i from the bus, duty * V_bus is its output).
    p_w = log.voltage_v * log.current_a
    return {
        "overshoot_deg": float(p.max() - 3000.0),
        "t_peak_s": float(t[np.argmax(p)]),
        "first_lockout_s": float(first),
        "locked_s": float(locked.sum() * dt_s),
        "bus_max_v": float(v.max()),
        "returned_j": float(-np.minimum(p_w, 0.0).sum() * dt_s),
        "peak_return_w": float(-p_w.min()),
        "final_error_deg": float(p[-1] - 3000.0),
        "fault_s": float(t[np.argmax(log.fault != 0)]) if log.fault.any() else float("nan"),
    }


def main(out: Path = Path(__file__).parent / "img" / "fig6_bus.png") -> Path:
    exp = experiments.load("fig6")
    fig, (ax_p, ax_v, ax_b) = plt.subplots(3, 1, figsize=(10, 10), sharex=True)
    print(
        f"{'variant':58s} {'overshoot':>10s} {'at':>6s} {'1st lock':>8s} {'locked':>7s} "
        f"{'bus max':>7s} {'returned':>8s} {'peak':>6s} {'end err':>8s} {'trip':>6s}"
    )
    for name, overrides in VARIANTS.items():
        log = loop.run(exp, seed=0, overrides=overrides or None).log
        m = _metrics(log, 0.002)
        print(
            f"{name:58s} {m['overshoot_deg']:8.1f} ° {m['t_peak_s']:5.2f}s "
            f"{m['first_lockout_s']:7.3f}s {m['locked_s']:6.2f}s {m['bus_max_v']:6.2f}V "
            f"{m['returned_j']:7.2f}J {m['peak_return_w']:5.1f}W {m['final_error_deg']:7.2f}° "
            f"{m['fault_s']:5.3f}s"
        )
        ax_p.plot(log.t_s, log.true_pos_deg, label=name, lw=1.1)
        ax_v.plot(log.t_s, log.true_vel_dps, lw=1.0)
        ax_b.plot(log.t_s, log.bus_v, lw=1.0)
    ax_p.axhline(3000.0, color="0.6", lw=0.8, ls=":")
    ax_p.set_ylabel("axis position (°)")
    ax_p.set_ylim(2000.0, 3900.0)
    ax_p.legend(fontsize=8, loc="lower right")
    ax_p.set_title(
        "Fig. 6 step (3000° without planning) with the bus model: braking returns energy\n"
        "into the 2,200 µF bus; at 28 V the BTN7971B locks its outputs out",
        fontsize=11,
    )
    ax_v.set_ylabel("axis velocity (°/s)")
    ax_b.axhline(28.0, color="tab:red", lw=0.8, ls="--")
    ax_b.text(0.1, 28.1, "BTN7971B over-voltage lock-out 28 V", color="tab:red", fontsize=8)
    ax_b.set_ylabel("bus voltage (V)")
    ax_b.set_xlabel("time (s)")
    ax_b.set_ylim(23.0, 29.0)
    for ax in (ax_p, ax_v, ax_b):
        ax.grid(True, lw=0.3)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return out


if __name__ == "__main__":
    print(main())
