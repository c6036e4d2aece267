"""The control law in float64 (``arithmetic = "float"``), written once for ``N`` members.

Each step is one loop over the members (numba, no ``fastmath``: no reassociation, no fused
multiply-add, so a member's result does not depend on N or on the machine's vector width).
``firmware_model/servo.py`` says what the steps compute; ``laws/layout.py`` names the rows
of the state arrays ``P, C, S, G, K`` (each ``(rows, N)``; ``K`` 1-D). The fixed-point law
(``laws/fixed_q.py``) has the same three steps with the same arguments.
"""

from __future__ import annotations

import math

import numpy as np

from firmware_model.kernel_cache import kernel
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
    K_A_PER_ADC,
    K_ARR,
    K_BUS_COMP,
    K_BUS_HOLD,
    K_DELAY,
    K_DPS_PER_COUNT_TICK,
    K_I_LIMIT_A,
    K_PIPE_I,
    K_REF_I,
    K_REGEN_A,
    K_SENSE_FLOOR,
    K_SUPPLY_V,
    K_U_LIM,
    K_V_PER_BUS_ADC,
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

__all__ = ["current", "estimate", "servo"]


@kernel
def _clip(x, limit):
    """``min(max(x, -limit), limit)`` (NaN passes)."""
    if x < -limit:
        x = -limit
    if x > limit:
        x = limit
    return x


@kernel
def estimate(raw, P, C, S, G, K):
    """Unwrap each member's 14-bit reading ``raw`` (int64 ``(N,)``) around the observer's
    prediction and update the third-order velocity observer."""
    ref_row = S_REF_PIPE + np.int64(K[K_REF_I])
    dps_per_count_tick = K[K_DPS_PER_COUNT_TICK]
    for j in range(raw.shape[0]):
        r = raw[j]
        # The current of the period that just ended: the reference of the duty applied in
        # it plus the model error seen at the last sample (this tick's sample comes later).
        i_expected = S[ref_row, j] + (S[S_IMEAS, j] - S[S_REF_D_LAST, j])
        acc = i_expected * G[G_K_ACC, j] + S[S_AD, j]
        pred = S[S_EP, j] + S[S_V, j] + acc * 0.5
        pred_int = np.int64(math.floor(pred + 0.5))
        delta = (r - C[C_COUNT, j] - pred_int) % REV  # floored modulo, as Python
        if delta >= HALF_REV:
            delta -= REV
        d = pred_int + delta
        err = d - pred
        S[S_EP, j] = err * G[G_KPOS_M1, j]
        vj = S[S_V, j] + acc + err * G[G_KVEL, j]
        S[S_V, j] = vj
        S[S_AD, j] = S[S_AD, j] + err * G[G_KDIST, j]
        c = C[C_COUNT, j] + d
        C[C_COUNT, j] = c
        P[P_POS, j] = c * AXIS_DEG_PER_COUNT
        C[C_INNOV, j] = delta
        C[C_D, j] = d
        C[C_STUCK, j] = C[C_STUCK, j] + 1 if r == C[C_RAW_PREV, j] else 0
        C[C_RAW_PREV, j] = r
        P[P_VEL_RAW, j] = d * dps_per_count_tick
        vel = vj * G[G_K_VEL, j]
        S[S_VEL, j] = vel
        P[P_VEL, j] = vel


@kernel
def bus_v(j, C, K):
    """Member ``j``'s bus voltage for the duty: measured (``K_BUS_COMP``), else the
    configured supply. A reading below 1 V counts as 1 V (no division by zero)."""
    if K[K_BUS_COMP] == 0.0:
        return K[K_SUPPLY_V]
    v = C[C_BUS_ADC, j] * K[K_V_PER_BUS_ADC]
    return v if v > 1.0 else 1.0


