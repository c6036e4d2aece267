"""The BTN7971B H-bridge: averaged PWM voltage, its own current limitation, current sense.

Averaged over a 20 kHz PWM period (50 us, far shorter than L/R = 0.5 ms), the enabled bridge
applies ``duty * V_supply`` with ``duty`` quantised to the timer's ``1/ARR`` steps. Disabled
(both low sides off), the motor current freewheels through the body diodes back into the
supply until it reaches zero. The chip's current limitation (I_CL, tens of A) chops the
high side; averaged, it pins the current at I_CL while the bridge would drive it higher.

Current sense: each half-bridge's IS pin sources ``I_load / k_ILIS`` while its *high side*
conducts, so the sense is unidirectional: the driven half-bridge reports the current that
flows in the driven direction, ``max(0, sign(duty) * i)``; a current against the duty (or in
a disabled bridge) flows through low sides and diodes and reads 0. The firmware rebuilds a
signed current as ``sign(duty) * sensed``.

Both high sides on (the firmware's IS-offset calibration at enable,
``firmware_model.sense_calibration``): both motor terminals at the supply, 0 V across the
motor, the current freewheels through the two high sides (a motor that turns drives its
back-EMF's current ``-K_e w / R`` around that loop). Each IS pin then mirrors its own high
side's forward current plus the offset, ``max(0, +-i) / k_ILIS + I_ISH``; the ADC reads one
pin per current-loop period, the one the firmware picks (``sense_sign`` +2: the pin of the
half-bridge that drives positive current, -2: the other's).

The two pins are two chips': each has its own offset (``[current_sense] is_offset_ua`` their
mean, ``is_offset_mismatch_ua`` their difference); a reading carries the offset of the pin
it is taken from, the one of the half-bridge whose high side switches (the duty's sign).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from firmware_model.kernel_cache import kernel
from sim.params import BridgeParams, CurrentSenseParams

__all__ = [
    "adc_counts", "apply_bridge", "inject_sense_fault", "pwm_sense_table", "quantise_duty",
    "read_adc", "sensed_current_a", "switching", "switching_table",
]  # fmt: skip

I_A = 0  # the current in a plant state (sim.plant)


def quantise_duty(duty: Any, bridge: BridgeParams) -> Any:
    """Clip to [-1, 1] and round to the timer's compare steps (1/ARR). Vectorised."""
    arr = bridge.arr
    return np.round(np.clip(duty, -1.0, 1.0) * arr) / arr


def sensed_current_a(current_a: Any, duty: Any, enable: Any) -> Any:
    """The current the IS pins report (A, >= 0): high-side conduction only. Vectorised."""
    return np.where(enable, np.maximum(0.0, np.sign(duty) * current_a), 0.0)


def adc_counts(sensed_a: Any, sense: CurrentSenseParams, noise_lsb: Any = 0.0) -> Any:
    """12-bit ADC reading of the IS voltage ``sensed_a / k_ILIS * R_IS`` (int, clipped)."""
    full = (1 << sense.adc_bits) - 1
    counts = np.floor(sensed_a / sense.a_per_lsb + 0.5 + noise_lsb)
    return np.clip(counts, 0, full).astype(np.int64)


def switching_table(bridge: BridgeParams, n: int) -> Any:
    """``switching``'s per-member ``(n, 2)`` pulse shifts in duty units (with, against the
    current), or ``(0, 2)`` for the ideal bridge."""
    w, a = bridge.pulse_shift_with_current_us, bridge.pulse_shift_against_current_us
    if np.all(np.asarray(w) == 0) and np.all(np.asarray(a) == 0):
        return np.zeros((0, 2))
    table = np.empty((n, 2))
    table[:, 0] = np.asarray(w) * 1e-6 * bridge.pwm_hz
    table[:, 1] = np.asarray(a) * 1e-6 * bridge.pwm_hz
    return table


@kernel
def switching(x, supply_v, shifts, d_out, sense_sign, volt):
    """The bridge's switching times per member, after ``apply_bridge``: the output pulse is
    ``|duty| / f_pwm + shift`` long, the shift by the current's direction at the start of
    the period (``x``): with the duty (or zero), the high side's delays set both edges
    (BTS7960B datasheet 4.2.2: ``(t_dr + t_r / 2) - (t_df + t_f / 2)`` of the high side);
    against it, the low side's. A pulse shortened to nothing is not switched (duty 0, no
    high side, the IS pin silent). ``shifts``: ``switching_table`` (empty: nothing to do)."""
    if shifts.shape[0] == 0:
        return
    for j in range(d_out.shape[0]):
        d = d_out[j]
        if d == 0.0 or sense_sign[j] == 0.0:
            continue
        shift = shifts[j, 0] if x[j, I_A] * d >= 0.0 else shifts[j, 1]
        m = abs(d) + shift
        m = 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)
        d = m if d > 0.0 else -m
        d_out[j] = d
        if d == 0.0:
            sense_sign[j] = 0.0
        volt[j] = d * supply_v[j]


