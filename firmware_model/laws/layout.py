"""The state layout both control laws share: every member's state is a column of a few
``(rows, N)`` arrays, so that a compiled step takes five arrays instead of thirty.

=====  ==========================  ==================================================
array  dtype                       rows
=====  ==========================  ==================================================
``P``  float64                     published signals in axis units (``P_*``)
``C``  int64                       counts and timer steps (``C_*``), then the PWM
                                   compute-delay pipeline (``delay`` rows from
                                   ``C_PIPE``)
``S``  float64 (float law) or      controller and observer state (``S_*``), then the
       int64 Q16.16 (fixed law)    current-reference pipeline (``delay + 1`` rows from
                                   ``S_REF_PIPE``)
``G``  as ``S`` (Q8.24 if fixed)   gains and derived per-member constants (``G_*``)
``K``  float64, 1-D                shared constants (``K_*``) and the pipeline indices
=====  ==========================  ==================================================
"""

from __future__ import annotations

from firmware_model import fixedpoint as fx
from firmware_model.units import AXIS_DEG_PER_COUNT, ENCODER_COUNTS_PER_REV

REV = ENCODER_COUNTS_PER_REV
HALF_REV = REV // 2
# Q16.16 raw units of axis degrees per encoder count (exact: 18).
Q_DEG_PER_COUNT = int(round(AXIS_DEG_PER_COUNT * (1 << fx.SIG_FRAC_BITS)))

# P: published, float axis units. P_DERATE: the fraction of the current limit the thermal
# protection takes away (0: none; firmware_model.thermal.thermal_protection writes it).
# P_R_RISE: the winding resistance's relative rise the same estimate gives, alpha (T_est -
# T_ref), bounded (0: the nominal R; written with [safety] thermal_ff_resistance).
# P_EMF_RISE: the back-EMF constant's relative change at the same estimate, beta (T_est -
# T_ref), bounded (0: the nominal k_emf; written with [safety] thermal_ff_back_emf).
(
    P_POS, P_VEL, P_VEL_RAW, P_VREF, P_IREF, P_IMEAS, P_DUTY, P_DERATE, P_R_RISE, P_EMF_RISE,
) = range(10)  # fmt: skip
N_P = 10
# C: integers.
# C_BUS_ADC: the bus-voltage ADC reading of the period (the board writes it, as the IS pin's).
# C_SENSE_OFFSET_A / _B: the IS readings' offsets (counts) the firmware subtracts, one per
# pin (A: the pin of the half-bridge that drives positive current, read while the duty is
# positive; B: the other's), as configured or as calibrated at the last enable; C_CAL_LEFT:
# the IS-offset calibration's current-loop periods left (0: not calibrating;
# firmware_model.sense_calibration), C_CAL_SUM_A / _B: its sums of the two pins' readings
# (A < 0: abandoned, the axis moved).
(
    C_COUNT, C_RAW_PREV, C_D, C_INNOV, C_STUCK, C_STEPS, C_BUS_ADC, C_SENSE_OFFSET_A,
    C_CAL_LEFT, C_CAL_SUM_A, C_CAL_SUM_B, C_SENSE_OFFSET_B,
) = range(12)  # fmt: skip
C_PIPE = 12
# S: the law's arithmetic (float64 or Q16.16).
S_EP, S_V, S_AD, S_VEL, S_I_V, S_I_I, S_VR, S_IREF, S_IMEAS, S_REF_D_LAST = range(10)
S_REF_PIPE = 10
# G: gains in the law's arithmetic (float64 or Q8.24). G_R_T: the feed-forward's R at the
# thermal estimate, G_R_FF * (1 + P_R_RISE), set by each servo step for the current loop;
# G_EMF_T likewise the back-EMF constant, G_EMF_FF * (1 + P_EMF_RISE).
(
    G_KP_P, G_VFF, G_KP_V, G_KI_V_DT, G_ACC_FF, G_KP_I, G_KI_I_DT, G_R_FF, G_EMF_FF,
    G_KPOS_M1, G_KVEL, G_KDIST, G_K_VEL, G_K_ACC, G_R_T, G_EMF_T,
) = range(16)  # fmt: skip
N_G = 16
# K: shared float constants; the two pipeline indices are stored as floats (exact).
# K_BUS_COMP: 1 = duty from the measured bus voltage; K_V_PER_BUS_ADC(_Q): volts per count
# of it (float, Q8.24); K_REGEN_A: the regenerative bus-current limit (A, 0 = off);
# K_BUS_HOLD: the bus reading (counts) from which the current integrator holds;
# K_CAL_SAMPLES: the IS-offset calibration's readings (even: half of them per pin);
# K_CAL_MAX_VEL: the axis speed (deg/s) above which it is abandoned.
(
    K_DPS_PER_COUNT_TICK, K_A_PER_ADC, K_SENSE_FLOOR, K_U_LIM, K_SUPPLY_V, K_ARR, K_DELAY,
    K_I_LIMIT_A, K_REF_I, K_PIPE_I, K_A_PER_ADC_Q, K_HALF_Q, K_INV_SUPPLY_Q, K_BUS_COMP,
    K_V_PER_BUS_ADC, K_V_PER_BUS_ADC_Q, K_REGEN_A, K_BUS_HOLD, K_CAL_SAMPLES, K_CAL_MAX_VEL,
) = range(20)  # fmt: skip
N_K = 20
