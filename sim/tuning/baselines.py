"""Classic tuning formulas, for comparison with the optimiser.

* Current loop from a bandwidth ``bw_rad_s``: ``Kp = bw L``, ``Ki = Kp R / L`` (the PI zero
  cancels the armature pole R/L; the open loop is then ``bw / s``).
* Velocity loop by the symmetric optimum (Kessler, a = 2) around the sum of the small lags
  ``T_sigma`` (compute delay, the current loop, the hold and the observer), on the rigid
  plant ``Kt / (J s)``: ``Kp = 1 / (a K T_sigma)`` with ``K`` the axis acceleration per
  ampere, ``Ti = a^2 T_sigma``; crossover at ``1 / (a T_sigma)``.
* Position loop: P at a quarter of the velocity crossover (the usual cascade spacing).

All plant numbers come from ``linear.LinearPlant.from_bench`` (the bench's plant tables).
"""

from __future__ import annotations

from sim.config import BenchConfig
from sim.tuning.gains import GainSet
from sim.tuning.linear import LinearPlant

__all__ = ["current_from_bandwidth", "symmetric_optimum", "t_sigma_s"]


def current_from_bandwidth(
    bench: BenchConfig, gains: GainSet, bw_rad_s: float | None = None
) -> GainSet:
    """``gains`` with the current PI from a bandwidth (default ``0.5 / Ts``, the most a
    loop with one tick of compute delay supports with ~60 deg phase margin)."""
    plant = LinearPlant.from_bench(bench)
    servo = bench.firmware.servo
    ts_s = servo.dt_s / servo.current_loop_multiple
    bw = 0.5 / ts_s if bw_rad_s is None else float(bw_rad_s)
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
