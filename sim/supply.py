"""The supply rail: a 24 V supply that cannot sink current, the bulk capacitor, the brake
chopper, and the BTN7971B's over- and under-voltage lock-out (``[supply] bus_model``).

The rail (cap voltage ``v``, V) obeys, with ``i_out`` the current the bridge and the logic
draw from it (negative while braking returns energy)::

    C dv/dt = i_sup(v) - i_out - i_brake(v)
    i_sup   = (V_s - v) / R_s   while v < V_s, else 0      (the supply's output diode)
    i_brake = the chopper's current: 0 below V_b; at V_b it holds the rail there while the
              returned current is at most V_b / R_b; above, the resistor is on: v / R_b
              (or a TVS's, ``[supply] tvs_breakdown_v`` > 0: (v - V_br) / R_d above V_br)

The bridge draws ``duty * i`` while it conducts (sign-magnitude PWM, averaged) and returns
``|i|`` through its body diodes while disabled or locked out; its output is ``duty * v``.

**The approximation (the only one of the plant).** ``v`` enters the armature equation
through the duty, ``L di/dt = duty * v - R i - K_e w``: a product of input and state, so
the exact per-mode step of ``sim.plant`` (one matrix per mode) would need a matrix per duty.
Instead each current-loop period is split into ``bus_substeps`` equal sub-steps; in each,
the plant takes its exact step with the bridge voltage held at ``duty * v_mid`` (``v_mid``
the rail half-way through the sub-step, predicted with the current at its start), then the
rail is advanced *exactly* (``rail_advance``: a piecewise-linear scalar equation, solved in
closed form across the supply-diode and chopper switches) with the bridge's current held at
its trapezoid mean. The lock-out comparator is sampled at the sub-step ends. The error
against ``solve_ivp`` on the continuous model is measured in ``tests/sim/test_supply.py``
and ``docs/model.md`` (section 2, "Supply and bus").

**The adaptive step** (``[supply] bus_quiet_v`` > 0). A period whose rail is quiet is one
exact step of the plant instead: the bridge conducting (no current through its diodes),
no lock-out comparator near a change, the chopper off, the supply's diode not switching
(the rail's current keeps its sign), and the rail swinging by at most ``bus_quiet_v``
within the period. Judged twice: before, on the rail predicted with the current at the
period's start (the one the member's last period averaged); after, on the rail the step
implies: the charge the armature passed
comes from its own equation (``(V h - L di - K_e dtheta) / R``, exact for the averaged
bridge), its rates at both ends too, and ``rail_profile`` gives the rail's end and mean
from them. If the held ``v_mid`` is further than ``bus_quiet_v / 10`` from that mean, the
step is taken once more holding the mean (a second pass; the mean moves by ~1.5 % of the
change, so one pass settles it); a period not quiet after all is taken again in
sub-steps. Each member decides for itself, and its result does not depend on the
others' (``step_period``).
"""

from __future__ import annotations

import math

import numpy as np

from firmware_model.kernel_cache import kernel
from sim.params import PlantParams, per_member
from sim.plant_kernel import _KE, _R, step_members

__all__ = [
    "N_SUPPLY",
    "Bus",
    "bridge_current_a",
    "rail_advance",
    "rail_profile",
    "read_bus_adc",
    "step_period",
]

# cfg[j, ...] columns.
(
    S_VS, S_RS, S_C, S_LOAD, S_RB, S_VB, S_OV_OFF, S_OV_ON, S_UV_OFF, S_UV_ON, S_VREF, S_VD2,
    S_H, S_QUIET, S_L, S_ICL, S_VOFF,
) = range(17)  # fmt: skip
N_SUPPLY = 17
# sub[...]: the period's progress (resumed after a mode load): the sub-step reached, the
# sub-steps per period, the phase (PH_*), the sub-step's table level, and two counters
# (statistics only): the member-periods taken whole, and those of them that needed the
# corrected second pass.
SUB_S, SUB_N, SUB_PHASE, SUB_LEVEL, SUB_QUIET, SUB_SECOND = range(6)
PH_NEW, PH_WHOLE, PH_WHOLE_AGAIN, PH_SUB, PH_DONE = range(5)
# A member's state in the period (Bus.state): sub-steps, a whole step (first pass, second
# pass), accepted whole.
ST_SUB, ST_WHOLE, ST_AGAIN, ST_DONE = range(4)


