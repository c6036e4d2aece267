"""The plant step of ``sim.plant.Plant``, compiled (numba, no ``fastmath``): ``step`` is one
member's step (the recursion over halved sub-steps), ``step_members`` runs it for every
member in one call. The one implementation for every N.

``step_members`` takes the common case itself: a whole step in the start mode that ends in
it and passes the excursion check (``step``'s first pass) is accepted without ``step``'s
sub-step stack. ``_stays`` tells it so with the same expressions as ``key``'s and
``_excursion``'s, evaluated together without branches (with the bridge on below I_CL, an
end speed not exactly 0, and every boundary apart from its edge; the speeds' exact gates
and Hermite tests, ``_speeds_leave``, only when a speed is within its gate's bound);
anything else goes to ``step`` from the start, which decides the same (a step that ends in
its start mode with a boundary near its edge: from its first pass's ``_excursion``
test, the advance and end key passed in). A batch of ``SWEEP_MIN`` or more members has that
common case swept first for every member in its known mode (``_sweep``: the same
expressions on rows of a scratch, each member's coefficients kept there between steps,
without a branch, so the compiler evaluates several members per instruction, four with
AVX2), and the member loop takes the members it accepted as they are.
Kernels use numba's numpy error model (``kernel``'s default): no division-by-zero checks in
the loops (no division here can be by zero on a valid bench; one would give inf/NaN
instead of raising inside compiled code).

The kernel is pure: the matrices come in as tables filled by ``Plant`` (a mode it has not
seen yet is returned as ``need`` and the caller loads it and calls again), and the event
count, the end mode and the new state go out as return values.

Tables (``M`` modes loaded so far, ``L = event_levels``, ``G`` parameter sets):

- ``slots`` ``(N_MODES,)`` int64 (``(G, N_MODES)`` for ``step_members``): row of a mode
  in the tables, -1 if not loaded;
- ``phis`` ``(M, L + 1, 5, 7)``: ``Phi`` of the mode over ``h / 2**level``;
- ``rates`` ``(M, 3, 7)``: the rows of ``[A | B | e]`` of the motor and platter
  accelerations and of di/dt (the excursion gate's Hermite slopes);
- ``consts`` ``(N_CONSTS,)`` (``(G, N_CONSTS)``): the coefficients, at the indices named
  below.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from firmware_model.kernel_cache import kernel

__all__ = [
    "N_CONSTS", "SWEEP_MIN", "hermite_leaves", "key", "pack_consts", "step", "step_members",
    "sweep_scratch", "warm_up",
]  # fmt: skip

# Bridge modes (sim.plant's numbering).
_B_ON, _B_LIMIT_POS, _B_LIMIT_NEG, _B_DIODE_POS, _B_DIODE_NEG, _B_OPEN = range(6)

# consts[...] indices.
(
    _WBM, _WBP, _HALF, _K, _C, _N, _VS, _R, _KE, _ICL, _VD2, _INV_N, _KT, _TCM, _BM, _G_MAX,
    _JM, _TCP, _BP, _JP, _H_S, _ETA, _TSM, _WSM, _TSP, _WSP,
    _UB_M0, _UB_MA, _UB_MW, _UB_MI, _UB_MT, _UB_P0, _UB_PA, _UB_PT, _UB_PP,
) = range(35)  # fmt: skip
N_CONSTS = 35
# _UB_*: the coefficients of gate_bounds (magnitudes, divided by J_m or J_p; never for a
# result). 1 + _MARGIN covers their rounding against the exact gates'.
_MARGIN = 1.0 + 1e-9
# Mechanical modes per bridge mode (sim.plant.MECH_MODES) and the stuck power-flow mode.
_MECH = 225
_F_STUCK = 2


def pack_consts(co: Any, h_s: float) -> np.ndarray:
    """The ``consts`` array of a ``sim.plant.Coefficients``: ``(N_CONSTS,)`` of scalar
    coefficients, ``(N, N_CONSTS)`` of a batch's (``(N,)`` arrays where they differ; each
    row the floats of that member's scalar coefficients: the same operations, element by
    element)."""
    g_max = 1.0 / (co.n * co.eta)  # the gearbox's largest gain (driving: sim.plant.affine)
    names = (
        "wbm", "wbp", "half", "k", "c", "n", "vs", "r", "ke", "icl", "vd2", "inv_n", "kt",
        "tcm", "bm",
    )  # fmt: skip
    values = [getattr(co, name) for name in names]
    values += [g_max, co.jm, co.tcp, co.bp, co.jp, h_s, co.eta, co.tsm, co.wsm, co.tsp, co.wsp]
    # gate_bounds' coefficients: sums of magnitudes, over |J_m| or |J_p|.
    a = np.abs
    kt, r, jm, jp = a(co.kt), a(co.r), a(co.jm), a(co.jp)
    values += [
        a(co.wsm),
        (kt * a(co.vs) / r + a(co.tsm)) / jm,
        (kt * a(co.ke) / r + a(co.bm)) / jm,
        kt / jm,
        a(g_max) / jm,
        a(co.wsp),
        a(co.tsp) / jp,
        2.0 / jp,
        a(co.bp) / jp,
    ]
    return np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in values)), axis=-1)


@kernel
def key(i, w, tw, wp, duty, enable, kc):
    """Mode key of one state (``sim.plant``'s numbering of bridge, friction, contact and
    power-flow modes)."""
    wbm, wbp, half, k, c, n = kc[_WBM], kc[_WBP], kc[_HALF], kc[_K], kc[_C], kc[_N]
    vs, r, ke, icl, vd2 = kc[_VS], kc[_R], kc[_KE], kc[_ICL], kc[_VD2]
    fm = _friction_region(w, wbm, kc[_WSM])
    fp = _friction_region(wp, wbp, kc[_WSP])
    if tw > half:
        contact = 2
        tb = k * (tw - half) + c * (w / n - wp)
    elif tw < -half:
        contact = 0
        tb = k * (tw + half) + c * (w / n - wp)
    else:
        contact = 1
        tb = 0.0
    flow = 1 if tb * w < 0 else 0
    if w == 0.0 and tb != 0.0:
        flow = _flow_at_rest(kc[_KT] * i, tb, n, kc[_ETA])
    if enable:
        bridge = _B_ON
        if i >= icl and vs * duty - r * i - ke * w > 0:
            bridge = _B_LIMIT_POS
        elif i <= -icl and vs * duty - r * i - ke * w < 0:
            bridge = _B_LIMIT_NEG
    elif i > 0:
        bridge = _B_DIODE_POS
    elif i < 0:
        bridge = _B_DIODE_NEG
    else:
        emf = ke * w
        bridge = _B_DIODE_NEG if emf > vd2 else (_B_DIODE_POS if emf < -vd2 else _B_OPEN)
    return (((bridge * 5 + fm) * 5 + fp) * 3 + contact) * 3 + flow


@kernel
def _friction_region(v, band, stribeck):
    """0..4: below -stribeck, falling (negative side), band, falling (positive), above."""
    if v > band:
        return 4 if v > stribeck else 3
    if v < -band:
        return 0 if v < -stribeck else 1
    return 2


@kernel
def _belt_torque(tw, rate, kc):
    """Belt torque on the platter (N*m) at twist ``tw`` and twist rate ``rate``."""
    half = kc[_HALF]
    if tw > half:
        return kc[_K] * (tw - half) + kc[_C] * rate
    if tw < -half:
        return kc[_K] * (tw + half) + kc[_C] * rate
    return 0.0


@kernel
def _flow_at_rest(torque_nm, tb, n, eta):
    """Power-flow mode of a motor at rest (w_m = 0) with belt torque ``tb`` != 0.

    Turning with the load (``tb w > 0``) the motor meets ``tb / (N eta)``, against it only
    ``eta tb / N``: a motor torque between the two turns it neither way (stuck, 2); above
    or below, it leaves in the direction of the net torque, driving (0) or driven (1)."""
    drive = tb / (n * eta)
    back = tb * eta / n
    lo = back if tb > 0 else drive
    hi = drive if tb > 0 else back
    if lo <= torque_nm <= hi:
        return 2
    return 0 if (torque_nm > hi) == (tb > 0) else 1


@kernel
def _region(v, edge):
    return 2 if v > edge else (0 if v < -edge else 1)


@kernel
def hermite_leaves(p0, p1, m0, m1, edge):
    """Whether the cubic Hermite through (p0, slope m0) at s = 0 and (p1, m1) at s = 1 has
    an interior extremum in another region of ``(-inf, -edge), [-edge, edge], (edge, inf)``
    than its ends (which share one)."""
    # Ends far from both edges compared with the change over the step: no excursion.
    reach = abs(m0) + abs(m1) + abs(p1 - p0)
    d0 = abs(p0) - edge
    d1 = abs(p1) - edge
    if (d0 > reach or -d0 > reach) and (d1 > reach or -d1 > reach):
        return False
    region = _region(p0, edge)
    a = 6.0 * (p0 - p1) + 3.0 * (m0 + m1)
    b = -6.0 * (p0 - p1) - 4.0 * m0 - 2.0 * m1
    c = m0
    n_roots = 0
    s0 = s1 = 0.0
    if abs(a) < 1e-300:
        if b:
            s0 = -c / b
            n_roots = 1
    else:
        disc = b * b - 4.0 * a * c
        if disc < 0:
            return False
        q = math.sqrt(disc)
        s0 = (-b - q) / (2.0 * a)
        s1 = (-b + q) / (2.0 * a)
        n_roots = 2
    for j in range(n_roots):
        s = s0 if j == 0 else s1
        if 0.0 < s < 1.0:
            s2, s3 = s * s, s * s * s
            v = (
                (2 * s3 - 3 * s2 + 1) * p0
                + (s3 - 2 * s2 + s) * m0
                + (-2 * s3 + 3 * s2) * p1
                + (s3 - s2) * m1
            )
            if _region(v, edge) != region:
                return True
    return False


@kernel(inline="always")
def _apart(p0, p1, m0, m1, edge):
    """``hermite_leaves``' first test where it is called (a call costs more than the test):
    True if both ends are farther from both edges than the change over the step, so the
    cubic cannot leave their region."""
    reach = abs(m0) + abs(m1) + abs(p1 - p0)
    # |d| > reach: d > reach or -d > reach, in fewer instructions (and no branch)
    return (abs(abs(p0) - edge) > reach) & (abs(abs(p1) - edge) > reach)


@kernel(inline="always")
def gates(wmax, ai, tbmax, apmax, h, kc):
    """``_excursion``'s gates ``(motor, platter)`` (rad/s): the speeds below which a step of
    ``h`` may reach a friction band, from the largest current the armature can approach
    (``(V_s + K_e |w|) / R``, or ``ai`` if more), the speeds' ends ``wmax``, ``apmax`` and the
    belt torque's bound ``tbmax``."""
    i_bound = (kc[_VS] + kc[_KE] * wmax) / kc[_R]
    if ai > i_bound:
        i_bound = ai
    a_m = (kc[_KT] * i_bound + kc[_TSM] + kc[_BM] * wmax + tbmax * kc[_G_MAX]) / kc[_JM]
    a_p = (2.0 * tbmax + kc[_TSP] + kc[_BP] * apmax) / kc[_JP]
    # the outer edges (the bands' without stiction)
    return kc[_WSM] + h * a_m, kc[_WSP] + h * a_p


