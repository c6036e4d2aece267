"""Q16.16 / Q8.24 helpers: rounding, saturation, the exact count scale."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from firmware_model import fixedpoint as fx
from firmware_model.units import AXIS_DEG_PER_COUNT


def test_one_count_is_exactly_18_raw_units():
    assert AXIS_DEG_PER_COUNT * 2**16 == 18.0


def test_saturation_at_int32():
    big = fx.to_sig(1e9)
    assert big == fx.INT32_MAX
    assert fx.to_sig(-1e9) == fx.INT32_MIN
    assert fx.mul_gain(np.array([fx.INT32_MAX]), fx.to_gain(100.0))[0] == fx.INT32_MAX
    assert fx.mul_gain(np.array([fx.INT32_MIN]), fx.to_gain(100.0))[0] == fx.INT32_MIN


@given(st.floats(-30000, 30000, allow_nan=False), st.floats(-100, 100, allow_nan=False))
def test_product_within_one_lsb_of_float(x, g):
    exact = x * g
    q = fx.mul_gain(fx.to_sig(x), fx.to_gain(g))
    if abs(exact) < 32767:
        # Input rounding (half an LSB of x times g, half an LSB of g times x) + output.
        bound = (0.5 * abs(g) + 0.5 * abs(x) * 2**-8 + 1.0) / 2**16
        assert abs(float(fx.from_sig(q)[()]) - exact) <= bound
    else:
        assert int(q) in (fx.INT32_MAX, fx.INT32_MIN)