# read_adc's ``pwm[2]`` columns: the IS offset of the pin of the half-bridge driving positive
# current (A of load current), the sample point, the ripple factor 1 / (L f_pwm) (A per V),
# the settling time and the pin's RC time constant over the PWM period, the other pin's
# offset (A); an injected sense fault (``SENSE_FAULTS``' code, 0 none) and the count a stuck
# reading holds (-1: the next reading's).
PW_OFFSET, PW_SAMPLE, PW_RIPPLE, PW_SETTLE, PW_TAU, PW_OFFSET_NEG, PW_FAULT, PW_HELD = range(8)
N_PW = 8
#: The sense faults ``inject_sense_fault`` can put on a member's IS reading.
SENSE_FAULTS = {"clear": 0.0, "short": 1.0, "stuck": 2.0}


def pwm_sense_table(sense: CurrentSenseParams, bridge: BridgeParams, l_h: Any, n: int) -> Any:
    """``read_adc``'s per-member table ``(n, N_PW)`` of the PWM-level sense, or ``(0, N_PW)``
    when the sense is the averaged one (sample point 0.5, no offset, no settling, no RC)."""
    neutral = (
        np.all(np.asarray(sense.sample_point) == 0.5)
        and np.all(np.asarray(sense.is_offset_ua) == 0)
        and np.all(np.asarray(sense.is_settling_us) == 0)
        and np.all(np.asarray(sense.is_filter_us) == 0)
    )
    if neutral:
        return np.zeros((0, N_PW))
    table = np.empty((n, N_PW))
    mean_ua, half_ua = np.asarray(sense.is_offset_ua), 0.5 * np.asarray(sense.is_offset_mismatch_ua)
    table[:, PW_OFFSET] = (mean_ua + half_ua) * 1e-6 * np.asarray(sense.k_ilis)
    table[:, PW_OFFSET_NEG] = (mean_ua - half_ua) * 1e-6 * np.asarray(sense.k_ilis)
    table[:, PW_SAMPLE] = sense.sample_point
    table[:, PW_RIPPLE] = 1.0 / (np.asarray(l_h) * bridge.pwm_hz)
    table[:, PW_SETTLE] = np.asarray(sense.is_settling_us) * 1e-6 * bridge.pwm_hz
    table[:, PW_TAU] = np.asarray(sense.is_filter_us) * 1e-6 * bridge.pwm_hz
    table[:, PW_FAULT], table[:, PW_HELD] = 0.0, -1.0
    return table


def inject_sense_fault(table: Any, n: int, kind: str, members: Any = None) -> Any:
    """``table`` (``pwm_sense_table``'s) with a fault on the IS reading of ``members`` (all
    if None): ``"short"`` the pin (or its sense resistor) shorted to ground, the ADC reads
    0 V (plus its noise); ``"stuck"`` the reading frozen at the count of the next period;
    ``"clear"`` none. An empty (averaged-sense) table becomes the equivalent full one (the
    sample point 1/2, no offset, settling or RC: the same readings, bit for bit)."""
    if kind not in SENSE_FAULTS:
        raise ValueError(f"sense fault {kind!r}: expected one of {', '.join(SENSE_FAULTS)}")
    if table.shape[0] == 0:
        table = np.zeros((n, N_PW))
        table[:, PW_SAMPLE], table[:, PW_HELD] = 0.5, -1.0
    else:
        table = table.copy()
    rows = slice(None) if members is None else members
    table[rows, PW_FAULT] = SENSE_FAULTS[kind]
    table[rows, PW_HELD] = -1.0
    return table


@kernel
def rc_factor(t_s, t_on, tau):
    """The IS pin's RC low-pass in the PWM's periodic steady state: its voltage at ``t_s``
    after the IS current turns on, per unit of that current, when it is on for ``t_on``
    of each period and off (0) for the rest (times and the time constant ``tau`` in
    periods). From ``v0`` at the turn-on, ``v(t) = 1 - (1 - v0) exp(-t / tau)``; the
    steady state closes the period: ``v0 = (1 - exp(-t_on / tau)) exp(-(1 - t_on) / tau)
    / (1 - exp(-1 / tau))``."""
    v0 = -math.expm1(-t_on / tau) * math.exp(-(1.0 - t_on) / tau) / -math.expm1(-1.0 / tau)
    return 1.0 - (1.0 - v0) * math.exp(-t_s / tau)


