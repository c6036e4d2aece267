"""Discrete loop transfers of the three loops, their margins and Bode data, and the gate that
refuses unstable gains.

Each loop is modelled at its own rate exactly as the firmware computes it
(``firmware_model/servo.py``): sampled at the tick, the duty loaded ``compute_delay_ticks``
current-loop periods later and held (zero-order hold), the plant discretised exactly with
that hold (``expm``). The loop is broken at the output of its controller: inject ``w`` where
the controller's output would go, read the output ``y`` the controller computes; the loop
gain is ``L(z) = -Y(z) / W(z)`` (negative feedback: the closed loop is stable when
``1 + L`` has no zeros outside the unit circle).

* **current** (rate ``tick_hz * current_loop_multiple``): the armature ``di/dt = (u - R i)/L``
  sampled every period, the PI ``Kp e + Ki Ts sum(e)`` (integrator updated after use), the
  compute delay. The back-EMF is left out (the feed-forward cancels it and the mechanics are
  ~1000x slower); the reference path (feed-forward, delayed reference) is outside the loop.
* **velocity** (servo rate): broken at the current reference; inside: the current loop
  closed (with its feed-forward and delayed reference, run ``current_loop_multiple`` times),
  the rigid mechanics of the nominal plant (``i -> v -> p``, viscous drag, back-EMF), the
  encoder sample, the third-order observer with its current input (the sample of the
  previous tick, as the firmware uses it) and the velocity PI; position loop open.
* **position** (servo rate): broken at the velocity reference, velocity loop closed.

Not modelled (a linear analysis cannot): the belt compliance and backlash, Coulomb
friction, encoder quantisation, the current and voltage clamps. The tests check the margins
against scipy.signal and a hand-derived case; ``docs/tuning.md`` has the equations.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.optimize import brentq

from firmware_model.params import FirmwareParams
from firmware_model.units import MOTOR_RAD_S_PER_AXIS_DPS
from serial_protocol.exceptions import ConfigError
from sim.config import BenchConfig
from sim.tuning.gains import GainSet

__all__ = [
    "LOOPS",
    "LinearPlant",
    "LoopTransfer",
    "Margins",
    "MarginSpec",
    "analyse",
    "check_gains",
    "firmware_gain_check",
    "loop_transfer",
    "margins",
    "rejection_reasons",
]

LOOPS = ("current", "velocity", "position")


def _scalar(value: object, name: str) -> float:
    arr = np.asarray(value, dtype=float)
    if arr.ndim:
        raise ValueError(f"{name}: the linear model needs scalar plant parameters")
    return float(arr)


@dataclass(frozen=True)
class LinearPlant:
    """The rigid nominal plant of the linear models (axis units).

    Attributes:
        r_ohm: armature plus bridge path resistance.
        l_h: armature inductance.
        ke_v_per_dps: back-EMF per axis deg/s.
        accel_dps2_per_a: axis acceleration per ampere (Kt / J_eq, J_eq = motor + platter
            reflected through 400:1 at the gearbox efficiency).
        drag_per_s: viscous drag over inertia (1/s).
    """

    r_ohm: float
    l_h: float
    ke_v_per_dps: float
    accel_dps2_per_a: float
    drag_per_s: float

    @classmethod
    def from_bench(cls, bench: BenchConfig) -> LinearPlant:
        p = bench.plant
        n2 = p.total_ratio**2
        eff = _scalar(p.gearbox.efficiency, "efficiency")
        j_eq = _scalar(p.motor.j_kgm2, "j_kgm2") + _scalar(p.platter.j_kgm2, "j_kgm2") / n2 / eff
        b_eq = (
            _scalar(p.motor_viscous_nm_s_rad, "viscous_nm_s_rad")
            + _scalar(p.platter.viscous_nm_s_rad, "viscous_nm_s_rad") / n2 / eff
        )
        return cls(
            r_ohm=_scalar(p.motor.r_ohm, "r_ohm") + _scalar(p.bridge.r_on_path_ohm, "r_on"),
            l_h=_scalar(p.motor.l_h, "l_h"),
            ke_v_per_dps=_scalar(p.motor.ke_v_s_rad, "ke") * MOTOR_RAD_S_PER_AXIS_DPS,
            accel_dps2_per_a=_scalar(p.motor.kt_nm_a, "kt") / j_eq / MOTOR_RAD_S_PER_AXIS_DPS,
            drag_per_s=b_eq / j_eq,
        )

    def zoh(self, h_s: float, *, mechanics: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Exact ZOH step over ``h_s`` of state ``(i_a, v_dps, p_deg)`` with the voltage held:
        ``(Phi (3, 3), Gamma (3,))``. Without ``mechanics`` the speed stays 0 (no EMF)."""
        return _zoh(self, float(h_s), mechanics)


