"""The BTN7971B H-bridge: averaged PWM voltage, its own current limitation, current sense.

Averaged over a 20 kHz PWM period (50 us, far shorter than L/R = 0.5 ms), the enabled bridge
applies ``duty * V_supply`` with ``duty`` quantised to the timer's ``1/ARR`` steps. Disabled
(both low sides off), the motor current freewheels through the body diodes back into the
supply until it reaches zero. The chip's current limitation (I_CL, tens of A) chops the
high side; averaged, it pins the current at I_CL while the bridge would drive it higher.

Current sense: each half-bridge's IS pin sources ``I_load / k_ILIS`` while its *high side*
conducts, so the sense is unidirectional: the driven half-bridge reports the current that
flows in the driven direction, ``max(0, sign(duty) * i)``; a current against the duty (or in
a disabled bridge) flows through low sides and diodes and reads 0. The firmware rebuilds a
signed current as ``sign(duty) * sensed``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim.params import BridgeParams, CurrentSenseParams

__all__ = ["adc_counts", "quantise_duty", "sensed_current_a"]


def quantise_duty(duty: Any, bridge: BridgeParams) -> Any:
    """Clip to [-1, 1] and round to the timer's compare steps (1/ARR). Vectorised."""
    arr = bridge.arr
    return np.round(np.clip(duty, -1.0, 1.0) * arr) / arr


def sensed_current_a(current_a: Any, duty: Any, enable: Any) -> Any:
    """The current the IS pins report (A, >= 0): high-side conduction only. Vectorised."""
    return np.where(enable, np.maximum(0.0, np.sign(duty) * current_a), 0.0)


def adc_counts(sensed_a: Any, sense: CurrentSenseParams, noise_lsb: Any = 0.0) -> Any:
    """12-bit ADC reading of the IS voltage ``sensed_a / k_ILIS * R_IS`` (int, clipped)."""
    full = (1 << sense.adc_bits) - 1
    counts = np.floor(sensed_a / sense.a_per_lsb + noise_lsb + 0.5)
    return np.clip(counts, 0, full).astype(np.int64)
