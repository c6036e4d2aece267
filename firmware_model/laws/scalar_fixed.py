"""One axis in saturating int32 Q16.16 / Q8.24 on Python ints: ``arithmetic = "fixed"``
with ``batch=None`` (see ``firmware_model/fixedpoint.py`` for the formats)."""

from __future__ import annotations

from firmware_model import fixedpoint as fx
from firmware_model.laws.common import HALF_REV, Q_DEG_PER_COUNT, REV, LawBase
from firmware_model.params import FirmwareParams
from firmware_model.units import AXIS_DEG_PER_COUNT

__all__ = ["ScalarFixedLaw"]

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


class ScalarFixedLaw(LawBase):
    """One axis in saturating int32 Q16.16 / Q8.24, on Python ints (the fast path for
    ``batch=None`` with ``arithmetic = "fixed"``). It computes exactly what
    ``ArrayLaw(fixed=True)`` computes for one member (tested); the attributes are those of
    :class:`ScalarLaw` (floats converted from the Q-format state)."""

    def __init__(self, params: FirmwareParams) -> None:
        self._init_common(params)
        self._require_scalar_gains()
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
        self._ref_d_last = 0

    def estimate(self, raw_counts: int) -> None:
        raw = int(raw_counts)
        i_expected = _qsat(self._ref_pipe[self._ref_i] + _qsat(self._imeas - self._ref_d_last))
        acc = _qsat(_qmul(i_expected, self._k_acc) + self._ad)
        pred = _qsat(_qsat(self._ep + self._v) + _qmul(acc, self._half))
        pred_int = (pred + (1 << 15)) >> fx.SIG_FRAC_BITS
        delta = (raw - self.count - pred_int) % REV
        if delta >= HALF_REV:
            delta -= REV
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
        e = _qsat(_qsat(sp_count - self.count) * Q_DEG_PER_COUNT)
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
        self.i_limit_a = i_limit_a

    def current(self, adc_counts: int, enabled: bool) -> float:
        adc = int(adc_counts)
        applied = self._steps
        sensed = (adc * self._a_per_adc_q + (1 << 7)) >> (fx.GAIN_FRAC_BITS - fx.SIG_FRAC_BITS)
        sign = (applied > 0) - (applied < 0)
        i_meas = sensed * sign
        i_ref = self._iref
        k = self._ref_i
        ref_d = self._ref_pipe[k]
        self._ref_d_last = ref_d
        if adc <= self.sense_floor and ((ref_d > 0) - (ref_d < 0)) * sign <= 0:
            i_meas = ref_d
        e = _qsat(ref_d - i_meas)
        self._ref_pipe[k] = i_ref
        self._ref_i = (k + 1) % (self.delay + 1)
        emf = _qmul(self._vel, self._emf_ff)
        u = _qsat(_qmul(e, self._kp_i) + self._i_i)
        u = _qsat(u + _qmul(i_ref, self._r_ff))
        u = _qsat(u + emf)
        ul = self._ul
        i_i = self._i_i
        # The regenerative clamp and its back-calculation (see ScalarLaw.current).
        r_lim = _qmul(_qsig(self.i_limit_a), self._r_ff)
        lo, hi = _qsat(emf - r_lim), _qsat(emf + r_lim)
        if u < lo and u >= 0:
            i_i = _qsat(i_i + _qsat(lo - u))
            u = lo
        elif u > hi and u <= 0:
            i_i = _qsat(i_i + _qsat(hi - u))
            u = hi
        elif not ((u > ul and e > 0) or (u < -ul and e < 0)):
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
