"""Classic tuning formulas, for comparison with the optimiser.

* Current loop from a bandwidth ``bw_rad_s`` (default: the firmware's ``bw Ts = 0.3``):
  ``Kp = bw L``, ``Ki = Kp R / L`` (the PI zero cancels the armature pole R/L; the open loop
  is then ``bw / s``).
* Velocity loop by the symmetric optimum (Kessler, a = 2) around the sum of the small lags
  ``T_sigma`` (compute delay, the current loop, the hold and the observer), on the rigid
  plant ``Kt / (J s)``: ``Kp = 1 / (a K T_sigma)`` with ``K`` the axis acceleration per
  ampere, ``Ti = a^2 T_sigma``; crossover at ``1 / (a T_sigma)``.
* Position loop: P at a quarter of the velocity crossover (the usual cascade spacing).

All plant numbers come from ``linear.LinearPlant.from_bench`` (the bench's plant tables).

:func:`firmware_model_for` gives the firmware's own plant model (the resistive, back-EMF and
inertia feed-forward terms) for the bench's motor, as ``firmware_model.params.NOMINAL`` is
derived from the data sheet of the assumed one; :func:`classic` is the whole classic set.
"""

from __future__ import annotations

from firmware_model.params import CURRENT_BW_TS
from sim.config import BenchConfig
from sim.tuning.gains import GainSet
from sim.tuning.linear import LinearPlant

__all__ = [
    "classic",
    "current_from_bandwidth",
    "firmware_model_for",
    "symmetric_optimum",
    "t_sigma_s",
]


def current_from_bandwidth(
    bench: BenchConfig, gains: GainSet, bw_rad_s: float | None = None
) -> GainSet:
    """``gains`` with the current PI from a bandwidth (default ``CURRENT_BW_TS / Ts`` =
    0.3 / Ts, as the firmware derives its default gains: with one period of compute delay,
    0.5 / Ts left a gain margin of 1.42 and a phase margin of 26 deg on this module's linear
    model, below the tuner's own ``MarginSpec``; 0.3 / Ts gives 2.4 and 52 deg)."""
    plant = LinearPlant.from_bench(bench)
    servo = bench.firmware.servo
    ts_s = servo.dt_s / servo.current_loop_multiple
    bw = CURRENT_BW_TS / ts_s if bw_rad_s is None else float(bw_rad_s)
    kp = bw * plant.l_h
    return gains.replace(kp_i_v_per_a=kp, ki_i_v_per_as=kp * plant.r_ohm / plant.l_h)


def t_sigma_s(bench: BenchConfig) -> float:
    """Sum of the small lags of the velocity loop: the compute delay and the hold
    (``d + 0.5`` ticks), the current loop's delayed-reference response (one current period
    per tick), the sample (one tick) and the observer (``1 / bandwidth``)."""
    servo = bench.firmware.servo
    ts = servo.dt_s
    d = servo.compute_delay_ticks
    return (
        (d + 0.5) * ts
        + ts / servo.current_loop_multiple
        + ts
        + 1.0 / (bench.firmware.estimator.bandwidth_rad_s)
    )


def symmetric_optimum(bench: BenchConfig, gains: GainSet, a: float = 2.0) -> GainSet:
    """``gains`` with the velocity PI by the symmetric optimum and the position P at a
    quarter of the velocity crossover."""
    plant = LinearPlant.from_bench(bench)
    ts = t_sigma_s(bench)
    kp_v = 1.0 / (a * plant.accel_dps2_per_a * ts)
    ki_v = kp_v / (a * a * ts)
    kp_p = 1.0 / (a * ts) / 4.0
    return gains.replace(kp_v_a_per_dps=kp_v, ki_v_a_per_deg=ki_v, kp_p_per_s=kp_p)


def classic(bench: BenchConfig, gains: GainSet) -> GainSet:
    """The "classic" baseline: ``gains`` with the current PI from the default bandwidth,
    the velocity PI by the symmetric optimum and the position P a quarter of its crossover
    (what ``turntable-sim tune`` reports as "classic")."""
    return symmetric_optimum(bench, current_from_bandwidth(bench, gains))


def firmware_model_for(bench: BenchConfig) -> dict[str, float]:
    """The firmware's feed-forward model of ``bench``'s plant, ``{"table.key": value}``
    overrides: the armature resistance (``[controller.current] resistance_ohm``, the
    motor's own, as the firmware's nominal model takes it), the back-EMF constant per axis
    deg/s and the inertia feed-forward ``J_eq / Kt`` (A per axis deg/s^2, ``J_eq`` the motor
    plus the platter reflected at the gearbox efficiency). On the paper bench these are the
    firmware's defaults (to rounding). The observer's ``Kt / J`` (``[estimator]
    accel_per_amp_dps2``) is left alone: the batch takes it as one number for all members.
    """
    plant = LinearPlant.from_bench(bench)
    return {
        "controller.current.resistance_ohm": float(bench.plant.motor.r_ohm),
        "controller.current.back_emf_v_per_dps": plant.ke_v_per_dps,
        "controller.velocity.acc_ff_a_per_dps2": 1.0 / plant.accel_dps2_per_a,
    }
