"""What the control-law variants share: the run-time gain names, the constants derived
from the parameters, and two array helpers."""

from __future__ import annotations

from typing import Any

import numpy as np

from firmware_model import fixedpoint as fx
from firmware_model.params import FirmwareParams
from firmware_model.units import AXIS_DEG_PER_COUNT, ENCODER_COUNTS_PER_REV

__all__ = ["GAIN_NAMES", "LawBase"]

REV = ENCODER_COUNTS_PER_REV
HALF_REV = REV // 2
# Q16.16 raw units of axis degrees per encoder count (exact: 18).
Q_DEG_PER_COUNT = int(round(AXIS_DEG_PER_COUNT * (1 << fx.SIG_FRAC_BITS)))

#: The run-time gains (name -> (params table attribute, field)).
GAIN_NAMES: dict[str, tuple[str, str]] = {
    "kp_i": ("current", "kp_v_per_a"),
    "ki_i": ("current", "ki_v_per_as"),
    "r_ff": ("current", "resistance_ohm"),
    "emf_ff": ("current", "back_emf_v_per_dps"),
    "kp_v": ("velocity", "kp_a_per_dps"),
    "ki_v": ("velocity", "ki_a_per_deg"),
    "acc_ff": ("velocity", "acc_ff_a_per_dps2"),
    "kp_p": ("position", "kp_per_s"),
    "vel_ff": ("position", "vel_ff"),
}


def identity(x: Any) -> Any:
    return x


def clip(x: Any, limit: Any) -> Any:
    """Clamp to [-limit, limit] (two ufuncs: cheaper than np.clip's wrapper)."""
    return np.minimum(np.maximum(x, -limit), limit)


class LawBase:
    """Constants every implementation derives from the parameters, and its run-time gains."""

    def _require_scalar_gains(self) -> None:
        """The single-axis laws take float gains; (N,) arrays belong to ``ArrayLaw``."""
        for name, value in self.gains.items():
            if isinstance(value, np.ndarray):
                raise ValueError(f"{name} = {value!r}: array gains need batch=N")

    def _init_common(self, params: FirmwareParams) -> None:
        servo, cur = params.servo, params.current
        self.dt_s = servo.dt_s
        self.dt_current_s = servo.dt_s / servo.current_loop_multiple
        self.delay = servo.compute_delay_ticks
        self.k_pos, self.k_vel, self.k_dist = params.estimator.observer_gains(servo.dt_s)
        self.dps_per_count_tick = AXIS_DEG_PER_COUNT * servo.tick_hz
        # Counts per tick^2 of acceleration per ampere of motor current (observer input).
        self.counts_tick2_per_a = (
            params.estimator.accel_per_amp_dps2 * servo.dt_s**2 / AXIS_DEG_PER_COUNT
        )
        self.supply_v = cur.supply_v
        self.duty_limit = cur.duty_limit
        self.arr = cur.pwm_arr
        self.a_per_adc = cur.a_per_adc
        self.sense_floor = cur.sense_floor_counts
        # The current limit of the last servo step (the regenerative clamp's bound).
        self.i_limit_a = params.limits.current_limit_a
        self.gains: dict[str, Any] = {
            name: getattr(getattr(params, table), key) for name, (table, key) in GAIN_NAMES.items()
        }
