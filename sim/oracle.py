"""An independent integration of the plant: ``solve_ivp`` on ``sim.plant.derivative``, the
reference the tests (and anyone checking a change to the plant) replay runs against.

The continuous model has one sliding motion: a motor at rest whose torque lies between the
driving and the back-driven load of the gearbox (``sim.drivetrain.stuck_at_rest``) stays at
rest. An integrator cannot cross that switch of the right-hand side (it chatters there),
so the oracle handles it as an event: it integrates with the power-flow side held
(``derivative(..., motor_dir=+-1)``) up to a terminal event at the zero crossing of the
motor speed; if the state there sticks, with ``motor_dir=0`` until the motor torque leaves
the band (two more events).

With the bus model (``[supply] bus_model``, ``sim.supply``) the state has a sixth entry, the
rail voltage, and the right-hand side is ``derivative_bus``: the bridge applies
``duty * v`` (the rail as it is at every instant, not held), the rail takes the bridge's
current ``duty * i`` (or ``-|i|`` through the diodes) as it is at every instant. The
lock-out comparators are sampled at the ends of the same sub-steps as the simulation's
(part of the model: their response time), so each sub-step is one held-input segment here.

With the heat model (``[thermal] model``, ``sim.thermal``) the state has two more entries,
the winding and housing temperatures (degC), and the right-hand side is ``derivative_heat``:
R, K_t and K_e at the winding's temperature *as it is at every instant* (the simulation
rounds it to ``matrix_step_k`` and holds it over a period), the copper loss ``i^2 R(T)`` and
the motor's friction loss as they are at every instant (the simulation's are held over a
period). The bus and the heat together are not offered.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from sim.drivetrain import belt_torque_nm, stuck_at_rest
from sim.params import PlantParams
from sim.plant import _derivative_one, derivative

__all__ = ["derivative_bus", "derivative_heat", "replay"]


def _motor_at(t_w: float, params: PlantParams) -> tuple[float, float, float]:
    """The motor's (R, K_t, K_e) with its winding at ``t_w`` (degC)."""
    m, th = params.motor, params.thermal
    dt = t_w - th.reference_c
    mag = 1.0 + th.magnet_tc_per_k * dt
    return m.r_ohm * (1.0 + th.alpha_cu_per_k * dt), m.kt_nm_a * mag, m.ke_v_s_rad * mag


def derivative_heat(
    t: float,
    y: np.ndarray,
    u: tuple[float, bool],
    params: PlantParams,
    motor_dir: float | None = None,
) -> np.ndarray:
    """dy/dt of the plant with its motor's heat, ``y`` = the 5 states of ``sim.plant``, the
    winding's and the housing's temperature (degC); the network of
    ``firmware_model.thermal`` written out with its capacities."""
    duty, enable = u
    th, m = params.thermal, params.motor
    t_w, t_h = float(y[5]), float(y[6])
    r_m, kt, ke = _motor_at(t_w, params)
    dx = _derivative_one(y, duty, bool(enable), params, motor_dir, motor_rke=(r_m, kt, ke))
    i, speed = float(y[0]), abs(float(y[2]))
    p_w = i * i * r_m
    sat = min(speed / m.coulomb_band_rad_s, 1.0)
    p_h = th.friction_heat_fraction * speed * (m.viscous_nm_s_rad * speed + m.coulomb_nm * sat)
    r_wh, r_ha = th.r_winding_housing_k_w, th.r_housing_ambient_k_w
    c_w, c_h = th.tau_winding_s / r_wh, th.tau_housing_s / r_ha
    flow = (t_w - t_h) / r_wh
    d_w = (p_w - flow) / c_w
    d_h = (p_h + flow - (t_h - th.ambient_c) / r_ha) / c_h
    return np.append(dx, (d_w, d_h))


def derivative_bus(
    t: float,
    y: np.ndarray,
    u: tuple[float, bool],
    params: PlantParams,
    motor_dir: float | None = None,
    locked: bool = False,
    current_dir: float = 0.0,
) -> np.ndarray:
    """dy/dt of the plant with its rail, ``y`` = the 5 states of ``sim.plant`` and the rail
    voltage (V); ``locked``: the bridge's outputs off (lock-out). The rail law is
    ``sim.supply``'s without a brake chopper (the oracle refuses one), with its TVS if any.
    ``current_dir``
    (+-1, outputs off) holds the diodes' side, as ``motor_dir`` the gearbox's, for an
    integrator that stops at the current's zero as an event."""
    duty, enable = u
    sup, br = params.supply, params.bridge
    v = float(y[5])
    conducting = bool(enable) and not locked
    dx = _derivative_one(y, duty, conducting, params, motor_dir, bus_v=v)
    i = float(y[0])
    if not conducting and current_dir:
        r = params.motor.r_ohm + br.r_on_path_ohm
        emf = params.motor.ke_v_s_rad * float(y[2])
        dx[0] = (-current_dir * (v + 2.0 * br.diode_drop_v) - r * i - emf) / params.motor.l_h
    i_out = duty * i if conducting else -abs(i)
    i_sup = (sup.voltage_v - v) / sup.source_resistance_ohm if v < sup.voltage_v else 0.0
    vt = sup.tvs_breakdown_v
    i_tvs = (v - vt) / sup.tvs_resistance_ohm if 0.0 < vt < v else 0.0
    dv = (i_sup - i_out - sup.logic_load_a - i_tvs) / sup.capacitance_f
    return np.append(dx, dv)


def _belt(y: np.ndarray, params: PlantParams) -> float:
    return float(belt_torque_nm(y[3], y[2] / params.total_ratio - y[4], params))