@functools.lru_cache(maxsize=64)
def _zoh(plant: LinearPlant, h_s: float, mechanics: bool) -> tuple[np.ndarray, np.ndarray]:
    # Cached: scipy's expm costs milliseconds even at 4 x 4 and the optimiser asks often.
    a = np.zeros((4, 4))
    a[0, 0] = -plant.r_ohm / plant.l_h
    a[0, 3] = 1.0 / plant.l_h
    if mechanics:
        a[0, 1] = -plant.ke_v_per_dps / plant.l_h
        a[1, 0] = plant.accel_dps2_per_a
        a[1, 1] = -plant.drag_per_s
        a[2, 1] = 1.0
    m = scipy.linalg.expm(a * h_s)
    return m[:3, :3], m[:3, 3]


@dataclass(frozen=True)
class LoopTransfer:
    """``L(z) = C (zI - A)^-1 B + D`` of one broken loop at sample time ``dt_s``; the loop
    closes with ``w = -L w`` feedback, i.e. the closed-loop matrix is ``A - B C / (1 + D)``."""

    name: str
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: float
    dt_s: float

    @property
    def nyquist_hz(self) -> float:
        return 0.5 / self.dt_s

    def response(self, freq_hz: np.ndarray | float) -> np.ndarray:
        """Complex ``L(exp(j 2 pi f dt))`` at each frequency (shape of ``freq_hz``)."""
        f = np.atleast_1d(np.asarray(freq_hz, dtype=float)).ravel()
        z = np.exp(2j * math.pi * f * self.dt_s)
        m = z[:, None, None] * np.eye(self.a.shape[0]) - self.a
        x = np.linalg.solve(m, np.broadcast_to(self.b[:, None], (f.size, self.b.size, 1)))
        out = x[:, :, 0] @ self.c + self.d
        return out.reshape(np.shape(freq_hz)) if np.ndim(freq_hz) else complex(out[0])

    def closed_loop_matrix(self) -> np.ndarray:
        return self.a - np.outer(self.b, self.c) / (1.0 + self.d)

    def spectral_radius(self) -> float:
        """Largest |eigenvalue| of the closed loop (< 1: stable)."""
        return float(np.max(np.abs(np.linalg.eigvals(self.closed_loop_matrix()))))

    def tf(self) -> tuple[np.ndarray, np.ndarray]:
        """``(num, den)`` in descending powers of z (``scipy.signal.ss2tf``)."""
        from scipy.signal import ss2tf

        num, den = ss2tf(self.a, self.b[:, None], self.c[None, :], np.array([[self.d]]))
        return num[0], den


class _Rows:
    """Linear signals as row vectors over ``[state..., w]`` (one tick written as code)."""

    def __init__(self, names: list[str]) -> None:
        self.index = {n: k for k, n in enumerate(names)}
        self.n = len(names)
        self.eye = np.eye(self.n + 1)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.eye[self.index[name]]

    @property
    def w(self) -> np.ndarray:
        return self.eye[self.n]

    def zero(self) -> np.ndarray:
        return np.zeros(self.n + 1)


def _finish(
    name: str, rows: _Rows, nxt: dict[str, np.ndarray], y: np.ndarray, dt_s: float
) -> LoopTransfer:
    m = np.array([nxt[n] for n in sorted(rows.index, key=rows.index.get)])
    # The loop gain is -y/w (module doc).
    return LoopTransfer(name, m[:, :-1], m[:, -1], -y[:-1], float(-y[-1]), dt_s)


def _current_loop(bench: BenchConfig, gains: GainSet, plant: LinearPlant) -> LoopTransfer:
    servo = bench.firmware.servo
    dt_c = servo.dt_s / servo.current_loop_multiple
    d = servo.compute_delay_ticks
    phi, gam = plant.zoh(dt_c, mechanics=False)
    names = ["i", "int_i"] + [f"u{k}" for k in range(d)]
    r = _Rows(names)
    e = -r["i"]  # reference 0: the sample against the (delayed) zero reference
    y = gains.kp_i_v_per_a * e + r["int_i"]
    nxt = {"i": None, "int_i": r["int_i"] + gains.ki_i_v_per_as * dt_c * e}
    u_cmd = r.w
    if d:
        applied = r["u0"]
        for k in range(d - 1):
            nxt[f"u{k}"] = r[f"u{k + 1}"]
        nxt[f"u{d - 1}"] = u_cmd
    else:
        applied = u_cmd
    nxt["i"] = phi[0, 0] * r["i"] + gam[0] * applied
    return _finish("current", r, nxt, y, dt_c)