@kernel
def rail_advance(v, i_out, h, vs, rs, c, rb, vb, voff):
    """The rail voltage after ``h`` seconds from ``v`` with ``i_out`` (A, drawn from the
    rail; < 0 returns) held: the exact solution of the rail equation (module docstring),
    across the supply diode's switch at ``vs`` and the clamp's at ``vb`` (``rb`` = 0: no
    clamp). The clamp draws ``(v - voff) / rb`` above ``vb``: a brake chopper (``voff`` =
    0; it holds the rail at ``vb`` while the returned current is below ``vb / rb``) or a
    TVS (``voff = vb``, its breakdown voltage, ``rb`` its dynamic resistance)."""
    t = h
    for _ in range(8):
        if t <= 0.0:
            break
        if v < vs or (v == vs and i_out > 0.0):
            # The supply conducts: first order towards vs - rs * i_out.
            tau = rs * c
            veq = vs - rs * i_out
            if veq <= vs:
                return veq + (v - veq) * math.exp(-t / tau)
            tc = tau * math.log((veq - v) / (veq - vs))
            if tc >= t:
                return veq + (v - veq) * math.exp(-t / tau)
            v = vs
            t -= tc
            continue
        if rb > 0.0 and v >= vb:
            veq = voff - i_out * rb  # where the clamp alone would hold the rail
            if v > vb or veq > vb:
                tau = rb * c
                if veq >= vb:
                    return veq + (v - veq) * math.exp(-t / tau)
                tc = tau * math.log((v - veq) / (vb - veq))
                if tc >= t:
                    return veq + (v - veq) * math.exp(-t / tau)
                v = vb
                t -= tc
                continue
            if i_out <= 0.0:
                return vb  # the chopper holds the rail at its threshold
            # Drawn from: below the threshold, the supply still blocked.
        # The supply blocked, the chopper off: the capacitor alone.
        if i_out == 0.0:
            return v
        if i_out > 0.0:
            tc = c * (v - vs) / i_out
            if tc >= t:
                return v - i_out * t / c
            v = vs
            t -= tc
            continue
        if rb > 0.0:
            tc = c * (vb - v) / -i_out
            if tc < t:
                v = vb
                t -= tc
                continue
        return v - i_out * t / c
    return v


@kernel
def bridge_current_a(duty, i_start, i_end, conducting):
    """The bridge's mean current from the rail over a sub-step (A): ``duty * i`` while it
    conducts, ``-|i|`` (returned through the body diodes) while its outputs are off."""
    if conducting:
        return duty * 0.5 * (i_start + i_end)
    return -0.5 * (abs(i_start) + abs(i_end))


@kernel
def _inputs(j, x, duty, enable, v, locked, cfg, d_eff, en_eff, v_mid, h):
    """Member ``j``'s plant input over the next ``h`` seconds: the duty scaled by the rail
    predicted half-way (``v_mid``), or, outputs off, the diode voltage ``v + 2 V_f`` in the
    unit the bus plant's diode modes take (``sim.plant.Coefficients.diode_in``). Returns
    the rail predicted at the end (the current held at its start)."""
    conducting = enable[j] and locked[j] == 0
    vs, rs, c, rb, vb = cfg[j, S_VS], cfg[j, S_RS], cfg[j, S_C], cfg[j, S_RB], cfg[j, S_VB]
    voff = cfg[j, S_VOFF]
    i0 = x[j, 0]
    i_pred = bridge_current_a(duty[j], i0, i0, conducting) + cfg[j, S_LOAD]
    vm = rail_advance(v[j], i_pred, 0.5 * h, vs, rs, c, rb, vb, voff)
    v_mid[j] = vm
    if conducting:
        d_eff[j] = duty[j] * vm / cfg[j, S_VREF]
        en_eff[j] = True
    else:
        vd2 = cfg[j, S_VD2]
        d_eff[j] = (vm + vd2 - cfg[j, S_VREF]) / vd2
        en_eff[j] = False
    return rail_advance(vm, i_pred, 0.5 * h, vs, rs, c, rb, vb, voff)