@kernel(inline="always")
def gate_bounds(wmax, ai, tbmax, apmax, h, kc):
    """Upper bounds of ``gates`` without a division: the same terms as magnitudes, with
    ``K_t max(a, ai)`` bounded by ``K_t (a + ai)`` and the coefficients summed and divided
    once in ``pack_consts`` (``_UB_*``), so a bound is at least its gate in exact arithmetic
    and the rounding of either is a few ulps, which ``_MARGIN`` covers (a speed beyond its
    bound is beyond its gate, whatever the rounding)."""
    a_m = kc[_UB_MA] + kc[_UB_MW] * wmax + kc[_UB_MI] * ai + kc[_UB_MT] * tbmax
    a_p = kc[_UB_PA] + kc[_UB_PT] * tbmax + kc[_UB_PP] * apmax
    return (kc[_UB_M0] + h * a_m) * _MARGIN, (kc[_UB_P0] + h * a_p) * _MARGIN


@kernel(inline="always")
def _current_row(rates, row):
    """The row of ``[A | B | e]`` of di/dt in the mode of table row ``row`` (``rates[row,
    2]``) as the 6 scalars ``_current_rates`` takes (the position's column is not used)."""
    # Scalar loads, no views (a view costs reference counting in numba).
    return (
        rates[row, 2, 0], rates[row, 2, 2], rates[row, 2, 3], rates[row, 2, 4],
        rates[row, 2, 5], rates[row, 2, 6],
    )  # fmt: skip


