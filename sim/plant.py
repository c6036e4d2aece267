"""The plant as a piecewise-affine state-space model, discretised exactly per mode.

State ``x`` (shape ``(5,)`` or ``(N, 5)``), input ``u = (duty, enable)``::

    x[0] current_a           armature current (A)
    x[1] motor_pos_rad       motor angle (rad, multi-turn)
    x[2] motor_vel_rad_s     motor speed (rad/s)
    x[3] twist_rad           theta_m / 400 - theta_platter (platter rad): backlash + belt
    x[4] platter_vel_rad_s   platter speed (rad/s)

Every nonlinearity of the model (saturated Coulomb friction of motor and platter, backlash
contact, power-flow direction through the gearbox, the bridge's current limitation and its
diodes when disabled) is piecewise linear, so in each *mode* the plant is
``dx/dt = A x + B duty + e``. With the duty held over a step (the PWM register), the exact
zero-order-hold step is one matrix product, ``x' = Phi [x; duty; 1]`` with
``Phi = expm([[A, B, e], [0, 0, 0], [0, 0, 0]] h)`` (cached per mode and step length). When
the mode at the end of a step differs from the mode at its start, the step is halved
(recursively, up to ``event_levels`` times) so that the switch is located in time: the only
sub-stepping the model needs.

``derivative(t, x, u, params)`` is the same continuous model written directly from the
physics (``sim.motor``, ``sim.drivetrain``), the oracle for ``scipy.integrate.solve_ivp``.
Functions take python-control's ``(t, x, u, params)`` order and have no side effects; the
plant objects only memoise their matrices. Only ``sim.loop`` owns the clock and the state.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from sim import plant_kernel
from sim.drivetrain import belt_torque_nm, load_factor
from sim.motor import friction_torque_nm
from sim.params import PlantParams

__all__ = [
    "BatchPlant",
    "Coefficients",
    "N_X",
    "ScalarPlant",
    "STATE_NAMES",
    "affine",
    "derivative",
    "mode_keys",
]

N_X = 5
I_A, POS, VEL, TWIST, PVEL = range(N_X)
STATE_NAMES = ("current_a", "motor_pos_rad", "motor_vel_rad_s", "twist_rad", "platter_vel_rad_s")

# Bridge modes.
B_ON, B_LIMIT_POS, B_LIMIT_NEG, B_DIODE_POS, B_DIODE_NEG, B_OPEN = range(6)
# key = (((bridge * 3 + fm) * 3 + fp) * 3 + contact) * 2 + flow, with fm, fp, contact in
# {0, 1, 2} for {negative, band/gap, positive} and flow 1 when the load drives the motor.
N_MODES = 6 * 3 * 3 * 3 * 2


@dataclass(frozen=True)
class Coefficients:
    """The numbers the mode logic and the matrices need (floats, or ``(N,)`` arrays)."""

    vs: Any
    r: Any
    l: Any  # noqa: E741 - inductance, the usual symbol
    kt: Any
    ke: Any
    jm: Any
    bm: Any
    tcm: Any
    wbm: Any
    jp: Any
    bp: Any
    tcp: Any
    wbp: Any
    k: Any
    c: Any
    half: Any
    n: Any
    eta: Any
    icl: Any
    vd2: Any
    inv_n: Any

    @classmethod
    def from_params(cls, p: PlantParams) -> Coefficients:
        def f(v: Any) -> Any:
            return v if isinstance(v, np.ndarray) else float(v)

        return cls(
            vs=f(p.supply.voltage_v),
            r=f(p.motor.r_ohm + p.bridge.r_on_path_ohm),
            l=f(p.motor.l_h),
            kt=f(p.motor.kt_nm_a),
            ke=f(p.motor.ke_v_s_rad),
            jm=f(p.motor.j_kgm2),
            bm=f(p.motor.viscous_nm_s_rad),
            tcm=f(p.motor.coulomb_nm),
            wbm=f(p.motor.coulomb_band_rad_s),
            jp=f(p.platter.j_kgm2),
            bp=f(p.platter.viscous_nm_s_rad),
            tcp=f(p.platter.coulomb_nm),
            wbp=f(p.platter.coulomb_band_rad_s),
            k=f(p.belt.stiffness_nm_rad),
            c=f(p.belt.damping_nm_s_rad),
            half=f(0.5 * np.radians(p.gearbox.backlash_deg) / p.belt.ratio),
            n=f(p.gearbox.ratio * p.belt.ratio),
            eta=f(p.gearbox.efficiency),
            icl=f(p.bridge.current_limit_a),
            vd2=f(p.supply.voltage_v + 2.0 * p.bridge.diode_drop_v),
            inv_n=f(1.0 / (p.gearbox.ratio * p.belt.ratio)),
        )


def affine(key: int, co: Coefficients) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous ``(A (5, 5), B (5,), e (5,))`` of mode ``key`` (scalar coefficients)."""
    flow = key % 2
    contact = (key // 2) % 3 - 1
    fp = (key // 6) % 3 - 1
    fm = (key // 18) % 3 - 1
    bridge = key // 54
    a = np.zeros((N_X, N_X))
    b = np.zeros(N_X)
    e = np.zeros(N_X)
    if bridge in (B_ON, B_DIODE_POS, B_DIODE_NEG):
        a[I_A, I_A] = -co.r / co.l
        a[I_A, VEL] = -co.ke / co.l
    if bridge == B_ON:
        b[I_A] = co.vs / co.l
    elif bridge == B_DIODE_POS:
        e[I_A] = -co.vd2 / co.l
    elif bridge == B_DIODE_NEG:
        e[I_A] = co.vd2 / co.l
    a[POS, VEL] = 1.0
    # Belt torque on the platter, tau = kt_ twist + kwm w_m + kwp w_p + t0 (zero in the gap).
    if contact:
        k_tw, k_wm, k_wp, t0 = co.k, co.c / co.n, -co.c, -co.k * co.half * contact
    else:
        k_tw = k_wm = k_wp = t0 = 0.0
    g = co.eta / co.n if flow else 1.0 / (co.n * co.eta)
    a[VEL, I_A] = co.kt / co.jm
    a[VEL, VEL] = (-co.bm - g * k_wm) / co.jm
    a[VEL, TWIST] = -g * k_tw / co.jm
    a[VEL, PVEL] = -g * k_wp / co.jm
    e[VEL] = -g * t0 / co.jm
    if fm:
        e[VEL] -= fm * co.tcm / co.jm
    else:
        a[VEL, VEL] -= co.tcm / co.wbm / co.jm
    a[TWIST, VEL] = 1.0 / co.n
    a[TWIST, PVEL] = -1.0
    a[PVEL, TWIST] = k_tw / co.jp
    a[PVEL, VEL] = k_wm / co.jp
    a[PVEL, PVEL] = (k_wp - co.bp) / co.jp
    e[PVEL] = t0 / co.jp
    if fp:
        e[PVEL] -= fp * co.tcp / co.jp
    else:
        a[PVEL, PVEL] -= co.tcp / co.wbp / co.jp
    return a, b, e


def _taylor_expm(a: np.ndarray) -> np.ndarray:
    """exp(a) for a small-norm matrix (<= 1/2): Taylor terms until they vanish."""
    eye = np.eye(a.shape[0])
    out = eye + a
    term = a
    for k in range(2, 40):
        term = np.einsum("ij,jk->ik", term, a) / k
        out = out + term
        if float(np.max(np.abs(term))) <= 1e-18 * float(np.max(np.abs(out))):
            break
    return out


def expm_small(m: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small square matrix: scaling and squaring around a Taylor
    series (truncated below 1e-18 relative), with ``einsum`` products.

    ``scipy.linalg.expm`` gives the same result, but its BLAS calls go multi-threaded even
    for 7 x 7 matrices and take milliseconds on a busy machine; the tests compare the two.
    """
    norm = float(np.max(np.sum(np.abs(m), axis=0)))
    squarings = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    out = _taylor_expm(m / (1 << squarings))
    for _ in range(squarings):
        out = np.einsum("ij,jk->ik", out, out)
    return out


def augmented(key: int, co: Coefficients) -> np.ndarray:
    """The 7 x 7 matrix ``[[A, B, e], [0, 0, 0], [0, 0, 0]]`` of mode ``key``."""
    a, b, e = affine(key, co)
    m = np.zeros((N_X + 2, N_X + 2))
    m[:N_X, :N_X] = a
    m[:N_X, N_X] = b
    m[:N_X, N_X + 1] = e
    return m


def zoh(key: int, co: Coefficients, h_s: float) -> np.ndarray:
    """Exact zero-order-hold step of mode ``key`` over ``h_s``: ``Phi`` of shape (5, 7)."""
    return expm_small(augmented(key, co) * h_s)[:N_X, :]


def zoh_ladder(key: int, co: Coefficients, h_s: float, levels: int) -> list[np.ndarray]:
    """``Phi`` of mode ``key`` over ``h_s / 2**l`` for l = 0..levels, each (5, 7).

    One exponential at the finest step, then squaring up (``exp(2 M h) = exp(M h)**2``):
    the scaling and squaring of ``expm_small`` with every intermediate kept.
    """
    m = augmented(key, co)
    fine = h_s / (1 << levels)
    norm = float(np.max(np.sum(np.abs(m), axis=0))) * fine
    extra = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    full = _taylor_expm(m * (fine / (1 << extra)))
    for _ in range(extra):
        full = np.einsum("ij,jk->ik", full, full)
    out = [full]
    for _ in range(levels):
        full = np.einsum("ij,jk->ik", full, full)
        out.append(full)
    return [p[:N_X, :] for p in reversed(out)]


# Matrices shared by every plant with the same coefficients and step (tests and benchmarks
# build many plants): (coefficients, h_s, levels, key) -> rows per level.
_LADDERS: dict[tuple[Coefficients, float, int, int], list[tuple[tuple[float, ...], ...]]] = {}
_LADDERS_MAX = 2000


def ladder_rows(
    key: int, co: Coefficients, h_s: float, levels: int
) -> list[tuple[tuple[float, ...], ...]]:
    """``zoh_ladder`` as nested float tuples, memoised across plants."""
    slot = (co, h_s, levels, key)
    rows = _LADDERS.get(slot)
    if rows is None:
        if len(_LADDERS) >= _LADDERS_MAX:
            _LADDERS.clear()  # bounded: ~26 kB per entry; plants keep their own copies
        rows = [
            tuple(tuple(float(v) for v in row) for row in mat)
            for mat in zoh_ladder(key, co, h_s, levels)
        ]
        _LADDERS[slot] = rows
    return rows


def mode_keys(x: np.ndarray, duty: Any, enable: Any, co: Coefficients) -> np.ndarray:
    """Mode key of every batch member (x of shape (N, 5)) -> int array (N,)."""
    i, w, tw, wp = x[:, I_A], x[:, VEL], x[:, TWIST], x[:, PVEL]
    fm = 1 + (w > co.wbm).astype(np.int64) - (w < -co.wbm)
    fp = 1 + (wp > co.wbp).astype(np.int64) - (wp < -co.wbp)
    side = (tw > co.half).astype(np.int64) - (tw < -co.half)  # -1, 0, +1
    tb = (side != 0) * (co.k * (tw - co.half * side) + co.c * (w * co.inv_n - wp))
    flow = (tb * w < 0).astype(np.int64)
    # The bridge: on, unless the chip limits the current or the bridge is disabled.
    bridge = np.zeros(x.shape[0], dtype=np.int64)
    if np.any(np.abs(i) >= co.icl):
        drive = co.vs * duty - co.r * i - co.ke * w
        bridge = np.where(
            (i >= co.icl) & (drive > 0),
            B_LIMIT_POS,
            np.where((i <= -co.icl) & (drive < 0), B_LIMIT_NEG, B_ON),
        )
    if not np.all(enable):
        emf = co.ke * w
        off = np.where(
            i > 0,
            B_DIODE_POS,
            np.where(
                i < 0,
                B_DIODE_NEG,
                np.where(emf > co.vd2, B_DIODE_NEG, np.where(emf < -co.vd2, B_DIODE_POS, B_OPEN)),
            ),
        )
        bridge = np.where(enable, bridge, off)
    return (((bridge * 3 + fm) * 3 + fp) * 3 + side + 1) * 2 + flow


def derivative(t: float, x: np.ndarray, u: tuple[Any, Any], params: PlantParams) -> np.ndarray:
    """dx/dt of the continuous model (x of shape (5,) or (N, 5); u = (duty, enable)).

    Written from the physics functions, independently of ``affine``, so that comparing the
    discrete plant with ``solve_ivp`` on this function checks the matrices as well.
    """
    duty, enable = u
    if x.ndim == 1:
        return _derivative_one(x, float(duty), bool(enable), params)
    m, pl = params.motor, params.platter
    n = params.total_ratio
    vs = params.supply.voltage_v
    r = m.r_ohm + params.bridge.r_on_path_ohm
    vd2 = vs + 2.0 * params.bridge.diode_drop_v
    icl = params.bridge.current_limit_a
    i, w, tw, wp = x[..., I_A], x[..., VEL], x[..., TWIST], x[..., PVEL]
    emf = m.ke_v_s_rad * w
    di_on = (vs * duty - r * i - emf) / m.l_h
    di_on = np.where(((i >= icl) & (di_on > 0)) | ((i <= -icl) & (di_on < 0)), 0.0, di_on)
    v_off = np.where(i > 0, -vd2, np.where(i < 0, vd2, np.clip(emf, -vd2, vd2)))
    di_off = np.where((i == 0) & (np.abs(emf) <= vd2), 0.0, (v_off - r * i - emf) / m.l_h)
    tb = belt_torque_nm(tw, w / n - wp, params)
    g = load_factor(tb, w, params)
    dx = np.empty_like(x, dtype=float)
    dx[..., I_A] = np.where(enable, di_on, di_off)
    dx[..., POS] = w
    dx[..., VEL] = (
        m.kt_nm_a * i
        - friction_torque_nm(w, m.coulomb_nm, m.coulomb_band_rad_s, m.viscous_nm_s_rad)
        - g * tb
    ) / m.j_kgm2
    dx[..., TWIST] = w / n - wp
    dx[..., PVEL] = (
        tb - friction_torque_nm(wp, pl.coulomb_nm, pl.coulomb_band_rad_s, pl.viscous_nm_s_rad)
    ) / pl.j_kgm2
    return dx


def _derivative_one(x: np.ndarray, duty: float, enable: bool, params: PlantParams) -> np.ndarray:
    """``derivative`` for one state (5,) on Python floats: the same laws, ~10x faster for
    ``solve_ivp``; the tests check it against the vectorised branch."""
    m, pl, br = params.motor, params.platter, params.bridge
    n = params.total_ratio
    vs = params.supply.voltage_v
    i, _, w, tw, wp = (float(v) for v in x)
    emf = m.ke_v_s_rad * w
    r = m.r_ohm + br.r_on_path_ohm
    if enable:
        di = (vs * duty - r * i - emf) / m.l_h
        icl = br.current_limit_a
        if (i >= icl and di > 0) or (i <= -icl and di < 0):
            di = 0.0
    else:
        vd2 = vs + 2.0 * br.diode_drop_v
        if i == 0 and abs(emf) <= vd2:
            di = 0.0
        else:
            v = -vd2 if i > 0 else (vd2 if i < 0 else max(-vd2, min(vd2, emf)))
            di = (v - r * i - emf) / m.l_h
    half = 0.5 * math.radians(params.gearbox.backlash_deg) / params.belt.ratio
    rate = w / n - wp
    if tw > half:
        tb = params.belt.stiffness_nm_rad * (tw - half) + params.belt.damping_nm_s_rad * rate
    elif tw < -half:
        tb = params.belt.stiffness_nm_rad * (tw + half) + params.belt.damping_nm_s_rad * rate
    else:
        tb = 0.0
    eta = params.gearbox.efficiency
    g = eta / n if tb * w < 0 else 1.0 / (n * eta)
    fm = m.coulomb_nm * max(-1.0, min(1.0, w / m.coulomb_band_rad_s)) + m.viscous_nm_s_rad * w
    fp = pl.coulomb_nm * max(-1.0, min(1.0, wp / pl.coulomb_band_rad_s))
    fp += pl.viscous_nm_s_rad * wp
    return np.array([di, w, (m.kt_nm_a * i - fm - g * tb) / m.j_kgm2, rate, (tb - fp) / pl.j_kgm2])


class ScalarPlant:
    """The N = 1 plant on Python floats, stepped by a compiled kernel (the fast path of the
    loop; ``sim.plant_kernel``).

    ``update(t_s, x, u) -> x_next`` advances a list of 5 floats by ``h_s`` with
    ``u = (duty, enable)`` held. It returns a new tuple and never changes ``x``. The object
    memoises one ``Phi`` per (mode, halving level); ``n_events`` counts located mode
    switches (statistics only). At most ``split_budget`` halvings are spent per step.
    """

    def __init__(self, params: PlantParams, h_s: float, event_levels: int = 20) -> None:
        if params.batch_size() is not None:
            raise ValueError("ScalarPlant needs scalar parameters; use BatchPlant")
        self.params = params
        self.h_s = float(h_s)
        self.event_levels = int(event_levels)
        self.co = Coefficients.from_params(params)
        self._phi: dict[int, tuple[tuple[float, ...], ...]] = {}
        self.n_events = 0
        # A state resting on a mode boundary (e.g. the belt unloaded exactly at the edge of
        # the backlash gap) switches mode in every sub-step; without a budget the halving
        # would take 2**levels steps. Past the budget a step is accepted in its start mode
        # (the dynamics on both sides of such a boundary agree there).
        self.split_budget = 4 * self.event_levels + 8
        self._g_max = 1.0 / (self.co.n * self.co.eta)
        # The tables of the compiled step (sim.plant_kernel), filled as modes are met.
        self._consts = plant_kernel.pack_consts(self.co, self._g_max, self.h_s)
        self._slots = np.full(N_MODES, -1, dtype=np.int64)
        self._phis = np.empty((0, self.event_levels + 1, N_X, N_X + 2))
        self._rates = np.empty((0, 2, N_X + 2))
        self._n_loaded = 0
        self._step = plant_kernel.step
        # BatchPlant turns this off for the members it hands over (batch semantics).
        self.check_excursions = True
        self._last_x: tuple[float, ...] | None = None
        self._last_mech = 0

    def phi(self, key: int, level: int = 0) -> tuple[tuple[float, ...], ...]:
        """``Phi`` of mode ``key`` over ``h_s / 2**level`` as nested tuples (memoised)."""
        slot = key * 64 + level
        rows = self._phi.get(slot)
        if rows is None:
            ladder = ladder_rows(key, self.co, self.h_s, self.event_levels)
            for lev, r in enumerate(ladder):
                self._phi[key * 64 + lev] = r
            rows = ladder[level]
        return rows

    def key(self, x: Sequence[float], duty: float, enable: bool) -> int:
        """Mode key of state ``x`` under input (duty, enable); same rules as ``mode_keys``."""
        i, _, w, tw, wp = x
        return plant_kernel.key(float(i), float(w), float(tw), float(wp), float(duty),
                                bool(enable), self._consts)  # fmt: skip

    def _load(self, key: int) -> None:
        """Put mode ``key``'s matrices into the kernel's tables (``sim.plant_kernel``)."""
        row = self._n_loaded
        if row == self._phis.shape[0]:  # grow by doubling
            grow = max(16, 2 * row)
            phis = np.empty((grow,) + self._phis.shape[1:])
            phis[:row] = self._phis[:row]
            rates = np.empty((grow, 2, N_X + 2))
            rates[:row] = self._rates[:row]
            self._phis, self._rates = phis, rates
        for level in range(self.event_levels + 1):
            self._phis[row, level] = self.phi(key, level)
        a, b, e = affine(key, self.co)
        for j, r in enumerate((VEL, PVEL)):
            self._rates[row, j, :N_X] = a[r]
            self._rates[row, j, N_X] = b[r]
            self._rates[row, j, N_X + 1] = e[r]
        self._slots[key] = row
        self._n_loaded = row + 1

    def update(self, t_s: float, x: Sequence[float], u: tuple[float, bool]) -> tuple[float, ...]:
        """Advance ``x`` by ``h_s`` with ``u = (duty, enable)`` held; returns the new state.

        From the mode of ``x``, the whole step is one ``Phi`` product; a step whose end
        lies in another mode (or, with ``check_excursions``, whose motor speed, platter
        speed or twist leaves its region and comes back within the step, judged by a cubic
        Hermite through the values and rates at both ends) is halved, the first half taken
        in the start mode and the second in the mode where the first ended, recursively
        down to ``h_s / 2**event_levels`` and within ``split_budget`` halvings; a switch
        located to the finest level is accepted (a current freewheeling through a diode
        stops at zero, one that reached the bridge's limitation is held at I_CL). Compiled
        in ``sim.plant_kernel.step``.
        """
        duty, enable = u
        duty = float(duty)
        enable = bool(enable)
        i = x[0]
        # The state this plant returned last: its mechanical mode is known; with the bridge
        # on and below I_CL the bridge part is B_ON (0).
        icl = self.co.icl
        key = self._last_mech if x is self._last_x and enable and -icl < i < icl else -1
        while True:
            r = self._step(
                i, x[1], x[2], x[3], x[4], duty, enable, key, self.event_levels,
                self.split_budget, self.check_excursions, self._slots, self._phis,
                self._rates, self._consts,
            )  # fmt: skip
            if r[7] < 0:
                break
            self._load(r[7])  # a mode met for the first time: load it and take the step again
        # A tuple of floats: the garbage collector stops tracking it (a run logs 500 per s).
        xn = r[:5]
        self.n_events += r[6]
        self._last_x = xn
        self._last_mech = r[5] % 54
        return xn


# Below this many switching members, BatchPlant hands them to the scalar recursion.
_SCALAR_EVENTS = 8

# The boundary columns of BatchPlant's fused step: for the end state, 14 linear functions
# whose signs (> 0) give its mechanical mode while the bridge is on: the motor and platter
# speeds against their friction bands, the twist against the backlash gap, the belt torque
# on either side of the gap and the motor speed (power flow), and I_CL - |i| (both signs).
_N_BOUNDS = 14


def _boundary_columns(co: Coefficients) -> tuple[np.ndarray, np.ndarray]:
    """``(C (..., 5, 14), c0 (..., 14))``: the boundary columns are ``x @ C + c0``."""
    shape = np.broadcast(co.wbm, co.wbp, co.half, co.k, co.c, co.icl).shape
    c = np.zeros(shape + (N_X, _N_BOUNDS))
    c0 = np.zeros(shape + (_N_BOUNDS,))
    for sign, col in ((1.0, 0), (-1.0, 1)):
        c[..., VEL, col] = sign
        c0[..., col] = -co.wbm
        c[..., PVEL, col + 2] = sign
        c0[..., col + 2] = -co.wbp
        c[..., TWIST, col + 4] = sign
        c0[..., col + 4] = -co.half
        for side, base in ((1.0, 6), (-1.0, 8)):  # belt torque in contact on either side
            c[..., TWIST, base + col] = sign * co.k
            c[..., VEL, base + col] = sign * co.c * co.inv_n
            c[..., PVEL, base + col] = -sign * co.c
            c0[..., base + col] = -sign * co.k * co.half * side
        c[..., VEL, col + 10] = sign
        c[..., I_A, col + 12] = sign
        c0[..., col + 12] = co.icl
    return c, c0


def _key_of_signs() -> np.ndarray:
    """Mode key (bridge on) for each pattern of the 14 boundary signs, -1 at I_CL."""
    table = np.empty(1 << _N_BOUNDS, dtype=np.int64)
    for code in range(1 << _N_BOUNDS):
        bit = [(code >> j) & 1 for j in range(_N_BOUNDS)]
        fm = 2 if bit[0] else (0 if bit[1] else 1)
        fp = 2 if bit[2] else (0 if bit[3] else 1)
        contact = 2 if bit[4] else (0 if bit[5] else 1)
        tb_pos = (contact == 2 and bit[6]) or (contact == 0 and bit[8])
        tb_neg = (contact == 2 and bit[7]) or (contact == 0 and bit[9])
        flow = 1 if (tb_pos and bit[11]) or (tb_neg and bit[10]) else 0
        key = (((B_ON * 3 + fm) * 3 + fp) * 3 + contact) * 2 + flow
        table[code] = key if bit[12] and bit[13] else -1
    return table


_KEY_OF_SIGNS = _key_of_signs()
_SIGN_WEIGHTS = 2.0 ** np.arange(_N_BOUNDS)  # boundary signs -> row of _KEY_OF_SIGNS
_FUSED = N_X + 2 + _N_BOUNDS  # columns of BatchPlant's fused product
# OpenBLAS runs a product of m * n * k below 65536 multiply-adds on one thread (its
# SMP_THRESHOLD_MIN; the default build multiplies it by 4).
_BLAS_SINGLE_THREAD = 65536
# BatchPlant._fused of shared-parameter plants: (coefficients, h_s, levels, slot) -> (7, 21).
_FUSED_SHARED: dict[tuple[Coefficients, float, int, int], np.ndarray] = {}


@numba.njit(cache=True)
def _same_end_modes(out, keys, key_of_signs):
    """Whether every member's end mode, read from the signs of the boundary columns of its
    fused product ``out`` (``BatchPlant._fused``), is its start mode ``keys`` (bridge on; a
    current at I_CL reads -1, never a start mode)."""
    for j in range(out.shape[0]):
        code = 0
        for b in range(_N_BOUNDS):
            if out[j, N_X + 2 + b] > 0.0:
                code |= 1 << b
        if key_of_signs[code] != keys[j]:
            return False
    return True


@numba.njit(cache=True)
def _mode_key_one(i, w, tw, wp, duty, enable, consts):
    """``mode_keys`` of one member (the same arithmetic, bit for bit)."""
    wbm, wbp, half, k, c, inv_n, icl, vs, r, ke, vd2 = consts
    fm = 1 + (1 if w > wbm else 0) - (1 if w < -wbm else 0)
    fp = 1 + (1 if wp > wbp else 0) - (1 if wp < -wbp else 0)
    side = (1 if tw > half else 0) - (1 if tw < -half else 0)
    tb = (1.0 if side != 0 else 0.0) * (k * (tw - half * side) + c * (w * inv_n - wp))
    flow = 1 if tb * w < 0 else 0
    if enable:
        bridge = B_ON
        if i >= icl or -i >= icl:
            drive = vs * duty - r * i - ke * w
            if i >= icl and drive > 0:
                bridge = B_LIMIT_POS
            elif i <= -icl and drive < 0:
                bridge = B_LIMIT_NEG
    elif i > 0:
        bridge = B_DIODE_POS
    elif i < 0:
        bridge = B_DIODE_NEG
    else:
        emf = ke * w
        bridge = B_DIODE_NEG if emf > vd2 else (B_DIODE_POS if emf < -vd2 else B_OPEN)
    return (((bridge * 3 + fm) * 3 + fp) * 3 + side + 1) * 2 + flow


@numba.njit(cache=True)
def _locate_members(
    x, duty, enable, key, done, level, budget, slot_row, stack, key_of_signs, consts,
    levels, missing,
):  # fmt: skip
    """The sub-steps of ``BatchPlant._locate``, member after member, each to the end of its
    step or to the first (mode, level) slot without a matrix in ``stack`` yet. The state
    (``x, key, done, level, budget``) is updated in place; the slots wanted are written to
    ``missing``. Returns ``(switches located, slots missing)``."""
    full = 1 << levels
    icl = consts[6]
    n_missing = 0
    n_located = 0
    xn = np.empty(N_X)
    for j in range(x.shape[0]):
        d, e = duty[j], enable[j]
        while done[j] < full:
            lv = level[j]
            k0 = key[j]
            row = slot_row[k0 * 64 + lv]
            if row < 0:
                missing[n_missing] = k0 * 64 + lv
                n_missing += 1
                break
            mat = stack[row]
            # [x; duty; 1] @ F, each column summed in order as numpy's einsum does.
            code = 0
            for col in range(_FUSED):
                acc = 0.0
                for m in range(N_X):
                    acc += x[j, m] * mat[m, col]
                acc += d * mat[N_X, col]
                acc += mat[N_X + 1, col]
                if col < N_X:
                    xn[col] = acc
                elif col >= N_X + 2 and acc > 0.0:
                    code |= 1 << (col - N_X - 2)
            k1 = key_of_signs[code]
            if k1 < 0 or not e:
                k1 = _mode_key_one(xn[I_A], xn[VEL], xn[TWIST], xn[PVEL], d, e, consts)
            if k1 != k0:
                if lv < levels and budget[j] > 0:
                    budget[j] -= 1
                    level[j] = lv + 1
                    continue
                # Located to h / 2**levels: as in BatchPlant._locate.
                n_located += 1
                b0, b1 = k0 // 54, k1 // 54
                i = xn[I_A]
                if (b0 == B_DIODE_POS and i < 0) or (b0 == B_DIODE_NEG and i > 0):
                    xn[I_A] = 0.0
                if b1 == B_LIMIT_POS and xn[I_A] > icl:
                    xn[I_A] = icl
                if b1 == B_LIMIT_NEG and xn[I_A] < -icl:
                    xn[I_A] = -icl
                k1 = _mode_key_one(xn[I_A], xn[VEL], xn[TWIST], xn[PVEL], d, e, consts)
            x[j, :] = xn
            key[j] = k1
            now = done[j] + (full >> lv)
            done[j] = now
            # Next: the longest aligned sub-step from the new time (its lowest set bit).
            low = now & -now
            p = 0
            while low > 1:
                low >>= 1
                p += 1
            level[j] = levels - p
    return n_located, n_missing


class BatchPlant:
    """N plants stepped in lock-step; parameters scalar or ``(N,)`` per member.

    ``update(t_s, x, u) -> x_next`` with ``x`` of shape ``(N, 5)`` and ``u = (duty (N,),
    enable (N,))``. Members whose mode stays the same over the step (almost all, almost
    always) share one matrix product per mode; the same product gives the end state's
    boundary columns, whose signs give its mode through one table lookup. The members that
    switch mode are halved again: a few by the ``ScalarPlant`` recursion, many (shared
    parameters) by the compiled ``_locate``, with the same sub-steps. The Hermite excursion
    check of ``ScalarPlant`` is not run in batch (it would cost more than the step for N
    members).
    """

    def __init__(self, params: PlantParams, n: int, h_s: float, event_levels: int = 20) -> None:
        size = params.batch_size()
        if size is not None and size != n:
            raise ValueError(f"batch = {n}: parameter arrays have {size} members")
        self.n = int(n)
        self.h_s = float(h_s)
        self.per_member = size is not None
        self.co = Coefficients.from_params(params)
        if self.per_member:
            self.members = [ScalarPlant(params.member(k), h_s, event_levels) for k in range(n)]
        else:
            shared = ScalarPlant(params, h_s, event_levels)
            self.members = [shared] * n
        for plant in self.members:
            plant.check_excursions = False  # not in the batch path (see the class docs)
        self._phi: dict[int, np.ndarray] = {}
        self.event_levels = int(event_levels)
        self.split_budget = 4 * self.event_levels + 8
        self.n_located = 0  # switches located by _locate (the scalar members count theirs)
        # _fused of every (mode, level) slot _locate has used, stacked for gathers.
        self._slot_row = np.full(N_MODES * 64, -1, dtype=np.int64)
        self._stack = np.empty((0, N_X + 2, _FUSED))
        self._stack_used = 0
        self._fused_mats: dict[int, np.ndarray] = {}
        self._last_out = np.empty((0, _FUSED))
        self._boundaries = _boundary_columns(self.co)
        co = self.co
        # The constants of _mode_key_one (shared parameters: floats).
        self._key_consts = (
            co.wbm, co.wbp, co.half, co.k, co.c, co.inv_n, co.icl, co.vs, co.r, co.ke, co.vd2,
        )  # fmt: skip
        self._last_x: np.ndarray | None = None
        self._last_mech = np.zeros(self.n, dtype=np.int64)

    @property
    def n_events(self) -> int:
        scalar = sum(p.n_events for p in {id(p): p for p in self.members}.values())
        return scalar + self.n_located

    def _phi_t(self, key: int, level: int = 0) -> np.ndarray:
        """Transposed ``Phi`` for row-vector products: (7, 5) shared or (N, 7, 5)."""
        slot = key * 64 + level
        mat = self._phi.get(slot)
        if mat is None:
            if self.per_member:
                mat = np.stack([np.array(p.phi(key, level)).T for p in self.members])
            else:
                mat = np.array(self.members[0].phi(key, level)).T
            mat = np.ascontiguousarray(mat)
            self._phi[slot] = mat
        return mat

    def _fused(self, key: int, level: int = 0) -> np.ndarray:
        """The step of mode ``key`` over ``h / 2**level`` as one product ``[x; duty; 1] @
        F``: shared ``F`` (7, 21) or per member (N, 7, 21). Columns 0-4 are ``Phi^T`` (the
        new state), 5 and 6 give 0 and 1 (the next step writes its duty into column 5 and
        multiplies the same rows again), 7-20 the end state's boundary columns
        (``_boundary_columns``)."""
        slot = key * 64 + level
        mat = self._fused_mats.get(slot)
        if mat is None:
            # Shared parameters: also shared across plants (every run builds a new one).
            shared = None if self.per_member else (self.co, self.h_s, self.event_levels, slot)
            mat = _FUSED_SHARED.get(shared) if shared else None
            if mat is None:
                phi_t = self._phi_t(key, level)
                c, c0 = self._boundaries
                z = phi_t @ c
                z[..., N_X + 1, :] += c0  # the last entry of [x; duty; 1] is 1
                carry = np.zeros(phi_t.shape[:-1] + (2,))
                carry[..., N_X + 1, 1] = 1.0
                mat = np.ascontiguousarray(np.concatenate([phi_t, carry, z], axis=-1))
                if shared:
                    if len(_FUSED_SHARED) >= _LADDERS_MAX:
                        _FUSED_SHARED.clear()  # bounded, as _LADDERS
                    _FUSED_SHARED[shared] = mat
            self._fused_mats[slot] = mat
        return mat

    def _apply(self, xa: np.ndarray, keys: np.ndarray) -> np.ndarray:
        """One whole step of every member in its mode: ``[x; duty; 1] (N, 7) @ F`` ->
        ``(N, 21)`` (``_fused``)."""
        n = xa.shape[0]
        k0 = int(keys[0])
        if bool((keys == k0).all()):
            groups: list[tuple[int, Any]] = [(k0, None)]
        else:
            groups = [(int(k), keys == k) for k in np.unique(keys)]
        out = np.empty((n, _FUSED))
        # BLAS (matmul) is 6x faster than einsum here, but goes multi-threaded on large
        # products, which stalls on a busy machine: only below OpenBLAS's threshold.
        blas = n * (N_X + 2) * _FUSED < _BLAS_SINGLE_THREAD
        for key, sel in groups:
            mat = self._fused(key)
            if self.per_member:
                if sel is None:
                    np.einsum("nj,nji->ni", xa, mat, out=out)
                else:
                    out[sel] = np.einsum("nj,nji->ni", xa[sel], mat[sel])
            elif sel is None:
                if blas:
                    np.matmul(xa, mat, out=out)
                else:
                    np.einsum("nj,ji->ni", xa, mat, out=out)
            else:
                out[sel] = xa[sel] @ mat if blas else np.einsum("nj,ji->ni", xa[sel], mat)
        return out

    def _load_slots(self, slots: np.ndarray) -> None:
        """Put ``_fused`` of every (mode, level) slot in ``slots`` that is not there yet into
        ``_stack`` (shared parameters; ``_slot_row[slot]`` is its row)."""
        missing = self._slot_row[slots] < 0
        for slot in np.unique(slots[missing]).tolist():
            used = self._stack_used
            if used == self._stack.shape[0]:  # grow by doubling: no copy per new slot
                grown = np.empty((max(64, 2 * used), N_X + 2, _FUSED))
                grown[:used] = self._stack[:used]
                self._stack = grown
            self._stack[used] = self._fused(slot // 64, slot % 64)
            self._slot_row[slot] = used
            self._stack_used = used + 1

    def _locate(
        self, x: np.ndarray, duty: np.ndarray, enable: np.ndarray, keys: np.ndarray
    ) -> np.ndarray:
        """The sub-steps of ``ScalarPlant._advance`` for members whose full step switched
        mode (shared parameters), compiled (``_locate_members``).

        The recursion of ``_advance`` tiles the step with aligned dyadic sub-steps: from
        time ``s`` it tries the longest aligned one (``h`` times the lowest set bit of
        ``s / h``), halves it while the mode changes within it (down to ``event_levels``,
        within the split budget) and takes each accepted sub-step in the mode of its start.
        Here every member carries its own ``s``, level and budget: the same sub-steps, each
        a fused product ``[x; duty; 1] @ F`` as in ``update``, its end mode from the
        boundary signs. A (mode, level) met for the first time sends the loop back here
        for its matrix, then it goes on where it stopped.
        """
        m = x.shape[0]
        x = np.array(x, dtype=float)  # a copy, C-ordered
        done = np.zeros(m, dtype=np.int64)  # time taken, in units of h / 2**levels
        level = np.ones(m, dtype=np.int64)  # the whole step (level 0) switched: halve
        budget = np.full(m, self.split_budget - 1, dtype=np.int64)
        key = np.array(keys, dtype=np.int64)
        missing = np.empty(m, dtype=np.int64)
        while True:
            located, n_missing = _locate_members(
                x, np.ascontiguousarray(duty, dtype=float), np.ascontiguousarray(enable),
                key, done, level, budget, self._slot_row, self._stack, _KEY_OF_SIGNS,
                self._key_consts, self.event_levels, missing,
            )  # fmt: skip
            self.n_located += located
            if not n_missing:
                return x
            self._load_slots(missing[:n_missing])

    def update(self, t_s: float, x: np.ndarray, u: tuple[Any, Any]) -> np.ndarray:
        duty, enable = u
        n = self.n
        if not (isinstance(duty, np.ndarray) and duty.shape == (n,) and duty.dtype == float):
            duty = np.broadcast_to(np.asarray(duty, dtype=float), (n,))
        if not (isinstance(enable, np.ndarray) and enable.shape == (n,) and enable.dtype == bool):
            enable = np.broadcast_to(np.asarray(enable, dtype=bool), (n,))
        co = self.co
        chained = x is self._last_x
        known = chained and bool(enable.all())
        if known:
            # The array this plant returned last: its mechanical modes are known and, the
            # bridge being on and every current below I_CL (checked with the modes), the
            # bridge part is B_ON (0).
            keys = self._last_mech
        else:
            keys = mode_keys(x, duty, enable, co)
        if chained:
            # x is columns 0-4 of the last product, whose column 6 is 1: [x; duty; 1] in place.
            xa = self._last_out[:, : N_X + 2]
        else:
            xa = np.empty((n, N_X + 2))
            xa[:, :N_X] = x
            xa[:, N_X + 1] = 1.0
        xa[:, N_X] = duty
        out = self._apply(xa, keys)
        xn = out[:, :N_X]
        if known and _same_end_modes(out, keys, _KEY_OF_SIGNS):
            # The common case, in one compiled pass: no member switched mode (its keys, all
            # mechanical, stay the next step's).
            self._last_x, self._last_out = xn, out
            return xn
        if known:
            # Mode of the end state from the signs of its boundary columns (one table
            # lookup); -1 where a current reached I_CL (the bridge part needs mode_keys).
            signs = (out[:, N_X + 2 :] > 0.0) @ _SIGN_WEIGHTS
            k_end = _KEY_OF_SIGNS[signs.astype(np.intp)]
        else:
            k_end = mode_keys(xn, duty, enable, co)
        moved = np.nonzero(k_end != keys)[0]
        if moved.size and known and bool((k_end < 0).any()):
            k_end = mode_keys(xn, duty, enable, co)
            moved = np.nonzero(k_end != keys)[0]
        if moved.size == 0:
            self._last_x, self._last_mech, self._last_out = xn, k_end % 54, out
            return xn
        self._last_x = None
        if self.per_member or moved.size <= _SCALAR_EVENTS or self.event_levels == 0:
            for j in moved:
                xj = x[j].tolist()
                xn[j] = self.members[j].update(t_s, xj, (float(duty[j]), bool(enable[j])))
            return xn
        xn[moved] = self._locate(x[moved], duty[moved], enable[moved], keys[moved])
        return xn
