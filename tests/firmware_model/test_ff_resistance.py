"""The current loop's feed-forward resistance and back-EMF constant follow the firmware's own
winding estimate (issue 13): ``R_nom (1 + alpha (T_est - T_ambient))`` and ``k_emf (1 + beta
(T_est - T_ambient))``, one implementation for N members in both arithmetics, bounded, each
with a switch (``[safety] thermal_ff_resistance``, ``thermal_ff_back_emf``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from firmware_model import tick as ftick
from firmware_model.firmware import Firmware
from firmware_model.laws.law import Law
from firmware_model.laws.layout import G_EMF_FF, G_EMF_T, G_R_FF, G_R_T, P_EMF_RISE, P_R_RISE
from firmware_model.params import FirmwareParams, SafetyParams, ServoParams
from firmware_model.thermal import (
    EMF_RISE_MAX,
    EMF_RISE_MIN,
    R_RISE_MAX,
    R_RISE_MIN,
    thermal_protection,
)
from sim import loop
from sim.config import ScriptedCommand
from sim.reproduce import experiments

ALPHA = SafetyParams().thermal_alpha_cu_per_k  # 0.00393 / K
AMBIENT = SafetyParams().thermal_ambient_c  # 40 degC: the estimate's power-up value
BETA = SafetyParams().thermal_magnet_tc_per_k  # -0.002 / K


def _protect(fw: Firmware, estimate_c, which: str = "r") -> np.ndarray:
    """One servo tick of the thermal protection from the winding estimates ``estimate_c``
    (no current, at rest): returns the rise it writes for R (``which = "r"``) or for the
    back-EMF constant (``"emf"``)."""
    n = fw._n
    fw._thermal_est[:, 0] = estimate_c
    fw._thermal_est[:, 1] = estimate_c
    derate, rise, emf_rise = np.zeros(n), np.zeros(n), np.zeros(n)
    zeros = np.zeros(n)
    thermal_protection(zeros, zeros, np.ones(n, bool), fw._r_ohm, fw._emf_v_per_dps, fw._fs,
                       ftick.FS_THERMAL, derate, rise, emf_rise)  # fmt: skip
    return rise if which == "r" else emf_rise


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


def test_the_back_emf_change_is_beta_times_the_estimate_s_rise_since_power_up_bounded():
    fw = Firmware(FirmwareParams(), batch=4)
    rise = _protect(fw, np.array([40.0, 65.0, 90.0, 2000.0]), "emf")
    after = fw._thermal_est[:, 0]
    assert rise[:3] == pytest.approx(BETA * (after[:3] - AMBIENT), rel=1e-12)
    assert rise[2] == pytest.approx(-0.002 * 50.0, abs=1e-6)  # 50 K: k_emf -10 %
    assert rise[3] == EMF_RISE_MIN  # an absurd estimate: the factor stays at 0.5
    assert _protect(fw, np.full(4, -1000.0), "emf")[0] == EMF_RISE_MAX
    off = Firmware(FirmwareParams(safety=SafetyParams(thermal_ff_back_emf=False)), batch=4)
    assert np.all(_protect(off, np.array([40.0, 65.0, 90.0, 2000.0]), "emf") == 0.0)
    # the two switches are independent
    assert np.all(_protect(off, np.array([40.0, 65.0, 90.0, 2000.0]))[1:3] > 0.0)


# (the rise's P row, the nominal's G row, the followed G row, the configuration's name)
FOLLOWED = {
    "r": (P_R_RISE, G_R_FF, G_R_T, "resistance_ohm", np.array([0.0, 0.1, 0.3])),
    "emf": (P_EMF_RISE, G_EMF_FF, G_EMF_T, "back_emf_v_per_dps", np.array([0.0, -0.1, -0.3])),
}


@pytest.mark.parametrize("which", ["r", "emf"])
@pytest.mark.parametrize("arithmetic", ["float", "fixed"])
def test_the_current_loop_takes_the_nominal_times_the_factor_for_each_member(arithmetic, which):
    # Three members with rises 0, +10 % and +30 % of R (0, -10 %, -30 % of k_emf); the same
    # law with the nominal * (1 + rise) configured and no rise computes the same duties
    # (float: bit for bit; fixed: the factor's product rounded once more, within one timer
    # step). The axis turns (50 deg/s), so the back-EMF feed-forward acts.
    p_row, g_nom, g_t, name, rise = FOLLOWED[which]
    params = FirmwareParams(servo=ServoParams(arithmetic=arithmetic))
    nominal = getattr(params.current, name)
    a = Law(params, 3)
    b = Law(dataclasses.replace(params, current=dataclasses.replace(
        params.current, **{name: nominal * (1.0 + rise)})), 3)  # fmt: skip
    raw = np.array([100, 100, 100], dtype=np.int64)
    for law in (a, b):
        law.reset(raw)
        if law is a:
            a.P[p_row] = rise  # what the thermal protection writes each servo tick
        for k in range(3):  # the duty leaves the compute-delay pipeline after one period
            law.estimate(raw + 3 * k)
            law.servo(1.0, 50.0, 0.0, 1000.0, 5.0)
            law.current(np.zeros(3, dtype=np.int64), np.ones(3, bool))
    if arithmetic == "float":
        assert np.array_equal(a.G[g_t], b.G[g_nom])
        assert np.array_equal(np.delete(a.P, p_row, 0), np.delete(b.P, p_row, 0))
        assert a.duty[0] != a.duty[2]  # the rise changes the duty
    else:
        assert np.all(np.abs(a.G[g_t] - b.G[g_nom]) <= 1)  # Q8.24 LSBs
        assert np.all(np.abs(a.duty - b.duty) * params.current.pwm_arr <= 1.0)
    # No rise: the nominal exactly (the law without the feature).
    assert a.G[g_t, 0] == a.G[g_nom, 0]


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


def _warm_reversal(**overrides):
    """Fig. 6's step to 3000 deg on a motor warm from ~20 min of the heat duty (plant
    winding 94 degC, housing 83 degC; the firmware's estimate 115.5 / 100 degC, as that run
    leaves them, so the limit is derated to ~3.1 A), and at 3.3 s, while the axis brakes
    near full speed, a new target beyond it: the current reverses from braking (blind) to
    driving at ~900 deg/s, as the heat duty's unsettled legs do from ~13 min on."""
    base = experiments.load("fig6")
    move = next(c for c in base.commands if c.type == "move")
    cmds = [c for c in base.commands if c.type != "move"]
    for t_s, target in ((0.0, 3e6), (3.3, 6e6)):
        fields = dict(move.fields)
        fields["target_mdeg"] = target
        cmds.append(ScriptedCommand(t_s, "move", tuple(fields.items())))
    exp = dataclasses.replace(base, commands=tuple(sorted(cmds, key=lambda c: c.t_s)),
                              duration_s=3.6)  # fmt: skip
    warm = {"thermal.model": True, "thermal.initial_winding_rise_k": 69.0,
            "thermal.initial_housing_rise_k": 58.0}  # fmt: skip
    saved = loop.Simulation

    class Warm(saved):  # type: ignore[misc, valid-type]
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.fw._thermal_est[:, 0] = 115.5
            self.fw._thermal_est[:, 1] = 100.0

    loop.Simulation = Warm
    try:
        return loop.run(exp, seed=0, overrides={**warm, **overrides}).log
    finally:
        loop.Simulation = saved


def test_a_warm_motor_s_reversing_current_stays_within_the_derated_limit():
    # With k_emf following the estimate the current the firmware measures (and the true
    # one) stays within the derated limit (the clamp on the reference) but for the loop's
    # own overshoot: measured 3.164 A against 3.140 A. With the cold k_emf the magnets' lost
    # 15 % of back-EMF, ~1.9 V at 900 deg/s, drives the current to 4.83 A (docs/model.md,
    # "Thermal protection"): the firmware measures it, the PI takes ~7 ticks to remove it.
    log = _warm_reversal()
    limit = np.abs(log.current_ref_a).max()  # the derated limit the reference is clamped to
    assert 3.0 < limit < 3.3
    assert np.abs(log.current_meas_a).max() <= 1.02 * limit
    assert np.abs(log.current_a).max() <= 1.02 * limit
    cold = _warm_reversal(**{"safety.thermal_ff_back_emf": False})
    assert np.abs(cold.current_meas_a).max() > 1.4 * np.abs(cold.current_ref_a).max()
