"""The brushed DC motor: armature circuit and rotor, with viscous and Coulomb friction.

    L di/dt = v - R i - Ke w            (v: bridge voltage, R includes the bridge path)
    J dw/dt = Kt i - b w - tau_c(w) - tau_load

Coulomb friction is regularised as a saturated linear law, ``tau_c = Tc * clip(w / w_band,
-1, 1)``: exact Coulomb outside the band, a steep viscous law inside it. That keeps the model
piecewise linear (so the plant is discretised exactly per mode) and continuous (so
``solve_ivp`` has a well-posed oracle). See docs/model.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim.params import MotorParams, PlantParams

__all__ = ["friction_torque_nm", "no_load_speed_rad_s", "steady_speed_rad_s"]


def friction_torque_nm(
    vel_rad_s: Any,
    coulomb_nm: Any,
    band_rad_s: Any,
    viscous: Any,
    breakaway_nm: Any = None,
    stribeck_rad_s: Any = None,
) -> Any:
    """Friction torque opposing motion (N*m), vectorised: viscous plus a piecewise-linear
    Coulomb law with stiction. Inside the band ``|w| <= band`` the torque rises linearly to
    the breakaway torque (sticking); between the band and the Stribeck speed it falls
    linearly to Coulomb (the Stribeck drop, a negative slope: stick-slip); beyond, Coulomb.
    Without ``breakaway_nm`` (or equal to Coulomb) it is the saturated Coulomb law."""
    if breakaway_nm is None:
        return coulomb_nm * np.clip(vel_rad_s / band_rad_s, -1.0, 1.0) + viscous * vel_rad_s
    speed = np.abs(vel_rad_s)
    sign = np.sign(vel_rad_s)
    width = np.maximum(stribeck_rad_s - band_rad_s, 1e-300)
    falling = breakaway_nm - (breakaway_nm - coulomb_nm) * (speed - band_rad_s) / width
    magnitude = np.where(
        speed <= band_rad_s,
        breakaway_nm * speed / band_rad_s,
        np.where(speed <= stribeck_rad_s, falling, coulomb_nm),
    )
    return sign * magnitude + viscous * vel_rad_s


def no_load_speed_rad_s(motor: MotorParams, voltage_v: float, r_path_ohm: float = 0.0) -> float:
    """Speed of the bare motor (no gearbox) at ``voltage_v``, with its own friction (rad/s)."""
    r = motor.r_ohm + r_path_ohm
    return (motor.kt_nm_a * voltage_v / r - motor.coulomb_nm) / (
        motor.kt_nm_a * motor.ke_v_s_rad / r + motor.viscous_nm_s_rad
    )


def steady_speed_rad_s(params: PlantParams, duty: float) -> float:
    """Steady motor speed of the whole drive train at a constant positive duty (rad/s).

    Belt in contact, platter friction reflected through the gearbox with its efficiency
    (motor driving), the gearbox's no-load drag at the motor, both friction laws saturated.
    Used by the analytic tests and docs.
    """
    m, p = params.motor, params.platter
    n = params.total_ratio
    eta = params.gearbox.efficiency
    r = m.r_ohm + params.bridge.r_on_path_ohm
    v = duty * params.supply.voltage_v
    load0 = params.motor_coulomb_nm + p.coulomb_nm / (n * eta)
    slope = (
        m.kt_nm_a * m.ke_v_s_rad / r
        + params.motor_viscous_nm_s_rad
        + p.viscous_nm_s_rad / (n * n * eta)
    )
    return (m.kt_nm_a * v / r - load0) / slope
