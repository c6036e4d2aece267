"""A two-node lumped thermal network, written once: the plant's motor (``sim.thermal``) and
the firmware's estimate of it (``firmware_model.safety.thermal_protection``) both step it.

Nodes: the winding (temperature ``T_w``, capacity ``C_w``) and the housing (``T_h``,
``C_h``); the winding loses heat to the housing through ``R_wh``, the housing to the
ambient ``T_a`` through ``R_ha`` (K/W)::

    C_w dT_w/dt = P_w - (T_w - T_h) / R_wh
    C_h dT_h/dt = P_h + (T_w - T_h) / R_wh - (T_h - T_a) / R_ha

``P_w`` (W) heats the winding (its copper loss), ``P_h`` the housing. With the inputs held
over a step ``h`` the exact step is ``T' = Phi T + Gamma (P_w, P_h, T_a)``
(``network_zoh``: the exponential of the augmented 5 x 5 matrix), six multiply-adds per
member (``network_step``). A catalogue gives the two thermal time constants and the two
resistances (maxon's lines "thermal resistance winding-housing / housing-ambient",
"thermal time constant winding / motor", the constants being "the product of thermal
capacity and given heat resistances"): ``C_w = tau_w / R_wh``, ``C_h = tau_h / R_ha``.
"""

from __future__ import annotations

import numpy as np

from firmware_model.kernel_cache import kernel

__all__ = [
    "N_NET", "N_TP", "network_advance", "network_step", "network_zoh", "protection_constants",
    "steady_rise_k",
    "thermal_protection",
]  # fmt: skip

# A step's numbers: Phi (2 x 2, row-major), then Gamma (2 x 3 row-major: P_w, P_h, T_a).
N_NET = 10


def _expm(m: np.ndarray) -> np.ndarray:
    """exp(m) of a small matrix: scaling and squaring around a Taylor series (the network's
    step matrix has a tiny norm; no BLAS threads for a 5 x 5 product)."""
    norm = float(np.max(np.sum(np.abs(m), axis=0)))
    s = max(0, int(np.ceil(np.log2(norm / 0.25)))) if norm > 0.25 else 0
    a = m / (1 << s)
    out = np.eye(m.shape[0])
    term = np.eye(m.shape[0])
    for k in range(1, 30):
        term = np.einsum("ij,jk->ik", term, a) / k
        out = out + term
        if float(np.max(np.abs(term))) <= 1e-18:
            break
    for _ in range(s):
        out = np.einsum("ij,jk->ik", out, out)
    return out


def network_zoh(
    r_wh_k_w: float, r_ha_k_w: float, tau_w_s: float, tau_h_s: float, h_s: float
) -> np.ndarray:
    """The exact step of the network over ``h_s`` with its inputs held: ``(10,)`` =
    ``Phi`` row-major (4) then ``Gamma`` row-major (2 x 3: P_w, P_h, T_a)."""
    c_w, c_h = tau_w_s / r_wh_k_w, tau_h_s / r_ha_k_w
    g_wh, g_ha = 1.0 / r_wh_k_w, 1.0 / r_ha_k_w
    m = np.zeros((5, 5))
    m[0, 0], m[0, 1], m[0, 2] = -g_wh / c_w, g_wh / c_w, 1.0 / c_w
    m[1, 0], m[1, 1] = g_wh / c_h, -(g_wh + g_ha) / c_h
    m[1, 3], m[1, 4] = 1.0 / c_h, g_ha / c_h
    e = _expm(m * h_s)
    return np.concatenate([e[:2, :2].ravel(), e[:2, 2:].ravel()])


def steady_rise_k(p_w: float, p_h: float, r_wh_k_w: float, r_ha_k_w: float) -> tuple[float, float]:
    """Steady temperature rises above ambient (K) of winding and housing for held powers."""
    rise_h = (p_w + p_h) * r_ha_k_w
    return rise_h + p_w * r_wh_k_w, rise_h


