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
import threading
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from sim import plant_kernel
from sim.drivetrain import belt_torque_nm, load_factor
from sim.motor import friction_torque_nm
from sim.params import PlantParams, replace_unchecked
from sim.plant_kernel import N_CONSTS

__all__ = [
    "Coefficients",
    "MECH_MODES",
    "N_X",
    "Plant",
    "STATE_NAMES",
    "affine",
    "derivative",
]

N_X = 5
I_A, POS, VEL, TWIST, PVEL = range(N_X)
STATE_NAMES = ("current_a", "motor_pos_rad", "motor_vel_rad_s", "twist_rad", "platter_vel_rad_s")

# Bridge modes.
B_ON, B_LIMIT_POS, B_LIMIT_NEG, B_DIODE_POS, B_DIODE_NEG, B_OPEN = range(6)
# Power flow through the gearbox: the motor drives the load, the load drives the motor, or
# the motor is held at rest by the gearbox's load-dependent friction (see ``affine``).
F_DRIVE, F_BACK, F_STUCK = range(3)
# key = (((bridge * 5 + fm) * 5 + fp) * 3 + contact) * 3 + flow: fm, fp the friction regions
# {0, 1, 2, 3, 4} = {below -Stribeck, falling -, band, falling +, above +Stribeck} of motor
# and platter speed; contact {0, 1, 2} = {negative, gap, positive}; MECH_MODES mechanical
# modes per bridge mode.
MECH_MODES = 5 * 5 * 3 * 3
N_MODES = 6 * MECH_MODES


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
    tsm: Any
    wsm: Any
    jp: Any
    bp: Any
    tcp: Any
    wbp: Any
    tsp: Any
    wsp: Any
    k: Any
    c: Any
    half: Any
    n: Any
    eta: Any
    icl: Any
    vd2: Any
    inv_n: Any
    # With the bus model (``sim.supply``) the diode modes take their voltage (V_bus + 2 V_f)
    # from the input, as ``vd2 * u``, instead of the constant ``vd2``.
    diode_in: bool = False

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
            bm=f(p.motor_viscous_nm_s_rad),
            tcm=f(p.motor_coulomb_nm),
            wbm=f(p.motor.coulomb_band_rad_s),
            tsm=f(p.motor_breakaway_nm),
            wsm=f(p.motor.stribeck_edge_rad_s),
            jp=f(p.platter.j_kgm2),
            bp=f(p.platter.viscous_nm_s_rad),
            tcp=f(p.platter.coulomb_nm),
            wbp=f(p.platter.coulomb_band_rad_s),
            tsp=f(p.platter.breakaway_nm),
            wsp=f(p.platter.stribeck_edge_rad_s),
            k=f(p.belt.stiffness_nm_rad),
            c=f(p.belt.damping_nm_s_rad),
            half=f(0.5 * np.radians(p.gearbox.backlash_deg) / p.belt.ratio),
            n=f(p.gearbox.ratio * p.belt.ratio),
            eta=f(p.gearbox.efficiency),
            icl=f(p.bridge.current_limit_a),
            vd2=f(p.supply.voltage_v + 2.0 * p.bridge.diode_drop_v),
            inv_n=f(1.0 / (p.gearbox.ratio * p.belt.ratio)),
            diode_in=bool(p.supply.bus_model),
        )

    def members(self, n: int) -> list[Coefficients]:
        """The coefficients of each of the ``n`` members (floats) of a batch's (``(N,)``
        arrays where its parameters differ): the floats ``from_params`` gives for each
        member's parameters (``PlantParams.member``), every coefficient being computed
        element by element (``tests/sim/test_plant.py`` checks it)."""
        varying = [f.name for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)]
        if not varying:  # the batch's arrays are parameters no coefficient takes
            return [self] * n
        columns = [getattr(self, name).tolist() for name in varying]
        # (dataclasses.replace would run __init__ again for each, ~14 us a member)
        return [
            replace_unchecked(self, dict(zip(varying, row, strict=True)))
            for row in zip(*columns, strict=True)
        ]


