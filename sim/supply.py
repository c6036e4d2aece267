"""The supply rail: a 24 V supply that cannot sink current, the bulk capacitor, the brake
chopper, and the BTN7971B's over- and under-voltage lock-out (``[supply] bus_model``).

The rail (cap voltage ``v``, V) obeys, with ``i_out`` the current the bridge and the logic
draw from it (negative while braking returns energy)::

    C dv/dt = i_sup(v) - i_out - i_brake(v)
    i_sup   = (V_s - v) / R_s   while v < V_s, else 0      (the supply's output diode)
    i_brake = the chopper's current: 0 below V_b; at V_b it holds the rail there while the
              returned current is at most V_b / R_b; above, the resistor is on: v / R_b

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
"""

from __future__ import annotations

import math

import numpy as np

from firmware_model.kernel_cache import kernel
from sim.params import PlantParams, per_member
from sim.plant_kernel import step_members

__all__ = [
    "N_SUPPLY",
    "Bus",
    "bridge_current_a",
    "rail_advance",
    "read_bus_adc",
    "step_period",
]

# cfg[j, ...] columns.
(
    S_VS, S_RS, S_C, S_LOAD, S_RB, S_VB, S_OV_OFF, S_OV_ON, S_UV_OFF, S_UV_ON, S_VREF, S_VD2,
    S_H,
) = range(13)  # fmt: skip
N_SUPPLY = 13


@kernel
def rail_advance(v, i_out, h, vs, rs, c, rb, vb):
    """The rail voltage after ``h`` seconds from ``v`` with ``i_out`` (A, drawn from the
    rail; < 0 returns) held: the exact solution of the rail equation (module docstring),
    across the supply diode's switch at ``vs`` and the chopper's at ``vb`` (``rb`` = 0: no
    chopper)."""
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
            veq = -i_out * rb  # where the resistor alone would hold the rail
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
def _inputs(j, x, duty, enable, v, locked, cfg, d_eff, en_eff, v_mid):
    """Member ``j``'s plant input over the next sub-step: the duty scaled by the rail
    predicted half-way (``v_mid``), or, outputs off, the diode voltage ``v + 2 V_f`` in the
    unit the bus plant's diode modes take (``sim.plant.Coefficients.diode_in``)."""
    conducting = enable[j] and locked[j] == 0
    vs, rs, c, rb, vb = cfg[j, S_VS], cfg[j, S_RS], cfg[j, S_C], cfg[j, S_RB], cfg[j, S_VB]
    i0 = x[j, 0]
    i_pred = bridge_current_a(duty[j], i0, i0, conducting) + cfg[j, S_LOAD]
    vm = rail_advance(v[j], i_pred, 0.5 * cfg[j, S_H], vs, rs, c, rb, vb)
    v_mid[j] = vm
    if conducting:
        d_eff[j] = duty[j] * vm / cfg[j, S_VREF]
        en_eff[j] = True
    else:
        vd2 = cfg[j, S_VD2]
        d_eff[j] = (vm + vd2 - cfg[j, S_VREF]) / vd2
        en_eff[j] = False


@kernel
def step_period(
    x, xn, duty, enable, keys, known, start, group, slots, phis, rates, consts, levels, budget,
    bus, volt, sense_sign,
):  # fmt: skip
    """One current-loop period of the plant (``x`` -> ``xn``, ``(N, 5)``) with the bridge's
    ``duty``/``enable`` held: ``sim.plant_kernel.step_members`` itself without the bus model
    (``bus[0]`` empty), else ``bus_substeps`` sub-steps coupled to the rail (module
    docstring). Returns ``step_members``' ``(next, events, group, need)``; on ``need`` >= 0
    the caller loads the mode and calls again with ``start = next`` (the sub-step reached is
    kept in ``bus``). ``bus = (v, locked, cfg, sub, xs, d_eff, en_eff, v_mid, v_sum, ...)``; with
    the bus model, ``volt`` gets the period's mean bridge output and ``sense_sign`` 0 for a
    locked-out member (its IS pins carry nothing)."""
    v, locked, cfg, sub, xs, d_eff, en_eff, v_mid, v_sum = bus[:9]
    if v.shape[0] == 0:
        return step_members(
            x, duty, enable, keys, known, start, group, slots, phis, rates, consts, levels,
            budget, xn, keys,
        )  # fmt: skip
    n = x.shape[0]
    n_sub = sub[1]
    s = sub[0]
    events = 0
    if s == 0 and start == 0:
        for j in range(n):
            for q in range(5):
                xn[j, q] = x[j, q]
            v_sum[j] = 0.0
    while s < n_sub:
        if start == 0:
            for j in range(n):
                _inputs(j, xn, duty, enable, v, locked, cfg, d_eff, en_eff, v_mid)
        nxt, ev, g, need = step_members(
            xn, d_eff, en_eff, keys, known or s > 0, start, group, slots, phis, rates, consts,
            levels, budget, xs, keys,
        )  # fmt: skip
        events += ev
        if need >= 0:
            sub[0] = s
            return nxt, events, g, need
        start = 0
        for j in range(n):
            vs, rs, c = cfg[j, S_VS], cfg[j, S_RS], cfg[j, S_C]
            i_out = bridge_current_a(duty[j], xn[j, 0], xs[j, 0], en_eff[j]) + cfg[j, S_LOAD]
            vj = rail_advance(v[j], i_out, cfg[j, S_H], vs, rs, c, cfg[j, S_RB], cfg[j, S_VB])
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
    sub[0] = 0
    for j in range(n):
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
        if self.on:
            columns = {
                S_VS: sup.voltage_v, S_RS: sup.source_resistance_ohm, S_C: sup.capacitance_f,
                S_LOAD: sup.logic_load_a, S_RB: sup.brake_resistor_ohm, S_VB: sup.brake_on_v,
                S_OV_OFF: br.ov_lockout_v, S_OV_ON: br.ov_release_v, S_UV_OFF: br.uv_lockout_v,
                S_UV_ON: br.uv_release_v, S_VREF: sup.voltage_v,
                S_VD2: sup.voltage_v + 2.0 * br.diode_drop_v, S_H: h_s / self.substeps,
            }  # fmt: skip
            for col, value in columns.items():
                cfg[:, col] = per_member(value, n)
        self.cfg = cfg
        self.sub = np.array([0, self.substeps], dtype=np.int64)
        self.xs = np.empty((size, 5))
        self.d_eff = np.empty(size)
        self.en_eff = np.empty(size, dtype=bool)
        self.v_mid = np.empty(size)
        self.v_sum = np.empty(size)
        # The board's bus-voltage channel: volts per ADC count through the divider.
        sense = params.current_sense
        self.v_per_count = per_member(
            sense.adc_vref_v / (1 << sense.adc_bits) * sup.sense_divider_ratio, n
        )

    def kernel_args(self) -> tuple[np.ndarray, ...]:
        """The ``bus`` tuple ``step_period`` and ``read_bus_adc`` take."""
        return (
            self.v, self.locked, self.cfg, self.sub, self.xs, self.d_eff, self.en_eff,
            self.v_mid, self.v_sum, self.v_per_count,
        )  # fmt: skip
