"""The control law in saturating int32 Q-format (``arithmetic = "fixed"``), as the FPU-less
STM32F103 runs it, written once for ``N`` members: signals Q16.16, gains Q8.24, a signal
times a gain ``(s * g + 2^23) >> 24`` saturated to int32, every sum saturated
(``firmware_model/fixedpoint.py``). Values live in int64 (the Cortex-M3's 32 x 32 -> 64
``SMULL`` product) and always hold int32-range numbers.

The same three steps and arguments as ``laws/float64.py``; ``S`` and ``G`` hold raw
Q-format integers, ``P`` the float view of what is published.
"""

from __future__ import annotations

import numpy as np

from firmware_model import fixedpoint as fx
from firmware_model.kernel_cache import kernel
from firmware_model.laws.float64 import _reset_member
from firmware_model.laws.layout import (
    C_BUS_ADC,
    C_COUNT,
    C_D,
    C_INNOV,
    C_PIPE,
    C_RAW_PREV,
    C_SENSE_OFFSET_A,
    C_SENSE_OFFSET_B,
    C_STEPS,
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
    K_A_PER_ADC_Q,
    K_ARR,
    K_BUS_COMP,
    K_BUS_HOLD,
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
    K_V_PER_BUS_ADC_Q,
    P_DERATE,
    P_DUTY,
    P_EMF_RISE,
    P_IMEAS,
    P_IREF,
    P_POS,
    P_R_RISE,
    P_VEL,
    P_VEL_RAW,
    P_VREF,
    Q_DEG_PER_COUNT,
    REV,
    S_AD,
    S_EP,
    S_I_I,
    S_I_V,
    S_IMEAS,
    S_IREF,
    S_REF_D_LAST,
    S_REF_PIPE,
    S_V,
    S_VEL,
    S_VR,
)  # fmt: skip
from firmware_model.units import AXIS_DEG_PER_COUNT

__all__ = ["current", "estimate", "qgain", "qsig", "servo"]

_LO = fx.INT32_MIN
_HI = fx.INT32_MAX
_G_HALF = 1 << (fx.GAIN_FRAC_BITS - 1)
_GB = fx.GAIN_FRAC_BITS
_SB = fx.SIG_FRAC_BITS
_SIG_ONE = float(1 << fx.SIG_FRAC_BITS)
_GAIN_ONE = float(1 << fx.GAIN_FRAC_BITS)


@kernel
def _sat(x):
    return _LO if x < _LO else (_HI if x > _HI else x)


@kernel
def _mul(s, g):
    """Q16.16 signal times Q8.24 gain -> Q16.16, rounded half up, saturated."""
    return _sat((s * g + _G_HALF) >> _GB)


@kernel
def _clamp(x, limit):
    return -limit if x < -limit else (limit if x > limit else x)


@kernel
def _sgn(x):
    return (1 if x > 0 else 0) - (1 if x < 0 else 0)


@kernel
def qsig(x):
    """A float as Q16.16 raw (rounded half to even, saturated)."""
    v = np.rint(x * _SIG_ONE)
    v = float(_LO) if v < _LO else (float(_HI) if v > _HI else v)
    return np.int64(v)


@kernel
def qgain(x):
    """A float as Q8.24 raw (rounded half to even, saturated)."""
    v = np.rint(x * _GAIN_ONE)
    v = float(_LO) if v < _LO else (float(_HI) if v > _HI else v)
    return np.int64(v)


@kernel
def _bus_v_q(j, C, K):
    """``float64.bus_v`` in Q16.16: the reading times volts per count (Q8.24), at least
    1 V."""
    if K[K_BUS_COMP] == 0.0:
        return qsig(K[K_SUPPLY_V])
    v = (C[C_BUS_ADC, j] * np.int64(K[K_V_PER_BUS_ADC_Q]) + (1 << 7)) >> (_GB - _SB)
    return v if v > _SIG_ONE else np.int64(_SIG_ONE)


@kernel
def _regen_limits_q(j, il, C, S, G, K):
    """``float64._regen_limits`` in Q16.16 (one 64-bit division)."""
    emf = _mul(S[S_VEL, j], G[G_EMF_T, j])
    lo, hi = -il, il
    if emf != 0:
        bound = (qsig(K[K_REGEN_A]) * _bus_v_q(j, C, K)) // abs(emf)
        if bound < il:
            if emf > 0:
                lo = -bound
            else:
                hi = bound
    return lo, hi


