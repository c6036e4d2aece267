"""One axis in plain Python floats: the fast path for ``batch=None`` (see
``firmware_model/servo.py`` for what one tick does)."""

from __future__ import annotations

import math

from firmware_model.laws.common import HALF_REV, REV, LawBase
from firmware_model.params import FirmwareParams
from firmware_model.units import AXIS_DEG_PER_COUNT

__all__ = ["ScalarLaw"]


class ScalarLaw(LawBase):
    """One axis in Python floats. Attributes after each call (axis units): ``pos_deg``,
    ``vel_dps``, ``vel_raw_dps``, ``innovation_counts`` (reading minus prediction),
    ``stuck_ticks`` (ticks the raw reading has not changed), ``vel_ref_dps``,
    ``current_ref_a``, ``current_meas_a``, ``duty`` (the duty being applied)."""

    def __init__(self, params: FirmwareParams) -> None:
        self._init_common(params)
        self._require_scalar_gains()
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
        self._r_lim = self._r_ff * self.i_limit_a

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
        self._ref_d_last = 0.0

    def estimate(self, raw_counts: int) -> None:
        """Unwrap the reading and update the velocity observer."""
        raw = int(raw_counts)
        # The current of the period that just ended: the reference of the duty applied in it
        # plus the model error seen at the last sample (this tick's sample comes later; the
        # last sample is a period old, and feeding it in cost half the velocity gain margin).
        i_expected = self._ref_pipe[self._ref_i] + (self.current_meas_a - self._ref_d_last)
        acc = self.counts_tick2_per_a * i_expected + self._ad
        pred = self._ep + self._v + 0.5 * acc
        pred_int = math.floor(pred + 0.5)
        delta = (raw - self.count - pred_int) % REV
        if delta >= HALF_REV:
            delta -= REV
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
        if i_limit_a != self.i_limit_a:
            self.i_limit_a = i_limit_a
            self._r_lim = self._r_ff * i_limit_a

    def current(self, adc_counts: int, enabled: bool) -> float:
        """One current-loop period; returns the duty the bridge applies next (ARR steps)."""
        applied = self.duty
        sensed = adc_counts * self.a_per_adc
        i_meas = sensed if applied > 0.0 else (-sensed if applied < 0.0 else 0.0)
        # The PI compares the sample with the reference of the duty that produced it
        # (delay + 1 periods ago); the feed-forward acts on the present reference.
        k = self._ref_i
        ref_d = self._ref_pipe[k]
        self._ref_d_last = ref_d
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
        emf = self._emf_ff * self.vel_dps
        u = self._kp_i * e + i_i + self._r_ff * i_ref + emf
        u_lim = self._u_lim
        # Regenerative clamp. A current against the duty (or with no duty) is invisible to
        # the high-side sense, so on that side the voltage is kept where the model predicts
        # at most the current limit, |u - emf| <= R * I_limit; the integrator tracks the
        # clamp (back-calculation), so that the loop leaves it without a jump.
        d = u - emf
        r_lim = self._r_lim
        if (d < -r_lim or d > r_lim) and d * u <= 0.0:
            c = emf - r_lim if d < 0.0 else emf + r_lim
            i_i += c - u
            u = u_lim if c > u_lim else (-u_lim if c < -u_lim else c)
        elif u > u_lim:
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
