"""The motor's heat (``[thermal] model``): winding temperature, R(T), Kt(T).

The motor is a two-node lumped network (``firmware_model.thermal``: winding -> housing ->
ambient). Its inputs over a current-loop period of length ``h``, held:

    P_w = R_m(T_w) * mean(i^2),   mean(i^2) = (i0^2 + i0 i1 + i1^2) / 3
    P_h = f * mean(w * T_f(w)),   T_f = b_m w + T_c sat(w / w_b)    (the motor's own friction)

``R_m(T) = R_ref (1 + alpha_cu (T - T_ref))``; ``i0``, ``i1`` the armature current at the
period's ends (``mean(i^2)`` is exact for a current linear over the period); ``f`` =
``friction_heat_fraction`` of the brushes' and bearings' loss that ends up in the housing
(the gearbox's drag heats the gearbox: not modelled).

The electrical and mechanical plant (``sim.plant``) is exact per mode for *constant*
coefficients. R, K_t and K_e now depend on the winding temperature, which moves by
millikelvin per period against the 2 ms step. The step matrices are built for the winding
temperature rounded to ``matrix_step_k`` (0.1 K by default): each rounded temperature is a
parameter set of the plant (``Plant.add_group``), made the first time a member's winding
reaches it and shared by every member with the same base parameters. A period takes the set
of its starting temperature (``heat_groups``, called before the plant step); the
temperatures advance after it (``heat_advance``). The rounding's error and the held inputs'
are measured against ``sim.oracle`` (docs/model.md, "Heat").

Kernel arrays (``Heat.kernel_args``; empty with the model off, and the kernels are then not
called): ``temps`` ``(N, 2)`` (T_w, T_h, degC), ``cfg`` ``(N, N_HEAT)``, ``table``
``(B, n_bins)`` the parameter set of each base set and rounded temperature (-1: not made
yet), ``base`` ``(N,)`` each member's base set, ``need`` ``(2,)`` the (member, bin) a
kernel asks the caller to make.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from firmware_model.kernel_cache import kernel
from firmware_model.thermal import N_NET, network_step, network_zoh
from sim.params import T_MAX_C, T_MIN_C, PlantParams, per_member
from sim.plant_kernel import key

if TYPE_CHECKING:
    from sim.plant import Plant

__all__ = ["Heat", "heat_advance", "heat_groups"]

# cfg columns after the network's N_NET numbers.
(
    H_AMB, H_RM, H_ALPHA, H_TREF, H_FRIC, H_TCM, H_BM, H_WBM, H_STEP,
) = range(N_NET, N_NET + 9)  # fmt: skip
N_HEAT = N_NET + 9
_MECH = 225  # sim.plant.MECH_MODES


@kernel
def _bin(t_w, step, n_bins):
    """The rounded-temperature index of a winding at ``t_w`` (clipped to the model's range)."""
    b = int(np.floor((t_w - T_MIN_C) / step + 0.5))
    return min(max(b, 0), n_bins - 1)


@kernel
def heat_groups(x, heat, group, keys, consts):
    """Put each member on the plant's parameter set of its winding's rounded temperature
    (``group[j]``; its known mechanical mode ``keys[j]`` recomputed with the new set).
    Returns True if a set is missing: ``need`` = (member, bin), the caller makes it
    (``Heat.make_group``) and calls again (idempotent: the temperatures do not change)."""
    temps, cfg, table, base, need = heat[0], heat[1], heat[2], heat[3], heat[4]
    n_bins = table.shape[1]
    for j in range(x.shape[0]):
        b = _bin(temps[j, 0], cfg[j, H_STEP], n_bins)
        g = table[base[j], b]
        if g < 0:
            need[0] = j
            need[1] = b
            return True
        if g != group[j]:
            group[j] = g
            k = key(x[j, 0], x[j, 2], x[j, 3], x[j, 4], 0.0, True, consts[g])
            keys[j] = k % _MECH
    return False


@kernel
def _friction_power_w(w, cfg, j):
    """The motor's own friction loss (W) at speed ``w`` (rad/s): w * T_f(w) >= 0."""
    speed = abs(w)
    sat = min(speed / cfg[j, H_WBM], 1.0)
    return speed * (cfg[j, H_BM] * speed + cfg[j, H_TCM] * sat)


@kernel
def heat_advance(x, xn, heat):
    """The temperatures over one period from state ``x`` to ``xn`` (``(N, 5)``): the module
    docstring's powers, held, through the network's exact step."""
    temps, cfg = heat[0], heat[1]
    for j in range(x.shape[0]):
        i0, i1 = x[j, 0], xn[j, 0]
        r = cfg[j, H_RM] * (1.0 + cfg[j, H_ALPHA] * (temps[j, 0] - cfg[j, H_TREF]))
        p_w = r * (i0 * i0 + i0 * i1 + i1 * i1) / 3.0
        p_h = (
            cfg[j, H_FRIC]
            * 0.5
            * (_friction_power_w(x[j, 2], cfg, j) + _friction_power_w(xn[j, 2], cfg, j))
        )
        network_step(temps, j, p_w, p_h, cfg[j, H_AMB], cfg[j])


class Heat:
    """The motor temperatures and the tables ``heat_groups`` / ``heat_advance`` take, one per
    ``Simulation``; with ``[thermal] model`` off, empty arrays (the kernels are not called)."""

    def __init__(self, params: PlantParams, n: int, h_s: float) -> None:
        th = params.thermal
        self.on = bool(th.model)
        self.params = params
        size = n if self.on else 0
        self.temps = np.empty((size, 2))
        self.cfg = np.empty((size, N_HEAT))
        self.base = np.zeros(size, dtype=np.int64)
        self.need = np.zeros(2, dtype=np.int64)
        self.table = np.full((0, 1), -1, dtype=np.int64)
        self.reference_c = per_member(th.reference_c, n)
        if not self.on:
            return
        amb = per_member(th.ambient_c, n)
        self.temps[:, 0] = amb + per_member(th.initial_winding_rise_k, n)
        self.temps[:, 1] = amb + per_member(th.initial_housing_rise_k, n)
        batch = params.batch_size() is not None
        for j in range(n):
            p = params.member(j) if batch else params
            t = p.thermal
            self.cfg[j, :N_NET] = network_zoh(
                t.r_winding_housing_k_w, t.r_housing_ambient_k_w, t.tau_winding_s,
                t.tau_housing_s, h_s,
            )  # fmt: skip
            self.cfg[j, N_NET:] = (
                t.ambient_c, p.motor.r_ohm, t.alpha_cu_per_k, t.reference_c,
                t.friction_heat_fraction, p.motor.coulomb_nm, p.motor.viscous_nm_s_rad,
                p.motor.coulomb_band_rad_s, t.matrix_step_k,
            )  # fmt: skip
        # Members share their base parameter set as the plant does (sim.plant.Plant).
        self.base = np.arange(n, dtype=np.int64) if batch else np.zeros(n, dtype=np.int64)
        bins = int(np.floor((T_MAX_C - T_MIN_C) / np.min(self.cfg[:, H_STEP]) + 0.5)) + 1
        self.table = np.full((n if batch else 1, bins), -1, dtype=np.int64)

    def kernel_args(self) -> tuple[np.ndarray, ...]:
        """The ``heat`` tuple of ``heat_groups`` and ``heat_advance`` (and the reference
        temperature, the log's ``winding_c`` with the model off)."""
        return (self.temps, self.cfg, self.table, self.base, self.need, self.reference_c)

    def bin_temperature_c(self, member: int, b: int) -> float:
        """The rounded winding temperature of bin ``b`` for ``member`` (degC)."""
        return T_MIN_C + b * float(self.cfg[member, H_STEP])

    def make_group(self, plant: Plant) -> None:
        """Make the parameter set ``heat_groups`` asked for (``need``) in ``plant``."""
        j, b = int(self.need[0]), int(self.need[1])
        base = int(self.base[j])
        p = self.params.member(base) if self.params.batch_size() is not None else self.params
        t_c = self.bin_temperature_c(j, b)
        dt = t_c - float(p.thermal.reference_c)
        r_m = float(p.motor.r_ohm) * (1.0 + float(p.thermal.alpha_cu_per_k) * dt)
        mag = 1.0 + float(p.thermal.magnet_tc_per_k) * dt
        co = plant._sets[base]
        self.table[base, b] = plant.add_group(
            replace(
                co, r=r_m + float(p.bridge.r_on_path_ohm), kt=float(p.motor.kt_nm_a) * mag,
                ke=float(p.motor.ke_v_s_rad) * mag,
            )
        )  # fmt: skip

    def winding_c(self) -> np.ndarray:
        """The winding temperatures now, ``(N,)`` (degC): the reference temperature (the
        motor's constants as given) with the model off."""
        return self.temps[:, 0].copy() if self.on else self.reference_c.copy()