@kernel(inline="always")
def network_advance(tw, th, p_w, p_h, t_a, net, at):
    """``(T_w, T_h)`` (degC) one step on from ``(tw, th)`` with the powers ``p_w``, ``p_h``
    (W) and the ambient ``t_a`` held; ``net[at:at + N_NET]``: ``network_zoh``'s numbers
    (an array, or a tuple of the ten: a loop's stores into the array would have the
    compiled code read them again for every member)."""
    return (
        net[at] * tw + net[at + 1] * th + net[at + 4] * p_w + net[at + 5] * p_h
        + net[at + 6] * t_a,
        net[at + 2] * tw + net[at + 3] * th + net[at + 7] * p_w + net[at + 8] * p_h
        + net[at + 9] * t_a,
    )  # fmt: skip


@kernel
def network_step(temps, j, p_w, p_h, t_a, net):
    """Advance member ``j``'s ``temps[j] = (T_w, T_h)`` (degC) by one step with the powers
    ``p_w``, ``p_h`` (W) and the ambient ``t_a`` held; ``net``: ``network_zoh``'s (10,)."""
    temps[j, 0], temps[j, 1] = network_advance(temps[j, 0], temps[j, 1], p_w, p_h, t_a, net, 0)


# The thermal protection's constants (``tp``, shared by the members): the network's step
# over one servo tick (``N_NET``), then these.
(
    TP_ON, TP_ALPHA, TP_REF_C, TP_AMBIENT_C, TP_NO_LOAD_A, TP_DERATE_C, TP_TRIP_C, TP_MIN_RATIO,
    TP_FF_R, TP_MAGNET, TP_FF_EMF,
) = range(N_NET, N_NET + 11)  # fmt: skip
N_TP = N_NET + 11
# The temperature the firmware's resistance ([controller.current] resistance_ohm) is given at.
REFERENCE_C = 20.0
# The bounds of the feed-forward resistance's relative rise alpha (T_est - T_ambient): the
# factor 1 + rise stays within [0.5, 2] (copper 127 K below to 254 K above its power-up
# temperature), so that R_nom times it stays a Q8.24 number for R_nom up to 64 Ohm in the
# fixed-point law.
R_RISE_MIN, R_RISE_MAX = -0.5, 1.0
# The bounds of the back-EMF constant's relative change beta (T_est - T_ambient): the factor
# stays within [0.5, 1.5] (a ferrite magnet 250 K above its power-up temperature at -0.2 %/K
# is still inside), a positive Q8.24 number in the fixed-point law.
EMF_RISE_MIN, EMF_RISE_MAX = -0.5, 0.5


def protection_constants(safety: object, dt_s: float) -> np.ndarray:
    """``tp`` of ``thermal_protection`` from ``[safety]`` (``SafetyParams``) at tick ``dt_s``."""
    s = safety
    tp = np.zeros(N_TP)
    tp[:N_NET] = network_zoh(
        s.thermal_r_winding_housing_k_w, s.thermal_r_housing_ambient_k_w,
        s.thermal_tau_winding_s, s.thermal_tau_housing_s, dt_s,
    )  # fmt: skip
    tp[N_NET:] = (
        1.0 if s.thermal_protection else 0.0, s.thermal_alpha_cu_per_k, REFERENCE_C,
        s.thermal_ambient_c, s.thermal_no_load_current_a, s.thermal_derate_c, s.thermal_trip_c,
        s.thermal_derate_min_ratio, 1.0 if s.thermal_ff_resistance else 0.0,
        s.thermal_magnet_tc_per_k, 1.0 if s.thermal_ff_back_emf else 0.0,
    )  # fmt: skip
    return tp