@kernel(inline="always")
def _current_rates(ci, i0, w0, t0, p0, i1, w1, t1, p1, d):
    """di/dt at both ends of a step with ``ci = _current_row(...)``."""
    c0, c2, c3, c4, c5, c6 = ci
    return (
        c0 * i0 + c2 * w0 + c3 * t0 + c4 * p0 + c5 * d + c6,
        c0 * i1 + c2 * w1 + c3 * t1 + c4 * p1 + c5 * d + c6,
    )


@kernel(inline="always")
def _speed_row(rates, row):
    """The rows of ``[A | B | e]`` of the motor's and the platter's accelerations in the mode
    of table row ``row`` (``rates[row, 0]``, ``rates[row, 1]``) as the 10 scalars
    ``_speed_rates`` takes (the position's and the duty's columns are 0)."""
    return (
        rates[row, 0, 0], rates[row, 0, 2], rates[row, 0, 3], rates[row, 0, 4], rates[row, 0, 6],
        rates[row, 1, 0], rates[row, 1, 2], rates[row, 1, 3], rates[row, 1, 4], rates[row, 1, 6],
    )  # fmt: skip


@kernel(inline="always")
def _speed_rates(sv, i0, w0, t0, p0, i1, w1, t1, p1):
    """The motor's and the platter's accelerations at both ends of a step with ``sv =
    _speed_row(...)``: ``(wd0, pd0, wd1, pd1)``."""
    v0, v2, v3, v4, v6, q0, q2, q3, q4, q6 = sv
    return (
        v0 * i0 + v2 * w0 + v3 * t0 + v4 * p0 + v6,
        q0 * i0 + q2 * w0 + q3 * t0 + q4 * p0 + q6,
        v0 * i1 + v2 * w1 + v3 * t1 + v4 * p1 + v6,
        q0 * i1 + q2 * w1 + q3 * t1 + q4 * p1 + q6,
    )


@kernel
def _excursion(i0, w0, t0, p0, i1, w1, t1, p1, d, bridge_on, rates, row, h, kc):
    """Whether a boundary was crossed and re-crossed inside a step of ``h`` whose start and
    end share a mode (a velocity dipping into a friction band and out, a short trip through
    the backlash gap, the belt torque changing sign and back in contact, which flips the
    gearbox's power flow, a current peaking past I_CL). Each boundary variable (motor speed,
    platter speed, twist, belt torque, current) is interpolated by the cubic Hermite through
    its values and rates at both ends (``rates[row]``: the mode's rows of the motor and
    platter accelerations and of di/dt); an interior extremum on the other side of a
    boundary calls for halving.

    A speed whose ends are farther from its band than ``h`` times a bound on its
    acceleration cannot reach the band and is not interpolated: the motor's bound uses the
    largest current the armature can approach, ``(V_s + |K_e w|) / R``; the platter's twice
    the belt torque at the ends plus its friction."""
    inv_n, half, k, c = kc[_INV_N], kc[_HALF], kc[_K], kc[_C]
    icl = kc[_ICL]
    r0 = w0 * inv_n - p0
    r1 = w1 * inv_n - p1
    ar0, ar1 = abs(r0), abs(r1)
    at0, at1 = abs(t0), abs(t1)
    reach = (ar0 + ar1) * h + abs(t1 - t0)
    d0 = at0 - half
    d1 = at1 - half
    if not ((d0 > reach or -d0 > reach) and (d1 > reach or -d1 > reach)) and (
        hermite_leaves(t0, t1, r0 * h, r1 * h, half)
    ):
        return True
    if bridge_on:
        # The chip's current limitation: a current that rises past I_CL and falls back
        # within the step (the back-EMF catching up) was held at I_CL meanwhile.
        di0, di1 = _current_rates(_current_row(rates, row), i0, w0, t0, p0, i1, w1, t1, p1, d)
        m0, m1 = di0 * h, di1 * h
        if not _apart(i0, i1, m0, m1, icl) and hermite_leaves(i0, i1, m0, m1, icl):
            return True
    wd0, pd0, wd1, pd1 = _speed_rates(_speed_row(rates, row), i0, w0, t0, p0, i1, w1, t1, p1)
    if d0 > 0.0 and d1 > 0.0:
        # In contact at both ends (same side): the belt torque's sign sets the power flow
        # through the gearbox; a sign change and back inside the step is a hidden switch.
        sh = half if t0 > 0.0 else -half
        tb0 = k * (t0 - sh) + c * r0
        tb1 = k * (t1 - sh) + c * r1
        tbd0 = k * r0 + c * (wd0 * inv_n - pd0)
        tbd1 = k * r1 + c * (wd1 * inv_n - pd1)
        m0, m1 = tbd0 * h, tbd1 * h
        if not _apart(tb0, tb1, m0, m1, 0.0) and hermite_leaves(tb0, tb1, m0, m1, 0.0):
            return True
    tbmax = k * (at0 if at0 > at1 else at1) + c * (ar0 if ar0 > ar1 else ar1)
    ai0, ai1 = abs(i0), abs(i1)
    ai = ai0 if ai0 >= ai1 else ai1
    return _speeds_leave(w0, w1, p0, p1, wd0, wd1, pd0, pd1, ai, tbmax, h, kc)