@kernel
def read_adc(x, sense_sign, a_per_lsb, noise_lsb, draw, adc_full, out, pwm):
    """The ADC counts of the IS pin per member: ``sim.bridge.sensed_current_a`` (the
    current in the direction of ``sense_sign``, the high side only) through
    ``sim.bridge.adc_counts`` (rounded to nearest, plus noise, clamped to the ADC range).
    ``draw``: one standard normal per member, or nothing for a noiseless ADC.

    ``sense_sign`` +-2 (both high sides on, ``apply_bridge``): the pin of the half-bridge
    that conducts ``sign(sense_sign) * i`` forward, its high side on all period.

    ``pwm = (duty, volt, table)``: the applied duty and mean output voltage ``(N,)`` and
    ``pwm_sense_table``'s ``(N, N_PW)`` (empty: the averaged sense). With it, the pin is read
    at ``sample_point`` of the high side's on-time: the current's PWM ripple, peak to peak
    ``|volt| (1 - |duty|) / (L f_pwm)`` (sign-magnitude, R neglected over a period), shifts
    the reading by ``(sample_point - 1/2)`` of it; a sample within the settling time of
    the turn-on reads nothing; the offset of the pin read (``sense_sign``'s: ``PW_OFFSET``
    positive, ``PW_OFFSET_NEG`` negative) adds while its high side switches; an RC
    low-pass on the pin scales what it reads by ``rc_factor``."""
    noisy = draw.shape[0] > 0
    duty, volt, table = pwm
    fine = table.shape[0] > 0
    for j in range(x.shape[0]):
        v = sense_sign[j] * x[j, I_A]
        c = 0.0 if 0.0 >= v else v  # np.maximum(0.0, v); NaN passes
        if abs(sense_sign[j]) == 2.0:
            # Both high sides on (apply_bridge): the pin's high side conducts all period,
            # no PWM (no ripple, settled, the RC charged): its current plus the offset.
            v = 0.5 * v  # sense_sign is +-2
            c = 0.0 if 0.0 >= v else v
            if fine:
                c = c + table[j, PW_OFFSET if sense_sign[j] > 0.0 else PW_OFFSET_NEG]
        elif fine and sense_sign[j] != 0.0:
            d = abs(duty[j])
            s = table[j, PW_SAMPLE]
            if s * d < table[j, PW_SETTLE]:
                c = 0.0
            else:
                v = v + abs(volt[j]) * (1.0 - d) * table[j, PW_RIPPLE] * (s - 0.5)
                off = table[j, PW_OFFSET if sense_sign[j] > 0.0 else PW_OFFSET_NEG]
                c = (0.0 if 0.0 >= v else v) + off
                tau = table[j, PW_TAU]
                if tau > 0.0:
                    settle = table[j, PW_SETTLE]
                    c = c * rc_factor(s * d - settle, d - settle, tau)
        if fine and table[j, PW_FAULT] == 1.0:
            c = 0.0  # an injected short: 0 V at the ADC
        c = c / a_per_lsb[j] + 0.5
        if noisy:
            c = c + noise_lsb[j] * draw[j]
        c = np.floor(c)
        if c > adc_full:
            c = adc_full
        if c < 0.0:
            c = 0.0
        out[j] = np.int64(c)
        if fine and table[j, PW_FAULT] == 2.0:  # an injected stuck reading
            if table[j, PW_HELD] < 0.0:
                table[j, PW_HELD] = c
            out[j] = np.int64(table[j, PW_HELD])


@kernel
def apply_bridge(duty, enable, high_sides, arr, supply_v, d_out, en_out, sense_sign, volt):
    """The bridge per member: the duty clamped to [-1, 1] on the timer's ``1/arr`` steps
    (``sim.bridge.quantise_duty``, half to even), the enable, the IS pin's sign of the
    next period and the average output voltage (0 while disabled).

    ``high_sides`` (int ``(N,)``, the firmware's ``C_CAL_LEFT`` row; empty: none): nonzero
    turns both high sides on whatever the duty and enable say (the plant sees an enabled
    bridge at duty 0: no voltage across the motor) and picks the IS pin the ADC reads next
    by its parity (``sense_sign`` +2 even, -2 odd; ``read_adc``)."""
    both = high_sides.shape[0] > 0
    for j in range(d_out.shape[0]):
        if both and high_sides[j] != 0:
            d_out[j] = 0.0
            en_out[j] = True
            sense_sign[j] = 2.0 if high_sides[j] % 2 == 0 else -2.0
            volt[j] = 0.0
            continue
        v = duty[j]
        if v < -1.0:
            v = -1.0
        if v > 1.0:
            v = 1.0
        v = np.rint(v * arr[j]) / arr[j]
        e = bool(enable[j])
        d_out[j] = v
        en_out[j] = e
        sign = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else (0.0 if v == 0.0 else v))
        sense_sign[j] = sign if e else 0.0
        volt[j] = v * supply_v[j] if e else 0.0