@kernel
def _quiet(j, v0, v1, i0, i1, r0, r1, conducting, cfg):
    """Whether member ``j``'s period may be one step: the bridge conducting (or no motor
    current ``i0`` -> ``i1`` through its diodes), the rail's current ``r0`` -> ``r1``
    (bridge and logic) keeping its sign, so that the rail moves one way while it is on one
    side of the supply voltage, and ``v0`` -> ``v1`` on the same side (the supply's diode
    does not switch); the chopper off, no lock-out comparator near a change."""
    if not conducting and (i0 != 0.0 or i1 != 0.0):
        return False
    if r0 * r1 < 0.0:
        return False
    vs = cfg[j, S_VS]
    if (v0 < vs) != (v1 < vs):
        return False
    if cfg[j, S_RB] > 0.0 and (v0 >= cfg[j, S_VB] or v1 >= cfg[j, S_VB]):
        return False
    for v in (v0, v1):
        if not cfg[j, S_UV_ON] < v < cfg[j, S_OV_ON]:
            return False  # at a lock-out or in its hysteresis band
    return True


@kernel
def rail_profile(v0, r0, r1, r_mean, dr0, dr1, h, vs, rs, c):
    """The rail after ``h`` seconds from ``v0`` and its mean over them, ``(v1, mean)``,
    with the current drawn from it going from ``r0`` to ``r1`` (A) at the rates ``dr0``,
    ``dr1`` (A/s) at the ends and averaging ``r_mean``, within one of ``rail_advance``'s
    pieces (the caller checks that, ``_quiet``). The supply conducting (``v0 < vs``):
    ``tau dv/dt = vs - rs r(t) - v`` is solved by ``v_p(t) + (v0 - v_p(0)) exp(-t / tau)``
    with ``v_p = vs - rs (r - tau r' + tau^2 r'' - ...)``, taken to ``tau r'`` at the ends
    and ``tau^2 r'`` in the mean (``tau`` = 0.11 ms against a 2 ms period: the next
    terms are ``(tau / h)^2`` smaller); blocked, the capacitor alone: ``v(t) = v0 -
    int_0^t r / C``, its mean from the quadratic through ``r0``, ``r1`` and ``r_mean``."""
    if v0 < vs:
        tau = rs * c
        vp0 = vs - rs * (r0 - tau * dr0)
        vp1 = vs - rs * (r1 - tau * dr1)
        mean_p = vs - rs * (r_mean - tau * (r1 - r0) / h + tau * tau * (dr1 - dr0) / h)
        a0 = v0 - vp0
        e = math.exp(-h / tau)
        return vp1 + a0 * e, mean_p + a0 * tau / h * (1.0 - e)
    k = -6.0 * (r_mean - 0.5 * (r0 + r1)) / (h * h)
    b = (r1 - r0) / h - k * h
    moment = r0 * h * h / 2.0 + b * h * h * h / 6.0 + k * h * h * h * h / 12.0
    return v0 - r_mean * h / c, v0 - moment / (c * h)


@kernel
def _whole_verdict(j, x, xe, duty, d_eff, en_eff, v, v_mid, cfg, kc, h):
    """After a whole step of member ``j`` (``x`` -> ``xe``): ``(verdict, v_end, i_mean)``,
    ``verdict`` 1 = quiet and ``v_mid`` close to the rail's mean (accept), 2 = quiet but the
    step must be taken again holding the mean (``v_mid``, ``d_eff`` set to it), 0 = not
    quiet (sub-steps). The rail over the period: its current from the start to the end
    value, its mean from the armature's equation (the charge it passed, ``(V h - L di -
    K_e dtheta) / R``, exact for the averaged bridge) and its rates at both ends, through
    ``rail_profile``."""
    i0, i1 = x[j, 0], xe[j, 0]
    load = cfg[j, S_LOAD]
    r0 = bridge_current_a(duty[j], i0, i0, en_eff[j]) + load
    r1 = bridge_current_a(duty[j], i1, i1, en_eff[j]) + load
    r_mean = load
    dr0 = dr1 = 0.0
    i_mean = i1
    if en_eff[j]:
        v_arm = cfg[j, S_VREF] * d_eff[j]
        # R and K_e of the member's parameter set (the winding's temperature bin with the
        # [thermal] model), L from the configuration.
        r_a, l_a, ke = kc[_R], cfg[j, S_L], kc[_KE]
        i_mean = (v_arm * h - l_a * (i1 - i0) - ke * (xe[j, 1] - x[j, 1])) / (r_a * h)
        r_mean += duty[j] * i_mean
        dr0 = duty[j] * (v_arm - r_a * i0 - ke * x[j, 2]) / l_a
        dr1 = duty[j] * (v_arm - r_a * i1 - ke * xe[j, 2]) / l_a
    v_end, mean = rail_profile(
        v[j], r0, r1, r_mean, dr0, dr1, h, cfg[j, S_VS], cfg[j, S_RS], cfg[j, S_C]
    )
    bound = cfg[j, S_QUIET]
    if (
        not _quiet(j, v[j], v_end, i0, i1, r0, r1, en_eff[j], cfg)
        or abs(i0) >= cfg[j, S_ICL] or abs(i1) >= cfg[j, S_ICL]
        or r0 * r_mean < 0.0 or r1 * r_mean < 0.0
        # The chip's current limitation out of reach within the step (the charge above is
        # the averaged bridge's).
        or (cfg[j, S_VREF] * abs(d_eff[j]) + kc[_KE] * max(abs(x[j, 2]), abs(xe[j, 2])))
        >= kc[_R] * cfg[j, S_ICL]
        # The rail swings more than the bound within the period (its ends, or the supply's
        # drop by the current's excursions from its mean).
        or max(abs(v[j] - mean), abs(v_end - mean),
               cfg[j, S_RS] * max(abs(r0 - r_mean), abs(r1 - r_mean))) > bound
    ):  # fmt: skip
        return 0, v_end, i_mean
    if en_eff[j] and abs(v_mid[j] - mean) > 0.01 * bound:
        v_mid[j] = mean
        d_eff[j] = duty[j] * mean / cfg[j, S_VREF]
        return 2, v_end, i_mean
    return 1, v_end, i_mean