def _servo_loop(bench: BenchConfig, gains: GainSet, plant: LinearPlant, loop: str) -> LoopTransfer:
    fw = bench.firmware
    servo = fw.servo
    dt = servo.dt_s
    mult = servo.current_loop_multiple
    h = dt / mult
    d = servo.compute_delay_ticks
    phi, gam = plant.zoh(h)
    k_pos, k_vel, k_dist = fw.estimator.observer_gains(dt)
    c_est = fw.estimator.accel_per_amp_dps2
    r_ff = _scalar(fw.current.resistance_ohm, "resistance_ohm")
    emf_ff = _scalar(fw.current.back_emf_v_per_dps, "back_emf_v_per_dps")
    expected = _observer_uses_expected_current(bench)
    names = ["i", "v", "p", "i_prev", "pe", "ve", "ae", "int_v", "int_i", "ref_d_last"]
    names += [f"r{k}" for k in range(d + 1)] + [f"u{k}" for k in range(d)]
    r = _Rows(names)
    # 1-2. Sample the encoder (true position) and run the observer with the current sample
    # of the previous tick as its known input.
    if expected:
        # The current of the period that just ended: the reference of the duty applied in
        # it plus the model error seen at the last sample (firmware_model/laws).
        i_obs = r["r0"] + r["i_prev"] - r["ref_d_last"]
    else:
        i_obs = r["i_prev"]  # the last sample
    acc = c_est * i_obs + r["ae"]
    pred = r["pe"] + dt * r["ve"] + 0.5 * dt * dt * acc
    err = r["p"] - pred
    nxt: dict[str, np.ndarray] = {
        "pe": pred + k_pos * err,
        "ae": r["ae"] + k_dist / (dt * dt) * err,
    }
    vel_est = r["ve"] + dt * acc + k_vel / dt * err
    nxt["ve"] = vel_est
    # 3. Position P (reference 0) and velocity PI.
    if loop == "position":
        y = -gains.kp_p_per_s * r["p"]
        vel_ref = r.w
    else:
        vel_ref = r.zero()  # position loop open
    ev = vel_ref - vel_est
    i_pi = gains.kp_v_a_per_dps * ev + r["int_v"]
    nxt["int_v"] = r["int_v"] + gains.ki_v_a_per_deg * dt * ev
    if loop == "velocity":
        y = i_pi
        i_ref = r.w
    else:
        i_ref = i_pi
    # 4. The current loop, mult times, the plant advancing h each time.
    state = {n: r[n] for n in ("i", "v", "p", "int_i")}
    refs = [r[f"r{k}"] for k in range(d + 1)]
    pipe = [r[f"u{k}"] for k in range(d)]
    sample = r["i"]
    ref_d = r["ref_d_last"]
    for _ in range(mult):
        sample = state["i"]
        ref_d = refs[0]
        e = ref_d - sample
        refs = refs[1:] + [i_ref]
        u = gains.kp_i_v_per_a * e + state["int_i"] + r_ff * i_ref + emf_ff * vel_est
        state["int_i"] = state["int_i"] + gains.ki_i_v_per_as * h * e
        if d:
            applied = pipe[0]
            pipe = pipe[1:] + [u]
        else:
            applied = u
        x = [state["i"], state["v"], state["p"]]
        new = [sum(phi[j, k] * x[k] for k in range(3)) + gam[j] * applied for j in range(3)]
        state["i"], state["v"], state["p"] = new
    nxt.update({n: state[n] for n in ("i", "v", "p", "int_i")})
    nxt["i_prev"] = sample
    nxt["ref_d_last"] = ref_d
    nxt.update({f"r{k}": refs[k] for k in range(d + 1)})
    nxt.update({f"u{k}": pipe[k] for k in range(d)})
    lt = _finish(loop, r, nxt, y, dt)
    if loop == "velocity":
        lt = _drop_position_mode(lt, r.index["p"], r.index["pe"])
    return lt


