"""The SetGains stability check on the nominal model."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_model.params import FirmwareParams, default_gains
from firmware_model.stability import current_loop_stable, unstable_reason


def _defaults() -> dict[str, float]:
    g = default_gains()
    return {
        "kp_i": g["current.kp_v_per_a"],
        "ki_i": g["current.ki_v_per_as"],
        "kp_v": g["velocity.kp_a_per_dps"],
        "ki_v": g["velocity.ki_a_per_deg"],
        "kp_p": g["position.kp_per_s"],
    }


def test_default_gains_pass():
    assert unstable_reason(FirmwareParams(), _defaults()) is None


@pytest.mark.parametrize(
    ("name", "value", "loop"),
    [
        ("kp_i", 2.0, "current"),  # Kp/R > 1
        ("ki_i", 2000.0, "current"),
        ("kp_v", 5.0, "velocity"),
        ("kp_p", 400.0, "velocity"),
    ],
)
def test_gains_far_too_high_fail(name, value, loop):
    gains = _defaults() | {name: value}
    reason = unstable_reason(FirmwareParams(), gains)
    assert reason is not None
    assert reason.startswith("current") == (loop == "current")


def test_current_loop_check_matches_simulation_of_the_sampled_loop():
    # Simulate i[k] = u[k-2] / R (static plant, one period compute delay), PI on the error.
    r, ts = 1.2, 0.002
    for kp, ki in [(0.15, 300.0), (0.6, 300.0), (0.15, 700.0), (1.0, 100.0)]:
        u_hist = [0.0, 0.0]
        integ = 0.0
        i_hist = []
        for _ in range(400):
            i = u_hist[-2] / r
            e = 1.0 - i
            integ += ki * ts * e
            u_hist.append(kp * e + integ)
            i_hist.append(i)
        settled = abs(i_hist[-1] - 1.0) < 1e-6 and np.all(np.isfinite(i_hist))
        assert current_loop_stable(kp, ki, ts, 1) == settled, (kp, ki)


@pytest.mark.parametrize(("factor", "stable"), [(8.0, True), (12.0, False)])
def test_velocity_gain_edge_agrees_with_the_closed_loop(make_bench, factor, stable):
    # Oracle: the closed loop on the test plant. x8 holds still, x12 rings at the clamp.
    from firmware_model.params import VelocityLoopGains
    from serial_protocol.messages import Move

    gains = _defaults()
    gains["kp_v"] *= factor
    assert (unstable_reason(FirmwareParams(), gains) is None) == stable
    params = FirmwareParams(velocity=VelocityLoopGains(kp_a_per_dps=gains["kp_v"]))
    b = make_bench(params)
    b.run(400, {5: [Move(cmd_id=1, target_deg=30.0, v_max_dps=200.0, a_max_dps2=1000.0)]})
    current = b.arr("true_i_a")[250:, 0]
    ringing = np.sqrt(np.mean(np.diff(current) ** 2))  # A per tick, rms
    assert (ringing < 0.1) == stable