@kernel
def _regen_limits(j, i_limit_a, regen_a, C, S, G, K):
    """The velocity loop's current clamp ``(lo, hi)`` with the regenerative bus-current
    limit: on the braking side (the current against the back-EMF ``k_emf v``), ``|i| <=
    regen_a V_bus / |k_emf v|``, which keeps the current returned to the bus, ``(|k_emf v|
    |i| - R i^2) / V_bus``, below ``regen_a`` (conservative by the copper loss)."""
    emf = S[S_VEL, j] * G[G_EMF_T, j]
    lo, hi = -i_limit_a, i_limit_a
    if emf != 0.0:
        bound = regen_a * bus_v(j, C, K) / abs(emf)
        if bound < i_limit_a:
            if emf > 0.0:
                lo = -bound
            else:
                hi = bound
    return lo, hi


@kernel
def servo(sp_pos_deg, sp_vel_dps, sp_acc_dps2, v_clamp_dps, i_limit_a, P, C, S, G, K):
    """Position P -> velocity PI with feed-forward, clamps and conditional integration:
    sets each member's velocity and current references."""
    regen = K[K_REGEN_A]
    i_limit_all = i_limit_a
    for j in range(C.shape[1]):
        # The thermal protection's derating of this member (1 - 0 = the limit itself), and
        # the current loop's feed-forward R and back-EMF constant at its winding estimate
        # (x 1.0: the nominal ones).
        i_limit_a = i_limit_all * (1.0 - P[P_DERATE, j])
        G[G_R_T, j] = G[G_R_FF, j] * (1.0 + P[P_R_RISE, j])
        G[G_EMF_T, j] = G[G_EMF_FF, j] * (1.0 + P[P_EMF_RISE, j])
        e = sp_pos_deg - C[C_COUNT, j] * AXIS_DEG_PER_COUNT
        vr = _clip(e * G[G_KP_P, j] + sp_vel_dps * G[G_VFF, j], v_clamp_dps)
        ev = vr - S[S_VEL, j]
        i_v = S[S_I_V, j]
        u = ev * G[G_KP_V, j] + i_v + sp_acc_dps2 * G[G_ACC_FF, j]
        if regen > 0.0:
            lo, hi = _regen_limits(j, i_limit_a, regen, C, S, G, K)
            if not ((u > hi and ev > 0.0) or (u < lo and ev < 0.0)):
                i_v = i_v + ev * G[G_KI_V_DT, j]
            S[S_I_V, j] = _clip(i_v, i_limit_a)
            S[S_VR, j] = vr
            P[P_VREF, j] = vr
            iref = hi if u > hi else (lo if u < lo else u)
            S[S_IREF, j] = iref
            P[P_IREF, j] = iref
            continue
        # Hold the integrator while the output is clamped and the error pushes further in.
        if not (abs(u) > i_limit_a and u * ev > 0.0):
            i_v = i_v + ev * G[G_KI_V_DT, j]
        S[S_I_V, j] = _clip(i_v, i_limit_a)
        S[S_VR, j] = vr
        P[P_VREF, j] = vr
        iref = _clip(u, i_limit_a)
        S[S_IREF, j] = iref
        P[P_IREF, j] = iref
    K[K_I_LIMIT_A] = i_limit_all