def _observer_uses_expected_current(bench: BenchConfig) -> bool:
    """Which current the firmware's observer takes as its known input: the last sample
    (as first committed) or the expected current of the period that just ended (reference
    plus the last sample's model error). Read off the law in use, so that the model follows
    the firmware; see the report of issue 6 for a public flag."""
    from firmware_model.laws import layout

    return hasattr(layout, "S_REF_D_LAST")


def _drop_position_mode(lt: LoopTransfer, ip: int, ipe: int) -> LoopTransfer:
    """With the position loop open nothing depends on the absolute position: shifting the
    true position and the observer's estimate together is a mode at z = 1 that the velocity
    loop neither sees nor moves. Keep only ``q = p - pe`` (row p becomes q, column pe goes)."""
    a = lt.a.copy()
    b = lt.b.copy()
    a[ip] = a[ip] - a[ipe]
    b[ip] = b[ip] - b[ipe]
    keep = [k for k in range(a.shape[0]) if k != ipe]
    return LoopTransfer(lt.name, a[np.ix_(keep, keep)], b[keep], lt.c[keep], lt.d, lt.dt_s)


def loop_transfer(bench: BenchConfig, gains: GainSet, loop: str) -> LoopTransfer:
    """The broken loop ``loop`` (``"current"``, ``"velocity"`` or ``"position"``)."""
    plant = LinearPlant.from_bench(bench)
    if loop == "current":
        return _current_loop(bench, gains, plant)
    if loop in ("velocity", "position"):
        return _servo_loop(bench, gains, plant, loop)
    raise ValueError(f"loop = {loop!r}: must be one of {LOOPS}")


@dataclass(frozen=True)
class Margins:
    """Stability margins of one loop.

    Attributes:
        spectral_radius: largest |closed-loop eigenvalue| (< 1: stable).
        gain_margin: factor the loop gain may grow by before instability (inf if the
            Nyquist plot never crosses the negative real axis inside the unit circle).
        phase_margin_deg: 180 + phase of L at the gain crossover (the smallest, if several).
        crossover_hz: gain-crossover frequency (|L| = 1) with that phase margin (NaN if none).
        phase_crossover_hz: frequency of the gain margin (NaN if none).
        bandwidth_hz: first frequency where |L / (1 + L)| falls below -3 dB (Nyquist if never).
    """

    loop: str
    spectral_radius: float
    gain_margin: float
    phase_margin_deg: float
    crossover_hz: float
    phase_crossover_hz: float
    bandwidth_hz: float

    @property
    def stable(self) -> bool:
        return self.spectral_radius < 1.0

    @property
    def gain_margin_db(self) -> float:
        return 20.0 * math.log10(self.gain_margin) if self.gain_margin > 0 else -math.inf


def _grid(lt: LoopTransfer, n: int = 500) -> np.ndarray:
    return np.concatenate([np.geomspace(1e-3, lt.nyquist_hz * 0.999, n - 1), [lt.nyquist_hz]])


def _crossings(freq: np.ndarray, g: np.ndarray) -> list[tuple[float, float]]:
    """Brackets ``(f0, f1)`` where ``g`` changes sign."""
    s = np.sign(g)
    idx = np.nonzero(s[:-1] * s[1:] < 0)[0]
    return [(float(freq[k]), float(freq[k + 1])) for k in idx]