@kernel
def _speeds_leave(w0, w1, p0, p1, wd0, wd1, pd0, pd1, ai, tbmax, h, kc):
    """``_excursion``'s last test, on the motor and platter speeds (``w``, ``p``) with their
    rates (``wd``, ``pd``) at both ends, ``ai`` the larger end current's magnitude and
    ``tbmax`` the belt torque's bound (its docstring)."""
    wbm, wbp = kc[_WBM], kc[_WBP]
    # Friction bounds at their largest (the breakaway torque; Coulomb without stiction).
    wsm, wsp = kc[_WSM], kc[_WSP]
    # First hermite_leaves' own first test (_apart), which needs no gate: a speed whose
    # ends are apart from its edges cannot leave (the common case: speeds within their
    # gates but far from the bands compared with their change over the step).
    mw0, mw1 = wd0 * h, wd1 * h
    mp0, mp1 = pd0 * h, pd1 * h
    near_m = not _apart(w0, w1, mw0, mw1, wbm) or (
        wsm > wbm and not _apart(w0, w1, mw0, mw1, wsm)
    )
    near_p = not _apart(p0, p1, mp0, mp1, wbp) or (
        wsp > wbp and not _apart(p0, p1, mp0, mp1, wsp)
    )
    if not (near_m or near_p):
        return False
    aw0, aw1 = abs(w0), abs(w1)
    wmax = aw0 if aw0 > aw1 else aw1
    ap0, ap1 = abs(p0), abs(p1)
    apmax = ap0 if ap0 > ap1 else ap1
    # Then the gates' upper bounds without a division (the exact gates divide twice in a
    # row): a speed beyond its bound is beyond its gate.
    ub_m, ub_p = gate_bounds(wmax, ai, tbmax, apmax, h, kc)
    check_m = near_m and not (aw0 > ub_m and aw1 > ub_m)
    check_p = near_p and not (ap0 > ub_p and ap1 > ub_p)
    if not (check_m or check_p):
        return False
    gate_m, gate_p = gates(wmax, ai, tbmax, apmax, h, kc)
    check_m = check_m and (aw0 <= gate_m or aw1 <= gate_m)
    check_p = check_p and (ap0 <= gate_p or ap1 <= gate_p)
    if check_m and (
        hermite_leaves(w0, w1, mw0, mw1, wbm)
        or (wsm > wbm and hermite_leaves(w0, w1, mw0, mw1, wsm))
    ):
        return True
    return check_p and (
        hermite_leaves(p0, p1, mp0, mp1, wbp)
        or (wsp > wbp and hermite_leaves(p0, p1, mp0, mp1, wsp))
    )


@kernel(inline="always")
def _stays(k0, i0, w0, t0, p0, i1, w1, t1, p1, d, en, ci, sv, h, kc):
    """``step_members``' test of ``step``'s first pass, the step of ``h`` in mode ``k0``
    (>= 0) from ``(i0, w0, t0, p0)`` to ``(i1, w1, t1, p1)``. Returns ``(ok, sure, mode,
    wd0, wd1, pd0, pd1, ai, tbmax)``: ``mode`` if the step ends in ``k0`` with an end speed
    not exactly 0 (``key``'s power flow at rest) and, with the bridge enabled, a current
    below I_CL (so ``k0``'s bridge is on iff enabled, and ``step``'s I_CL test passes);
    ``ok`` if besides ``_excursion``'s tests before ``_speeds_leave`` pass (twist, current
    with the bridge on, belt torque in contact: each apart from its edge); ``sure`` if both
    speeds are beyond their gates' bounds too (``_speeds_leave`` is then False); the rest
    are ``_speeds_leave``'s arguments. So ``ok and (sure or not _speeds_leave(...))`` is
    ``step``'s acceptance, and ``mode`` and ``not _excursion(...)`` too; False only means
    "not sure" (``step`` decides).

    ``key``'s and ``_excursion``'s expressions, evaluated together and without branches:
    the common case is one stretch of code (~25 % less time than taking the branches
    one after the other, the same operations)."""
    half, k, c, icl = kc[_HALF], kc[_K], kc[_C], kc[_ICL]
    # key(i1, w1, t1, p1, d, en) == k0
    fm = _friction_region(w1, kc[_WBM], kc[_WSM])
    fp = _friction_region(p1, kc[_WBP], kc[_WSP])
    contact = 2 if t1 > half else (0 if t1 < -half else 1)
    tb = k * (t1 - (half if t1 > half else -half)) + c * (w1 / kc[_N] - p1)
    flow = 1 if (contact != 1) & (tb * w1 < 0) else 0
    emf = kc[_KE] * w1
    vd2 = kc[_VD2]
    off = _B_DIODE_NEG if emf > vd2 else (_B_DIODE_POS if emf < -vd2 else _B_OPEN)
    off = _B_DIODE_POS if i1 > 0 else (_B_DIODE_NEG if i1 < 0 else off)
    # Enabled below I_CL the bridge is on (so k0 is, and step's I_CL test cannot fail).
    bridge = _B_ON if en else off
    same = ((((bridge * 5 + fm) * 5 + fp) * 3 + contact) * 3 + flow == k0) & (w1 != 0.0)
    same &= (not en) | (abs(i1) < icl)
    mode = same
    # _excursion's quick tests: twist, current (bridge on), belt torque (in contact), gates.
    inv_n = kc[_INV_N]
    r0 = w0 * inv_n - p0
    r1 = w1 * inv_n - p1
    ar0, ar1 = abs(r0), abs(r1)
    at0, at1 = abs(t0), abs(t1)
    reach = (ar0 + ar1) * h + abs(t1 - t0)
    d0 = at0 - half
    d1 = at1 - half
    same &= (abs(d0) > reach) & (abs(d1) > reach)
    di0, di1 = _current_rates(ci, i0, w0, t0, p0, i1, w1, t1, p1, d)
    same &= (k0 >= _MECH) | _apart(i0, i1, di0 * h, di1 * h, icl)
    wd0, pd0, wd1, pd1 = _speed_rates(sv, i0, w0, t0, p0, i1, w1, t1, p1)
    sh = half if t0 > 0.0 else -half
    tb0 = k * (t0 - sh) + c * r0
    tb1 = k * (t1 - sh) + c * r1
    tbd0 = k * r0 + c * (wd0 * inv_n - pd0)
    tbd1 = k * r1 + c * (wd1 * inv_n - pd1)
    same &= (not ((d0 > 0.0) & (d1 > 0.0))) | _apart(tb0, tb1, tbd0 * h, tbd1 * h, 0.0)
    aw0, aw1 = abs(w0), abs(w1)
    wmax = aw0 if aw0 > aw1 else aw1
    tbmax = k * (at0 if at0 > at1 else at1) + c * (ar0 if ar0 > ar1 else ar1)
    ai0, ai1 = abs(i0), abs(i1)
    ai = ai0 if ai0 >= ai1 else ai1
    ap0, ap1 = abs(p0), abs(p1)
    apmax = ap0 if ap0 > ap1 else ap1
    ub_m, ub_p = gate_bounds(wmax, ai, tbmax, apmax, h, kc)
    sure = (aw0 > ub_m) & (aw1 > ub_m) & (ap0 > ub_p) & (ap1 > ub_p)
    return same, sure, mode, wd0, wd1, pd0, pd1, ai, tbmax