@kernel
def thermal_protection(
    i_meas_a, vel_dps, enabled, r_ohm, emf_v_per_dps, fs, at, derate, rise, emf_rise
):
    """The firmware's thermal protection, one servo tick for every member. ``fs[at:]``
    holds its constants (``tp``: ``N_TP`` numbers, the ``TP_*`` offsets from ``at``), then
    each member's estimate of the winding and housing temperatures (degC, two numbers per
    member), which advances through the
    network with ``i_meas^2 R(T_est)`` into the winding (the current it measured, or its
    model's where the sense is blind) and the no-load current times the back-EMF (``emf
    * |v|``, the friction loss a datasheet's no-load current stands for) into the housing;
    ``derate[j]`` (the law's ``P_DERATE``) becomes the fraction of the current limit taken
    away: 0 up to ``TP_DERATE_C``, rising linearly to ``1 - TP_MIN_RATIO`` at ``TP_TRIP_C``;
    with ``TP_FF_R`` set, ``rise[j]`` (the law's ``P_R_RISE``) becomes the winding
    resistance's relative rise since power-up at the new estimate, ``alpha (T_est -
    T_ambient)`` within ``[R_RISE_MIN, R_RISE_MAX]``, which the current loop's feed-forward R
    follows (its ``R_nom`` is the power-up value: the assumed ambient is the protection's
    worst case, not a measurement, and would bias the feed-forward); with ``TP_FF_EMF`` set,
    ``emf_rise[j]`` (the law's ``P_EMF_RISE``) likewise becomes the back-EMF constant's
    relative change, ``beta (T_est - T_ambient)`` within ``[EMF_RISE_MIN, EMF_RISE_MAX]``
    (``beta``: the magnets' remanence coefficient, ``TP_MAGNET``), which the current loop's
    back-EMF feed-forward and its regenerative clamp follow.
    Returns True if an enabled member's estimate reached ``TP_TRIP_C`` (the ``THERMAL``
    trip). It knows nothing of the plant's temperatures."""
    lo, hi = fs[at + TP_DERATE_C], fs[at + TP_TRIP_C]
    depth = 1.0 - fs[at + TP_MIN_RATIO]
    # The constants as locals: the loop writes the estimate into fs, so the compiled code
    # would read each of them again for every member (it cannot tell the indices apart).
    alpha, ref_c, ambient_c = fs[at + TP_ALPHA], fs[at + TP_REF_C], fs[at + TP_AMBIENT_C]
    no_load_a, magnet = fs[at + TP_NO_LOAD_A], fs[at + TP_MAGNET]
    ff_r, ff_emf = fs[at + TP_FF_R] != 0.0, fs[at + TP_FF_EMF] != 0.0
    # The network's step too (a tuple: network_advance reads it at 0 on).
    net = (
        fs[at], fs[at + 1], fs[at + 2], fs[at + 3], fs[at + 4], fs[at + 5], fs[at + 6],
        fs[at + 7], fs[at + 8], fs[at + 9],
    )  # fmt: skip
    hit = False
    for j in range(derate.shape[0]):
        w = at + N_TP + 2 * j
        i = i_meas_a[j]
        r = r_ohm[j] * (1.0 + alpha * (fs[w] - ref_c))
        p_h = no_load_a * abs(vel_dps[j] * emf_v_per_dps[j])
        fs[w], fs[w + 1] = network_advance(fs[w], fs[w + 1], i * i * r, p_h, ambient_c, net, 0)
        t_w = fs[w]
        if ff_r:
            up = alpha * (t_w - ambient_c)
            rise[j] = min(max(up, R_RISE_MIN), R_RISE_MAX)
        if ff_emf:
            up = magnet * (t_w - ambient_c)
            emf_rise[j] = min(max(up, EMF_RISE_MIN), EMF_RISE_MAX)
        if t_w <= lo:
            derate[j] = 0.0
        elif t_w >= hi:
            derate[j] = depth
            if enabled[j]:
                hit = True
        else:
            derate[j] = depth * (t_w - lo) / (hi - lo)
    return hit