@kernel
def current(adc, enabled, P, C, S, G, K):
    """One current-loop period per member: the signed IS reading, the current PI with its
    feed-forward, the regenerative clamp, the duty on the timer grid, the compute delay,
    and the bridge enable (a disabled member's controller is reset)."""
    ref_i = np.int64(K[K_REF_I])
    pipe_i = np.int64(K[K_PIPE_I])
    delay = np.int64(K[K_DELAY])
    ref_row = S_REF_PIPE + ref_i
    a_per_adc, sense_floor, u_lim = K[K_A_PER_ADC], K[K_SENSE_FLOOR], K[K_U_LIM]
    supply_v, arr, i_limit_a = K[K_SUPPLY_V], K[K_ARR], K[K_I_LIMIT_A]
    # Read once a period: K is an array the loop's stores might alias for the compiler.
    bus_hold, bus_comp = K[K_BUS_HOLD], K[K_BUS_COMP] != 0.0
    for j in range(adc.shape[0]):
        applied = C[C_STEPS, j]
        # The offset of the pin read: the one of the half-bridge the applied duty drives.
        a = adc[j] - C[C_SENSE_OFFSET_B if applied < 0 else C_SENSE_OFFSET_A, j]
        if a < 0:
            a = 0
        sign = 1.0 if applied > 0 else (-1.0 if applied < 0 else 0.0)
        i_meas = a * a_per_adc * sign
        ref_d = S[ref_row, j]
        S[S_REF_D_LAST, j] = ref_d
        ref_sign = 1.0 if ref_d > 0.0 else (-1.0 if ref_d < 0.0 else ref_d)  # np.sign
        if a <= sense_floor and ref_sign * sign <= 0:
            # High-side sense blind (current against the duty, or no duty): the model.
            i_meas = ref_d
        e = ref_d - i_meas
        i_ref = S[S_IREF, j]
        S[ref_row, j] = i_ref
        emf = S[S_VEL, j] * G[G_EMF_T, j]
        u = e * G[G_KP_I, j] + S[S_I_I, j] + i_ref * G[G_R_T, j] + emf
        ii = S[S_I_I, j]
        if not (abs(u) > u_lim and u * e > 0.0):
            ii = ii + e * G[G_KI_I_DT, j]
        # The regenerative clamp: a current against the duty (or with no duty) is invisible
        # to the high-side sense, so on that side the voltage is kept where the model
        # predicts at most the current limit, |u - emf| <= R * I_limit; the integrator
        # tracks the clamp (back-calculation), so that the loop leaves it without a jump.
        r_lim = G[G_R_T, j] * (i_limit_a * (1.0 - P[P_DERATE, j]))
        d = u - emf
        if abs(d) > r_lim and d * u <= 0.0:
            c = emf - r_lim if d < 0.0 else emf + r_lim
            ii = S[S_I_I, j] + (c - u)
            u = c
        if C[C_BUS_ADC, j] < bus_hold:
            S[S_I_I, j] = _clip(ii, u_lim)
        # else: at the lock-out the IS pin may read nothing; hold the integrator.
        if bus_comp:
            # The duty from the measured bus: u / V_bus, within the same duty limit.
            v = bus_v(j, C, K)
            new_steps = np.int64(np.rint(_clip(u, u_lim / supply_v * v) / v * arr))
        else:
            new_steps = np.int64(np.rint(_clip(u, u_lim) / supply_v * arr))
        if delay > 0:
            out = C[C_PIPE + pipe_i, j]
            C[C_PIPE + pipe_i, j] = new_steps
        else:
            out = new_steps
        S[S_IMEAS, j] = i_meas
        P[P_IMEAS, j] = i_meas
        if not enabled[j]:
            out = 0
            _reset_member(j, P, C, S, delay)
        C[C_STEPS, j] = out
        P[P_DUTY, j] = out / arr
    K[K_REF_I] = (ref_i + 1) % (delay + 1)
    if delay > 0:
        K[K_PIPE_I] = (pipe_i + 1) % delay


@kernel
def _reset_member(j, P, C, S, delay):
    """Zero member ``j``'s integrators, references and pipelines (not its measurement)."""
    S[S_I_V, j] = 0
    S[S_I_I, j] = 0
    S[S_VR, j] = 0
    S[S_IREF, j] = 0
    P[P_VREF, j] = 0.0
    P[P_IREF, j] = 0.0
    for k in range(delay + 1):
        S[S_REF_PIPE + k, j] = 0
    S[S_REF_D_LAST, j] = 0
    for k in range(delay):
        C[C_PIPE + k, j] = 0
    C[C_STEPS, j] = 0
    P[P_DUTY, j] = 0.0


@kernel
def reset_control(mask, P, C, S, K):
    """``_reset_member`` for every member in ``mask`` (bool ``(N,)``), and its current
    measurement (a tripped or re-enabled controller starts from nothing)."""
    delay = np.int64(K[K_DELAY])
    for j in range(mask.shape[0]):
        if mask[j]:
            _reset_member(j, P, C, S, delay)
            S[S_IMEAS, j] = 0
            P[P_IMEAS, j] = 0.0
