"""The current loop's feed-forward resistance follows the firmware's own winding estimate
(issue 13): ``R_nom (1 + alpha (T_est - T_ambient))``, one implementation for N members in
both arithmetics, bounded, with a switch (``[safety] thermal_ff_resistance``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from firmware_model import tick as ftick
from firmware_model.firmware import Firmware
from firmware_model.laws.law import Law
from firmware_model.laws.layout import G_R_FF, G_R_T, P_R_RISE
from firmware_model.params import FirmwareParams, SafetyParams, ServoParams
from firmware_model.thermal import R_RISE_MAX, R_RISE_MIN, thermal_protection
from sim import loop
from sim.reproduce import experiments

ALPHA = SafetyParams().thermal_alpha_cu_per_k  # 0.00393 / K
AMBIENT = SafetyParams().thermal_ambient_c  # 40 degC: the estimate's power-up value


def _protect(fw: Firmware, estimate_c) -> np.ndarray:
    """One servo tick of the thermal protection from the winding estimates ``estimate_c``
    (no current, at rest): returns the rise it writes."""
    n = fw._n
    fw._thermal_est[:, 0] = estimate_c
    fw._thermal_est[:, 1] = estimate_c
    derate, rise = np.zeros(n), np.zeros(n)
    zeros = np.zeros(n)
    thermal_protection(zeros, zeros, np.ones(n, bool), fw._r_ohm, fw._emf_v_per_dps, fw._fs,
                       ftick.FS_THERMAL, derate, rise)  # fmt: skip
    return rise


def test_the_rise_is_alpha_times_the_estimate_s_rise_since_power_up_bounded():
    fw = Firmware(FirmwareParams(), batch=4)
    rise = _protect(fw, np.array([40.0, 65.0, 90.0, 2000.0]))
    after = fw._thermal_est[:, 0]  # one tick of cooling at rest later
    assert rise[:3] == pytest.approx(ALPHA * (after[:3] - AMBIENT), rel=1e-12)
    assert rise[1] == pytest.approx(0.00393 * 25.0, abs=1e-6)  # 25 K: R +9.8 %
    assert rise[3] == R_RISE_MAX  # an absurd estimate: the factor stays at 2
    assert _protect(fw, np.full(4, -1000.0))[0] == R_RISE_MIN
    off = Firmware(FirmwareParams(safety=SafetyParams(thermal_ff_resistance=False)), batch=4)
    assert np.all(_protect(off, np.array([40.0, 65.0, 90.0, 2000.0])) == 0.0)


@pytest.mark.parametrize("arithmetic", ["float", "fixed"])
def test_the_current_loop_takes_r_times_the_factor_for_each_member(arithmetic):
    # Three members with rises 0, +10 % and +30 %; the same law with R_nom * (1 + rise)
    # configured and no rise computes the same duties (float: bit for bit; fixed: the
    # factor's product rounded once more, within one timer step).
    params = FirmwareParams(servo=ServoParams(arithmetic=arithmetic))
    rise = np.array([0.0, 0.1, 0.3])
    r_nom = params.current.resistance_ohm
    a = Law(params, 3)
    b = Law(dataclasses.replace(params, current=dataclasses.replace(
        params.current, resistance_ohm=r_nom * (1.0 + rise))), 3)  # fmt: skip
    raw = np.array([100, 100, 100], dtype=np.int64)
    for law in (a, b):
        law.reset(raw)
        if law is a:
            a.P[P_R_RISE] = rise  # what the thermal protection writes each servo tick
        for k in range(3):  # the duty leaves the compute-delay pipeline after one period
            law.estimate(raw + 3 * k)
            law.servo(1.0, 50.0, 0.0, 1000.0, 5.0)
            law.current(np.zeros(3, dtype=np.int64), np.ones(3, bool))
    if arithmetic == "float":
        assert np.array_equal(a.G[G_R_T], b.G[G_R_FF])
        assert np.array_equal(np.delete(a.P, P_R_RISE, 0), np.delete(b.P, P_R_RISE, 0))
        assert a.duty[0] != a.duty[2]  # the rise changes the duty
    else:
        assert np.all(np.abs(a.G[G_R_T] - b.G[G_R_FF]) <= 1)  # Q8.24 LSBs
        assert np.all(np.abs(a.duty - b.duty) * params.current.pwm_arr <= 1.0)
    # No rise: the nominal R exactly (the law without the feature).
    assert a.G[G_R_T, 0] == a.G[G_R_FF, 0]


def test_a_stalled_motor_s_feed_forward_r_follows_the_estimate():
    # 20 s of a stall at 5 A: the estimate rises ~40 K, the feed-forward R with it, by the
    # same factor the protection heats with (alpha, from the power-up estimate).
    stall = {"platter.coulomb_nm": 1e4, "platter.stiction_nm": 0.0,
             "safety.thermal_trip_c": 200.0, "safety.thermal_derate_c": 190.0}  # fmt: skip
    exp = experiments.with_duration(experiments.load("fig6"), 20.0)
    holder = {}
    saved = loop.Simulation

    class Keep(saved):  # type: ignore[misc, valid-type]
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            holder["sim"] = self

    loop.Simulation = Keep
    try:
        loop.run(exp, seed=0, overrides=stall)
    finally:
        loop.Simulation = saved
    fw = holder["sim"].fw
    est = float(fw.thermal_estimate_c)
    assert est > 70.0
    factor = fw.law.G[G_R_T, 0] / fw.law.G[G_R_FF, 0]
    # the factor of the last servo step, from the estimate one tick before this one
    assert factor == pytest.approx(1.0 + ALPHA * (est - AMBIENT), abs=1e-5)
    off = loop.run(exp, seed=0, overrides={**stall, "safety.thermal_ff_resistance": False})
    on = loop.run(exp, seed=0, overrides=stall)
    assert not np.array_equal(on.log.duty, off.log.duty)
