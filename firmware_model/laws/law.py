"""``Law``: the control law's state for ``N`` members and the calls into the compiled
steps of the chosen arithmetic (``laws/float64.py`` or ``laws/fixed_q.py``).

One axis is ``Law(params)`` (N = 1): the same steps, the same arrays.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_model import fixedpoint as fx
from firmware_model.laws import fixed_q, float64
from firmware_model.laws.layout import (
    C_BUS_ADC,
    C_COUNT,
    C_D,
    C_INNOV,
    C_PIPE,
    C_RAW_PREV,
    C_SENSE_OFFSET_A,
    C_SENSE_OFFSET_B,
    C_STUCK,
    G_ACC_FF,
    G_EMF_FF,
    G_EMF_T,
    G_K_ACC,
    G_K_VEL,
    G_KDIST,
    G_KI_I_DT,
    G_KI_V_DT,
    G_KP_I,
    G_KP_P,
    G_KP_V,
    G_KPOS_M1,
    G_KVEL,
    G_R_FF,
    G_R_T,
    G_VFF,
    HALF_REV,
    K_A_PER_ADC,
    K_A_PER_ADC_Q,
    K_ARR,
    K_BUS_COMP,
    K_BUS_HOLD,
    K_CAL_MAX_VEL,
    K_CAL_SAMPLES,
    K_DELAY,
    K_DPS_PER_COUNT_TICK,
    K_HALF_Q,
    K_I_LIMIT_A,
    K_INV_SUPPLY_Q,
    K_PIPE_I,
    K_REF_I,
    K_REGEN_A,
    K_SENSE_FLOOR,
    K_SUPPLY_V,
    K_U_LIM,
    K_V_PER_BUS_ADC,
    K_V_PER_BUS_ADC_Q,
    N_G,
    N_K,
    N_P,
    P_DUTY,
    P_IMEAS,
    P_IREF,
    P_POS,
    P_VEL,
    P_VEL_RAW,
    P_VREF,
    REV,
    S_AD,
    S_EP,
    S_IREF,
    S_REF_PIPE,
    S_V,
    S_VEL,
)  # fmt: skip
from firmware_model.params import FirmwareParams
from firmware_model.units import AXIS_DEG_PER_COUNT

__all__ = ["GAIN_NAMES", "Law"]

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
_SIG_ONE = float(1 << fx.SIG_FRAC_BITS)


class Law:
    """The control law of ``n`` axes in lock-step (``firmware_model/servo.py`` says what it
    computes). ``arithmetic = "fixed"`` in ``params.servo`` runs the Q-format law.

    Attributes (``(n,)`` arrays, axis units; views of the state, updated in place by each
    step: copy what must outlive the next step): ``pos_deg``, ``vel_dps``, ``vel_raw_dps``
    (plain differencing), ``vel_ref_dps``, ``current_ref_a``, ``current_meas_a``, ``duty``
    (the duty being applied), ``count`` (multi-turn encoder count), ``innovation_counts``
    (reading minus prediction), ``stuck_ticks`` (ticks the raw reading has not changed),
    ``raw_counts`` (the last reading).
    """

    def __init__(self, params: FirmwareParams, n: int = 1) -> None:
        if not isinstance(n, int) or n < 1:
            raise ValueError(f"batch = {n!r}: must be an integer >= 1")
        self.n = n
        servo, cur = params.servo, params.current
        self.fixed = servo.arithmetic == "fixed"
        #: The module of compiled steps of this arithmetic (``estimate``, ``servo``, ``current``).
        self.steps = fixed_q if self.fixed else float64
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
        self.gains: dict[str, Any] = {
            name: getattr(getattr(params, table), key) for name, (table, key) in GAIN_NAMES.items()
        }
        for name, value in self.gains.items():
            if isinstance(value, np.ndarray) and value.shape != (n,):
                raise ValueError(f"{name}: gain array shape {value.shape} != ({n},)")
        dtype = np.int64 if self.fixed else np.float64
        d = self.delay
        self.P = np.zeros((N_P, n))
        self.C = np.zeros((C_PIPE + d, n), dtype=np.int64)
        self.S = np.zeros((S_REF_PIPE + d + 1, n), dtype=dtype)
        self.G = np.zeros((N_G, n), dtype=dtype)
        self.K = np.zeros(N_K)
        k = self.K
        k[K_DPS_PER_COUNT_TICK] = self.dps_per_count_tick
        k[K_A_PER_ADC], k[K_SENSE_FLOOR] = self.a_per_adc, self.sense_floor
        k[K_U_LIM], k[K_SUPPLY_V] = self.duty_limit * self.supply_v, self.supply_v
        k[K_ARR], k[K_DELAY] = self.arr, d
        k[K_I_LIMIT_A] = params.limits.current_limit_a
        k[K_A_PER_ADC_Q] = int(round(self.a_per_adc * (1 << fx.GAIN_FRAC_BITS)))
        # The kernel's Python (the same operations): calling the compiled one from here
        # would load one more kernel from numba's cache in every fresh process.
        k[K_HALF_Q] = fixed_q.qgain.py_func(0.5)
        k[K_INV_SUPPLY_Q] = fixed_q.qgain.py_func(1.0 / self.supply_v)
        k[K_BUS_COMP] = float(cur.bus_compensation)
        k[K_V_PER_BUS_ADC] = cur.v_per_bus_adc
        k[K_V_PER_BUS_ADC_Q] = int(round(cur.v_per_bus_adc * (1 << fx.GAIN_FRAC_BITS)))
        k[K_REGEN_A] = cur.regen_bus_current_limit_a
        k[K_BUS_HOLD] = math.ceil(cur.bus_hold_v / cur.v_per_bus_adc)
        k[K_CAL_SAMPLES] = cur.sense_calibration_samples
        k[K_CAL_MAX_VEL] = cur.sense_calibration_max_speed_dps
        self.sense_offset_counts = cur.sense_offset_counts
        # Until the board reports a reading: the configured supply (nominal).
        self.bus_adc_nominal = int(round(self.supply_v / cur.v_per_bus_adc))
        self._derive()
        self.reset(np.zeros(n, dtype=np.int64))

    # -- gains
    def _derive(self) -> None:
        """The ``G`` rows from the gains and the derived constants."""
        g = self.gains
        rows = {
            G_KP_P: g["kp_p"], G_VFF: g["vel_ff"], G_KP_V: g["kp_v"],
            G_KI_V_DT: np.asarray(g["ki_v"]) * self.dt_s, G_ACC_FF: g["acc_ff"],
            G_KP_I: g["kp_i"], G_KI_I_DT: np.asarray(g["ki_i"]) * self.dt_current_s,
            G_R_FF: g["r_ff"], G_R_T: g["r_ff"], G_EMF_FF: g["emf_ff"], G_EMF_T: g["emf_ff"],
            G_KPOS_M1: self.k_pos - 1.0,
            G_KVEL: self.k_vel, G_KDIST: self.k_dist, G_K_VEL: self.dps_per_count_tick,
            G_K_ACC: self.counts_tick2_per_a,
        }  # fmt: skip
        for row, value in rows.items():
            value = np.asarray(value, dtype=float)
            self.G[row] = fx.to_gain(value) if self.fixed else value

    def set_gains(self, **gains: Any) -> None:
        """Replace some of the run-time gains (names of :data:`GAIN_NAMES`)."""
        self.gains.update(gains)
        self._derive()

    @property
    def i_limit_a(self) -> float:
        """The current limit of the last servo step (the regenerative clamp's bound) (A)."""
        return float(self.K[K_I_LIMIT_A])

    # -- state
    def reset(self, raw_counts: npt.ArrayLike) -> None:
        """Power-on: the multi-turn count starts at the raw reading taken within half a
        motor turn of zero (``[-8192, 8191]`` counts, +-2.25 deg at the axis: a noisy
        first reading of 16383 at rest on zero is -1 count, not one motor turn = 4.5 deg
        away), everything at rest. The members share one setpoint: each count starts at its
        reading unwrapped around member 0's (16383 next to 0 is -1, not +1 revolution)."""
        raw = np.broadcast_to(np.asarray(raw_counts, dtype=np.int64), (self.n,))
        self.C[:] = 0
        base = (raw[0] + HALF_REV) % REV - HALF_REV
        self.C[C_COUNT] = base + (raw - raw[0] + HALF_REV) % REV - HALF_REV
        self.C[C_RAW_PREV] = raw
        self.C[C_BUS_ADC] = self.bus_adc_nominal
        # Both pins' until a calibration measures each.
        self.C[C_SENSE_OFFSET_A] = self.C[C_SENSE_OFFSET_B] = self.sense_offset_counts
        self.S[:] = 0
        self.P[:] = 0.0
        self.P[P_POS] = self.C[C_COUNT] * AXIS_DEG_PER_COUNT
        # reset_control()'s rows are zero with the arrays: only its pipeline indices remain
        # (its kernel is not called here, so that a cold start compiles it in the second
        # process, sim.loop._compile_plant_aside, not before the tick).
        self.K[K_REF_I] = self.K[K_PIPE_I] = 0

    def resync(self) -> None:
        """Restart the observer on the encoder: no offset, no disturbance, the last raw
        difference as the speed (after a glitch, so that its ringing cannot trip anything)."""
        s, d = self.S, self.C[C_D]
        s[S_EP] = 0
        s[S_AD] = 0
        if self.fixed:
            s[S_V] = fx.sat32(d << fx.SIG_FRAC_BITS)
            s[S_VEL] = fx.mul_gain(s[S_V], self.G[G_K_VEL])
            self.P[P_VEL] = s[S_VEL] / _SIG_ONE
        else:
            s[S_V] = d
            s[S_VEL] = s[S_V] * self.G[G_K_VEL]
            self.P[P_VEL] = s[S_VEL]
        self.C[C_INNOV] = 0
        self.C[C_STUCK] = 0

    def reset_control(self, mask: npt.NDArray[np.bool_] | None = None) -> None:
        """Zero the integrators, references, current measurement and PWM pipeline (of the
        members in ``mask``; all by default): the bridge is off."""
        if mask is None:
            mask = np.ones(self.n, dtype=bool)
            self.K[K_REF_I] = self.K[K_PIPE_I] = 0
        float64.reset_control(np.asarray(mask, dtype=bool), self.P, self.C, self.S, self.K)

    # -- the three steps
    def estimate(self, raw_counts: npt.NDArray[np.int64]) -> None:
        """Unwrap the readings (int64 ``(n,)``) and update the velocity observer."""
        self.steps.estimate(raw_counts, self.P, self.C, self.S, self.G, self.K)

    def servo(
        self,
        sp_pos_deg: float,
        sp_vel_dps: float,
        sp_acc_dps2: float,
        v_clamp_dps: float,
        i_limit_a: float,
    ) -> None:
        """Position P and velocity PI: sets ``vel_ref_dps`` and ``current_ref_a``."""
        self.steps.servo(
            float(sp_pos_deg), float(sp_vel_dps), float(sp_acc_dps2), float(v_clamp_dps),
            float(i_limit_a), self.P, self.C, self.S, self.G, self.K,
        )  # fmt: skip

    def current(
        self, adc_counts: npt.NDArray[np.int64], enabled: npt.NDArray[np.bool_]
    ) -> npt.NDArray[np.float64]:
        """One current-loop period (``adc_counts`` int64 ``(n,)``, ``enabled`` bool
        ``(n,)``); returns ``duty`` (the view), applied by the bridge next period."""
        self.steps.current(adc_counts, enabled, self.P, self.C, self.S, self.G, self.K)
        return self.P[P_DUTY]

    # -- views (axis units)
    pos_deg = property(lambda self: self.P[P_POS])
    vel_dps = property(lambda self: self.P[P_VEL])
    vel_raw_dps = property(lambda self: self.P[P_VEL_RAW])
    vel_ref_dps = property(lambda self: self.P[P_VREF])
    current_meas_a = property(lambda self: self.P[P_IMEAS])
    duty = property(lambda self: self.P[P_DUTY])
    count = property(lambda self: self.C[C_COUNT])
    innovation_counts = property(lambda self: self.C[C_INNOV])
    stuck_ticks = property(lambda self: self.C[C_STUCK])
    raw_counts = property(lambda self: self.C[C_RAW_PREV])

    @property
    def current_ref_a(self) -> npt.NDArray[np.float64]:
        return self.P[P_IREF]

    @current_ref_a.setter
    def current_ref_a(self, value: npt.ArrayLike) -> None:
        """Set the current reference directly (an experiment that drives the current loop
        itself, e.g. the relay tuner)."""
        self.P[P_IREF] = value
        self.S[S_IREF] = fx.to_sig(self.P[P_IREF]) if self.fixed else self.P[P_IREF]
