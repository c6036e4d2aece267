"""Plot seed 000's four Fig. 7 profiles (planner only, no plant) to docs/img/fig7_planner.png.

Start at 0 with v0 = 400 deg/s, targets S_1..S_4 = 1e7, 3e6, -3e6, -8e6 (the paper's
"x10^6" positions read as millidegrees of the gearmotor shaft, i.e. 10,000 ... -8,000 deg),
v_max = 990 deg/s, a_max = 148 deg/s^2. Run: ``python3 docs/fig7_planner.py``.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from planner import plan_trapezoid  # noqa: E402

V0_DPS, V_MAX_DPS, A_MAX_DPS2 = 400.0, 990.0, 148.0
TARGETS_MDEG = {"S1": 1e7, "S2": 3e6, "S3": -3e6, "S4": -8e6}


def main(out: Path = Path(__file__).parent / "img" / "fig7_planner.png") -> Path:
    fig, (ax_v, ax_p) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    for name, target_mdeg in TARGETS_MDEG.items():
        prof = plan_trapezoid(
            0.0, target_mdeg / 1000.0, v_max=V_MAX_DPS, a_max=A_MAX_DPS2, v0=V0_DPS
        )
        t_s = np.linspace(0.0, prof.duration + 1.0, 2000)
        pos_deg, vel_dps, _ = prof.at(t_s)
        label = f"{name} = {target_mdeg:.0e} m° (case {prof.case}, {prof.duration:.2f} s)"
        ax_v.plot(t_s, vel_dps, label=label)
        ax_p.plot(t_s, pos_deg * 1000.0 / 1e6, label=name)
    ax_v.axhline(V0_DPS, color="0.6", lw=0.8, ls=":")
    ax_v.set_ylabel("velocity setpoint (°/s, gearmotor shaft)")
    ax_v.set_title(
        "Seed 000 Fig. 7: trapezoid-like planning from v0 = 400 °/s\n"
        f"v_max = {V_MAX_DPS:.0f} °/s, a_max = {A_MAX_DPS2:.0f} °/s² (planner setpoints only)",
        fontsize=11,
    )
    ax_v.legend(fontsize=8)
    ax_v.grid(alpha=0.3)
    ax_p.set_ylabel("position setpoint (×10⁶ m°)")
    ax_p.set_xlabel("time (s)")
    ax_p.grid(alpha=0.3)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(main())
