"""The float64 steps of :class:`~firmware_model.laws.array.ArrayLaw`, compiled with numba.

One loop over the members per step instead of ~70 numpy calls on ``(N,)`` arrays: at
N = 256 each numpy call costs far more than its arithmetic. Each member computes exactly
what :class:`~firmware_model.laws.scalar.ScalarLaw` computes, the same operations in the
same order (no ``fastmath``: no reassociation, no fused multiply-add), so the results agree
bit for bit (tested).

Arrays are ``(N,)`` (the pipelines ``(delay (+ 1), N)``). The integrator and observer states
(``ep, v, ad, i_v, i_i, ref_d_last``) and the pipelines are updated in place; what the
firmware publishes (``pos_deg``, ``vel_dps``, ...) is written into fresh arrays the caller
passes as ``out_*``, so that an array handed out by ``Firmware.signals`` never changes.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from firmware_model.laws.common import HALF_REV, REV
from firmware_model.units import AXIS_DEG_PER_COUNT

__all__ = ["current_step", "estimate_step", "servo_step"]


@numba.njit(cache=True)
def estimate_step(
    raw, count, raw_prev, stuck, ep, v, ad, d_last, ref_d, imeas, ref_d_last,
    k_acc, kpos_m1, kvel, kdist, k_vel, dps_per_count_tick,
    out_count, out_pos_deg, out_innov, out_stuck, out_vel_raw_dps, out_vel_dps,
):  # fmt: skip
    """``ScalarLaw.estimate`` per member. ``ref_d``: the reference pipeline's row of the
    period that just ended; ``d_last`` receives the unwrapped count difference."""
    for j in range(raw.shape[0]):
        r = raw[j]
        i_expected = ref_d[j] + (imeas[j] - ref_d_last[j])
        acc = i_expected * k_acc[j] + ad[j]
        pred = ep[j] + v[j] + acc * 0.5
        pred_int = np.int64(math.floor(pred + 0.5))
        delta = (r - count[j] - pred_int) % REV  # floored modulo, as numpy and Python
        if delta >= HALF_REV:
            delta -= REV
        d = pred_int + delta
        err = d - pred
        ep[j] = err * kpos_m1[j]
        vj = v[j] + acc + err * kvel[j]
        v[j] = vj
        ad[j] = ad[j] + err * kdist[j]
        c = count[j] + d
        out_count[j] = c
        out_pos_deg[j] = c * AXIS_DEG_PER_COUNT
        out_innov[j] = delta
        d_last[j] = d
        out_stuck[j] = stuck[j] + 1 if r == raw_prev[j] else 0
        out_vel_raw_dps[j] = d * dps_per_count_tick
        out_vel_dps[j] = vj * k_vel[j]


@numba.njit(cache=True)
def _clip(x, limit):
    """``min(max(x, -limit), limit)`` as numpy's two ufuncs compute it (NaN passes)."""
    if x < -limit:
        x = -limit
    if x > limit:
        x = limit
    return x


@numba.njit(cache=True)
def servo_step(
    count, vel, i_v, kp_p, vff, kp_v, ki_v_dt, acc_ff,
    sp_pos_deg, sp_vel_dps, sp_acc_dps2, v_clamp_dps, i_limit_a,
    out_vel_ref_dps, out_current_ref_a,
):  # fmt: skip
    """``ScalarLaw.servo`` per member; ``i_v`` in place."""
    for j in range(count.shape[0]):
        e = sp_pos_deg - count[j] * AXIS_DEG_PER_COUNT
        vr = _clip(e * kp_p[j] + sp_vel_dps * vff[j], v_clamp_dps)
        ev = vr - vel[j]
        u = ev * kp_v[j] + i_v[j] + sp_acc_dps2 * acc_ff[j]
        # Hold the integrator while the output is clamped and the error pushes further in.
        iv = i_v[j]
        if not (abs(u) > i_limit_a and u * ev > 0.0):
            iv = iv + ev * ki_v_dt[j]
        i_v[j] = _clip(iv, i_limit_a)
        out_vel_ref_dps[j] = vr
        out_current_ref_a[j] = _clip(u, i_limit_a)


@numba.njit(cache=True)
def current_step(
    adc, enabled, steps, iref, vel, i_i, i_v, vr, ref_pipe, ref_i, ref_d_last, pipe, pipe_i,
    delay, kp_i, ki_i_dt, r_ff, emf_ff, r_lim, a_per_adc, sense_floor, u_lim, supply_v, arr,
    out_steps, out_duty, out_imeas,
):  # fmt: skip
    """``ScalarLaw.current`` per member, then the compute-delay pipeline and the bridge
    enable of ``ArrayLaw._apply``. ``ref_i`` / ``pipe_i``: this period's rows of
    ``ref_pipe`` and ``pipe`` (``pipe`` is unused without a delay). A disabled member's
    controller is reset as ``ArrayLaw.reset_control`` does."""
    delayed = delay > 0
    for j in range(adc.shape[0]):
        a = adc[j]
        applied = steps[j]
        sign = 1.0 if applied > 0 else (-1.0 if applied < 0 else 0.0)
        i_meas = a * a_per_adc * sign
        ref_d = ref_pipe[ref_i, j]
        ref_d_last[j] = ref_d
        ref_sign = 1.0 if ref_d > 0.0 else (-1.0 if ref_d < 0.0 else ref_d)  # np.sign
        if a <= sense_floor and ref_sign * sign <= 0:
            i_meas = ref_d
        e = ref_d - i_meas
        i_ref = iref[j]
        ref_pipe[ref_i, j] = i_ref
        emf = vel[j] * emf_ff[j]
        u = e * kp_i[j] + i_i[j] + i_ref * r_ff[j] + emf
        ii = i_i[j]
        if not (abs(u) > u_lim and u * e > 0.0):
            ii = ii + e * ki_i_dt[j]
        # The regenerative clamp and its back-calculation (see ScalarLaw.current).
        d = u - emf
        if abs(d) > r_lim[j] and d * u <= 0.0:
            c = emf - r_lim[j] if d < 0.0 else emf + r_lim[j]
            ii = i_i[j] + (c - u)
            u = c
        i_i[j] = _clip(ii, u_lim)
        new_steps = np.int64(np.rint(_clip(u, u_lim) / supply_v * arr))
        if delayed:
            out = pipe[pipe_i, j]
            pipe[pipe_i, j] = new_steps
        else:
            out = new_steps
        out_imeas[j] = i_meas
        if not enabled[j]:
            out = 0
            i_v[j] = 0.0
            i_i[j] = 0.0
            vr[j] = 0.0
            iref[j] = 0.0
            ref_pipe[:, j] = 0.0
            ref_d_last[j] = 0.0
            if delayed:
                pipe[:, j] = 0
        out_steps[j] = out
        out_duty[j] = out / arr
