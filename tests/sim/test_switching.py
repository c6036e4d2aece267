"""The bridge's switching times (issue 13 §2.4, ``sim.bridge.switching``): the output pulse
differs from the input pulse by the high side's or the low side's delays, by the current's
direction; a pulse shortened to nothing is not switched (the minimum pulse width)."""

from __future__ import annotations

import numpy as np
import pytest

from sim import loop
from sim.bridge import switching, switching_table
from sim.params import BridgeParams
from sim.reproduce import experiments

# BTS7960B datasheet 4.2.2 and 4.2.7-4.2.18, typical at R_SR = 0 (the BTN7971B's sister):
# high side (3.1 + 1/2) - (2.4 + 1/2) = 0.7 us shorter, low side (4 + 1/2) - (1.3 + 1/2)
# = 2.7 us longer.
TYP = {"bridge.pulse_shift_with_current_us": -0.7, "bridge.pulse_shift_against_current_us": 2.7}


def _switch(duty: float, current_a: float, vs: float = 24.0):
    table = switching_table(
        BridgeParams(pulse_shift_with_current_us=-0.7, pulse_shift_against_current_us=2.7), 1
    )
    d = np.array([duty])
    sign = np.array([np.sign(duty)])
    volt = d * vs
    switching(np.array([[current_a, 0.0, 0.0, 0.0, 0.0]]), np.array([vs]), table, d, sign, volt)
    return float(d[0]), float(sign[0]), float(volt[0])


def test_pulse_shifts_by_current_direction_and_short_pulses_vanish():
    # 20 kHz: 0.7 us is 0.014 of the period, 2.7 us 0.054.
    assert _switch(0.3, 2.0)[0] == pytest.approx(0.3 - 0.014)  # driving: high side's edges
    assert _switch(0.3, -2.0)[0] == pytest.approx(0.3 + 0.054)  # braking: low side's
    assert _switch(-0.3, 2.0)[0] == pytest.approx(-0.3 - 0.054)  # against a negative duty
    assert _switch(-0.3, -2.0)[0] == pytest.approx(-0.3 + 0.014)
    assert _switch(0.99, -2.0)[0] == 1.0  # not beyond full duty
    # A 1 % duty (0.5 us) at rest or driving is shorter than the 0.7 us: not switched at all.
    d, sign, volt = _switch(0.01, 0.0)
    assert (d, sign, volt) == (0.0, 0.0, 0.0)
    assert _switch(0.0, 1.0) == (0.0, 0.0, 0.0)
    # The ideal bridge has no table: nothing to do.
    assert switching_table(BridgeParams(), 4).shape == (0, 2)


def test_switching_times_on_the_closed_loop():
    exp = experiments.with_duration(experiments.load("fig6"), 6.0)
    ideal = loop.run(exp, seed=0).log
    real = loop.run(exp, seed=0, overrides=TYP).log
    rest = ideal.t_s > 5.0
    # Holding, the firmware's small duties are swallowed in part: it raises them (the
    # integrator finds the dead band) and the holding current grows.
    swallowed = (real.voltage_v == 0.0) & (real.duty != 0.0)
    assert swallowed[rest].sum() > 50
    assert np.median(np.abs(real.duty[rest])) > 2 * np.median(np.abs(ideal.duty[rest]))
    # Braking against the current, the low side lengthens the pulse: softer braking,
    # a larger overshoot of the step (measured 74.4 against 42.3 deg).
    assert real.true_pos_deg.max() - ideal.true_pos_deg.max() > 20.0
    assert np.all(real.fault == 0)