@kernel(inline="always")
def _coefficients(phis, row, level):
    """The coefficients of one sub-step of ``h / 2**level`` in the mode of table row ``row``
    (``_apply``'s ``c``): the rows of ``Phi`` but the position's column, which is 0 (the
    position is the integral: ``p`` adds to its row), as 30 scalars."""
    # Scalar loads, no views (a view costs reference counting in numba).
    return (
        phis[row, level, 0, 0], phis[row, level, 0, 2], phis[row, level, 0, 3],
        phis[row, level, 0, 4], phis[row, level, 0, 5], phis[row, level, 0, 6],
        phis[row, level, 1, 0], phis[row, level, 1, 2], phis[row, level, 1, 3],
        phis[row, level, 1, 4], phis[row, level, 1, 5], phis[row, level, 1, 6],
        phis[row, level, 2, 0], phis[row, level, 2, 2], phis[row, level, 2, 3],
        phis[row, level, 2, 4], phis[row, level, 2, 5], phis[row, level, 2, 6],
        phis[row, level, 3, 0], phis[row, level, 3, 2], phis[row, level, 3, 3],
        phis[row, level, 3, 4], phis[row, level, 3, 5], phis[row, level, 3, 6],
        phis[row, level, 4, 0], phis[row, level, 4, 2], phis[row, level, 4, 3],
        phis[row, level, 4, 4], phis[row, level, 4, 5], phis[row, level, 4, 6],
    )  # fmt: skip


@kernel(inline="always")
def _apply(c, i, p, w, tw, wp, d):
    """The state after one sub-step: ``Phi [x; d; 1]`` with ``c = _coefficients(...)``."""
    ni = c[0] * i + c[1] * w + c[2] * tw + c[3] * wp + c[4] * d + c[5]
    np_ = p + c[6] * i + c[7] * w + c[8] * tw + c[9] * wp + c[10] * d + c[11]
    nw = c[12] * i + c[13] * w + c[14] * tw + c[15] * wp + c[16] * d + c[17]
    ntw = c[18] * i + c[19] * w + c[20] * tw + c[21] * wp + c[22] * d + c[23]
    nwp = c[24] * i + c[25] * w + c[26] * tw + c[27] * wp + c[28] * d + c[29]
    return ni, np_, nw, ntw, nwp


@kernel
def _advance(phis, row, level, i, p, w, tw, wp, d):
    """The state after one sub-step of ``h / 2**level`` in the mode of table row ``row``."""
    return _apply(_coefficients(phis, row, level), i, p, w, tw, wp, d)


@kernel
def step(
    i, p, w, tw, wp, d, en, start_key, levels, budget, slots, phis, rates, kc, level0, near,
    ni, np_, nw, ntw, nwp,
):  # fmt: skip
    """One plant step of ``h_s / 2**level0`` with ``(d, en)`` held, from mode ``start_key``
    (-1: work it out), as ``Plant.update`` describes: halve a step whose end mode differs from
    its start mode (or that leaves and re-enters it) up to ``levels`` times,
    within ``budget`` halvings; take the first half in the start mode, the second in the
    mode where the first ended.

    Returns ``(i, p, w, tw, wp, end_key, n_events, need)``: the new state, the mode key of
    the last sub-step's end, the switches located to the finest level, and ``need`` = -1;
    or ``need`` >= 0 when mode ``need`` is not in the tables yet (the other values are then
    meaningless: load the mode and call again with the same arguments).

    ``near``: the first pass is known to end in ``start_key`` at ``(ni, np_, nw, ntw, nwp)``
    with no I_CL crossing and ``level0 < levels``, ``budget > 0`` (``step_members``: its
    ``_stays``' ``mode``); then it takes ``_excursion``'s test at once. Else those five
    values are not used.
    """
    h_s = kc[_H_S]
    icl = kc[_ICL]
    if near:
        # step's first pass with its advance and end key known (bridge on iff key < _MECH)
        h = h_s / (1 << level0)
        bridge_on = start_key < _MECH
        row = slots[start_key]
        if not _excursion(i, w, tw, wp, ni, nw, ntw, nwp, d, bridge_on, rates, row, h, kc):
            return ni, np_, nw, ntw, nwp, start_key, 0, -1
    if start_key < 0:
        start_key = key(i, w, tw, wp, d, en, kc)
    # The sub-steps, last in first out: a halved step does its first half next (in its
    # start mode) and leaves its second half pending (in the mode the first half reaches:
    # key -1). A second half pends one level deeper than the step that halved, which is at
    # least as deep as every pending one, so the pending second halves have distinct levels
    # and the deepest is the last pushed: a bit mask of levels (<= levels <= 41) is the
    # whole stack, and the step needs no scratch array (the kernel allocates nothing).
    pending = 0
    level = level0
    k = start_key
    n_events = 0
    key_end = start_key
    k_row = row = -1
    while True:
        if k < 0:
            k = key(i, w, tw, wp, d, en, kc)
        if k != k_row:
            # (a branch, taken rarely: the tables' loads need not wait for the key)
            k_row = k
            row = slots[k]
        if row < 0:
            return i, p, w, tw, wp, key_end, n_events, k
        ni, np_, nw, ntw, nwp = _advance(phis, row, level, i, p, w, tw, wp, d)
        key_end = key(ni, nw, ntw, nwp, d, en, kc)
        accept = key_end == k
        bridge_on = k // _MECH == _B_ON
        if accept and bridge_on and -icl <= i <= icl and (ni > icl or ni < -icl):
            # Past I_CL at the end, but the drive has turned back (so the end's mode is
            # "on" again): the limitation held the current at I_CL in between.
            accept = False
        if accept and level < levels and budget > 0:
            h = h_s / (1 << level)
            accept = not _excursion(i, w, tw, wp, ni, nw, ntw, nwp, d, bridge_on, rates, row, h, kc)
        if not accept and (level >= levels or budget <= 0):
            # Located to h / 2**levels: accept (a diode current stops at zero, a current that
            # reached the bridge's limitation is held at I_CL).
            n_events += 1
            bridge = k // _MECH
            if (bridge == _B_DIODE_POS and ni < 0) or (bridge == _B_DIODE_NEG and ni > 0):
                ni = 0.0
            limit = key_end // _MECH
            if ni > icl and (limit == _B_LIMIT_POS or (bridge_on and i <= icl)):
                ni = icl
            elif ni < -icl and (limit == _B_LIMIT_NEG or (bridge_on and i >= -icl)):
                ni = -icl
            if (w > 0.0 and nw <= 0.0) or (w < 0.0 and nw >= 0.0):
                # The motor speed passed zero: if the gearbox holds it there (the power-flow
                # switch's stick), it stays at rest until the torque leaves the band.
                tb = _belt_torque(ntw, nw * kc[_INV_N] - nwp, kc)
                if tb != 0.0 and _flow_at_rest(kc[_KT] * ni, tb, kc[_N], kc[_ETA]) == _F_STUCK:
                    nw = 0.0
            key_end = key(ni, nw, ntw, nwp, d, en, kc)
            accept = True
        if accept:
            i, p, w, tw, wp = ni, np_, nw, ntw, nwp
            if pending == 0:
                break
            level = levels  # the deepest pending second half next
            while not (pending >> level) & 1:
                level -= 1
            pending ^= 1 << level
            k = -1
            continue
        budget -= 1
        level += 1
        pending |= 1 << level
    return i, p, w, tw, wp, key_end, n_events, -1