def _band(y: np.ndarray, params: PlantParams) -> tuple[float, float]:
    tb = _belt(y, params)
    n, eta = params.total_ratio, params.gearbox.efficiency
    a, b = tb / (n * eta), tb * eta / n
    return min(a, b), max(a, b)


def replay(
    params: PlantParams,
    duty: np.ndarray,
    enable: np.ndarray,
    h_s: float,
    x0: np.ndarray | None = None,
    rtol: float = 1e-12,
    atol: float = 1e-14,
    every: int = 1,
) -> np.ndarray:
    """Integrate the plant through ``K`` inputs held ``h_s`` each (``duty``, ``enable``:
    ``(K,)``, as ``sim.loop.Simulation.inputs()`` records them) from ``x0`` (zeros by
    default); returns the states ``(K // every, 5)`` after each ``every``-th input.

    With ``[supply] bus_model`` the states are ``(K // every, 6)``, the rail voltage last
    (``x0`` of 5 entries starts the rail at the supply voltage), each input held over
    ``bus_substeps`` sub-steps with the lock-out sampled at their ends. With ``[thermal]
    model``, ``(K // every, 7)``: the winding's and the housing's temperature last (``x0``
    of 5 entries starts them as ``[thermal]`` says)."""
    bus = bool(params.supply.bus_model)
    heat = bool(params.thermal.model)
    if bus and heat:
        raise ValueError("the oracle takes the bus model or the heat model, not both")
    n_x = 6 if bus else (7 if heat else 5)
    y = np.zeros(n_x) if x0 is None else np.array(x0, dtype=float)
    if heat and (x0 is None or y.shape[0] == 5):
        th = params.thermal
        y = np.append(
            y[:5],
            (th.ambient_c + th.initial_winding_rise_k, th.ambient_c + th.initial_housing_rise_k),
        )
    if bus:
        if params.supply.brake_resistor_ohm > 0:
            raise ValueError("brake_resistor_ohm > 0: the oracle has no brake chopper")
        if y.shape[0] == 5:
            y = np.append(y, params.supply.voltage_v)
        if x0 is None:
            y[5] = params.supply.voltage_v
    sub = int(params.supply.bus_substeps) if bus else 1
    br = params.bridge
    locked = False
    rhs = derivative_bus if bus else (derivative_heat if heat else derivative)
    stuck = False
    side = 0.0

    def kt_of(s: np.ndarray) -> float:
        return _motor_at(float(s[5]), params)[1] if heat else params.motor.kt_nm_a
    out = []
    for kk in range(len(duty) * sub):
        k = kk // sub
        u = (float(duty[k]), bool(enable[k]))
        t, t_end = kk * h_s / sub, (kk + 1) * h_s / sub
        while t < t_end:
            outputs_off = not u[1] or locked
            i_dir = math.copysign(1.0, y[0]) if outputs_off and y[0] != 0.0 else 0.0
            extra = (locked, i_dir) if bus else ()
            if stuck:

                def leave_lo(_t, s, p=params):
                    return kt_of(s) * s[0] - _band(s, p)[0]

                def leave_hi(_t, s, p=params):
                    return kt_of(s) * s[0] - _band(s, p)[1]

                leave_lo.terminal = leave_hi.terminal = True
                leave_lo.direction, leave_hi.direction = -1, 1
                events = [leave_lo, leave_hi]
            else:
                w = y[2]
                if w == 0.0:
                    w = rhs(t, y, u, params, None, *extra)[2]
                side = math.copysign(1.0, w) if w else 1.0

                def zero_speed(_t, s):
                    return s[2]

                zero_speed.terminal = True
                zero_speed.direction = -side
                events = [zero_speed]
            if bus and i_dir:
                # Freewheeling through the diodes, the current stops at zero (the diodes
                # block): an event, or the integrator chatters across the switch.
                def zero_current(_t, s):
                    return s[0]

                zero_current.terminal = True
                zero_current.direction = -i_dir
                events = [*events, zero_current]
            sol = solve_ivp(
                lambda tt, s, u=u, d=0.0 if stuck else side, x=extra: rhs(tt, s, u, params, d, *x),
                (t, t_end), y, method="DOP853", rtol=rtol, atol=atol, events=events,
            )  # fmt: skip
            if sol.status < 0:
                raise RuntimeError(f"solve_ivp failed at t = {t:.9f} s: {sol.message}")
            if sol.status != 1:
                y, t = sol.y[:, -1], t_end
                continue
            hit = next(j for j, te in enumerate(sol.t_events) if len(te))
            t_hit, y = float(sol.t_events[hit][0]), sol.y_events[hit][0].copy()
            if events[hit].__name__ == "zero_current":
                y[0] = 0.0
                t = t_hit
                continue
            if stuck:
                stuck = False  # the torque left the band: the motor turns again
            else:
                y[2] = 0.0
                stuck = stuck_at_rest(kt_of(y) * y[0], _belt(y, params), params)
            if t_hit <= t:  # an event at the start (at rest with no force): step over it
                sol = solve_ivp(
                    lambda tt, s, u=u, x=extra: rhs(tt, s, u, params, None, *x), (t, t_end), y,
                    method="DOP853", rtol=rtol, atol=atol,
                )  # fmt: skip
                y, t_hit = sol.y[:, -1], t_end
            t = t_hit
        if bus:  # the lock-out comparators at the sub-step's end (sim.supply.step_period)
            v = y[5]
            if locked:
                locked = not (br.uv_release_v < v < br.ov_release_v)
            else:
                locked = v >= br.ov_lockout_v or v <= br.uv_lockout_v
        if (kk + 1) % (every * sub) == 0:
            out.append(y.copy())
    return np.array(out)
