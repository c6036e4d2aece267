"""``N`` axes in lock-step on numpy arrays of shape ``(N,)``: float64, or saturating int32
Q16.16 / Q8.24 (``fixed=True``). The float64 steps run compiled kernels
(``firmware_model/laws/array_float.py``); the fixed-point steps run numpy."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_model import fixedpoint as fx
from firmware_model.laws.array_float import current_step, estimate_step, servo_step
from firmware_model.laws.common import (
    HALF_REV,
    Q_DEG_PER_COUNT,
    REV,
    LawBase,
    clip,
    identity,
)
from firmware_model.params import FirmwareParams
from firmware_model.units import AXIS_DEG_PER_COUNT

__all__ = ["ArrayLaw"]


class ArrayLaw(LawBase):
    """``n`` axes in lock-step; float64 or saturating int32 Q16.16/Q8.24 (``fixed``).

    The same attributes as :class:`ScalarLaw`, as float arrays of shape ``(n,)`` (converted
    from Q-format where ``fixed``), plus ``count`` (int64 multi-turn count).
    """

    def __init__(self, params: FirmwareParams, n: int, *, fixed: bool = False) -> None:
        if n < 1:
            raise ValueError(f"batch = {n!r}: must be >= 1")
        self._init_common(params)
        self.n = n
        self.fixed = fixed
        # Bind the arithmetic once: no per-call branch on the hot path.
        if fixed:
            self._mul, self._sat = fx.mul_gain, fx.sat32
            self._sig, self._out = fx.to_sig, fx.from_sig
        else:
            self._mul, self._sat = np.multiply, identity
            self._sig, self._out = identity, identity
            # Float64 runs compiled kernels (no saturation); the same results bit for bit.
            self.estimate = self._estimate_float  # type: ignore[method-assign]
            self.servo = self._servo_float  # type: ignore[method-assign]
            self.current = self._current_float  # type: ignore[method-assign]
        for name, value in self.gains.items():
            if isinstance(value, np.ndarray) and value.shape != (n,):
                raise ValueError(f"{name}: gain array shape {value.shape} != ({n},)")
        self._derive()
        self.reset(np.zeros(n, dtype=np.int64))

    # -- arithmetic: float64 or saturating Q-format
    def _gain(self, x: Any) -> npt.NDArray[Any]:
        arr = np.broadcast_to(np.asarray(x, dtype=float), (self.n,)).copy()
        return fx.to_gain(arr) if self.fixed else arr

    def _derive(self) -> None:
        g = self.gains
        self._kp_p, self._vff = self._gain(g["kp_p"]), self._gain(g["vel_ff"])
        self._kp_v = self._gain(g["kp_v"])
        self._ki_v_dt = self._gain(np.asarray(g["ki_v"]) * self.dt_s)
        self._acc_ff = self._gain(g["acc_ff"])
        self._kp_i = self._gain(g["kp_i"])
        self._ki_i_dt = self._gain(np.asarray(g["ki_i"]) * self.dt_current_s)
        self._r_ff, self._emf_ff = self._gain(g["r_ff"]), self._gain(g["emf_ff"])
        if not self.fixed:
            # R * I_limit and the voltage clamp of the float steps (the fixed steps work
            # them out in Q-format).
            self._r_lim = self._r_ff * self.i_limit_a
            self._u_lim = self.duty_limit * self.supply_v
        self._kpos_m1 = self._gain(self.k_pos - 1.0)
        self._kvel = self._gain(self.k_vel)
        self._kdist = self._gain(self.k_dist)
        self._k_vel = self._gain(self.dps_per_count_tick)
        self._k_acc = self._gain(self.counts_tick2_per_a)
        self._half = self._gain(0.5)
        self._inv_supply = self._gain(1.0 / self.supply_v)
        # Amperes per ADC count in Q8.24, applied as (adc * k + 2^7) >> 8 -> Q16.16.
        self._a_per_adc_q = int(round(self.a_per_adc * (1 << fx.GAIN_FRAC_BITS)))

    def set_gains(self, **gains: Any) -> None:
        """Replace some of the run-time gains (names of :data:`GAIN_NAMES`)."""
        self.gains.update(gains)
        self._derive()

    def reset(self, raw_counts: npt.ArrayLike) -> None:
        raw = np.broadcast_to(np.asarray(raw_counts, dtype=np.int64), (self.n,)).copy()
        # The members share one setpoint: start each multi-turn count at its reading
        # unwrapped around member 0's (a reading of 16383 next to 0 is -1, not +1 rev).
        self.count = raw[0] + (raw - raw[0] + HALF_REV) % REV - HALF_REV
        self.pos_deg = self.count * AXIS_DEG_PER_COUNT
        self._d = np.zeros(self.n, dtype=np.int64)
        self._raw_prev = raw
        zero = np.zeros(self.n, dtype=np.int64 if self.fixed else float)
        self._ep = zero.copy()
        self._v = zero.copy()
        self._ad = zero.copy()
        self._vel = zero.copy()
        self.vel_raw_dps = np.zeros(self.n)
        self.innovation_counts = np.zeros(self.n, dtype=np.int64)
        self.stuck_ticks = np.zeros(self.n, dtype=np.int64)
        self.reset_control()

    def resync(self) -> None:
        """See :meth:`ScalarLaw.resync` (every member)."""
        self._ep = np.zeros_like(self._ep)
        self._ad = np.zeros_like(self._ad)
        if self.fixed:
            self._v = fx.sat32(self._d << fx.SIG_FRAC_BITS)
        else:
            self._v = self._d.astype(float)
        self._vel = self._mul(self._v, self._k_vel)
        self.innovation_counts = np.zeros(self.n, dtype=np.int64)
        self.stuck_ticks = np.zeros(self.n, dtype=np.int64)

    def reset_control(self, mask: npt.NDArray[np.bool_] | None = None) -> None:
        """Zero integrators, references and PWM pipeline (of the members in ``mask``)."""
        dtype = np.int64 if self.fixed else float
        if mask is None:
            self._i_v = np.zeros(self.n, dtype=dtype)
            self._i_i = np.zeros(self.n, dtype=dtype)
            self._vr = np.zeros(self.n, dtype=dtype)
            self._iref = np.zeros(self.n, dtype=dtype)
            self._imeas = np.zeros(self.n, dtype=dtype)
            self._steps = np.zeros(self.n, dtype=np.int64)
            self.duty = np.zeros(self.n)
            self._pipe = np.zeros((max(self.delay, 1), self.n), dtype=np.int64)
            self._pipe_i = 0
            self._ref_pipe = np.zeros((self.delay + 1, self.n), dtype=dtype)
            self._ref_i = 0
            self._ref_d_last = np.zeros(self.n, dtype=dtype)
            return
        for arr in (self._i_v, self._i_i, self._vr, self._iref, self._steps):
            arr[mask] = 0
        self._pipe[:, mask] = 0
        self._ref_pipe[:, mask] = 0
        self._ref_d_last[mask] = 0
        self.duty = np.where(mask, 0.0, self.duty)  # a new array: callers may hold the old

    # -- the three steps
    def estimate(self, raw_counts: npt.ArrayLike) -> None:
        raw = np.asarray(raw_counts, dtype=np.int64)
        # The current of the period that just ended: the reference of the duty applied in it
        # plus the model error seen at the last sample (the sample of this tick comes later).
        i_expected = self._sat(
            self._ref_pipe[self._ref_i] + self._sat(self._imeas - self._ref_d_last)
        )
        acc = self._sat(self._mul(i_expected, self._k_acc) + self._ad)
        half_acc = self._mul(acc, self._half)
        if self.fixed:
            pred = fx.sat32(fx.sat32(self._ep + self._v) + half_acc)
            pred_int = (pred + (1 << 15)) >> fx.SIG_FRAC_BITS
        else:
            pred = self._ep + self._v + half_acc
            pred_int = np.floor(pred + 0.5).astype(np.int64)
        delta = (raw - self.count - pred_int) % REV
        delta -= (delta >= HALF_REV) * REV
        d = pred_int + delta
        if self.fixed:
            err = fx.sat32((d << fx.SIG_FRAC_BITS) - pred)
        else:
            err = d - pred
        self._ep = self._mul(err, self._kpos_m1)
        self._v = self._sat(self._sat(self._v + acc) + self._mul(err, self._kvel))
        self._ad = self._sat(self._ad + self._mul(err, self._kdist))
        self.count = self.count + d
        self.pos_deg = self.count * AXIS_DEG_PER_COUNT
        self.innovation_counts = delta
        self._d = d
        self.stuck_ticks = (self.stuck_ticks + 1) * (raw == self._raw_prev)
        self._raw_prev = raw
        self.vel_raw_dps = d * self.dps_per_count_tick
        self._vel = self._mul(self._v, self._k_vel)

    def servo(
        self,
        sp_pos_deg: float,
        sp_vel_dps: float,
        sp_acc_dps2: float,
        v_clamp_dps: float,
        i_limit_a: float,
    ) -> None:
        if self.fixed:
            sp_count = int(round(sp_pos_deg / AXIS_DEG_PER_COUNT))
            e = fx.sat32(fx.sat32(sp_count - self.count) * Q_DEG_PER_COUNT)
        else:
            e = sp_pos_deg - self.count * AXIS_DEG_PER_COUNT
        vc, il = self._sig(v_clamp_dps), self._sig(i_limit_a)
        vr = self._sat(self._mul(e, self._kp_p) + self._mul(self._sig(sp_vel_dps), self._vff))
        vr = clip(vr, vc)
        ev = self._sat(vr - self._vel)
        ff = self._mul(self._sig(sp_acc_dps2), self._acc_ff)
        u = self._sat(self._sat(self._mul(ev, self._kp_v) + self._i_v) + ff)
        hold = ((u > il) & (ev > 0)) | ((u < -il) & (ev < 0))
        i_v = np.where(hold, self._i_v, self._sat(self._i_v + self._mul(ev, self._ki_v_dt)))
        self._i_v = clip(i_v, il)
        self._vr = vr
        self._iref = clip(u, il)
        self.i_limit_a = i_limit_a

    def current(
        self, adc_counts: npt.ArrayLike, enabled: npt.NDArray[np.bool_]
    ) -> npt.NDArray[np.float64]:
        adc = np.asarray(adc_counts, dtype=np.int64)
        applied = self._steps
        if self.fixed:
            sensed = (adc * self._a_per_adc_q + (1 << 7)) >> (fx.GAIN_FRAC_BITS - fx.SIG_FRAC_BITS)
        else:
            sensed = adc * self.a_per_adc
        sign = np.sign(applied)
        i_meas = sensed * sign
        i_ref = self._iref
        k = self._ref_i
        ref_d = self._ref_pipe[k]
        self._ref_d_last = ref_d.copy()
        blind = (adc <= self.sense_floor) & (np.sign(ref_d) * sign <= 0)
        i_meas = np.where(blind, ref_d, i_meas)
        e = self._sat(ref_d - i_meas)
        self._ref_pipe[k] = i_ref
        self._ref_i = (k + 1) % (self.delay + 1)
        # Same association as ScalarLaw, so that float results agree bit for bit.
        emf = self._mul(self._vel, self._emf_ff)
        u = self._sat(self._mul(e, self._kp_i) + self._i_i)
        u = self._sat(u + self._mul(i_ref, self._r_ff))
        u = self._sat(u + emf)
        ul = self._sig(self.duty_limit * self.supply_v)
        hold = ((u > ul) & (e > 0)) | ((u < -ul) & (e < 0))
        i_i = np.where(hold, self._i_i, self._sat(self._i_i + self._mul(e, self._ki_i_dt)))
        # The regenerative clamp and its back-calculation (see ScalarLaw.current).
        r_lim = self._mul(self._sig(self.i_limit_a), self._r_ff)
        lo, hi = self._sat(emf - r_lim), self._sat(emf + r_lim)
        raised = (u < lo) & (u >= 0)
        lowered = (u > hi) & (u <= 0)
        regen = raised | lowered
        if regen.any():
            c = np.where(raised, lo, hi)
            i_i = np.where(regen, self._sat(self._i_i + self._sat(c - u)), i_i)
            u = np.where(regen, c, u)
        self._i_i = clip(i_i, ul)
        u = clip(u, ul)
        if self.fixed:
            duty_q = self._mul(u, self._inv_supply)
            steps = (duty_q * self.arr + (1 << 15)) >> fx.SIG_FRAC_BITS
        else:
            steps = np.round(u / self.supply_v * self.arr).astype(np.int64)
        return self._apply(steps, i_meas, enabled)

    def _apply(self, steps: np.ndarray, i_meas: np.ndarray, enabled) -> np.ndarray:
        """Tail of the fixed-point current step (the float kernel does the same per member):
        the compute-delay pipeline, the bridge enable, and the duty on the timer grid."""
        if self.delay:
            out = self._pipe[self._pipe_i].copy()
            self._pipe[self._pipe_i] = steps
            self._pipe_i = (self._pipe_i + 1) % self.delay
        else:
            out = steps
        self._imeas = i_meas
        enabled = np.asarray(enabled, dtype=bool)
        if not enabled.all():
            out = out * enabled
            self.reset_control(~enabled)
        self._steps = out
        self.duty = out / self.arr
        return self.duty

    # -- the float64 steps: compiled kernels (firmware_model/laws/array_float.py)
    def _estimate_float(self, raw_counts: npt.ArrayLike) -> None:
        raw = np.asarray(raw_counts, dtype=np.int64)
        n = self.n
        count, innov, stuck = (np.empty(n, dtype=np.int64) for _ in range(3))
        pos, vel_raw, vel = np.empty(n), np.empty(n), np.empty(n)
        estimate_step(
            raw, self.count, self._raw_prev, self.stuck_ticks, self._ep, self._v, self._ad,
            self._d, self._ref_pipe[self._ref_i], self._imeas, self._ref_d_last,
            self._k_acc, self._kpos_m1, self._kvel, self._kdist, self._k_vel,
            self.dps_per_count_tick, count, pos, innov, stuck, vel_raw, vel,
        )  # fmt: skip
        self.count, self.pos_deg, self.innovation_counts = count, pos, innov
        self.stuck_ticks, self.vel_raw_dps, self._vel = stuck, vel_raw, vel
        self._raw_prev = raw

    def _servo_float(
        self,
        sp_pos_deg: float,
        sp_vel_dps: float,
        sp_acc_dps2: float,
        v_clamp_dps: float,
        i_limit_a: float,
    ) -> None:
        vr, iref = np.empty(self.n), np.empty(self.n)
        servo_step(
            self.count, self._vel, self._i_v, self._kp_p, self._vff, self._kp_v,
            self._ki_v_dt, self._acc_ff, float(sp_pos_deg), float(sp_vel_dps),
            float(sp_acc_dps2), float(v_clamp_dps), float(i_limit_a), vr, iref,
        )  # fmt: skip
        self._vr, self._iref = vr, iref
        if i_limit_a != self.i_limit_a:
            self.i_limit_a = i_limit_a
            self._r_lim = self._r_ff * i_limit_a

    def _current_float(
        self, adc_counts: npt.ArrayLike, enabled: npt.NDArray[np.bool_]
    ) -> npt.NDArray[np.float64]:
        n = self.n
        adc = np.asarray(adc_counts, dtype=np.int64)
        enabled = np.asarray(enabled, dtype=bool)
        if enabled.shape != (n,):
            enabled = np.broadcast_to(enabled, (n,))
        steps, duty, i_meas = np.empty(n, dtype=np.int64), np.empty(n), np.empty(n)
        current_step(
            adc, enabled, self._steps, self._iref, self._vel, self._i_i, self._i_v, self._vr,
            self._ref_pipe, self._ref_i, self._ref_d_last, self._pipe, self._pipe_i,
            self.delay, self._kp_i, self._ki_i_dt, self._r_ff, self._emf_ff, self._r_lim,
            float(self.a_per_adc), int(self.sense_floor), self._u_lim, float(self.supply_v),
            float(self.arr), steps, duty, i_meas,
        )  # fmt: skip
        self._ref_i = (self._ref_i + 1) % (self.delay + 1)
        if self.delay:
            self._pipe_i = (self._pipe_i + 1) % self.delay
        self._steps, self.duty, self._imeas = steps, duty, i_meas
        return duty

    # -- float views of the state (axis units)
    @property
    def vel_dps(self) -> npt.NDArray[np.float64]:
        return self._out(self._vel)

    @property
    def vel_ref_dps(self) -> npt.NDArray[np.float64]:
        return self._out(self._vr)

    @property
    def current_ref_a(self) -> npt.NDArray[np.float64]:
        return self._out(self._iref)

    @property
    def current_meas_a(self) -> npt.NDArray[np.float64]:
        return self._out(self._imeas)