# Members from which step_members sweeps the common case over the whole batch first.
SWEEP_MIN = 16
# step_members' scratch, ``(blocks, MEMBER_ROWS * _LANES)``: member j is lane j % _LANES of
# block j // _LANES, and row r of a block its entries [r * _LANES, (r + 1) * _LANES). A row's
# offset is a constant: the compiler sees that the sweep's stores and loads, all in one
# block, never overlap (rows of runtime length would need a check for each pair, more than
# it makes, and the loop would stay scalar). Rows: 0-4 a member's state before the step,
# 5-9 after, 10 whether the sweep accepted it, then the coefficients of the mode it was
# last swept in, kept between steps and copied again when its mode, parameter set or level
# changes (so the sweep reads rows, not ~80 scattered table entries a member).
_LANES = 64
_DONE = 10
_TAG = 11  # (group * n_modes + key) * 64 + level0 of a member's rows below; NaN: none
_C_PHI = 12  # 30 rows: _coefficients(phis, row, level0)
_C_CUR = _C_PHI + 30  # 6: _current_row(rates, row)
_C_SPD = _C_CUR + 6  # 10: _speed_row(rates, row)
_C_K = _C_SPD + 10  # N_CONSTS: consts[group]
MEMBER_ROWS = _C_K + N_CONSTS


