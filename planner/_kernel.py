"""The planners' arithmetic: one implementation of each law, used by the trapezoid, the
velocity pulses of the S-curve and the S-curve's search (compiled with numba, ``cache=True``,
no ``fastmath``).

Inside the search, phases are written into ``out``, an array of shape ``(2, MAX_PHASES)``:
``out[0, i]`` the duration of phase ``i``, ``out[1, i]`` its value (an acceleration for the
trapezoid, a jerk for the S-curve). A phase of zero duration may be written;
:func:`planner.profile.build_profile` drops it.

Everything here is unit-free and pure: arguments in, phases out, no clock, no I/O.
:func:`segments` and :func:`integrate` are plain Python that numba can compile: the
trapezoid runs them interpreted (no start-up cost), the S-curve search runs the same source
compiled. The S-curve kernel loads from numba's on-disk cache after the first process that
compiled it (about 20 s of CPU once); :func:`warm_up` loads it ahead of a real-time loop
(0.3-0.9 s).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["MAX_PHASES", "pulse_phases", "scurve_phases", "trapezoid_phases", "warm_up"]

MAX_PHASES = 16

# Candidate grids of the S-curve search (see planner.scurve's docstring).
_GRID_PEAK = 32  # family A: peak velocities on [-v_max, v_max]
_GRID_TAU = 16  # family B: durations of the first jerk phase
_GRID_TAU1 = 8  # family C: durations of the first of two jerk phases
_GRID_TAU2 = 8  # family C: roots over the second one

# The search's state, one float64 array (numba passes it by reference): the filter's
# bounds, then the best candidate, the fallback of the least peak speed (a candidate that
# ends right but fails the filter) and that of the least residual (none ends right: only at
# the edge of floating point). Their phases live in slots 0, 1 and 2 of ``best``.
_V_ALLOWED, _V_LIM, _T_BRAKE, _BEST_DUR, _BEST_N, _LOW_PEAK, _LOW_N, _NEAR_ERR, _NEAR_N = range(9)
_N_STATE = 9


def segments(x0, x1, v0, v1, v_max, a_acc, a_dec):
    """The time-optimal double-integrator move from ``(x0, v0)`` to ``(x1, v1)``.

    Limits: ``|v| <= v_max`` (after a brake at ``a_dec`` if ``|v0| > v_max``), ``|a| <=
    a_acc`` while the speed ``|v|`` grows and ``|a| <= a_dec`` while it falls; ``|v1| <=
    v_max``.

    Returns ``(sigma, cruise, braked, phases)``: sigma +1 if the main part accelerates first
    (peak above both end velocities), -1 if it decelerates first; cruise whether there is a
    cruise at ``sigma * v_max`` of non-zero duration; ``phases`` six ``(dt, a)`` pairs,
    flattened: the brake, the ramp to the peak in two parts (down to zero velocity at a_dec,
    then up at a_acc), the cruise, the ramp to v1 in two parts; a part that is not there
    has ``dt = 0`` (returned as values, not written to an array: interpreted, a tuple is
    the cheap way). Used one order down for velocities (acceleration- and jerk-limited
    velocity changes, symmetric limits).
    """
    braked = False
    v = v0
    d = x1 - x0
    t_brake = 0.0
    a_brake = 0.0
    if abs(v0) > v_max:
        s = 1.0 if v0 > 0.0 else -1.0
        t_brake = (abs(v0) - v_max) / a_dec
        a_brake = -s * a_dec
        v = s * v_max
        d -= (v0 + v) * 0.5 * t_brake
        braked = True
    # Displacement of the single fastest ramp from v to v1 (through zero: down to 0 at
    # a_dec, up at a_acc).
    if v * v1 >= 0.0:
        d_direct = abs(v1 - v) * (v1 + v) / (2.0 * (a_acc if abs(v1) >= abs(v) else a_dec))
    else:
        d_direct = abs(v) * v / (2.0 * a_dec) + abs(v1) * v1 / (2.0 * a_acc)
    # At d == d_direct the single ramp is the answer; it belongs to the "accelerate first"
    # family only if v + v1 >= 0 (otherwise that family's root is the far, slow one).
    sigma = 1 if d > d_direct or (d == d_direct and v + v1 >= 0.0) else -1
    # Work in the frame where the peak lies above both ends (sigma = +1).
    fd = sigma * d
    fv = sigma * v
    fv1 = sigma * v1
    acc, dec = a_acc, a_dec
    # Displacement to the peak vp >= 0 and back: vp^2 / h - c1 - c2, 1/h = 1/2acc + 1/2dec.
    # (1/h from the two reciprocals: 2 acc dec / (acc + dec) underflows to 0 for a
    # subnormal limit, and a division by it would raise; an infinite 1/h gives inf times.)
    sym = acc == dec
    h_inv = 0.5 / acc + 0.5 / dec
    h = acc if sym else 1.0 / h_inv
    c1 = fv * fv / (2.0 * (acc if fv >= 0.0 else dec))
    c2 = fv1 * fv1 / (2.0 * (dec if fv1 >= 0.0 else acc))
    m = max(fv, fv1)
    # Clamp only against rounding: the peak is never below the end nearer to it.
    peak_sq = max((fd + c1 + c2) * h, m * m)
    vp = math.sqrt(peak_sq)
    t_cruise = 0.0
    if vp >= v_max:
        vp = v_max
        ramps = v_max * v_max / acc if sym else v_max * v_max * h_inv
        t_cruise = max((fd - (ramps - c1 - c2)) / v_max, 0.0)
        up = vp - fv
        down = vp - fv1
    else:
        # vp - fv without the cancellation of two near-equal speeds: (vp^2 - fv^2)/(vp + fv).
        if fv > 0.0:
            if fv1 >= 0.0:
                rise = h * (fd + (fv1 - fv) * (fv1 + fv) / (2.0 * dec))
            else:
                rise = h * (fd + fv1 * fv1 / (2.0 * acc) - fv * fv / (2.0 * dec))
            up = rise / (vp + fv)
        else:
            up = vp - fv
        if fv1 > 0.0:
            if fv >= 0.0:
                fall = h * (fd + (fv - fv1) * (fv + fv1) / (2.0 * acc))
            else:
                fall = h * (fd + fv * fv / (2.0 * dec) - fv1 * fv1 / (2.0 * acc))
            down = fall / (vp + fv1)
        else:
            down = vp - fv1
    up = max(up, 0.0)
    down = max(down, 0.0)
    sg = float(sigma)
    # Ramp up from fv to vp: slowing (dec) while fv < 0, then speeding (acc).
    if fv < 0.0 and acc != dec:
        t_u1 = min(-fv, up) / dec
        a_u1 = sg * dec
        t_u2 = max(up + fv, 0.0) / acc
    else:
        t_u1 = up / (acc if fv >= 0.0 else dec)
        a_u1 = sg * (acc if fv >= 0.0 else dec)
        t_u2 = 0.0
    # Ramp down from vp to fv1: slowing (dec) to zero, then speeding the other way (acc).
    if fv1 < 0.0 and acc != dec:
        t_d1 = vp / dec
        a_d1 = -sg * dec
        t_d2 = max(down - vp, 0.0) / acc
    else:
        t_d1 = down / (dec if fv1 >= 0.0 else acc)
        a_d1 = -sg * (dec if fv1 >= 0.0 else acc)
        t_d2 = 0.0
    phases = (
        t_brake, a_brake, t_u1, a_u1, t_u2, sg * acc, t_cruise, 0.0, t_d1, a_d1, t_d2, -sg * acc
    )  # fmt: skip
    return sigma, t_cruise > 0.0, braked, phases


def integrate(out, n0, n1, v, a):
    """Distance and duration of phases ``n0..n1`` from ``(v, a)``, exactly as
    ``build_profile`` integrates them (a zero acceleration's rounding residue snapped)."""
    dist = 0.0
    dur = 0.0
    a_scale = abs(a)
    for i in range(n0, n1):
        dt = out[0, i]
        j = out[1, i]
        if dt > 0.0:
            if abs(a) <= 1e-12 * a_scale:
                a = 0.0
            dist += dt * (v + dt * (0.5 * a + dt * j / 6.0))
            v += dt * (a + 0.5 * dt * j)
            a += dt * j
            a_scale = max(a_scale, abs(a))
            dur += dt
    return dist, dur


# The same two functions compiled, for the S-curve search below. Interpreted, they serve
# plan_trapezoid and the single velocity pulses, which must not wait for a compiled
# kernel to load (about 0.3-0.9 s the first time in a process: a stall a real-time loop
# would see as a lost link).
_segments = numba.njit(cache=True)(segments)
_integrate = numba.njit(cache=True)(integrate)


def phase_list(ph, braked):
    """The phases of :func:`segments` as a list of ``(dt, value)``: the brake if there is
    one, then the non-empty parts of each ramp, and the cruise (possibly empty)."""
    out = [(ph[0], ph[1])] if braked else []
    out.append((ph[2], ph[3]))
    if ph[4] > 0.0:
        out.append((ph[4], ph[5]))
    out.append((ph[6], 0.0))
    out.append((ph[8], ph[9]))
    if ph[10] > 0.0:
        out.append((ph[10], ph[11]))
    return out


def trapezoid_phases(x0, x1, v0, v1, v_max, a_acc, a_dec):
    """:func:`segments` as ``(phases, sigma, cruise, braked)``, phases a list of
    ``(dt, a)``."""
    sigma, cruise, braked, ph = segments(x0, x1, v0, v1, v_max, a_acc, a_dec)
    return phase_list(ph, braked), sigma, cruise, braked


def pulse_phases(v0, a0, v1, a_lim, j_max):
    """The velocity pulse (see :func:`_pulse`): ``(phases, distance, duration)``, the phases
    a list of ``(dt, jerk)``."""
    _, _, braked, ph = segments(v0, v1, a0, 0.0, a_lim, j_max, j_max)
    phases = phase_list(ph, braked)
    out = np.array(phases).T.copy()
    # numpy scalars here: an overflow (extreme arguments) gives inf as it does compiled,
    # without a warning on stderr; the caller refuses a non-finite profile.
    with np.errstate(all="ignore"):
        dist, dur = integrate(out, 0, len(phases), v0, a0)
    return phases, float(dist), float(dur)


@numba.njit(cache=True)
def _pulse(v0, a0, v1, a_lim, j_max, out, n):
    """Fastest velocity change from ``(v0, a0)`` to ``(v1, 0)`` with ``|a| <= a_lim``
    (``|a0| > a_lim`` brought back first) and ``|j| <= j_max``: the trapezoid one order
    down. Appends ``(dt, jerk)`` phases from column ``n``; returns the new ``n``."""
    _, _, braked, ph = _segments(v0, v1, a0, 0.0, a_lim, j_max, j_max)
    if braked:
        out[0, n] = ph[0]
        out[1, n] = ph[1]
        n += 1
    for k in range(1, 6):
        # The second part of a ramp only when there is one (the cruise always: it may
        # be empty, as in the interpreted list).
        if k == 2 or k == 5:
            if not ph[2 * k] > 0.0:
                continue
        out[0, n] = ph[2 * k]
        out[1, n] = ph[2 * k + 1]
        n += 1
    return n


@numba.njit(cache=True)
def _bound(va, vb, a_acc, a_dec):
    """The acceleration limit of a pulse from va to vb: a_acc if the speed grows, a_dec if
    it falls, the smaller one if the velocity passes through zero (it is continuous there,
    where both apply)."""
    if va * vb < 0.0:
        return min(a_acc, a_dec)
    return a_acc if abs(vb) >= abs(va) else a_dec


@numba.njit(cache=True)
def _excursion(out, n, v, a):
    """Distance travelled (not displaced) along the phases, bounded above: the scale of the
    rounding error of their integrated displacement."""
    total = 0.0
    for i in range(n):
        dt = out[0, i]
        j = out[1, i]
        if dt > 0.0:
            total += dt * (abs(v) + dt * (0.5 * abs(a) + dt * abs(j) / 6.0))
            v += dt * (a + 0.5 * dt * j)
            a += dt * j
    return total


@numba.njit(cache=True)
def _peak_speed(out, n, v, a):
    """The largest |v| along the phases (extremes sit at phase ends or where a = 0)."""
    peak = abs(v)
    for i in range(n):
        dt = out[0, i]
        j = out[1, i]
        if dt <= 0.0:
            continue
        if j != 0.0:
            tau = -a / j
            if 0.0 < tau < dt:
                peak = max(peak, abs(v + tau * (a + 0.5 * tau * j)))
        v += dt * (a + 0.5 * dt * j)
        a += dt * j
        peak = max(peak, abs(v))
    return peak


@numba.njit(cache=True)
def _last_over(out, n, v, a, v_lim):
    """The last time at which |v| > v_lim along the phases (0 if never)."""
    last = 0.0
    t = 0.0
    for i in range(n):
        dt = out[0, i]
        j = out[1, i]
        if dt <= 0.0:
            continue
        v_end = v + dt * (a + 0.5 * dt * j)
        if abs(v_end) > v_lim:
            last = t + dt
        else:
            # Crossings of v = +-v_lim inside the phase: |v| > v_lim just before the last
            # downward one.
            for sgn in (1.0, -1.0):
                c0 = v - sgn * v_lim
                for k in range(2):
                    tau = -1.0
                    if j != 0.0:
                        disc = a * a - 2.0 * j * c0
                        if disc >= 0.0:
                            sq = math.sqrt(disc)
                            tau = (-a - sq) / j if k == 0 else (-a + sq) / j
                    elif a != 0.0 and k == 0:
                        tau = -c0 / a
                    if 0.0 < tau <= dt:
                        tb = max(tau - 1e-9 * dt, 0.0)
                        if abs(v + tb * (a + 0.5 * tb * j)) > v_lim:
                            last = max(last, t + tau)
        v = v_end
        a += dt * j
        t += dt
    return last


@numba.njit(cache=True)
def _acc_ok(out, n, v, a, a_acc, a_dec):
    """Whether the acceleration respects a_acc while the speed grows and a_dec while it
    falls (both where the velocity passes through zero), beyond what the start state
    brings (|a0|). Checked at every phase end and every zero of the velocity."""
    tol = 1.0 + 1e-9
    a_start = abs(a)
    for i in range(n):
        dt = out[0, i]
        j = out[1, i]
        if dt <= 0.0:
            continue
        # Zeros of v inside the phase: there both limits apply.
        for k in range(2):
            tau = -1.0
            if j != 0.0:
                disc = a * a - 2.0 * j * v
                if disc >= 0.0:
                    sq = math.sqrt(disc)
                    tau = (-a - sq) / j if k == 0 else (-a + sq) / j
            elif a != 0.0 and k == 0:
                tau = -v / a
            if 0.0 < tau < dt:
                if abs(a + tau * j) > max(min(a_acc, a_dec) * tol, a_start):
                    return False
        v_end = v + dt * (a + 0.5 * dt * j)
        a_end = a + dt * j
        lim = a_acc if a_end * v_end >= 0.0 else a_dec
        if abs(a_end) > max(lim * tol, a_start):
            return False
        v = v_end
        a = a_end
    return True


@numba.njit(cache=True)
def _build(fam, x, s, tau1, v0, a0, vf, v_max, a_acc, a_dec, j_max, out):
    """The phases of one candidate (see :func:`scurve_phases`); returns their count.

    fam 0: pulse to the peak ``x`` (a = 0 there), cruise for ``tau1``, pulse to vf.
    fam 1: jerk ``s * j_max`` for ``x``, then one pulse to vf.
    fam 2: jerk ``s * j_max`` for ``tau1``, jerk ``-s * j_max`` for ``x``, one pulse to vf.
    """
    if fam == 0:
        n = _pulse(v0, a0, x, _bound(v0, x, a_acc, a_dec), j_max, out, 0)
        out[0, n] = tau1
        out[1, n] = 0.0
        n += 1
        return _pulse(x, 0.0, vf, _bound(x, vf, a_acc, a_dec), j_max, out, n)
    if fam == 1:
        out[0, 0] = x
        out[1, 0] = s * j_max
        a1 = a0 + s * j_max * x
        v1 = v0 + x * (a0 + 0.5 * s * j_max * x)
        return _pulse(v1, a1, vf, _bound(v1, vf, a_acc, a_dec), j_max, out, 1)
    out[0, 0] = tau1
    out[1, 0] = s * j_max
    a1 = a0 + s * j_max * tau1
    v1 = v0 + tau1 * (a0 + 0.5 * s * j_max * tau1)
    out[0, 1] = x
    out[1, 1] = -s * j_max
    a2 = a1 - s * j_max * x
    v2 = v1 + x * (a1 - 0.5 * s * j_max * x)
    return _pulse(v2, a2, vf, _bound(v2, vf, a_acc, a_dec), j_max, out, 2)


@numba.njit(cache=True)
def _residual(fam, x, s, tau1, d, v0, a0, vf, v_max, a_acc, a_dec, j_max, out):
    n = _build(fam, x, s, tau1, v0, a0, vf, v_max, a_acc, a_dec, j_max, out)
    dist, _ = _integrate(out, 0, n, v0, a0)
    return dist - d


@numba.njit(cache=True)
def _refine(fam, s, tau1, lo, hi, f_lo, f_hi, d, v0, a0, vf, v_max, a_acc, a_dec, j_max, out):
    """Root of the residual in the sign-changing bracket ``[lo, hi]`` (Illinois regula
    falsi: keeps the bracket, so it also converges across the kinks between shapes)."""
    side = 0
    x = 0.5 * (lo + hi)
    for _ in range(200):
        x = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        if not lo < x < hi:
            x = 0.5 * (lo + hi)
            if not lo < x < hi:
                break
        fx = _residual(fam, x, s, tau1, d, v0, a0, vf, v_max, a_acc, a_dec, j_max, out)
        if fx == 0.0:
            return x
        if (fx < 0.0) == (f_hi < 0.0):
            hi = x
            f_hi = fx
            if side == 1:
                f_lo *= 0.5
            side = 1
        else:
            lo = x
            f_lo = fx
            if side == -1:
                f_hi *= 0.5
            side = -1
        if hi - lo <= 4e-16 * max(abs(lo), abs(hi)):
            break
    return x


@numba.njit(cache=True)
def _search(d, v0, a0, vf, v_max, a_acc, a_dec, j_max, two_pre, best, cand, lim):
    """Offer every candidate of families A, B (and C if ``two_pre``) that ends at
    ``(d, vf, 0)`` to :func:`_offer` (``best`` and ``lim`` hold the result). A jerk phase
    that cannot be part of a profile faster than the best so far is not searched."""
    a_top = max(a_acc, a_dec)
    # Family A with a cruise at +-v_max.
    for k in range(2):
        sv = 1.0 if k == 0 else -1.0
        n = _build(0, sv * v_max, 0.0, 0.0, v0, a0, vf, v_max, a_acc, a_dec, j_max, cand)
        dist, _ = _integrate(cand, 0, n, v0, a0)
        t_c = (d - dist) / (sv * v_max)
        if t_c >= 0.0:
            _consider(0, sv * v_max, 0.0, t_c, d, v0, a0, vf, v_max, a_acc, a_dec, j_max,
                      best, cand, lim)  # fmt: skip
    # Family A: all roots over the peak on a grid of [-v_max, v_max] with the natural
    # points (0, v0, the velocity where a0 runs out, vf) added.
    v_nat = v0 + a0 * abs(a0) / (2.0 * j_max)
    grid = np.empty(_GRID_PEAK + 5)
    for k in range(_GRID_PEAK + 1):
        grid[k] = -v_max + 2.0 * v_max * k / _GRID_PEAK
    grid[_GRID_PEAK + 1] = 0.0
    grid[_GRID_PEAK + 2] = min(max(v0, -v_max), v_max)
    grid[_GRID_PEAK + 3] = min(max(v_nat, -v_max), v_max)
    grid[_GRID_PEAK + 4] = min(max(vf, -v_max), v_max)
    grid.sort()
    _roots(0, 0.0, 0.0, grid, d, v0, a0, vf, v_max, a_acc, a_dec, j_max, best, cand, lim)
    # Family B: a first jerk phase of +-j_max for tau, then one pulse to vf.
    for k in range(2):
        s = 1.0 if k == 0 else -1.0
        tau_max = min((a_top - s * a0) / j_max, lim[_BEST_DUR])
        if not tau_max > 0.0:
            continue
        taus = np.empty(_GRID_TAU + 1)
        for i in range(_GRID_TAU + 1):
            taus[i] = tau_max * i / _GRID_TAU
        _roots(1, s, 0.0, taus, d, v0, a0, vf, v_max, a_acc, a_dec, j_max, best, cand, lim)
    if not two_pre:
        return
    # Family C: two jerk phases of opposite sign (tau1 on a grid, roots over tau2), then one
    # pulse to vf: the shape of a brake pre-profile followed by the rest.
    for k in range(2):
        s = 1.0 if k == 0 else -1.0
        tau1_max = min((a_top - s * a0) / j_max, lim[_BEST_DUR])
        if not tau1_max > 0.0:
            continue
        for i1 in range(1, _GRID_TAU1 + 1):
            tau1 = tau1_max * i1 / _GRID_TAU1
            a1 = a0 + s * j_max * tau1
            tau2_max = min((a_top + s * a1) / j_max, lim[_BEST_DUR] - tau1)
            if not tau2_max > 0.0:
                continue
            taus = np.empty(_GRID_TAU2 + 1)
            for i in range(_GRID_TAU2 + 1):
                taus[i] = tau2_max * i / _GRID_TAU2
            _roots(2, s, tau1, taus, d, v0, a0, vf, v_max, a_acc, a_dec, j_max, best, cand, lim)


@numba.njit(cache=True)
def _roots(fam, s, tau1, xs, d, v0, a0, vf, v_max, a_acc, a_dec, j_max, best, cand, lim):
    """Consider every root of the residual bracketed by consecutive points of ``xs``."""
    m = xs.shape[0]
    fs = np.empty(m)
    for i in range(m):
        fs[i] = _residual(fam, xs[i], s, tau1, d, v0, a0, vf, v_max, a_acc, a_dec, j_max, cand)
    for i in range(m):
        if fs[i] == 0.0:
            _consider(fam, xs[i], s, tau1, d, v0, a0, vf, v_max, a_acc, a_dec, j_max,
                      best, cand, lim)  # fmt: skip
    for i in range(m - 1):
        f_lo = fs[i]
        f_hi = fs[i + 1]
        if f_lo != 0.0 and f_hi != 0.0 and (f_lo < 0.0) != (f_hi < 0.0):
            x = _refine(fam, s, tau1, xs[i], xs[i + 1], f_lo, f_hi, d, v0, a0, vf, v_max,
                        a_acc, a_dec, j_max, cand)  # fmt: skip
            _consider(fam, x, s, tau1, d, v0, a0, vf, v_max, a_acc, a_dec, j_max,
                      best, cand, lim)  # fmt: skip


@numba.njit(cache=True)
def _new_state(v_allowed, v_lim, t_brake):
    st = np.zeros(_N_STATE)
    st[_V_ALLOWED] = v_allowed
    st[_V_LIM] = v_lim
    st[_T_BRAKE] = t_brake
    st[_BEST_DUR] = math.inf
    st[_LOW_PEAK] = math.inf
    st[_NEAR_ERR] = math.inf
    return st


@numba.njit(cache=True)
def _consider(fam, x, s, tau1, d, v0, a0, vf, v_max, a_acc, a_dec, j_max, best, cand, lim):
    """Build one candidate and :func:`_offer` it."""
    n = _build(fam, x, s, tau1, v0, a0, vf, v_max, a_acc, a_dec, j_max, cand)
    _offer(cand, n, d, v0, a0, a_acc, a_dec, best, lim)


@numba.njit(cache=True)
def _offer(cand, n, d, v0, a0, a_acc, a_dec, best, lim):
    """Keep ``cand[:, :n]`` as the best if it ends at ``d``, is faster than the best so far
    and passes the filter: peak speed within ``lim[_V_ALLOWED]``, above v_max
    (``lim[_V_LIM]``) no later than ``lim[_T_BRAKE]``, accelerations within the asymmetric
    limits. Otherwise keep it as a fallback if it is the least bad so far."""
    dist, dur = _integrate(cand, 0, n, v0, a0)
    err = abs(dist - d)
    if not err <= 1e-9 * max(abs(d), _excursion(cand, n, v0, a0)):
        # A root at a jump of the residual is no root.
        if err < lim[_NEAR_ERR]:
            lim[_NEAR_ERR] = err
            lim[_NEAR_N] = n
            best[:, 2 * MAX_PHASES : 2 * MAX_PHASES + n] = cand[:, :n]
        return
    # Ties (to rounding) keep the earlier candidate: family A's shapes come first.
    if not dur < lim[_BEST_DUR] * (1.0 - 1e-12):
        return
    peak = _peak_speed(cand, n, v0, a0)
    ok = peak <= lim[_V_ALLOWED]
    ok = ok and _last_over(cand, n, v0, a0, lim[_V_LIM]) <= lim[_T_BRAKE] * (1 + 1e-9) + 1e-300
    ok = ok and (a_acc == a_dec or _acc_ok(cand, n, v0, a0, a_acc, a_dec))
    if ok:
        lim[_BEST_DUR] = dur
        lim[_BEST_N] = n
        best[:, :n] = cand[:, :n]
    elif peak < lim[_LOW_PEAK]:
        lim[_LOW_PEAK] = peak
        lim[_LOW_N] = n
        best[:, MAX_PHASES : MAX_PHASES + n] = cand[:, :n]


@numba.njit(cache=True)
def _classic(d, v0, v_max, a_max, j_max, best, cand, lim):
    """From ``(v0, 0)``, |v0| <= v_max, to rest at ``d``: the peak ``vp`` goes the way of the
    target beyond the stopping point (``sigma``), and the distance of pulse-peak-pulse is
    increasing in ``sigma * vp`` from ``max(sigma * v0, 0)`` to ``v_max``, so the root is the
    one bracketed there (a cruise at ``sigma * v_max`` if even that peak falls short)."""
    n = _pulse(v0, 0.0, 0.0, a_max, j_max, cand, 0)
    stop_dist, _ = _integrate(cand, 0, n, v0, 0.0)
    sigma = 1.0 if d >= stop_dist else -1.0
    f_hi = _residual(0, sigma * v_max, 0.0, 0.0, d, v0, 0.0, 0.0, v_max, a_max, a_max, j_max,
                     cand)  # fmt: skip
    if sigma * f_hi <= 0.0:
        t_c = -f_hi / (sigma * v_max)
        _consider(0, sigma * v_max, 0.0, t_c, d, v0, 0.0, 0.0, v_max, a_max, a_max, j_max,
                  best, cand, lim)  # fmt: skip
        return
    lo = max(sigma * v0, 0.0) * sigma
    f_lo = _residual(0, lo, 0.0, 0.0, d, v0, 0.0, 0.0, v_max, a_max, a_max, j_max, cand)
    if sigma * f_lo >= 0.0:
        vp = lo  # the direct stop (or rest to rest over no distance): no second pulse
    else:
        a, b, fa, fb = lo, sigma * v_max, f_lo, f_hi
        if a > b:
            a, b, fa, fb = b, a, fb, fa
        vp = _refine(0, 0.0, 0.0, a, b, fa, fb, d, v0, 0.0, 0.0, v_max, a_max, a_max, j_max,
                     cand)  # fmt: skip
    _consider(0, vp, 0.0, 0.0, d, v0, 0.0, 0.0, v_max, a_max, a_max, j_max, best, cand, lim)


@numba.njit(cache=True)
def _brake(v0, a0, v_max, a_max, j_max):
    """A brake pre-profile to a state within the limits, ``(t_jerk, jerk, t_const)``: the
    rule of ruckig's position brake (jerk toward -a_max until the speed is back at v_max, or
    until the acceleration reaches -a_max and then constant -a_max until it is; an
    acceleration above a_max first brought down at -j_max). All zero if the state is within
    the limits and its acceleration can run out within v_max."""
    v_run = a0 * a0 / (2.0 * j_max)  # speed gained while an acceleration runs out
    pos = (v0 > v_max and v0 - v_run > -v_max) or (a0 > 0.0 and v0 + v_run > v_max)
    neg = (v0 < -v_max and v0 + v_run < v_max) or (a0 < 0.0 and v0 - v_run < -v_max)
    # Work in the frame where the excess is positive; the jerk is signed back by s.
    if a0 > a_max:
        s = 1.0
    elif a0 < -a_max:
        s = -1.0
    elif pos:
        s = 1.0
    elif neg:
        s = -1.0
    else:
        return 0.0, 0.0, 0.0
    v, a = s * v0, s * a0
    if a > a_max:
        t_zero = a / j_max
        v_zero = v + t_zero * (a - 0.5 * j_max * t_zero)
        if v_zero > v_max:
            return _velocity_brake(v, a, v_max, a_max, j_max, s)
        t_amax = (a - a_max) / j_max
        v_amax = v + t_amax * (a - 0.5 * j_max * t_amax)
        if v_amax < -v_max:
            # Down to a_max still below -v_max: hold a_max until back inside.
            t_in = -(v_amax + v_max) / a_max
            t_out = -a_max / (2.0 * j_max) - (v_amax - v_max) / a_max
            return t_amax, -s * j_max, max(min(t_in, t_out), 0.0)
        return t_amax, -s * j_max, 0.0
    return _velocity_brake(v, a, v_max, a_max, j_max, s)


@numba.njit(cache=True)
def _velocity_brake(v, a, v_max, a_max, j_max, s):
    """Jerk -j_max until v = v_max (or the acceleration reaches -a_max, then constant -a_max
    until v = v_max); in the frame where the excess is positive, jerk signed back by s."""
    t_to_amin = (a + a_max) / j_max
    t_to_vmax = a / j_max + math.sqrt(max(a * a + 2.0 * j_max * (v - v_max), 0.0)) / j_max
    t_to_vmin = a / j_max + math.sqrt(max(0.5 * a * a + j_max * (v + v_max), 0.0)) / j_max
    t_first = min(t_to_vmax, t_to_vmin)
    if t_to_amin < t_first:
        v_amin = v + t_to_amin * (a - 0.5 * j_max * t_to_amin)
        t_in = (v_amin - v_max) / a_max
        t_out = -a_max / (2.0 * j_max) + (v_amin + v_max) / a_max
        t_const = max(min(t_in, t_out), 0.0)
        return max(t_to_amin, 0.0), -s * j_max, t_const
    return max(t_first, 0.0), -s * j_max, 0.0


@numba.njit(cache=True)
def scurve_phases(d, v0, a0, vf, v_max, a_acc, a_dec, j_max):
    """The jerk phases of the S-curve from ``(0, v0, a0)`` to ``(d, vf, 0)``.

    Limits: ``|v| <= v_max``, ``|a| <= a_acc`` while the speed grows and ``<= a_dec`` while
    it falls (a pulse that reverses the direction keeps the smaller one), ``|j| <= j_max``;
    ``|vf| <= v_max``. A start beyond the limits (|v0| > v_max, or an acceleration that
    carries the speed past v_max before it can run out) may exceed v_max only while braking
    back: never faster than its unavoidable excess, and within v_max for good no later than
    the fastest settled brake to v_max.

    Returns ``(out, n, found)``: phases ``out[:, :n]``; ``found`` is False only when no
    candidate passed (then the least bad one is returned).
    """
    best = np.zeros((2, 3 * MAX_PHASES))
    cand = np.zeros((2, MAX_PHASES))
    a_top = max(a_acc, a_dec)
    v_nat = v0 + a0 * abs(a0) / (2.0 * j_max)
    t_brake = 0.0
    if max(abs(v0), abs(v_nat)) > v_max:
        side = 1.0 if (v0 if abs(v0) > v_max else v_nat) > 0.0 else -1.0
        n = _pulse(v0, a0, side * v_max, a_dec, j_max, cand, 0)
        _, t_brake = _integrate(cand, 0, n, v0, a0)
    v_allowed = max(v_max, abs(v0), abs(v_nat)) * (1 + 1e-9)
    lim = _new_state(v_allowed, v_max * (1 + 1e-9), t_brake)
    outside = t_brake > 0.0 or abs(a0) > a_top
    if a0 == 0.0 and vf == 0.0 and a_acc == a_dec and not outside:
        # The classic case (a move or a replan from a cruise): family A's distance is
        # monotonic on the branch that holds the optimum, so one bracketed root does.
        _classic(d, v0, v_max, a_acc, j_max, best, cand, lim)
        if lim[_BEST_DUR] < math.inf:
            n = int(lim[_BEST_N])
            return best[:, :n].copy(), n, True
    _search(d, v0, a0, vf, v_max, a_acc, a_dec, j_max, outside, best, cand, lim)
    if outside:
        # One more candidate: ruckig's brake pre-profile (back within the limits), then the
        # fastest profile from there. With it the result is never slower than ruckig's.
        t1, jb, t2 = _brake(v0, a0, v_max, a_dec, j_max)
        if t1 > 0.0 or t2 > 0.0:
            a1 = a0 + jb * t1
            v1 = v0 + t1 * (a0 + 0.5 * jb * t1)
            p1 = t1 * (v0 + t1 * (0.5 * a0 + t1 * jb / 6.0))
            v2 = v1 + a1 * t2
            p2 = p1 + t2 * (v1 + 0.5 * a1 * t2)
            v_nat2 = v2 + a1 * abs(a1) / (2.0 * j_max)
            sub_best = np.zeros((2, 3 * MAX_PHASES))
            v_allowed2 = max(v_max, abs(v2), abs(v_nat2)) * (1 + 1e-9)
            sub = _new_state(v_allowed2, v_max * (1 + 1e-9), math.inf)
            _search(d - p2, v2, a1, vf, v_max, a_acc, a_dec, j_max, False, sub_best, cand, sub)
            m = int(sub[_BEST_N])
            if sub[_BEST_DUR] < math.inf and m + 2 <= MAX_PHASES:
                cand[0, 0] = t1
                cand[1, 0] = jb
                cand[0, 1] = t2
                cand[1, 1] = 0.0
                cand[:, 2 : 2 + m] = sub_best[:, :m]
                _offer(cand, 2 + m, d, v0, a0, a_acc, a_dec, best, lim)
    if lim[_BEST_DUR] < math.inf:
        n = int(lim[_BEST_N])
        return best[:, :n].copy(), n, True
    if lim[_LOW_PEAK] < math.inf:
        n = int(lim[_LOW_N])
        return best[:, MAX_PHASES : MAX_PHASES + n].copy(), n, False
    n = int(lim[_NEAR_N])
    return best[:, 2 * MAX_PHASES : 2 * MAX_PHASES + n].copy(), n, False


def warm_up() -> None:
    """Load (or compile, the first time on a machine) the S-curve kernel: call it before a
    real-time loop or a timing."""
    scurve_phases(1.0, 0.5, 0.5, 0.0, 1.0, 1.0, 1.0, 1.0)
