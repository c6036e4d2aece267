"""BTN7971B bridge: duty quantisation, unidirectional current sense, ADC scaling."""

from __future__ import annotations

import numpy as np
import pytest

from sim.bridge import adc_counts, quantise_duty, sensed_current_a
from sim.params import BridgeParams, CurrentSenseParams


def test_duty_quantised_to_arr_steps():
    b = BridgeParams()
    assert b.arr == 3600
    d = quantise_duty(np.array([0.1234567, -0.5, 1.7, -3.0, 1 / 7200 + 1e-9]), b)
    np.testing.assert_allclose(d * 3600, np.round(d * 3600), atol=1e-9)
    assert d[2] == 1.0 and d[3] == -1.0
    assert abs(d[0] - 0.1234567) <= 0.5 / 3600


def test_sense_sees_only_forward_high_side_current():
    i = np.array([2.0, -2.0, 2.0, -2.0, 2.0])
    duty = np.array([0.5, 0.5, -0.5, -0.5, 0.0])
    sensed = sensed_current_a(i, duty, np.array([True] * 5))
    np.testing.assert_array_equal(sensed, [2.0, 0.0, 0.0, 2.0, 0.0])
    assert np.all(sensed_current_a(i, duty, np.array([False] * 5)) == 0)


def test_adc_scaling_and_clipping():
    s = CurrentSenseParams()
    # 5 A / 8500 * 1 kOhm = 0.588 V -> 0.588 / 3.3 * 4096 = 730 counts
    assert adc_counts(np.array(5.0), s) == round(5.0 / 8500 * 1000 / 3.3 * 4096)
    assert s.a_per_lsb == pytest.approx(3.3 / 4096 * 8.5)
    assert adc_counts(np.array(100.0), s) == 4095
    assert adc_counts(np.array(0.0), s, noise_lsb=-3.0) == 0
