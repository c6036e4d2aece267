"""The control law of one servo tick: encoder unwrap, velocity observer, position P ->
velocity PI -> current PI -> PWM duty, with clamps and anti-windup.

Interchangeable implementations with the same methods and attributes:

* :class:`ScalarLaw`: one axis in plain Python floats (the fast path for ``batch=None``).
* :class:`ScalarFixedLaw`: one axis in saturating int32 Q16.16 / Q8.24 on Python ints
  (``arithmetic = "fixed"``, ``batch=None``).
* :class:`ArrayLaw`: ``N`` axes in lock-step on numpy arrays of shape ``(N,)``, in float64
  or in saturating int32 Q-format (``fixed=True``; see ``firmware_model/fixedpoint.py``).

``ArrayLaw`` with N = 1 computes bit for bit what the scalar law of the same arithmetic
computes (tested): the same operations in the same order.

The order of one servo tick (seed 000 Fig. 5), with the firmware's shell around it:

1. :meth:`estimate`: unwrap the 14-bit reading around the observer's *prediction* (so the
   motor may turn more than half a revolution per tick as long as the prediction is within
   half a revolution), then a third-order observer (position, velocity, acceleration
   disturbance; the sensed current as a known acceleration) gives the velocity; the plain
   difference is kept as ``vel_raw_dps``.
2. :meth:`servo`: position error -> ``v_ref = Kp_pos e + vel_ff sp_vel`` clamped to the velocity
   limit -> ``i_ref = Kp_vel (v_ref - vel) + I + acc_ff sp_acc`` clamped to the current limit,
   integrating only when that does not push further into the clamp (conditional integration).
3. :meth:`current` (``current_loop_multiple`` times per tick): the sensed current is the
   BTN7971 IS reading (high side only) signed by the duty being applied (or, while the
   sense is blind to a current against the duty, the reference); the PI error compares it
   with the reference of the duty that produced it; ``u = R i_ref + k_emf vel + Kp e + I``
   volts, clamped to ``duty_limit * supply_v`` with the same anti-windup, divided by the
   supply and quantised to the timer's ARR steps. The duty computed now is returned
   ``compute_delay_ticks`` calls later (the timer loads the compare register at its next
   update event).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_model import fixedpoint as fx
from firmware_model.params import FirmwareParams
from firmware_model.units import AXIS_DEG_PER_COUNT, ENCODER_COUNTS_PER_REV

__all__ = ["ArrayLaw", "GAIN_NAMES", "ScalarFixedLaw", "ScalarLaw"]

_REV = ENCODER_COUNTS_PER_REV
_HALF_REV = _REV // 2
# Q16.16 raw units of axis degrees per encoder count (exact: 18).
_Q_DEG_PER_COUNT = int(round(AXIS_DEG_PER_COUNT * (1 << fx.SIG_FRAC_BITS)))

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


def _identity(x: Any) -> Any:
    return x


def _clip(x: Any, limit: Any) -> Any:
    """Clamp to [-limit, limit] (two ufuncs: cheaper than np.clip's wrapper)."""
    return np.minimum(np.maximum(x, -limit), limit)


class _Common:
    """Constants both implementations derive from the parameters."""

    def _init_common(self, params: FirmwareParams) -> None:
        servo, cur = params.servo, params.current
        self.dt_s = servo.dt_s
        self.dt_current_s = servo.dt_s / servo.current_loop_multiple
        self.delay = servo.compute_delay_ticks
        self.k_pos, self.k_vel, self.k_dist = params.estimator.observer_gains(servo.dt_s)
        self.dps_per_count_tick = AXIS_DEG_PER_COUNT * servo.tick_hz
        # Counts per tick^2 of acceleration per ampere of sensed current (observer input).
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


class ScalarLaw(_Common):
    """One axis in Python floats. Attributes after each call (axis units): ``pos_deg``,
    ``vel_dps``, ``vel_raw_dps``, ``innovation_counts`` (reading minus prediction),
    ``stuck_ticks`` (ticks the raw reading has not changed), ``vel_ref_dps``,
    ``current_ref_a``, ``current_meas_a``, ``duty`` (the duty being applied)."""

    def __init__(self, params: FirmwareParams) -> None:
        self._init_common(params)
        for name, value in self.gains.items():
            if isinstance(value, np.ndarray):
                raise ValueError(f"{name} = {value!r}: array gains need batch=N")
        self._derive()
        self.reset(0)

    def _derive(self) -> None:
        g = self.gains
        self._kp_p, self._vff = float(g["kp_p"]), float(g["vel_ff"])
        self._kp_v, self._ki_v_dt = float(g["kp_v"]), float(g["ki_v"]) * self.dt_s
        self._acc_ff = float(g["acc_ff"])
        self._kp_i, self._ki_i_dt = float(g["kp_i"]), float(g["ki_i"]) * self.dt_current_s
        self._r_ff, self._emf_ff = float(g["r_ff"]), float(g["emf_ff"])
        self._u_lim = self.duty_limit * self.supply_v

    def set_gains(self, **gains: float) -> None:
        """Replace some of the run-time gains (names of :data:`GAIN_NAMES`)."""
        self.gains.update(gains)
        self._derive()

    def reset(self, raw_counts: int) -> None:
        """Power-on: the multi-turn count starts at the raw reading, everything at rest."""
        self.count = int(raw_counts)
        self._raw_prev = int(raw_counts)
        self._d = 0
        self._ep = 0.0
        self._v = 0.0
        self._ad = 0.0
        self.pos_deg = self.count * AXIS_DEG_PER_COUNT
        self.vel_dps = 0.0
        self.vel_raw_dps = 0.0
        self.innovation_counts = 0
        self.stuck_ticks = 0
        self.reset_control()

    def resync(self) -> None:
        """Restart the observer on the encoder: no offset, no disturbance, the last raw
        difference as the speed (after a glitch, so that its ringing cannot trip anything)."""
        self._ep = 0.0
        self._ad = 0.0
        self._v = float(self._d)
        self.vel_dps = self._v * self.dps_per_count_tick
        self.innovation_counts = 0
        self.stuck_ticks = 0

    def reset_control(self) -> None:
        """Zero the integrators, the references and the PWM pipeline (bridge off)."""
        self._i_v = 0.0
        self._i_i = 0.0
        self.vel_ref_dps = 0.0
        self.current_ref_a = 0.0
        self.current_meas_a = 0.0
        self.duty = 0.0
        self._pipe = [0.0] * self.delay
        self._pipe_i = 0
        self._ref_pipe = [0.0] * (self.delay + 1)
        self._ref_i = 0

    def estimate(self, raw_counts: int) -> None:
        """Unwrap the reading and update the velocity observer."""
        raw = int(raw_counts)
        acc = self.counts_tick2_per_a * self.current_meas_a + self._ad
        pred = self._ep + self._v + 0.5 * acc
        pred_int = math.floor(pred + 0.5)
        delta = (raw - self.count - pred_int) % _REV
        if delta >= _HALF_REV:
            delta -= _REV
        d = pred_int + delta
        err = d - pred
        self._ep = (self.k_pos - 1.0) * err
        self._v = (self._v + acc) + self.k_vel * err
        self._ad = self._ad + self.k_dist * err
        self.count += d
        self.innovation_counts = delta
        self._d = d
        self.stuck_ticks = self.stuck_ticks + 1 if raw == self._raw_prev else 0
        self._raw_prev = raw
        k = self.dps_per_count_tick
        self.vel_raw_dps = d * k
        self.vel_dps = self._v * k
        self.pos_deg = self.count * AXIS_DEG_PER_COUNT

    def servo(
        self,
        sp_pos_deg: float,
        sp_vel_dps: float,
        sp_acc_dps2: float,
        v_clamp_dps: float,
        i_limit_a: float,
    ) -> None:
        """Position P and velocity PI: sets ``vel_ref_dps`` and ``current_ref_a``."""
        vr = self._kp_p * (sp_pos_deg - self.pos_deg) + self._vff * sp_vel_dps
        if vr > v_clamp_dps:
            vr = v_clamp_dps
        elif vr < -v_clamp_dps:
            vr = -v_clamp_dps
        ev = vr - self.vel_dps
        u = self._kp_v * ev + self._i_v + self._acc_ff * sp_acc_dps2
        i_v = self._i_v
        if u > i_limit_a:
            u = i_limit_a
            if ev < 0.0:
                i_v += self._ki_v_dt * ev
        elif u < -i_limit_a:
            u = -i_limit_a
            if ev > 0.0:
                i_v += self._ki_v_dt * ev
        else:
            i_v += self._ki_v_dt * ev
        if i_v > i_limit_a:
            i_v = i_limit_a
        elif i_v < -i_limit_a:
            i_v = -i_limit_a
        self._i_v = i_v
        self.vel_ref_dps = vr
        self.current_ref_a = u

    def current(self, adc_counts: int, enabled: bool) -> float:
        """One current-loop period; returns the duty the bridge applies next (ARR steps)."""
        applied = self.duty
        sensed = adc_counts * self.a_per_adc
        i_meas = sensed if applied > 0.0 else (-sensed if applied < 0.0 else 0.0)
        # The PI compares the sample with the reference of the duty that produced it
        # (delay + 1 periods ago); the feed-forward acts on the present reference.
        k = self._ref_i
        ref_d = self._ref_pipe[k]
        if adc_counts <= self.sense_floor and ref_d * applied <= 0.0:
            # High-side sense blind (current against the duty, or no duty): trust the model.
            i_meas = ref_d
        if not enabled:
            self.reset_control()
            self.current_meas_a = i_meas
            return 0.0
        i_ref = self.current_ref_a
        self.current_meas_a = i_meas
        e = ref_d - i_meas
        self._ref_pipe[k] = i_ref
        self._ref_i = (k + 1) % (self.delay + 1)
        i_i = self._i_i
        u = self._kp_i * e + i_i + self._r_ff * i_ref + self._emf_ff * self.vel_dps
        u_lim = self._u_lim
        if u > u_lim:
            u = u_lim
            if e < 0.0:
                i_i += self._ki_i_dt * e
        elif u < -u_lim:
            u = -u_lim
            if e > 0.0:
                i_i += self._ki_i_dt * e
        else:
            i_i += self._ki_i_dt * e
        if i_i > u_lim:
            i_i = u_lim
        elif i_i < -u_lim:
            i_i = -u_lim
        self._i_i = i_i
        arr = self.arr
        duty = round(u / self.supply_v * arr) / arr
        if self.delay:
            out = self._pipe[self._pipe_i]
            self._pipe[self._pipe_i] = duty
            self._pipe_i = (self._pipe_i + 1) % self.delay
        else:
            out = duty
        self.duty = out
        return out


_I32_MIN, _I32_MAX = fx.INT32_MIN, fx.INT32_MAX
_G_HALF = 1 << (fx.GAIN_FRAC_BITS - 1)
_SIG_SCALE = float(1 << fx.SIG_FRAC_BITS)


def _qsat(x: int) -> int:
    return _I32_MIN if x < _I32_MIN else (_I32_MAX if x > _I32_MAX else x)


def _qmul(s: int, g: int) -> int:
    return _qsat((s * g + _G_HALF) >> fx.GAIN_FRAC_BITS)


def _qsig(x: float) -> int:
    return _qsat(round(x * _SIG_SCALE))


def _qgain(x: float) -> int:
    return _qsat(round(float(x) * (1 << fx.GAIN_FRAC_BITS)))


class ScalarFixedLaw(_Common):
    """One axis in saturating int32 Q16.16 / Q8.24, on Python ints (the fast path for
    ``batch=None`` with ``arithmetic = "fixed"``). It computes exactly what
    ``ArrayLaw(fixed=True)`` computes for one member (tested); the attributes are those of
    :class:`ScalarLaw` (floats converted from the Q-format state)."""

    def __init__(self, params: FirmwareParams) -> None:
        self._init_common(params)
        for name, value in self.gains.items():
            if isinstance(value, np.ndarray):
                raise ValueError(f"{name} = {value!r}: array gains need batch=N")
        self._derive()
        self.reset(0)

    def _derive(self) -> None:
        g = self.gains
        self._kp_p, self._vff = _qgain(g["kp_p"]), _qgain(g["vel_ff"])
        self._kp_v, self._ki_v_dt = _qgain(g["kp_v"]), _qgain(float(g["ki_v"]) * self.dt_s)
        self._acc_ff = _qgain(g["acc_ff"])
        self._kp_i = _qgain(g["kp_i"])
        self._ki_i_dt = _qgain(float(g["ki_i"]) * self.dt_current_s)
        self._r_ff, self._emf_ff = _qgain(g["r_ff"]), _qgain(g["emf_ff"])
        self._kpos_m1 = _qgain(self.k_pos - 1.0)
        self._kvel, self._kdist = _qgain(self.k_vel), _qgain(self.k_dist)
        self._k_vel = _qgain(self.dps_per_count_tick)
        self._k_acc = _qgain(self.counts_tick2_per_a)
        self._half = _qgain(0.5)
        self._inv_supply = _qgain(1.0 / self.supply_v)
        self._a_per_adc_q = int(round(self.a_per_adc * (1 << fx.GAIN_FRAC_BITS)))
        self._ul = _qsig(self.duty_limit * self.supply_v)

    def set_gains(self, **gains: float) -> None:
        """Replace some of the run-time gains (names of :data:`GAIN_NAMES`)."""
        self.gains.update(gains)
        self._derive()

    def reset(self, raw_counts: int) -> None:
        self.count = int(raw_counts)
        self._raw_prev = int(raw_counts)
        self._d = 0
        self._ep = self._v = self._ad = self._vel = 0
        self.vel_raw_dps = 0.0
        self.innovation_counts = 0
        self.stuck_ticks = 0
        self.reset_control()

    def resync(self) -> None:
        """See :meth:`ScalarLaw.resync`."""
        self._ep = self._ad = 0
        self._v = _qsat(self._d << fx.SIG_FRAC_BITS)
        self._vel = _qmul(self._v, self._k_vel)
        self.innovation_counts = 0
        self.stuck_ticks = 0

    def reset_control(self) -> None:
        self._i_v = self._i_i = self._vr = self._iref = self._imeas = 0
        self._steps = 0
        self._pipe = [0] * self.delay
        self._pipe_i = 0
        self._ref_pipe = [0] * (self.delay + 1)
        self._ref_i = 0

    def estimate(self, raw_counts: int) -> None:
        raw = int(raw_counts)
        acc = _qsat(_qmul(self._imeas, self._k_acc) + self._ad)
        pred = _qsat(_qsat(self._ep + self._v) + _qmul(acc, self._half))
        pred_int = (pred + (1 << 15)) >> fx.SIG_FRAC_BITS
        delta = (raw - self.count - pred_int) % _REV
        if delta >= _HALF_REV:
            delta -= _REV
        d = pred_int + delta
        err = _qsat((d << fx.SIG_FRAC_BITS) - pred)
        self._ep = _qmul(err, self._kpos_m1)
        self._v = _qsat(_qsat(self._v + acc) + _qmul(err, self._kvel))
        self._ad = _qsat(self._ad + _qmul(err, self._kdist))
        self.count += d
        self.innovation_counts = delta
        self._d = d
        self.stuck_ticks = self.stuck_ticks + 1 if raw == self._raw_prev else 0
        self._raw_prev = raw
        self.vel_raw_dps = d * self.dps_per_count_tick
        self._vel = _qmul(self._v, self._k_vel)

    def servo(
        self,
        sp_pos_deg: float,
        sp_vel_dps: float,
        sp_acc_dps2: float,
        v_clamp_dps: float,
        i_limit_a: float,
    ) -> None:
        sp_count = int(round(sp_pos_deg / AXIS_DEG_PER_COUNT))
        e = _qsat(_qsat(sp_count - self.count) * _Q_DEG_PER_COUNT)
        vc, il = _qsig(v_clamp_dps), _qsig(i_limit_a)
        vr = _qsat(_qmul(e, self._kp_p) + _qmul(_qsig(sp_vel_dps), self._vff))
        vr = -vc if vr < -vc else (vc if vr > vc else vr)
        ev = _qsat(vr - self._vel)
        ff = _qmul(_qsig(sp_acc_dps2), self._acc_ff)
        u = _qsat(_qsat(_qmul(ev, self._kp_v) + self._i_v) + ff)
        i_v = self._i_v
        if not ((u > il and ev > 0) or (u < -il and ev < 0)):
            i_v = _qsat(i_v + _qmul(ev, self._ki_v_dt))
        self._i_v = -il if i_v < -il else (il if i_v > il else i_v)
        self._vr = vr
        self._iref = -il if u < -il else (il if u > il else u)

    def current(self, adc_counts: int, enabled: bool) -> float:
        adc = int(adc_counts)
        applied = self._steps
        sensed = (adc * self._a_per_adc_q + (1 << 7)) >> (fx.GAIN_FRAC_BITS - fx.SIG_FRAC_BITS)
        sign = (applied > 0) - (applied < 0)
        i_meas = sensed * sign
        i_ref = self._iref
        k = self._ref_i
        ref_d = self._ref_pipe[k]
        if adc <= self.sense_floor and ((ref_d > 0) - (ref_d < 0)) * sign <= 0:
            i_meas = ref_d
        e = _qsat(ref_d - i_meas)
        self._ref_pipe[k] = i_ref
        self._ref_i = (k + 1) % (self.delay + 1)
        u = _qsat(_qmul(e, self._kp_i) + self._i_i)
        u = _qsat(u + _qmul(i_ref, self._r_ff))
        u = _qsat(u + _qmul(self._vel, self._emf_ff))
        ul = self._ul
        i_i = self._i_i
        if not ((u > ul and e > 0) or (u < -ul and e < 0)):
            i_i = _qsat(i_i + _qmul(e, self._ki_i_dt))
        self._i_i = -ul if i_i < -ul else (ul if i_i > ul else i_i)
        u = -ul if u < -ul else (ul if u > ul else u)
        duty_q = _qmul(u, self._inv_supply)
        steps = (duty_q * self.arr + (1 << 15)) >> fx.SIG_FRAC_BITS
        if self.delay:
            out = self._pipe[self._pipe_i]
            self._pipe[self._pipe_i] = steps
            self._pipe_i = (self._pipe_i + 1) % self.delay
        else:
            out = steps
        self._imeas = i_meas
        if not enabled:
            self.reset_control()
            self._imeas = i_meas
            return 0.0
        self._steps = out
        return out / self.arr

    @property
    def pos_deg(self) -> float:
        return self.count * AXIS_DEG_PER_COUNT

    @property
    def vel_dps(self) -> float:
        return self._vel / _SIG_SCALE

    @property
    def vel_ref_dps(self) -> float:
        return self._vr / _SIG_SCALE

    @property
    def current_ref_a(self) -> float:
        return self._iref / _SIG_SCALE

    @property
    def current_meas_a(self) -> float:
        return self._imeas / _SIG_SCALE

    @property
    def duty(self) -> float:
        return self._steps / self.arr


class ArrayLaw(_Common):
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
            self._mul, self._sat = np.multiply, _identity
            self._sig, self._out = _identity, _identity
            # Float64 has its own, leaner steps (no saturation); same results bit for bit.
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
        self.count = raw[0] + (raw - raw[0] + _HALF_REV) % _REV - _HALF_REV
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
            return
        for arr in (self._i_v, self._i_i, self._vr, self._iref, self._steps):
            arr[mask] = 0
        self._pipe[:, mask] = 0
        self._ref_pipe[:, mask] = 0
        self.duty = np.where(mask, 0.0, self.duty)  # a new array: callers may hold the old

    # -- the three steps
    def estimate(self, raw_counts: npt.ArrayLike) -> None:
        raw = np.asarray(raw_counts, dtype=np.int64)
        acc = self._sat(self._mul(self._imeas, self._k_acc) + self._ad)
        half_acc = self._mul(acc, self._half)
        if self.fixed:
            pred = fx.sat32(fx.sat32(self._ep + self._v) + half_acc)
            pred_int = (pred + (1 << 15)) >> fx.SIG_FRAC_BITS
        else:
            pred = self._ep + self._v + half_acc
            pred_int = np.floor(pred + 0.5).astype(np.int64)
        delta = (raw - self.count - pred_int) % _REV
        delta -= (delta >= _HALF_REV) * _REV
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
            e = fx.sat32(fx.sat32(sp_count - self.count) * _Q_DEG_PER_COUNT)
        else:
            e = sp_pos_deg - self.count * AXIS_DEG_PER_COUNT
        vc, il = self._sig(v_clamp_dps), self._sig(i_limit_a)
        vr = self._sat(self._mul(e, self._kp_p) + self._mul(self._sig(sp_vel_dps), self._vff))
        vr = _clip(vr, vc)
        ev = self._sat(vr - self._vel)
        ff = self._mul(self._sig(sp_acc_dps2), self._acc_ff)
        u = self._sat(self._sat(self._mul(ev, self._kp_v) + self._i_v) + ff)
        hold = ((u > il) & (ev > 0)) | ((u < -il) & (ev < 0))
        i_v = np.where(hold, self._i_v, self._sat(self._i_v + self._mul(ev, self._ki_v_dt)))
        self._i_v = _clip(i_v, il)
        self._vr = vr
        self._iref = _clip(u, il)

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
        blind = (adc <= self.sense_floor) & (np.sign(ref_d) * sign <= 0)
        i_meas = np.where(blind, ref_d, i_meas)
        e = self._sat(ref_d - i_meas)
        self._ref_pipe[k] = i_ref
        self._ref_i = (k + 1) % (self.delay + 1)
        # Same association as ScalarLaw, so that float results agree bit for bit.
        u = self._sat(self._mul(e, self._kp_i) + self._i_i)
        u = self._sat(u + self._mul(i_ref, self._r_ff))
        u = self._sat(u + self._mul(self._vel, self._emf_ff))
        ul = self._sig(self.duty_limit * self.supply_v)
        hold = ((u > ul) & (e > 0)) | ((u < -ul) & (e < 0))
        i_i = np.where(hold, self._i_i, self._sat(self._i_i + self._mul(e, self._ki_i_dt)))
        self._i_i = _clip(i_i, ul)
        u = _clip(u, ul)
        if self.fixed:
            duty_q = self._mul(u, self._inv_supply)
            steps = (duty_q * self.arr + (1 << 15)) >> fx.SIG_FRAC_BITS
        else:
            steps = np.round(u / self.supply_v * self.arr).astype(np.int64)
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

    # -- the float64 steps: the same arithmetic as ScalarLaw, in the same order
    def _estimate_float(self, raw_counts: npt.ArrayLike) -> None:
        raw = np.asarray(raw_counts, dtype=np.int64)
        acc = self._imeas * self._k_acc + self._ad
        pred = self._ep + self._v + acc * 0.5
        pred_int = np.floor(pred + 0.5).astype(np.int64)
        delta = (raw - self.count - pred_int) % _REV
        delta -= (delta >= _HALF_REV) * _REV
        d = pred_int + delta
        err = d - pred
        self._ep = err * self._kpos_m1
        self._v = self._v + acc + err * self._kvel
        self._ad = self._ad + err * self._kdist
        self.count = self.count + d
        self.pos_deg = self.count * AXIS_DEG_PER_COUNT
        self.innovation_counts = delta
        self._d = d
        self.stuck_ticks = (self.stuck_ticks + 1) * (raw == self._raw_prev)
        self._raw_prev = raw
        self.vel_raw_dps = d * self.dps_per_count_tick
        self._vel = self._v * self._k_vel

    def _servo_float(
        self,
        sp_pos_deg: float,
        sp_vel_dps: float,
        sp_acc_dps2: float,
        v_clamp_dps: float,
        i_limit_a: float,
    ) -> None:
        e = sp_pos_deg - self.count * AXIS_DEG_PER_COUNT
        vr = _clip(e * self._kp_p + sp_vel_dps * self._vff, v_clamp_dps)
        ev = vr - self._vel
        u = ev * self._kp_v + self._i_v + sp_acc_dps2 * self._acc_ff
        # Hold the integrator while the output is clamped and the error pushes further in.
        hold = (np.abs(u) > i_limit_a) & (u * ev > 0.0)
        i_v = np.where(hold, self._i_v, self._i_v + ev * self._ki_v_dt)
        self._i_v = _clip(i_v, i_limit_a)
        self._vr = vr
        self._iref = _clip(u, i_limit_a)

    def _current_float(
        self, adc_counts: npt.ArrayLike, enabled: npt.NDArray[np.bool_]
    ) -> npt.NDArray[np.float64]:
        adc = np.asarray(adc_counts)
        sign = np.sign(self._steps)
        i_meas = adc * self.a_per_adc * sign
        i_ref = self._iref
        k = self._ref_i
        ref_d = self._ref_pipe[k]
        blind = (adc <= self.sense_floor) & (np.sign(ref_d) * sign <= 0)
        i_meas = np.where(blind, ref_d, i_meas)
        e = ref_d - i_meas
        self._ref_pipe[k] = i_ref
        self._ref_i = (k + 1) % (self.delay + 1)
        u = e * self._kp_i + self._i_i + i_ref * self._r_ff + self._vel * self._emf_ff
        ul = self.duty_limit * self.supply_v
        hold = (np.abs(u) > ul) & (u * e > 0.0)
        i_i = np.where(hold, self._i_i, self._i_i + e * self._ki_i_dt)
        self._i_i = _clip(i_i, ul)
        steps = np.round(_clip(u, ul) / self.supply_v * self.arr).astype(np.int64)
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
