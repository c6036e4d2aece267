"""The IS-pin offset calibration at enable (``[controller.current] sense_calibration``).

The BTN7971's IS pin sources an offset current ``I_ISH`` while its high side conducts, load
or not (up to 200 uA: 1.7 A of the firmware's current scale at k_ILIS 8,500). A real board
measures it where the load current is known to be zero: at enable, both high sides on (both
motor terminals at the supply, no voltage across the motor: at rest no current flows),
read the IS pins, keep the mean, subtract it from every later reading. With the bridge off
the pins carry nothing and a calibration would read 0 (``sim/bridge.py``).

The sequence, per member, in current-loop periods (``C_CAL_LEFT`` counts it down):

1. ``SetEnable`` (or the power-up enable with ``start_enabled``) sets ``C_CAL_LEFT`` to
   ``samples + 1`` (``Firmware._start_calibration``); the bridge's high sides turn on at
   the end of that period (``sim.bridge.apply_bridge`` reads ``C_CAL_LEFT``: nonzero, both
   high sides), so that period's reading is not used;
2. ``samples`` periods (16 by default: 32 ms at one current loop per servo tick): each
   reads one pin, chosen by the parity of ``C_CAL_LEFT`` (even: the pin of the half-bridge
   that drives positive current, odd: the other's), into ``C_CAL_SUM_A`` / ``_B``. The
   control law's output is held at zero (no duty, no integration) meanwhile;
3. the last reading ends it (``C_CAL_LEFT`` 0): ``calibration_step`` returns True and the
   firmware's Python (``Firmware._calibration_done``) judges the sums: each pin's mean is
   that pin's offset (``C_SENSE_OFFSET_A`` / ``_B``; the two pins are two chips, whose
   offsets differ), subtracted from the readings taken from it. A member whose axis
   turns faster than ``K_CAL_MAX_VEL`` during it is abandoned at once (``C_CAL_SUM_A`` -1).

Why 16 readings (8 per pin): the mean of n readings of an ADC with ``s`` LSB rms of noise is
within ``s / sqrt(n)`` of the offset; with the STM32F103's 1-2 LSB that is 0.35-0.7 count at
8, about the half count the firmware's integer offset rounds to anyway, and 32 ms is short
against an operator's enable and long against the pin's settling (microseconds). Twice as
many readings would halve the noise term's variance for another 32 ms; it is a setting.
"""

from __future__ import annotations

import numpy as np

from firmware_model.kernel_cache import kernel
from firmware_model.laws.float64 import _reset_member
from firmware_model.laws.layout import (
    C_CAL_LEFT,
    C_CAL_SUM_A,
    C_CAL_SUM_B,
    K_CAL_MAX_VEL,
    K_CAL_SAMPLES,
    K_DELAY,
    P_IMEAS,
    P_VEL,
    S_IMEAS,
)

__all__ = ["calibration_step", "judge"]


@kernel
def calibration_step(adc, P, C, S, K):
    """One current-loop period of the calibration for the members calibrating
    (``C_CAL_LEFT`` > 0), after the law's step: take the reading (``adc``, int ``(N,)``)
    into the sum of its pin, count down, and hold the member's control output at zero (its
    duty, integrators, references and compute-delay pipeline, as a disabled member's).
    Returns True when a member finished (or was abandoned) this period."""
    n_samples = np.int64(K[K_CAL_SAMPLES])
    max_vel = K[K_CAL_MAX_VEL]
    delay = np.int64(K[K_DELAY])
    done = False
    for j in range(adc.shape[0]):
        left = C[C_CAL_LEFT, j]
        if left <= 0:
            continue
        if abs(P[P_VEL, j]) > max_vel:
            C[C_CAL_SUM_A, j] = -1  # the axis turns: abandoned
            left = 0
        else:
            if left <= n_samples:  # (the first period's reading is from before the state)
                if left % 2 == 0:
                    C[C_CAL_SUM_A, j] += adc[j]
                else:
                    C[C_CAL_SUM_B, j] += adc[j]
            left -= 1
        C[C_CAL_LEFT, j] = left
        _reset_member(j, P, C, S, delay)
        S[S_IMEAS, j] = 0
        P[P_IMEAS, j] = 0.0
        if left == 0:
            done = True
    return done


def judge(
    sum_a: np.ndarray,
    sum_b: np.ndarray,
    samples: int,
    pin_counts: int,
    max_counts: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The outcome of finished calibrations: ``(offset_a, offset_b, reason)``, int ``(N,)``
    each.

    ``offset_a`` / ``offset_b``: each pin's mean (``samples / 2`` readings each) rounded to a
    count (half up, integer arithmetic as on the MCU); 0 for an abandoned member. ``reason``:
    0 accepted, ``MOVED`` (abandoned, or the two pins' means differ by more than
    ``pin_counts``: more than two offsets can differ, a loop current flows, the motor turns),
    ``IMPLAUSIBLE`` (a pin's offset above ``max_counts``)."""
    sum_a = np.asarray(sum_a, dtype=np.int64)
    sum_b = np.asarray(sum_b, dtype=np.int64)
    half = samples // 2
    offset_a = (2 * sum_a + half) // (2 * half)
    offset_b = (2 * sum_b + half) // (2 * half)
    # |mean_a - mean_b| > pin_counts, in integers
    moved = (sum_a < 0) | (np.abs(sum_a - sum_b) > pin_counts * half)
    high = np.maximum(offset_a, offset_b) > max_counts
    reason = np.where(moved, MOVED, np.where(high, IMPLAUSIBLE, 0))
    return np.where(sum_a < 0, 0, offset_a), np.where(sum_a < 0, 0, offset_b), reason


#: ``judge``'s reasons.
MOVED, IMPLAUSIBLE = 1, 2