@kernel
def estimate(raw, P, C, S, G, K):
    """``float64.estimate`` in Q-format."""
    ref_row = S_REF_PIPE + np.int64(K[K_REF_I])
    half = np.int64(K[K_HALF_Q])
    dps_per_count_tick = K[K_DPS_PER_COUNT_TICK]
    for j in range(raw.shape[0]):
        r = raw[j]
        i_expected = _sat(S[ref_row, j] + _sat(S[S_IMEAS, j] - S[S_REF_D_LAST, j]))
        acc = _sat(_mul(i_expected, G[G_K_ACC, j]) + S[S_AD, j])
        pred = _sat(_sat(S[S_EP, j] + S[S_V, j]) + _mul(acc, half))
        pred_int = (pred + (1 << 15)) >> _SB
        delta = (r - C[C_COUNT, j] - pred_int) % REV
        if delta >= HALF_REV:
            delta -= REV
        d = pred_int + delta
        err = _sat((d << _SB) - pred)
        S[S_EP, j] = _mul(err, G[G_KPOS_M1, j])
        S[S_V, j] = _sat(_sat(S[S_V, j] + acc) + _mul(err, G[G_KVEL, j]))
        S[S_AD, j] = _sat(S[S_AD, j] + _mul(err, G[G_KDIST, j]))
        c = C[C_COUNT, j] + d
        C[C_COUNT, j] = c
        P[P_POS, j] = c * AXIS_DEG_PER_COUNT
        C[C_INNOV, j] = delta
        C[C_D, j] = d
        C[C_STUCK, j] = C[C_STUCK, j] + 1 if r == C[C_RAW_PREV, j] else 0
        C[C_RAW_PREV, j] = r
        P[P_VEL_RAW, j] = d * dps_per_count_tick
        vel = _mul(S[S_V, j], G[G_K_VEL, j])
        S[S_VEL, j] = vel
        P[P_VEL, j] = vel / _SIG_ONE


@kernel
def servo(sp_pos_deg, sp_vel_dps, sp_acc_dps2, v_clamp_dps, i_limit_a, P, C, S, G, K):
    """``float64.servo`` in Q-format: the setpoint is rounded to whole counts on the way
    in (one count is exactly 18 raw Q16.16 units)."""
    sp_count = np.int64(np.rint(sp_pos_deg / AXIS_DEG_PER_COUNT))
    vc, il = qsig(v_clamp_dps), qsig(i_limit_a)
    sv, sa = qsig(sp_vel_dps), qsig(sp_acc_dps2)
    for j in range(C.shape[1]):
        # The thermal protection's derating of this member (1 - 0 = the limit itself).
        il = qsig(i_limit_a * (1.0 - P[P_DERATE, j]))
        # The feed-forward's R at the winding estimate: R_nom (Q8.24) times the factor
        # 1 + rise (Q8.24, within [0.5, 2]), one SMULL and a shift; the factor comes from the
        # thermal estimate once per servo tick, as the derating does.
        G[G_R_T, j] = _mul(G[G_R_FF, j], qgain(1.0 + P[P_R_RISE, j]))
        G[G_EMF_T, j] = _mul(G[G_EMF_FF, j], qgain(1.0 + P[P_EMF_RISE, j]))
        e = _sat(_sat(sp_count - C[C_COUNT, j]) * Q_DEG_PER_COUNT)
        vr = _clamp(_sat(_mul(e, G[G_KP_P, j]) + _mul(sv, G[G_VFF, j])), vc)
        ev = _sat(vr - S[S_VEL, j])
        ff = _mul(sa, G[G_ACC_FF, j])
        i_v = S[S_I_V, j]
        u = _sat(_sat(_mul(ev, G[G_KP_V, j]) + i_v) + ff)
        lo, hi = -il, il
        if K[K_REGEN_A] > 0.0:
            lo, hi = _regen_limits_q(j, il, C, S, G, K)
        if not ((u > hi and ev > 0) or (u < lo and ev < 0)):
            i_v = _sat(i_v + _mul(ev, G[G_KI_V_DT, j]))
        S[S_I_V, j] = _clamp(i_v, il)
        S[S_VR, j] = vr
        P[P_VREF, j] = vr / _SIG_ONE
        iref = hi if u > hi else (lo if u < lo else u)
        S[S_IREF, j] = iref
        P[P_IREF, j] = iref / _SIG_ONE
    K[K_I_LIMIT_A] = i_limit_a