@kernel
def step_period(
    x, xn, duty, enable, keys, known, start, group, slots, phis, rates, consts, levels, budget,
    bus, volt, sense_sign, scratch,
):  # fmt: skip
    """One current-loop period of the plant (``x`` -> ``xn``, ``(N, 5)``) with the bridge's
    ``duty``/``enable`` held: ``sim.plant_kernel.step_members`` itself without the bus model
    (``bus[0]`` empty), else coupled to the rail (module docstring): each member whose rail
    is quiet over the period takes one exact step of it (module docstring, "The adaptive
    step"), the others ``bus_substeps`` sub-steps. Returns ``step_members``' ``(next,
    events, group, need)``; on ``need`` >= 0 the caller loads the mode and calls again with
    ``start = next`` (the progress is kept in ``bus``'s ``sub``). ``bus = (v, locked, cfg,
    sub, xs, d_eff, en_eff, v_mid, v_sum, ...)`` (``Bus.kernel_args``); with the bus model,
    ``volt`` gets the period's mean bridge output and ``sense_sign`` 0 for a locked-out
    member (its IS pins carry nothing). ``scratch``: ``step_members``'.

    A member's result does not depend on the others': the whole step is computed for
    every member (in one ``step_members`` call) when one may be quiet, each member keeps
    the result of the pass that accepted it, and the sub-steps, when a member needs them,
    run for all but change the rail and the result of those members only; ``keys`` are
    restored to the period's start before a pass is taken again."""
    v, locked, cfg, sub, xs, d_eff, en_eff, v_mid, v_sum = bus[:9]
    i_hint, state, xw, keys0, keys_w, v_w = bus[10:16]
    if v.shape[0] == 0:
        return step_members(
            x, duty, enable, keys, known, start, group, slots, phis, rates, consts, levels,
            budget, xn, keys, np.int64(0), scratch,
        )  # fmt: skip
    n = x.shape[0]
    n_sub = sub[SUB_N]
    s = sub[SUB_S]
    events = 0
    if sub[SUB_PHASE] == PH_NEW:
        any_whole = False
        for j in range(n):
            for q in range(5):
                xn[j, q] = x[j, q]
            v_sum[j] = 0.0
            keys0[j] = keys[j]
            state[j] = ST_SUB
            if cfg[j, S_QUIET] > 0.0 and locked[j] == 0:
                h = cfg[j, S_H] * n_sub
                i0 = xn[j, 0]
                if enable[j]:
                    # The rail held by the current the member's last period averaged (the
                    # loops keep it steady): its mean is v_mid.
                    r_hint = duty[j] * i_hint[j] + cfg[j, S_LOAD]
                    v_end, mean = rail_profile(
                        v[j], r_hint, r_hint, r_hint, 0.0, 0.0, h, cfg[j, S_VS], cfg[j, S_RS],
                        cfg[j, S_C],
                    )  # fmt: skip
                    v_mid[j] = mean
                    d_eff[j] = duty[j] * mean / cfg[j, S_VREF]
                    en_eff[j] = True
                else:
                    v_end = _inputs(j, xn, duty, enable, v, locked, cfg, d_eff, en_eff, v_mid, h)
                r0 = bridge_current_a(duty[j], i0, i0, en_eff[j]) + cfg[j, S_LOAD]
                if _quiet(j, v[j], v_end, i0, i0, r0, r0, en_eff[j], cfg):
                    state[j] = ST_WHOLE
                    any_whole = True
        sub[SUB_PHASE] = PH_WHOLE if any_whole else PH_SUB
    while sub[SUB_PHASE] == PH_WHOLE or sub[SUB_PHASE] == PH_WHOLE_AGAIN:
        # One exact step of the period for every member, the bridge's voltage held at
        # duty * v_mid (the members not quiet ignore theirs).
        nxt, ev, g, need = step_members(
            xn, d_eff, en_eff, keys, known, start, group, slots, phis, rates, consts, levels,
            budget, xs, keys, np.int64(0), scratch,
        )  # fmt: skip
        events += ev
        if need >= 0:
            return nxt, events, g, need
        start = 0
        again = False
        subs = False
        for j in range(n):
            if state[j] != ST_WHOLE and state[j] != ST_AGAIN:
                subs = subs or state[j] == ST_SUB
                continue
            h = cfg[j, S_H] * n_sub
            verdict, v_end, i_mean = _whole_verdict(
                j, xn, xs, duty, d_eff, en_eff, v, v_mid, cfg, consts[group[j]], h
            )
            if verdict == 1:
                if state[j] == ST_AGAIN:
                    sub[SUB_SECOND] += 1
                state[j] = ST_DONE
                for q in range(5):
                    xw[j, q] = xs[j, q]
                keys_w[j] = keys[j]
                v_w[j] = v_end
                i_hint[j] = i_mean
                volt[j] = duty[j] * v_mid[j] if en_eff[j] else 0.0
                sub[SUB_QUIET] += 1
            elif verdict == 2 and state[j] == ST_WHOLE:
                state[j] = ST_AGAIN
                again = True
            else:
                state[j] = ST_SUB
                subs = True
        for j in range(n):
            keys[j] = keys0[j]  # the period's start modes, for whatever is taken next
        if again:
            sub[SUB_PHASE] = PH_WHOLE_AGAIN
            continue
        sub[SUB_PHASE] = PH_SUB if subs else PH_DONE
        s = 0
    if sub[SUB_PHASE] == PH_SUB:
        level = sub[SUB_LEVEL]
        while s < n_sub:
            if start == 0:
                for j in range(n):
                    _inputs(j, xn, duty, enable, v, locked, cfg, d_eff, en_eff, v_mid, cfg[j, S_H])
            nxt, ev, g, need = step_members(
                xn, d_eff, en_eff, keys, known or s > 0, start, group, slots, phis, rates,
                consts, levels, budget, xs, keys, level, scratch,
            )  # fmt: skip
            events += ev
            if need >= 0:
                sub[SUB_S] = s
                return nxt, events, g, need
            start = 0
            for j in range(n):
                if state[j] == ST_SUB:
                    vs, rs, c = cfg[j, S_VS], cfg[j, S_RS], cfg[j, S_C]
                    i_out = (
                        bridge_current_a(duty[j], xn[j, 0], xs[j, 0], en_eff[j]) + cfg[j, S_LOAD]
                    )
                    vj = rail_advance(
                        v[j], i_out, cfg[j, S_H], vs, rs, c, cfg[j, S_RB], cfg[j, S_VB],
                        cfg[j, S_VOFF],
                    )  # fmt: skip
                    v[j] = vj
                    if en_eff[j]:
                        v_sum[j] += duty[j] * v_mid[j]
                    # The lock-out comparators, sampled at the sub-step's end.
                    if locked[j]:
                        if cfg[j, S_UV_ON] < vj < cfg[j, S_OV_ON]:
                            locked[j] = 0
                    elif vj >= cfg[j, S_OV_OFF] or vj <= cfg[j, S_UV_OFF]:
                        locked[j] = 1
                for q in range(5):
                    xn[j, q] = xs[j, q]
            s += 1
    # PH_DONE, or the sub-steps done: each member's result.
    sub[SUB_S] = 0
    sub[SUB_PHASE] = PH_NEW
    for j in range(n):
        if state[j] == ST_DONE:
            for q in range(5):
                xn[j, q] = xw[j, q]
            keys[j] = keys_w[j]
            v[j] = v_w[j]
        else:
            i_hint[j] = xn[j, 0]
            volt[j] = v_sum[j] / n_sub
        if locked[j]:
            sense_sign[j] = 0.0
    return n, events, 0, -1