def sweep_scratch(n: int) -> np.ndarray:
    """``step_members``' scratch for ``n`` members (no sweep below ``SWEEP_MIN``)."""
    blocks = -(-n // _LANES) if n >= SWEEP_MIN else 0
    return np.full((blocks, MEMBER_ROWS * _LANES), np.nan)


@kernel
def _columns(x, keys, group, level0, slots, phis, rates, consts, s):
    """The states ``x`` (``(N, 5)``) into rows 0-4 of the scratch ``s``, and each member's
    coefficient rows for its mode ``keys[j]`` (bridge on) at ``level0`` in parameter set
    ``group[j]``, copied only where they are not already (``_TAG``); a NaN tag where that
    mode is not in the tables yet (the member loop loads it)."""
    n_modes = slots.shape[1]
    for j in range(x.shape[0]):
        f = s[j // _LANES]
        ln = j % _LANES
        for q in range(5):
            f[q * _LANES + ln] = x[j, q]
        g = group[j]
        k = keys[j]
        tag = float((g * n_modes + k) * 64 + level0)
        if f[_TAG * _LANES + ln] == tag:
            continue
        row = slots[g, k]
        if row < 0:
            f[_TAG * _LANES + ln] = np.nan
            continue
        # the entries _coefficients, _current_row and _speed_row take from the tables
        c = _coefficients(phis, row, level0)
        for q in range(len(c)):
            f[(_C_PHI + q) * _LANES + ln] = c[q]
        ci = _current_row(rates, row)
        for q in range(len(ci)):
            f[(_C_CUR + q) * _LANES + ln] = ci[q]
        sv = _speed_row(rates, row)
        for q in range(len(sv)):
            f[(_C_SPD + q) * _LANES + ln] = sv[q]
        for q in range(consts.shape[1]):
            f[(_C_K + q) * _LANES + ln] = consts[g, q]
        f[_TAG * _LANES + ln] = tag


@kernel(inline="always")
def _coefficients_at(f, ln):
    """Lane ``ln``'s ``_coefficients`` from its block ``f`` (``_columns``)."""
    return (
        f[_C_PHI * _LANES + ln], f[(_C_PHI + 1) * _LANES + ln],
        f[(_C_PHI + 2) * _LANES + ln], f[(_C_PHI + 3) * _LANES + ln],
        f[(_C_PHI + 4) * _LANES + ln], f[(_C_PHI + 5) * _LANES + ln],
        f[(_C_PHI + 6) * _LANES + ln], f[(_C_PHI + 7) * _LANES + ln],
        f[(_C_PHI + 8) * _LANES + ln], f[(_C_PHI + 9) * _LANES + ln],
        f[(_C_PHI + 10) * _LANES + ln], f[(_C_PHI + 11) * _LANES + ln],
        f[(_C_PHI + 12) * _LANES + ln], f[(_C_PHI + 13) * _LANES + ln],
        f[(_C_PHI + 14) * _LANES + ln], f[(_C_PHI + 15) * _LANES + ln],
        f[(_C_PHI + 16) * _LANES + ln], f[(_C_PHI + 17) * _LANES + ln],
        f[(_C_PHI + 18) * _LANES + ln], f[(_C_PHI + 19) * _LANES + ln],
        f[(_C_PHI + 20) * _LANES + ln], f[(_C_PHI + 21) * _LANES + ln],
        f[(_C_PHI + 22) * _LANES + ln], f[(_C_PHI + 23) * _LANES + ln],
        f[(_C_PHI + 24) * _LANES + ln], f[(_C_PHI + 25) * _LANES + ln],
        f[(_C_PHI + 26) * _LANES + ln], f[(_C_PHI + 27) * _LANES + ln],
        f[(_C_PHI + 28) * _LANES + ln], f[(_C_PHI + 29) * _LANES + ln],
    )  # fmt: skip


@kernel(inline="always")
def _rates_at(f, ln):
    """Lane ``ln``'s ``_current_row`` and ``_speed_row`` from its block ``f``."""
    return (
        f[_C_CUR * _LANES + ln], f[(_C_CUR + 1) * _LANES + ln],
        f[(_C_CUR + 2) * _LANES + ln], f[(_C_CUR + 3) * _LANES + ln],
        f[(_C_CUR + 4) * _LANES + ln], f[(_C_CUR + 5) * _LANES + ln],
    ), (
        f[_C_SPD * _LANES + ln], f[(_C_SPD + 1) * _LANES + ln],
        f[(_C_SPD + 2) * _LANES + ln], f[(_C_SPD + 3) * _LANES + ln],
        f[(_C_SPD + 4) * _LANES + ln], f[(_C_SPD + 5) * _LANES + ln],
        f[(_C_SPD + 6) * _LANES + ln], f[(_C_SPD + 7) * _LANES + ln],
        f[(_C_SPD + 8) * _LANES + ln], f[(_C_SPD + 9) * _LANES + ln],
    )  # fmt: skip


@kernel(inline="always")
def _consts_at(f, ln):
    """Lane ``ln``'s coefficients (``consts[group[j]]``) from its block ``f``, as a tuple
    indexed like ``consts``' rows."""
    return (
        f[_C_K * _LANES + ln], f[(_C_K + 1) * _LANES + ln],
        f[(_C_K + 2) * _LANES + ln], f[(_C_K + 3) * _LANES + ln],
        f[(_C_K + 4) * _LANES + ln], f[(_C_K + 5) * _LANES + ln],
        f[(_C_K + 6) * _LANES + ln], f[(_C_K + 7) * _LANES + ln],
        f[(_C_K + 8) * _LANES + ln], f[(_C_K + 9) * _LANES + ln],
        f[(_C_K + 10) * _LANES + ln], f[(_C_K + 11) * _LANES + ln],
        f[(_C_K + 12) * _LANES + ln], f[(_C_K + 13) * _LANES + ln],
        f[(_C_K + 14) * _LANES + ln], f[(_C_K + 15) * _LANES + ln],
        f[(_C_K + 16) * _LANES + ln], f[(_C_K + 17) * _LANES + ln],
        f[(_C_K + 18) * _LANES + ln], f[(_C_K + 19) * _LANES + ln],
        f[(_C_K + 20) * _LANES + ln], f[(_C_K + 21) * _LANES + ln],
        f[(_C_K + 22) * _LANES + ln], f[(_C_K + 23) * _LANES + ln],
        f[(_C_K + 24) * _LANES + ln], f[(_C_K + 25) * _LANES + ln],
        f[(_C_K + 26) * _LANES + ln], f[(_C_K + 27) * _LANES + ln],
        f[(_C_K + 28) * _LANES + ln], f[(_C_K + 29) * _LANES + ln],
        f[(_C_K + 30) * _LANES + ln], f[(_C_K + 31) * _LANES + ln],
        f[(_C_K + 32) * _LANES + ln], f[(_C_K + 33) * _LANES + ln],
        f[(_C_K + 34) * _LANES + ln],
    )  # fmt: skip


@kernel
def _sweep(s, duty, enable, keys, scale, n):
    """``step_members``' common case for every member at once: each member's step from its
    known mode with its coefficient rows (``_columns``), the end states into rows 5-9 of
    the scratch ``s`` and row 10 1.0 if the member is enabled, below I_CL, has its rows
    (not a NaN tag) and ``_stays`` accepts its step with both speeds beyond their gates'
    bounds (``ok`` and ``sure``). The member loop's expressions on rows: no branch, so the
    compiler evaluates several members per instruction (SIMD; 4 with AVX2)."""
    for b in range(s.shape[0]):
        f = s[b]
        j0 = b * _LANES
        for ln in range(min(_LANES, n - j0)):
            i, p, w = f[ln], f[_LANES + ln], f[2 * _LANES + ln]
            tw, wp = f[3 * _LANES + ln], f[4 * _LANES + ln]
            d = duty[j0 + ln]
            en = enable[j0 + ln]
            kc = _consts_at(f, ln)
            ci, sv = _rates_at(f, ln)
            ni, np_, nw, ntw, nwp = _apply(_coefficients_at(f, ln), i, p, w, tw, wp, d)
            f[5 * _LANES + ln] = ni
            f[6 * _LANES + ln] = np_
            f[7 * _LANES + ln] = nw
            f[8 * _LANES + ln] = ntw
            f[9 * _LANES + ln] = nwp
            h = kc[_H_S] * scale
            k0 = keys[j0 + ln]
            ok, sure = _stays(k0, i, w, tw, wp, ni, nw, ntw, nwp, d, en, ci, sv, h, kc)[:2]
            icl = kc[_ICL]
            tag = f[_TAG * _LANES + ln]
            accept = (tag == tag) & en & (-icl < i) & (i < icl) & ok & sure
            f[_DONE * _LANES + ln] = 1.0 if accept else 0.0


@kernel
def step_members(
    x, duty, enable, keys_in, known, start, group, slots, phis, rates, consts, levels,
    budget, out_x, out_keys, level0, scratch,
):  # fmt: skip
    """``step`` of ``h_s / 2**level0`` (``sim.supply``'s sub-steps: ``level0`` > 0; the
    finest step stays ``h_s / 2**levels``) for members ``start, start + 1, ...`` of ``x``
    (``(N, 5)``) with inputs
    ``duty`` / ``enable`` (``(N,)``), member j using parameter set ``group[j]``; new states
    into ``out_x``, each member's mechanical end mode into ``out_keys``. ``keys_in``: the
    mechanical modes of ``x`` if ``known`` (``x`` is the last ``out_x``). Returns ``(next,
    events, group, need)``: ``need`` = -1 when every member is done, else mode ``need`` of
    set ``group`` is missing and members from ``next`` on are still to do (``out_x[next]``
    may have been written). ``scratch``: ``sweep_scratch(N)`` (``_sweep``'s rows: the states
    before and after, whether it accepted each member, the coefficients of each member's
    mode kept between calls), or no block: no sweep."""
    events = 0
    # One parameter set (the common case): its views once, not per member.
    shared = consts.shape[0] == 1
    g = 0
    kc = consts[0]
    scale = 1.0 / (1 << level0)
    h_s = kc[_H_S] * scale
    sl = slots[0]
    k_last = -1
    row_last = -1
    n = x.shape[0]
    # The common case swept at once (_sweep, each member in its known mode); the loop then
    # takes each member it accepted as it is.
    swept = known and start == 0 and n >= SWEEP_MIN and levels > level0 and budget > 0
    swept = swept and scratch.shape[0] * _LANES >= n
    swept = swept and scratch.shape[1] == MEMBER_ROWS * _LANES
    if swept:
        _columns(x, keys_in, group, level0, slots, phis, rates, consts, scratch)
        _sweep(scratch, duty, enable, keys_in, scale, n)
    for j in range(start, n):
        if swept and scratch[j // _LANES, _DONE * _LANES + j % _LANES] != 0.0:
            f = scratch[j // _LANES]
            ln = j % _LANES
            out_x[j, 0] = f[5 * _LANES + ln]
            out_x[j, 1] = f[6 * _LANES + ln]
            out_x[j, 2] = f[7 * _LANES + ln]
            out_x[j, 3] = f[8 * _LANES + ln]
            out_x[j, 4] = f[9 * _LANES + ln]
            out_keys[j] = keys_in[j] % _MECH
            continue
        if not shared:
            g = group[j]
            kc = consts[g]
            sl = slots[g]
            h_s = kc[_H_S] * scale
            k_last = -1
        i, p, w, tw, wp = x[j, 0], x[j, 1], x[j, 2], x[j, 3], x[j, 4]
        d = duty[j]
        en = enable[j]
        icl = kc[_ICL]
        if known and en and -icl < i < icl:
            k0 = keys_in[j]
        else:
            k0 = key(i, w, tw, wp, d, en, kc)
        # The common case first, without step's sub-step stack: the whole step in the start
        # mode ends in it and leaves it nowhere in between (step's first pass, _stays). The
        # row by a branch (most members share the mode): the loads need not wait for it.
        if k0 != k_last:
            k_last = k0
            row_last = sl[k0]
        row = row_last
        if row >= 0 and levels > level0 and budget > 0:
            ni, np_, nw, ntw, nwp = _advance(phis, row, level0, i, p, w, tw, wp, d)
            # The member's result if accepted (step overwrites it otherwise); stored first,
            # so that nothing lives across the call below.
            out_x[j, 0] = ni
            out_x[j, 1] = np_
            out_x[j, 2] = nw
            out_x[j, 3] = ntw
            out_x[j, 4] = nwp
            ok, sure, mode, wd0, wd1, pd0, pd1, ai, tbmax = _stays(
                k0, i, w, tw, wp, ni, nw, ntw, nwp, d, en, _current_row(rates, row),
                _speed_row(rates, row), h_s, kc,
            )  # fmt: skip
            if ok and (
                sure or not _speeds_leave(w, nw, wp, nwp, wd0, wd1, pd0, pd1, ai, tbmax, h_s, kc)
            ):
                out_keys[j] = k0 % _MECH
                continue
            near = mode and not ok
        else:
            near = False
        # (the end state from out_x: nothing of the common case lives across the calls)
        r = step(
            i, p, w, tw, wp, d, en, k0, levels, budget, sl, phis, rates, kc, level0, near,
            out_x[j, 0], out_x[j, 1], out_x[j, 2], out_x[j, 3], out_x[j, 4],
        )  # fmt: skip
        if r[7] >= 0:
            return j, events, g, r[7]
        out_x[j, 0] = r[0]
        out_x[j, 1] = r[1]
        out_x[j, 2] = r[2]
        out_x[j, 3] = r[3]
        out_x[j, 4] = r[4]
        out_keys[j] = r[5] % _MECH
        events += r[6]
    return n, events, 0, -1


def warm_up(event_levels: int = 20) -> None:
    """Load the compiled kernels (compile them, the first time on a machine) with the
    argument types ``Plant`` passes, so that a caller can time this apart from a run.
    Numba's own start-up makes it ~0.3 s in a fresh process; later calls cost nothing."""
    kc = np.ones((1, N_CONSTS))
    key(0.0, 0.0, 0.0, 0.0, 0.0, True, kc[0])
    x = np.zeros((1, 5))
    ints = np.zeros(1, dtype=np.int64)
    # Mode 0 is not in the tables: the kernel returns at once, asking for it.
    step_members(
        x, np.zeros(1), np.ones(1, dtype=bool), ints, True, 0, ints,
        np.full((1, 1), -1, dtype=np.int64), np.empty((0, event_levels + 1, 5, 7)),
        np.empty((0, 3, 7)), kc, event_levels, 1, np.empty((1, 5)), ints, 0, sweep_scratch(1),
    )  # fmt: skip