def _friction_piece(region: int, tc: float, wb: float, ts: float, ws: float) -> tuple[float, float]:
    """The Coulomb/stiction law ``sim.motor.friction_torque_nm`` in friction region
    ``region`` (0..4) as ``slope * w + offset`` (viscous friction apart)."""
    if region == 2:  # band: up to the breakaway torque
        return ts / wb, 0.0
    sign = 1.0 if region > 2 else -1.0
    if region in (0, 4):  # beyond the Stribeck speed: Coulomb
        return 0.0, sign * tc
    # The Stribeck drop, a negative slope (no such region without stiction: ws = wb).
    drop = (ts - tc) / (ws - wb) if ws > wb else 0.0
    return -drop, sign * (ts + drop * wb)


def affine(key: int, co: Coefficients) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous ``(A (5, 5), B (5,), e (5,))`` of mode ``key`` (scalar coefficients)."""
    flow = key % 3
    contact = (key // 3) % 3 - 1
    fp = (key // 9) % 5
    fm = (key // 45) % 5
    bridge = key // MECH_MODES
    a = np.zeros((N_X, N_X))
    b = np.zeros(N_X)
    e = np.zeros(N_X)
    if bridge in (B_ON, B_DIODE_POS, B_DIODE_NEG):
        a[I_A, I_A] = -co.r / co.l
        a[I_A, VEL] = -co.ke / co.l
    if bridge == B_ON:
        b[I_A] = co.vs / co.l
    elif bridge == B_DIODE_POS:
        if co.diode_in:
            b[I_A] = -co.vd2 / co.l
        else:
            e[I_A] = -co.vd2 / co.l
    elif bridge == B_DIODE_NEG:
        if co.diode_in:
            b[I_A] = co.vd2 / co.l
        else:
            e[I_A] = co.vd2 / co.l
    a[POS, VEL] = 1.0
    # Belt torque on the platter, tau = kt_ twist + kwm w_m + kwp w_p + t0 (zero in the gap).
    if contact:
        k_tw, k_wm, k_wp, t0 = co.k, co.c / co.n, -co.c, -co.k * co.half * contact
    else:
        k_tw = k_wm = k_wp = t0 = 0.0
    g = co.eta / co.n if flow == F_BACK else 1.0 / (co.n * co.eta)
    a[VEL, I_A] = co.kt / co.jm
    a[VEL, VEL] = (-co.bm - g * k_wm) / co.jm
    a[VEL, TWIST] = -g * k_tw / co.jm
    a[VEL, PVEL] = -g * k_wp / co.jm
    e[VEL] = -g * t0 / co.jm
    slope, offset = _friction_piece(fm, co.tcm, co.wbm, co.tsm, co.wsm)
    a[VEL, VEL] -= slope / co.jm
    e[VEL] -= offset / co.jm
    if flow == F_STUCK:
        # Held at w_m = 0 (Filippov's sliding motion on the power-flow switch): the motor
        # torque lies between the back-driven and the driving loads, so it can turn neither
        # way; the gearbox's friction takes the difference. w_m stays exactly 0.
        a[VEL, :] = 0.0
        e[VEL] = 0.0
    a[TWIST, VEL] = 1.0 / co.n
    a[TWIST, PVEL] = -1.0
    a[PVEL, TWIST] = k_tw / co.jp
    a[PVEL, VEL] = k_wm / co.jp
    a[PVEL, PVEL] = (k_wp - co.bp) / co.jp
    e[PVEL] = t0 / co.jp
    slope, offset = _friction_piece(fp, co.tcp, co.wbp, co.tsp, co.wsp)
    a[PVEL, PVEL] -= slope / co.jp
    e[PVEL] -= offset / co.jp
    return a, b, e


def _taylor_expm1(a: np.ndarray) -> np.ndarray:
    """exp(a) - I for a small-norm matrix (<= 1/2): Taylor terms until they vanish.

    Kept without the identity so that squaring up (``_square_up``) never rounds the small
    entries of a short step against the 1 on the diagonal."""
    out = a.copy()
    term = a
    for k in range(2, 40):
        term = np.einsum("ij,jk->ik", term, a) / k
        out = out + term
        if float(np.max(np.abs(term))) <= 1e-18 * float(np.max(np.abs(out))):
            break
    return out


def _square_up(e: np.ndarray) -> np.ndarray:
    """``exp(2M) - I`` from ``E = exp(M) - I``: ``(I + E)**2 - I = 2E + E**2``."""
    return 2.0 * e + np.einsum("ij,jk->ik", e, e)


def expm_small(m: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small square matrix: scaling and squaring around a Taylor
    series (truncated below 1e-18 relative), with ``einsum`` products; the squaring is done
    on ``E = exp - I`` (``E <- 2E + E**2``, then ``I + E``), which keeps the digits of a
    short step that squaring ``exp`` itself rounds away against the identity.

    ``scipy.linalg.expm`` gives the same result, but its BLAS calls go multi-threaded even
    for 7 x 7 matrices and take milliseconds on a busy machine; the tests compare the two.
    """
    norm = float(np.max(np.sum(np.abs(m), axis=0)))
    squarings = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    e = _taylor_expm1(m / (1 << squarings))
    for _ in range(squarings):
        e = _square_up(e)
    return np.eye(m.shape[0]) + e


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

    One exponential at the finest step, then squaring up (``exp(2 M h) = exp(M h)**2``) in
    the form ``E <- 2E + E**2`` on ``E = Phi - I``, ``Phi = I + E`` at the end: the scaling
    and squaring of ``expm_small`` with every intermediate kept. (Squaring ``Phi`` itself
    twenty times rounds a 2 ns step's small entries against the 1 on the diagonal: 2e-6 rev
    of motor drift per 5 s at 990 deg/s, against 3e-15 this way.)
    """
    m = augmented(key, co)
    fine = h_s / (1 << levels)
    norm = float(np.max(np.sum(np.abs(m), axis=0))) * fine
    extra = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    e = _taylor_expm1(m * (fine / (1 << extra)))
    for _ in range(extra):
        e = _square_up(e)
    out = [e]
    for _ in range(levels):
        e = _square_up(e)
        out.append(e)
    eye = np.eye(N_X, N_X + 2)
    return [eye + p[:N_X, :] for p in reversed(out)]


def _with_room(
    phis: np.ndarray, rates: np.ndarray, used: int, more: int
) -> tuple[np.ndarray, np.ndarray]:
    """Mode tables ``(phis, rates)`` with room for ``more`` rows after the ``used`` ones:
    the same arrays if they have it, else copies grown by doubling (at least 16 rows)."""
    if used + more <= phis.shape[0]:
        return phis, rates
    grow = max(16, 2 * used, used + more)
    new_phis = np.empty((grow,) + phis.shape[1:])
    new_phis[:used] = phis[:used]
    new_rates = np.empty((grow,) + rates.shape[1:])
    new_rates[:used] = rates[:used]
    return new_phis, new_rates


class _ModeStore:
    """The rows of mode matrices of every parameter set (``phis`` ``(rows, levels + 1, 5,
    7)``: ``Phi`` over ``h_s / 2**level``; ``rates`` ``(rows, 3, 7)``: the rows of ``[A | B |
    e]`` of the motor and platter accelerations and of di/dt) for one ladder depth, in one
    pair of arrays that plants pass to the compiled step as they are: a row, once added,
    never changes, so a plant (or a Monte-Carlo batch's N sets) takes the rows earlier
    plants computed by their index (``Plant._slots``), with no copy. Process-wide and
    bounded (``mode_tables``); rows are added under a lock (runs may share a process)."""

    def __init__(self, levels: int) -> None:
        self.levels = levels
        self.phis = np.empty((0, levels + 1, N_X, N_X + 2))
        self.rates = np.empty((0, 3, N_X + 2))
        self.used = 0

    def add(self, key: int, co: Coefficients, h_s: float) -> int:
        """A new row: mode ``key``'s matrices for ``co`` at step ``h_s``."""
        ladder = zoh_ladder(key, co, h_s, self.levels)
        a, b, e = affine(key, co)
        with _STORE_LOCK:
            r = self.used
            phis, rates = _with_room(self.phis, self.rates, r, 1)
            phis[r] = ladder
            for j, q in enumerate((VEL, PVEL, I_A)):
                rates[r, j, :N_X] = a[q]
                rates[r, j, N_X] = b[q]
                rates[r, j, N_X + 1] = e[q]
            # the arrays first, then the count: a reader never sees a row not yet written
            self.phis, self.rates = phis, rates
            self.used = r + 1
        return r


class _ModeTables:
    """The modes met so far for one parameter set, step and ladder depth, as rows of a
    ``_ModeStore``, shared by every ``Plant`` with those (runs of a tuner or a study build
    many plants with the same coefficients): a plant starts with every mode an earlier one
    loaded, so its compiled step does not stop to ask for them (``Plant._load``); the
    numbers are the same whichever plant computed them (``zoh_ladder``, ``affine``)."""

    def __init__(self, store: _ModeStore) -> None:
        self.store = store
        self.rows: dict[int, int] = {}  # mode key -> row of store.phis / store.rates
        self._arrays = (np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64))

    def row(self, key: int, co: Coefficients, h_s: float) -> int:
        """The row of mode ``key``, computed the first time."""
        r = self.rows.get(key)
        if r is None:
            r = self.rows[key] = self.store.add(key, co, h_s)
        return r

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The modes met (keys) and their rows, as arrays."""
        if self._arrays[0].shape[0] != len(self.rows):
            keys = np.fromiter(self.rows.keys(), dtype=np.int64, count=len(self.rows))
            rows = np.fromiter(self.rows.values(), dtype=np.int64, count=len(self.rows))
            self._arrays = (keys, rows)
        return self._arrays


# (coefficients, h_s, levels) -> their _ModeTables, rows of _STORES[levels]; bounded (~6 kB
# a row at 20 levels): past _STORE_MAX_ROWS a new store starts, and plants made before keep
# the one they have (its rows stay valid; they add their new modes to it).
_MODE_TABLES: dict[tuple[Coefficients, float, int], _ModeTables] = {}
_STORES: dict[int, _ModeStore] = {}
_STORE_MAX_ROWS = 8192
_STORE_LOCK = threading.Lock()


def mode_store(levels: int) -> _ModeStore:
    """The current ``_ModeStore`` of ladder depth ``levels``."""
    store = _STORES.get(levels)
    if store is None or store.used >= _STORE_MAX_ROWS:
        with _STORE_LOCK:  # (runs may share a process: one new store, the memo not iterated
            store = _STORES.get(levels)  # while another thread adds to it)
            if store is None or store.used >= _STORE_MAX_ROWS:
                for slot in list(_MODE_TABLES):
                    if slot[2] == levels:
                        _MODE_TABLES.pop(slot, None)
                store = _STORES[levels] = _ModeStore(levels)
    return store


def mode_tables(co: Coefficients, h_s: float, levels: int) -> _ModeTables:
    """The shared ``_ModeTables`` of ``co`` (scalar coefficients) at step ``h_s``."""
    store = mode_store(levels)
    slot = (co, h_s, levels)
    tables = _MODE_TABLES.get(slot)
    if tables is None:
        tables = _MODE_TABLES[slot] = _ModeTables(store)
    return tables


# A batch's parameter sets and their _ModeTables, by the batch's coefficients: a study or
# a tuner builds the same batch run after run, and finding N sets' tables one by one costs
# a hash and a comparison of 25 fields each (~0.6 ms at N = 256). Bounded.
_BATCH_SETS: dict[tuple, tuple[list[Coefficients], list[_ModeTables]]] = {}
_BATCH_SETS_MAX = 8


def batch_sets(
    co: Coefficients, n: int, h_s: float, levels: int
) -> tuple[list[Coefficients], list[_ModeTables]]:
    """The ``n`` members' coefficients (``co.members(n)``) and their shared ``_ModeTables``
    (``mode_tables``), the same objects for a batch with the same coefficients (equal
    bytes) while the shared store is the same."""
    key = [n, h_s, levels]
    for f in fields(co):
        v = getattr(co, f.name)
        key.append((v.dtype.str, v.tobytes()) if isinstance(v, np.ndarray) else v)
    slot = tuple(key)
    store = mode_store(levels)
    hit = _BATCH_SETS.get(slot)
    if hit is not None and all(t.store is store for t in hit[1]):
        return hit
    sets = co.members(n)
    tables = [mode_tables(c, h_s, levels) for c in sets]
    if len(_BATCH_SETS) >= _BATCH_SETS_MAX:
        _BATCH_SETS.clear()
    _BATCH_SETS[slot] = (sets, tables)
    return sets, tables


def derivative(
    t: float,
    x: np.ndarray,
    u: tuple[Any, Any],
    params: PlantParams,
    motor_dir: float | None = None,
) -> np.ndarray:
    """dx/dt of the continuous model (x of shape (5,) or (N, 5); u = (duty, enable)).

    Written from the physics functions, independently of ``affine``, so that comparing the
    discrete plant with ``solve_ivp`` on this function checks the matrices as well.

    ``motor_dir`` (one state only) holds the gearbox's power-flow side for an integrator
    that handles w_m = 0 as an event: +1 or -1, the power flow as if the motor turned that
    way (the right-hand side then has no switch inside the segment); 0, the motor held at
    rest by the gearbox (``dw_m/dt = 0``: the sliding motion on the power-flow switch,
    ``sim.drivetrain.stuck_at_rest``). ``None``: the sign of w_m itself.
    """
    duty, enable = u
    if x.ndim == 1:
        return _derivative_one(x, float(duty), bool(enable), params, motor_dir)
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
        - friction_torque_nm(
            w,
            params.motor_coulomb_nm,
            m.coulomb_band_rad_s,
            params.motor_viscous_nm_s_rad,
            params.motor_breakaway_nm,
            m.stribeck_edge_rad_s,
        )  # fmt: skip
        - g * tb
    ) / m.j_kgm2
    dx[..., TWIST] = w / n - wp
    dx[..., PVEL] = (
        tb
        - friction_torque_nm(
            wp,
            pl.coulomb_nm,
            pl.coulomb_band_rad_s,
            pl.viscous_nm_s_rad,
            pl.breakaway_nm,
            pl.stribeck_edge_rad_s,
        )  # fmt: skip
    ) / pl.j_kgm2
    return dx


def _friction_one(w: float, tc: float, wb: float, ts: float, ws: float) -> float:
    """Coulomb/stiction torque at speed ``w`` on floats (``friction_torque_nm``'s law)."""
    speed = abs(w)
    if speed <= wb:
        return ts * w / wb
    mag = ts - (ts - tc) * (speed - wb) / (ws - wb) if speed <= ws else tc
    return math.copysign(mag, w)


def _derivative_one(
    x: np.ndarray,
    duty: float,
    enable: bool,
    params: PlantParams,
    motor_dir: float | None = None,
    bus_v: float | None = None,
    motor_rke: tuple[float, float, float] | None = None,
) -> np.ndarray:
    """``derivative`` for one state (5,) on Python floats: the same laws, ~10x faster for
    ``solve_ivp``; the tests check it against the vectorised branch. ``bus_v``: the bridge's
    rail (V) instead of the stiff supply (the bus model's oracle, ``sim.oracle``);
    ``motor_rke``: the motor's (R, K_t, K_e) instead of ``[motor]``'s (the heat model's
    oracle: R and K_t at the winding's temperature; R without the bridge's R_ON)."""
    m, pl, br = params.motor, params.platter, params.bridge
    n = params.total_ratio
    vs = params.supply.voltage_v if bus_v is None else bus_v
    i, _, w, tw, wp = (float(v) for v in x[:5])
    r_m, kt, ke = (m.r_ohm, m.kt_nm_a, m.ke_v_s_rad) if motor_rke is None else motor_rke
    emf = ke * w
    r = r_m + br.r_on_path_ohm
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
    side = w if motor_dir is None else motor_dir
    g = eta / n if tb * side < 0 else 1.0 / (n * eta)
    fm = _friction_one(
        w, params.motor_coulomb_nm, m.coulomb_band_rad_s, params.motor_breakaway_nm,
        m.stribeck_edge_rad_s,
    ) + params.motor_viscous_nm_s_rad * w  # fmt: skip
    fp = (
        _friction_one(
            wp, pl.coulomb_nm, pl.coulomb_band_rad_s, pl.breakaway_nm, pl.stribeck_edge_rad_s
        )
        + pl.viscous_nm_s_rad * wp
    )
    dw = 0.0 if motor_dir == 0 else (kt * i - fm - g * tb) / m.j_kgm2
    return np.array([di, w, dw, rate, (tb - fp) / pl.j_kgm2])


class Plant:
    """``n`` plants stepped in lock-step (one axis is n = 1); parameters scalar or ``(n,)``
    per member (``PlantParams`` with arrays).

    ``update(t_s, x, u) -> x_next`` advances the states ``x`` (``(n, 5)``) by ``h_s`` with
    ``u = (duty (n,), enable (n,))`` held, and returns a new array (``x`` is not changed).
    Each member's step is ``sim.plant_kernel.step``, compiled, in one call for all members:
    from the member's mode, the whole step is one ``Phi`` product; a step whose end lies in
    another mode (or whose motor speed, platter speed or twist leaves its region and comes
    back within the step, judged by a cubic Hermite through the values and rates at both
    ends) is halved, the first half taken in the start mode and the second in the mode
    where the first ended, recursively down to ``h_s / 2**event_levels`` and within
    ``split_budget`` halvings; a switch located to the finest level is accepted (a current
    freewheeling through a diode stops at zero, one that reached the bridge's limitation
    is held at I_CL).

    The matrices are memoised per (parameter set, mode): members with the same parameters
    share one set of tables. A mode met for the first time is computed here (``zoh_ladder``)
    and the compiled step resumes where it stopped. ``n_events`` counts located mode
    switches (statistics only).

    To extend the physics: a new parameter goes into ``Coefficients`` (and
    ``plant_kernel.pack_consts`` if the mode logic needs it), a new state or mode into
    ``affine`` and ``plant_kernel.key``; both serve every N.
    """

    def __init__(self, params: PlantParams, n: int, h_s: float, event_levels: int = 20) -> None:
        size = params.batch_size()
        if size is not None and size != n:
            raise ValueError(f"batch = {n}: parameter arrays have {size} members")
        self.n = int(n)
        self.params = params
        self.h_s = float(h_s)
        self.event_levels = int(event_levels)
        # A state resting on a mode boundary (e.g. the belt unloaded exactly at the edge of
        # the backlash gap) switches mode in every sub-step; without a budget the halving
        # would take 2**levels steps. Past the budget a step is accepted in its start mode
        # (the dynamics on both sides of such a boundary agree there).
        self.split_budget = 4 * self.event_levels + 8
        self.co = Coefficients.from_params(params)
        # One parameter set per member with arrays, else one for all.
        if size is None:
            self._sets = [self.co]
            tables = [mode_tables(self.co, self.h_s, self.event_levels)]
            self._group = np.zeros(self.n, dtype=np.int64)
        else:
            sets, tables = batch_sets(self.co, self.n, self.h_s, self.event_levels)
            self._sets = list(sets)  # add_group appends to it (heat): not to the shared one
            self._group = np.arange(self.n, dtype=np.int64)
        self._consts = plant_kernel.pack_consts(self.co, self.h_s).reshape(-1, N_CONSTS)
        if self._consts.shape[0] != len(self._sets):  # a batch whose arrays no coefficient takes
            self._consts = np.repeat(self._consts, len(self._sets), axis=0)
        self._slots = np.full((len(self._sets), N_MODES), -1, dtype=np.int64)
        # The rows of every mode's matrices, shared with other plants (no copy: _slots
        # index them).
        self._store = mode_store(self.event_levels)
        self.n_events = 0
        self._last_x: np.ndarray | None = None
        self._last_mech = np.zeros(self.n, dtype=np.int64)
        # step_members' scratch: a batch of SWEEP_MIN or more sweeps its common case.
        self._scratch = plant_kernel.sweep_scratch(self.n)
        self._preload(range(len(self._sets)), tables)

    @property
    def _phis(self) -> np.ndarray:
        """The ``phis`` table of the compiled step (``sim.plant_kernel``)."""
        return self._store.phis

    @property
    def _rates(self) -> np.ndarray:
        """The ``rates`` table of the compiled step."""
        return self._store.rates

    @property
    def _n_loaded(self) -> int:
        """How many (parameter set, mode) pairs this plant has the matrices of."""
        return int(np.count_nonzero(self._slots[: len(self._sets)] >= 0))

    def phi(self, key: int, level: int = 0, member: int = 0) -> np.ndarray:
        """``Phi`` (5, 7) of mode ``key`` over ``h_s / 2**level`` for ``member``."""
        g = int(self._group[member])
        if self._slots[g, key] < 0:
            self._load(g, key)
        return self._phis[self._slots[g, key], level].copy()

    def key(self, x: Sequence[float], duty: float, enable: bool, member: int = 0) -> int:
        """Mode key of one member's state ``x`` (5,) under input (duty, enable)."""
        i, _, w, tw, wp = (float(v) for v in x)
        consts = self._consts[self._group[member]]
        return int(plant_kernel.key(i, w, tw, wp, float(duty), bool(enable), consts))

    def add_group(self, co: Coefficients) -> int:
        """A new parameter set ``co`` (e.g. the motor at another temperature, ``sim.thermal``)
        with no matrices loaded yet; returns its index for ``group``."""
        g = len(self._sets)
        self._sets.append(co)
        if g == self._consts.shape[0]:  # grow by doubling (rows past the last set unused)
            grow = 2 * g
            consts = np.zeros((grow, self._consts.shape[1]))
            consts[:g] = self._consts
            slots = np.full((grow, N_MODES), -1, dtype=np.int64)
            slots[:g] = self._slots
            self._consts, self._slots = consts, slots
        self._consts[g] = plant_kernel.pack_consts(co, self.h_s)
        self._preload([g])
        return g

    def _preload(self, groups: Sequence[int], tables: Sequence[_ModeTables] | None = None) -> None:
        """Every mode of the parameter sets ``groups`` that an earlier plant with the same
        coefficients loaded (their ``mode_tables``, or ``tables``) and that is in this
        plant's store, in one assignment."""
        if tables is None:
            tables = [mode_tables(self._sets[g], self.h_s, self.event_levels) for g in groups]
        found = [(g, *t.arrays()) for g, t in zip(groups, tables, strict=True)
                 if t.store is self._store]  # fmt: skip
        if found:
            lengths = [keys.shape[0] for _, keys, _ in found]
            at = np.repeat(np.array([g for g, _, _ in found], dtype=np.int64), lengths)
            keys = np.concatenate([keys for _, keys, _ in found])
            self._slots[at, keys] = np.concatenate([rows for _, _, rows in found])

    def _load(self, group: int, key: int) -> None:
        """Find or compute mode ``key``'s matrices (parameter set ``group``) for the step."""
        co = self._sets[group]
        tables = mode_tables(co, self.h_s, self.event_levels)
        if tables.store is self._store:
            row = tables.row(key, co, self.h_s)
        else:  # the shared store was replaced since this plant was made (bounded): its own
            row = self._store.add(key, co, self.h_s)
        self._slots[group, key] = row

    def update(self, t_s: float, x: np.ndarray, u: tuple[Any, Any]) -> np.ndarray:
        """Advance ``x`` (``(n, 5)``) by ``h_s`` with ``u = (duty, enable)`` held (each a
        scalar or ``(n,)``); returns the new states ``(n, 5)``."""
        duty, enable = u
        n = self.n
        if not (isinstance(duty, np.ndarray) and duty.shape == (n,) and duty.dtype == float):
            duty = np.broadcast_to(np.asarray(duty, dtype=float), (n,))
        if not (isinstance(enable, np.ndarray) and enable.shape == (n,) and enable.dtype == bool):
            enable = np.broadcast_to(np.asarray(enable, dtype=bool), (n,))
        # The array this plant returned last: its mechanical modes are known (with the
        # bridge on and below I_CL, the bridge part is B_ON).
        known = x is self._last_x
        xn = np.empty((n, N_X))
        start = 0
        while True:
            start, events, group, need = plant_kernel.step_members(
                x, duty, enable, self._last_mech, known, start, self._group, self._slots,
                self._phis, self._rates, self._consts, self.event_levels,
                self.split_budget, xn, self._last_mech, 0, self._scratch,
            )  # fmt: skip
            self.n_events += events
            if need < 0:
                break
            # A mode met for the first time: load it, then go on from that member.
            self._load(group, need)
        self._last_x = xn
        return xn