@kernel
def current(adc, enabled, P, C, S, G, K):
    """``float64.current`` in Q-format; the duty is ``u / V_supply`` in Q16.16 times ARR."""
    ref_i = np.int64(K[K_REF_I])
    pipe_i = np.int64(K[K_PIPE_I])
    delay = np.int64(K[K_DELAY])
    ref_row = S_REF_PIPE + ref_i
    a_per_adc_q = np.int64(K[K_A_PER_ADC_Q])
    sense_floor = K[K_SENSE_FLOOR]
    ul = qsig(K[K_U_LIM])
    inv_supply = np.int64(K[K_INV_SUPPLY_Q])
    arr = np.int64(K[K_ARR])
    for j in range(adc.shape[0]):
        applied = C[C_STEPS, j]
        # The offset of the pin read: the one of the half-bridge the applied duty drives.
        a = adc[j] - C[C_SENSE_OFFSET_B if applied < 0 else C_SENSE_OFFSET_A, j]
        if a < 0:
            a = 0
        sensed = (a * a_per_adc_q + (1 << 7)) >> (_GB - _SB)
        sign = _sgn(applied)
        i_meas = sensed * sign
        ref_d = S[ref_row, j]
        S[S_REF_D_LAST, j] = ref_d
        if a <= sense_floor and _sgn(ref_d) * sign <= 0:
            i_meas = ref_d
        e = _sat(ref_d - i_meas)
        i_ref = S[S_IREF, j]
        S[ref_row, j] = i_ref
        emf = _mul(S[S_VEL, j], G[G_EMF_T, j])
        u = _sat(_mul(e, G[G_KP_I, j]) + S[S_I_I, j])
        u = _sat(u + _mul(i_ref, G[G_R_T, j]))
        u = _sat(u + emf)
        i_i = S[S_I_I, j]
        # The regenerative clamp and its back-calculation (see float64.current).
        r_lim = _mul(qsig(K[K_I_LIMIT_A] * (1.0 - P[P_DERATE, j])), G[G_R_T, j])
        lo, hi = _sat(emf - r_lim), _sat(emf + r_lim)
        if u < lo and u >= 0:
            i_i = _sat(i_i + _sat(lo - u))
            u = lo
        elif u > hi and u <= 0:
            i_i = _sat(i_i + _sat(hi - u))
            u = hi
        elif not ((u > ul and e > 0) or (u < -ul and e < 0)):
            i_i = _sat(i_i + _mul(e, G[G_KI_I_DT, j]))
        if C[C_BUS_ADC, j] < K[K_BUS_HOLD]:
            S[S_I_I, j] = _clamp(i_i, ul)
        if K[K_BUS_COMP] != 0.0:
            # u / V_bus (a 64-bit division, truncated), within the duty limit.
            au = u if u >= 0 else -u
            duty_q = (au << _SB) // _bus_v_q(j, C, K)
            duty_q = min(duty_q, qsig(K[K_U_LIM] / K[K_SUPPLY_V]))
            duty_q = duty_q if u >= 0 else -duty_q
        else:
            u = _clamp(u, ul)
            duty_q = _mul(u, inv_supply)
        new_steps = (duty_q * arr + (1 << 15)) >> _SB
        if delay > 0:
            out = C[C_PIPE + pipe_i, j]
            C[C_PIPE + pipe_i, j] = new_steps
        else:
            out = new_steps
        S[S_IMEAS, j] = i_meas
        P[P_IMEAS, j] = i_meas / _SIG_ONE
        if not enabled[j]:
            out = 0
            _reset_member(j, P, C, S, delay)
        C[C_STEPS, j] = out
        P[P_DUTY, j] = out / K[K_ARR]
    K[K_REF_I] = (ref_i + 1) % (delay + 1)
    if delay > 0:
        K[K_PIPE_I] = (pipe_i + 1) % delay
