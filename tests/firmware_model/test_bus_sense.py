"""The firmware's bus-voltage channel (issue 13 §2.1): the duty from the measured bus
(``bus_compensation``), the regenerative bus-current limit (``regen_bus_current_limit_a``),
the current integrator held at the lock-out (``bus_hold_v``), in both arithmetics."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_model import fixedpoint as fx
from firmware_model.laws import Law
from firmware_model.laws.layout import C_BUS_ADC, S_I_I, S_VEL
from firmware_model.params import CurrentLoopGains, FirmwareParams, ServoParams

ARR = 3600


def _law(arithmetic: str, **current) -> Law:
    params = FirmwareParams(
        servo=ServoParams(arithmetic=arithmetic, compute_delay_ticks=0),
        current=CurrentLoopGains(**current),
    )
    law = Law(params)
    law.reset(np.array([0]))
    return law


def _counts(volts: float) -> int:
    return int(round(volts / CurrentLoopGains().v_per_bus_adc))


def _duty_for(arithmetic: str, bus_v: float, **current) -> float:
    """The duty for a 2 A reference at rest (blind sense: u = R i_ref = 2.4 V)."""
    law = _law(arithmetic, **current)
    law.current_ref_a = np.array([2.0])
    law.C[C_BUS_ADC] = _counts(bus_v)
    return float(law.current(np.zeros(1, dtype=np.int64), np.ones(1, dtype=bool))[0])


@pytest.mark.parametrize("arithmetic", ["float", "fixed"])
def test_duty_follows_the_measured_bus(arithmetic):
    v_per = CurrentLoopGains().v_per_bus_adc
    for bus_v in (20.0, 24.0, 28.0):
        duty = _duty_for(arithmetic, bus_v, bus_compensation=True)
        measured = _counts(bus_v) * v_per
        # The applied voltage is the loop's 2.4 V, to one timer step of the measured bus.
        assert duty * measured == pytest.approx(2.4, abs=measured / ARR)
        # Without compensation the duty is for the configured 24 V whatever the bus reads.
        assert _duty_for(arithmetic, bus_v) == pytest.approx(2.4 / 24.0, abs=1.0 / ARR)


@pytest.mark.parametrize("arithmetic", ["float", "fixed"])
def test_regenerative_limit_caps_the_braking_current(arithmetic):
    # At 990 deg/s (20 V of back-EMF) a setpoint far behind asks for full braking (-5 A).
    # With 0.5 A of bus current allowed at a 24 V bus: |i| <= 0.5 * 24 / 20.04 = 0.599 A.
    for limit, expect in ((0.0, -5.0), (0.5, -0.5 * 24.0 / (990.0 * 0.0202458))):
        law = _law(arithmetic, regen_bus_current_limit_a=limit)
        law.S[S_VEL] = fx.to_sig(990.0) if law.fixed else 990.0
        law.servo(-1000.0, 0.0, 0.0, 1000.0, 5.0)
        assert float(law.current_ref_a[0]) == pytest.approx(expect, abs=2e-4)
        # Driving (the current with the back-EMF) is not limited.
        law.servo(1000.0, 0.0, 0.0, 5000.0, 5.0)
        assert float(law.current_ref_a[0]) == pytest.approx(5.0)


@pytest.mark.parametrize("arithmetic", ["float", "fixed"])
def test_current_integrator_holds_at_the_lock_out(arithmetic):
    # A visible error (sensed 0 A against a 2 A reference with a positive duty) integrates
    # below the hold threshold and not from it up (the bridge may be locked out).
    moved = {}
    for bus_v in (24.0, 28.0):
        law = _law(arithmetic)
        law.current_ref_a = np.array([2.0])
        law.C[C_BUS_ADC] = _counts(bus_v)
        for _ in range(3):
            law.current(np.zeros(1, dtype=np.int64), np.ones(1, dtype=bool))
        moved[bus_v] = int(law.S[S_I_I, 0]) if law.fixed else float(law.S[S_I_I, 0])
    assert moved[24.0] != 0
    assert moved[28.0] == 0
