"""Gearbox (80:1, efficiency, backlash), 17 -> 85 timing belt and the platter.

The motor and the gearbox output (the *axis*, carrying the 17T pulley) are rigid apart from
the gearbox backlash; the belt is a spring-damper to the platter. With the output shaft's
inertia neglected, backlash and belt combine into a dead-zone spring on the *twist*
``delta = theta_m / (Ng * Nb) - theta_p`` (platter radians), with total gap
``b = backlash_deg / Nb``:

    tau_belt = k (delta - b/2) + c d(delta)/dt     for delta >  b/2
    tau_belt = 0                                   for |delta| <= b/2
    tau_belt = k (delta + b/2) + c d(delta)/dt     for delta < -b/2

``tau_belt`` acts on the platter; the motor feels ``tau_belt / (N eta)`` while it drives the
load (``tau_belt * w_m > 0``) and ``tau_belt * eta / N`` while the load drives it back, so the
gearbox always loses power.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sim.params import PlantParams

__all__ = ["belt_torque_nm", "gap_rad", "load_factor", "resonance_hz", "stuck_at_rest"]


def gap_rad(params: PlantParams) -> float:
    """Total backlash gap on the twist coordinate (platter radians)."""
    return math.radians(params.gearbox.backlash_deg) / params.belt.ratio


def belt_torque_nm(twist_rad: Any, twist_rate_rad_s: Any, params: PlantParams) -> Any:
    """Torque of the belt on the platter (N*m), zero inside the backlash gap. Vectorised."""
    half = 0.5 * gap_rad(params)
    k, c = params.belt.stiffness_nm_rad, params.belt.damping_nm_s_rad
    spring = np.where(
        twist_rad > half, twist_rad - half, np.where(twist_rad < -half, twist_rad + half, 0.0)
    )
    contact = np.abs(twist_rad) > half
    return np.where(contact, k * spring + c * twist_rate_rad_s, 0.0)


def load_factor(belt_torque_nm: Any, motor_vel_rad_s: Any, params: PlantParams) -> Any:
    """Motor-side torque per N*m of belt torque: 1/(N eta) driving, eta/N back-driven."""
    n, eta = params.total_ratio, params.gearbox.efficiency
    back = belt_torque_nm * motor_vel_rad_s < 0
    return np.where(back, eta / n, 1.0 / (n * eta))


def resonance_hz(params: PlantParams) -> float:
    """Undamped belt resonance of the two-mass system, motor side free (Hz).

    ``w^2 = k (1/J_p + 1/(N^2 eta J_m))`` with the motor driving (efficiency in the reflected
    coupling). The armature circuit and damping shift the real peak slightly; see the tests.
    """
    n, eta = params.total_ratio, params.gearbox.efficiency
    k = params.belt.stiffness_nm_rad
    w2 = k * (1.0 / params.platter.j_kgm2 + 1.0 / (n * n * eta * params.motor.j_kgm2))
    return math.sqrt(w2) / (2.0 * math.pi)


def stuck_at_rest(motor_torque_nm: float, belt_torque_nm: float, params: PlantParams) -> bool:
    """Whether a motor at rest stays there: its torque lies between the load it meets
    turning with the belt torque (``tau / (N eta)``, driving) and against it (``eta tau /
    N``, driven). There the gearbox's load-dependent friction holds it (Filippov's sliding
    motion on the power-flow switch of ``load_factor``)."""
    if belt_torque_nm == 0.0:
        return False
    n, eta = params.total_ratio, params.gearbox.efficiency
    drive, back = belt_torque_nm / (n * eta), belt_torque_nm * eta / n
    return min(drive, back) <= motor_torque_nm <= max(drive, back)
