"""Firmware config tables: defaults, validation messages, batch gains, the table map."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from firmware_model import params as fp


def test_every_table_builds_with_defaults_and_the_composite_is_consistent():
    for path, cls in fp.TABLES.items():
        assert dataclasses.is_dataclass(cls), path
        cls()
    p = fp.FirmwareParams.from_tables({path: cls() for path, cls in fp.TABLES.items()})
    assert p == fp.FirmwareParams()
    assert p.batch_size() is None


@pytest.mark.parametrize(
    ("cls", "key", "value", "reason"),
    [
        (fp.CurrentLoopGains, "kp_v_per_a", -0.1, "must be in"),
        (fp.CurrentLoopGains, "ki_v_per_as", float("nan"), "must be finite"),
        (fp.CurrentLoopGains, "pwm_arr", 3.5, "must be an integer"),
        (fp.VelocityLoopGains, "kp_a_per_dps", "fast", "must be a number"),
        (fp.VelocityLoopGains, "ki_a_per_deg", [0.1, -0.2], "must be >= 0"),
        (fp.PositionLoopGains, "kp_per_s", [[1.0]], "shape (N,)"),
        (fp.ServoParams, "arithmetic", "double", "must be one of"),
        (fp.ServoParams, "current_loop_multiple", 0, "must be in"),
        (fp.ServoParams, "start_enabled", 1, "true or false"),
        (fp.SafetyParams, "over_current_a", float("inf"), "must be finite"),
        (fp.LimitsParams, "travel_max_deg", -2e5, "must be > travel_min_deg"),
        (fp.TelemetryParams, "baud", 10, "must be in"),
        (fp.EstimatorParams, "bandwidth_rad_s", 0.0, "must be in"),
    ],
)
def test_bad_values_name_key_and_value(cls, key, value, reason):
    with pytest.raises(ValueError) as info:
        cls(**{key: value})
    text = str(info.value)
    assert text.startswith(f"{key} = ")
    assert reason in text


def test_composite_relations_are_checked():
    with pytest.raises(ValueError, match="current_limit_a = 8.0"):
        fp.FirmwareParams(limits=fp.LimitsParams(current_limit_a=8.0))
    with pytest.raises(ValueError, match="v_max_dps = 1200.0"):
        fp.FirmwareParams(limits=fp.LimitsParams(v_max_dps=1200.0))
    # 500 Hz: one motor revolution per tick is 2250 axis deg/s; above it nothing unwraps.
    with pytest.raises(ValueError, match="over_speed_dps"):
        fp.FirmwareParams(
            safety=fp.SafetyParams(over_speed_dps=3000.0),
            limits=fp.LimitsParams(v_max_dps=2900.0),
        )


def test_gain_arrays_are_read_only_and_set_the_batch_size():
    vel = fp.VelocityLoopGains(kp_a_per_dps=[0.05, 0.06, 0.07])
    assert isinstance(vel.kp_a_per_dps, np.ndarray)
    with pytest.raises(ValueError):
        vel.kp_a_per_dps[0] = 1.0
    assert fp.FirmwareParams(velocity=vel).batch_size() == 3
    with pytest.raises(ValueError, match="same length"):
        fp.FirmwareParams(
            velocity=vel, position=fp.PositionLoopGains(kp_per_s=[1.0, 2.0])
        ).batch_size()


def test_default_gains_follow_the_documented_derivation():
    g = fp.default_gains()
    n = fp.NOMINAL
    ts = 1.0 / n["tick_hz"]
    bw = fp.CURRENT_BW_TS / ts
    assert g["current.kp_v_per_a"] == pytest.approx(bw * n["inductance_h"])
    assert g["current.ki_v_per_as"] == pytest.approx(bw * n["resistance_ohm"])
    # Velocity PI: symmetric optimum, Ti = 4 T_sigma; position P = crossover / 4.
    t_sigma = g["velocity.kp_a_per_dps"] / g["velocity.ki_a_per_deg"] / 4.0
    assert g["position.kp_per_s"] == pytest.approx(1.0 / (8.0 * t_sigma))
    # Inertia feed-forward and the observer's current input are reciprocal (both J/Kt).
    assert g["velocity.acc_ff_a_per_dps2"] * g["estimator.accel_per_amp_dps2"] == pytest.approx(1.0)


def test_observer_gains_place_a_triple_pole():
    est = fp.EstimatorParams(bandwidth_rad_s=300.0)
    k = np.array(est.observer_gains(0.002))
    f = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    h = np.array([[1.0, 0.0, 0.0]])
    eig = np.linalg.eigvals((np.eye(3) - np.outer(k, h)) @ f)
    np.testing.assert_allclose(np.abs(eig), np.exp(-0.6), rtol=1e-3)


def test_current_sense_scale():
    cur = fp.CurrentLoopGains()
    # 3.3 V / 4096 / 1 kOhm * 8500 = 6.85 mA per count.
    assert cur.a_per_adc == pytest.approx(3.3 / 4096 / 1000 * 8500)