@kernel
def read_bus_adc(bus, supply_v, adc_full, out):
    """The bus voltage through the board's divider into the STM32's ADC, per member
    (rounded to nearest, clamped to the ADC's range): the rail with the bus model, the
    supply's voltage without it. ``bus``: ``Bus.kernel_args()``."""
    v, v_per_count = bus[0], bus[9]
    for j in range(out.shape[0]):
        volts = v[j] if v.shape[0] else supply_v[j]
        c = np.floor(volts / v_per_count[j] + 0.5)
        if c > adc_full:
            c = adc_full
        if c < 0.0:
            c = 0.0
        out[j] = np.int64(c)


class Bus:
    """The rail's state and scratch for ``step_period``, one per ``Simulation``; empty
    arrays (``step_period`` is then the plain plant step) when ``[supply] bus_model`` is
    off. ``v`` (``(N,)``, V) starts charged to the supply voltage."""

    def __init__(self, params: PlantParams, n: int, h_s: float) -> None:
        sup, br = params.supply, params.bridge
        self.on = bool(sup.bus_model)
        self.substeps = int(sup.bus_substeps) if self.on else 1
        size = n if self.on else 0
        self.v = per_member(sup.voltage_v, n).copy() if self.on else np.empty(0)
        self.locked = np.zeros(size, dtype=np.int64)
        cfg = np.empty((size, N_SUPPLY))
        # The rail's clamp: the brake chopper, or a TVS (SupplyParams: not both).
        tvs = np.asarray(sup.tvs_breakdown_v) > 0
        clamp_ohm = np.where(tvs, sup.tvs_resistance_ohm, sup.brake_resistor_ohm)
        clamp_v = np.where(tvs, sup.tvs_breakdown_v, sup.brake_on_v)
        clamp_off_v = np.where(tvs, sup.tvs_breakdown_v, 0.0)
        if self.on:
            columns = {
                S_VS: sup.voltage_v, S_RS: sup.source_resistance_ohm, S_C: sup.capacitance_f,
                S_LOAD: sup.logic_load_a, S_RB: clamp_ohm, S_VB: clamp_v, S_VOFF: clamp_off_v,
                S_OV_OFF: br.ov_lockout_v, S_OV_ON: br.ov_release_v, S_UV_OFF: br.uv_lockout_v,
                S_UV_ON: br.uv_release_v, S_VREF: sup.voltage_v,
                S_VD2: sup.voltage_v + 2.0 * br.diode_drop_v, S_H: h_s / self.substeps,
                S_QUIET: sup.bus_quiet_v, S_L: params.motor.l_h, S_ICL: br.current_limit_a,
            }  # fmt: skip
            for col, value in columns.items():
                cfg[:, col] = per_member(value, n)
        self.cfg = cfg
        # (SUB_*): the sub-step's table level in a plant whose step is the whole period.
        self.substep_level = self.substeps.bit_length() - 1
        self.sub = np.array([0, self.substeps, 0, self.substep_level, 0, 0], dtype=np.int64)
        self.xs = np.empty((size, 5))
        self.d_eff = np.empty(size)
        self.en_eff = np.empty(size, dtype=bool)
        self.v_mid = np.empty(size)
        self.v_sum = np.empty(size)
        # The armature's mean current of each member's last period (the adaptive step's
        # predictor of the rail; A).
        self.i_hint = np.zeros(size)
        # The adaptive step's per-member state (ST_*), accepted whole steps (state, end
        # modes, rail), and the modes at the period's start.
        self.state = np.zeros(size, dtype=np.int64)
        self.xw = np.empty((size, 5))
        self.keys0 = np.zeros(size, dtype=np.int64)
        self.keys_w = np.zeros(size, dtype=np.int64)
        self.v_w = np.empty(size)
        # The board's bus-voltage channel: volts per ADC count through the divider.
        sense = params.current_sense
        self.v_per_count = per_member(
            sense.adc_vref_v / (1 << sense.adc_bits) * sup.sense_divider_ratio, n
        )

    def kernel_args(self) -> tuple[np.ndarray, ...]:
        """The ``bus`` tuple ``step_period`` and ``read_bus_adc`` take."""
        return (
            self.v, self.locked, self.cfg, self.sub, self.xs, self.d_eff, self.en_eff,
            self.v_mid, self.v_sum, self.v_per_count, self.i_hint, self.state, self.xw,
            self.keys0, self.keys_w, self.v_w,
        )  # fmt: skip
