"""An independent integration of the plant: ``solve_ivp`` on ``sim.plant.derivative``, the
reference the tests (and anyone checking a change to the plant) replay runs against.

The continuous model has one sliding motion: a motor at rest whose torque lies between the
driving and the back-driven load of the gearbox (``sim.drivetrain.stuck_at_rest``) stays at
rest. An integrator cannot cross that switch of the right-hand side (it chatters there),
so the oracle handles it as an event: it integrates with the power-flow side held
(``derivative(..., motor_dir=+-1)``) up to a terminal event at the zero crossing of the
motor speed; if the state there sticks, with ``motor_dir=0`` until the motor torque leaves
the band (two more events).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from sim.drivetrain import belt_torque_nm, stuck_at_rest
from sim.params import PlantParams
from sim.plant import derivative

__all__ = ["replay"]


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
    default); returns the states ``(K // every, 5)`` after each ``every``-th input."""
    y = np.zeros(5) if x0 is None else np.array(x0, dtype=float)
    stuck = False
    side = 0.0
    kt = params.motor.kt_nm_a
    out = []
    for k in range(len(duty)):
        u = (float(duty[k]), bool(enable[k]))
        t, t_end = k * h_s, (k + 1) * h_s
        while t < t_end:
            if stuck:

                def leave_lo(_t, s, p=params):
                    return kt * s[0] - _band(s, p)[0]

                def leave_hi(_t, s, p=params):
                    return kt * s[0] - _band(s, p)[1]

                leave_lo.terminal = leave_hi.terminal = True
                leave_lo.direction, leave_hi.direction = -1, 1
                events = [leave_lo, leave_hi]
            else:
                w = y[2]
                if w == 0.0:
                    w = derivative(t, y, u, params)[2]
                side = math.copysign(1.0, w) if w else 1.0

                def zero_speed(_t, s):
                    return s[2]

                zero_speed.terminal = True
                zero_speed.direction = -side
                events = [zero_speed]
            sol = solve_ivp(
                lambda tt, s, u=u, d=0.0 if stuck else side: derivative(tt, s, u, params, d),
                (t, t_end), y, method="DOP853", rtol=rtol, atol=atol, events=events,
            )  # fmt: skip
            if sol.status != 1:
                y, t = sol.y[:, -1], t_end
                continue
            hit = next(j for j, te in enumerate(sol.t_events) if len(te))
            t_hit, y = float(sol.t_events[hit][0]), sol.y_events[hit][0].copy()
            if stuck:
                stuck = False  # the torque left the band: the motor turns again
            else:
                y[2] = 0.0
                stuck = stuck_at_rest(kt * y[0], _belt(y, params), params)
            if t_hit <= t:  # an event at the start (at rest with no force): step over it
                sol = solve_ivp(
                    lambda tt, s, u=u: derivative(tt, s, u, params), (t, t_end), y,
                    method="DOP853", rtol=rtol, atol=atol,
                )  # fmt: skip
                y, t_hit = sol.y[:, -1], t_end
            t = t_hit
        if (k + 1) % every == 0:
            out.append(y.copy())
    return np.array(out)