def _fast_response(lt: LoopTransfer, freq: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """``L`` on frequency arrays: the transfer-function polynomials when they agree with the
    state-space solve (checked on 8 grid points to 1e-4: a phase error below 0.01 deg),
    else the state-space solve (a 500-point grid costs ~70 ms for the 20-state loops; the
    optimiser asks for margins thousands of times)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        num, den = lt.tf()

    def poly(f: np.ndarray) -> np.ndarray:
        z = np.exp(2j * math.pi * f * lt.dt_s)
        return np.polyval(num, z) / np.polyval(den, z)

    probe = freq[:: max(1, len(freq) // 8)]
    exact = lt.response(probe)
    if np.all(np.isfinite(num)) and np.allclose(poly(probe), exact, rtol=1e-4, atol=0.0):
        return poly
    return lt.response


def margins(lt: LoopTransfer) -> Margins:
    """Margins, crossovers and bandwidth of a broken loop (dense grid, then ``brentq``)."""
    freq = _grid(lt)
    at_vec = _fast_response(lt, freq)
    resp = at_vec(freq)
    mag = np.abs(resp)

    def at(f: float) -> complex:
        return complex(at_vec(np.array([f]))[0])

    pm, fc = math.inf, math.nan
    for f0, f1 in _crossings(freq, mag - 1.0):
        f = brentq(lambda x: abs(at(x)) - 1.0, f0, f1, xtol=1e-7 * f1)
        p = 180.0 + math.degrees(np.angle(at(f)))
        p = (p + 180.0) % 360.0 - 180.0
        if p < pm:
            pm, fc = p, f
    gm, fg = math.inf, math.nan
    brackets = _crossings(freq, resp.imag)
    candidates = [brentq(lambda x: at(x).imag, f0, f1, xtol=1e-7 * f1) for f0, f1 in brackets]
    if abs(resp[-1].imag) < 1e-9 * max(1.0, mag[-1]):
        candidates.append(float(freq[-1]))  # z = -1: L is real at the Nyquist frequency
    rho = lt.spectral_radius()
    gm, fg = (math.inf, math.nan) if rho < 1.0 else (math.nan, math.nan)
    for f in candidates:
        val = at(f)
        if not (val.real < 0.0 and abs(val) > 0.0):
            continue
        g = 1.0 / abs(val)
        # Stable: the smallest factor > 1 that reaches -1; unstable: the one closest below 1.
        if (rho < 1.0 and 1.0 < g < gm) or (rho >= 1.0 and g <= 1.0 and not g <= gm):
            gm, fg = g, f
    closed = np.abs(resp / (1.0 + resp))
    below = np.nonzero(closed < 1.0 / math.sqrt(2.0))[0]
    bw = float(freq[below[0]]) if below.size else lt.nyquist_hz
    return Margins(lt.name, rho, gm, pm, fc, fg, bw)


def analyse(bench: BenchConfig, gains: GainSet) -> dict[str, Margins]:
    """Margins of the three loops, inner to outer."""
    return {name: margins(loop_transfer(bench, gains, name)) for name in LOOPS}


@dataclass(frozen=True)
class MarginSpec:
    """Least margins a tuned gain set must keep (settable; docs/tuning.md).

    Attributes:
        gain_margin: smallest gain margin (factor; 2.0 = 6 dB).
        phase_margin_deg: smallest phase margin.
    """

    gain_margin: float = 2.0
    phase_margin_deg: float = 35.0


def rejection_reasons(
    bench: BenchConfig, gains: GainSet, spec: MarginSpec | None = None
) -> list[str]:
    """Why ``gains`` are refused: unstable loops always; margins below ``spec`` if given.
    Empty when accepted. Only the spectral radius is computed when ``spec`` is None."""
    reasons = []
    for name in LOOPS:
        lt = loop_transfer(bench, gains, name)
        rho = lt.spectral_radius()
        if not rho < 1.0:
            reasons.append(f"{name} loop unstable (closed-loop spectral radius {rho:.4f} >= 1)")
            continue
        if spec is not None:
            m = margins(lt)
            if m.gain_margin < spec.gain_margin:
                reasons.append(
                    f"{name} loop gain margin {m.gain_margin:.2f} < {spec.gain_margin:.2f}"
                )
            if m.phase_margin_deg < spec.phase_margin_deg:
                reasons.append(
                    f"{name} loop phase margin {m.phase_margin_deg:.1f} deg "
                    f"< {spec.phase_margin_deg:.1f} deg"
                )
    return reasons


def check_gains(bench: BenchConfig, gains: GainSet, source: str) -> None:
    """Raise ``ConfigError`` naming ``source`` and the gains if any loop is unstable."""
    reasons = rejection_reasons(bench, gains)
    if reasons:
        values = ", ".join(f"{k} = {v:.6g}" for k, v in gains.as_dict().items())
        raise ConfigError(f"{source}: gains refused ({'; '.join(reasons)}): {values}")


def firmware_gain_check(
    bench: BenchConfig,
) -> Callable[[FirmwareParams, dict[str, float]], str | None]:
    """A ``gain_check`` for ``firmware_model.firmware.Firmware(gain_check=...)``: the gate
    of this module (stability of the three loops on ``bench``'s plant) for gains that
    arrive over the wire (``SetGains``); returns the reason, or None to accept."""

    def check(params: FirmwareParams, gains: dict[str, float]) -> str | None:
        trial = GainSet(
            kp_i_v_per_a=gains["kp_i"],
            ki_i_v_per_as=gains["ki_i"],
            kp_v_a_per_dps=gains["kp_v"],
            ki_v_a_per_deg=gains["ki_v"],
            kp_p_per_s=gains["kp_p"],
        )
        reasons = rejection_reasons(dataclasses.replace(bench, firmware=params), trial)
        return "; ".join(reasons) or None

    return check
