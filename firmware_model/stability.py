"""A simple stability check of a gain set against the firmware's nominal plant model.

Used by the firmware to NACK ``SetGains`` with ``NackCode.UNSTABLE_GAINS``. It is a
necessary check on a linear model (no saturation, no quantisation, no belt resonance), not a
margin analysis: gains that pass can still ring on the real plant.

* Current loop: with resistive and back-EMF feed-forward the PI acts on the model error of
  a plant that, sampled every ``Ts_c`` with an electrical time constant L/R (0.5 ms) far
  shorter than the period, is a static gain 1/R seen ``d + 1`` periods after the duty is
  computed (``d`` = compute delay): ``z^(d+1) (z - 1) + a (z - 1) + b z = 0`` with
  ``a = Kp/R``, ``b = Ki Ts_c / R``; all roots inside the unit circle (for d = 0 that is
  Jury's ``0 <= a < 1``, ``2a + b < 2``). The PI compares each sample with the reference of
  the duty that produced it, so the feed-forward path does not enter this loop.
* The whole loop at the servo rate, as one discrete state-space matrix whose spectral
  radius must be below 1: a rigid motor (``Kt/J``) whose current over a tick is
  ``(u - k_emf v) / R`` (static: L/R << Ts), the applied voltage ``u`` computed ``d`` ticks
  earlier from the resistive and back-EMF feed-forward (on the *estimated* velocity: the
  estimation error drives current) and the current PI, the third-order velocity observer
  fed with the current of the period that just ended, the velocity PI and the position P.
  Against the closed loop (friction, belt, backlash, noise) it agrees at the high-gain
  edges: it refuses the velocity gain from 9.5x the default (the test plant holds at 8x,
  rings at 12x) and the position gain from 11x. At the low edge it refuses velocity gains
  below 0.34x the default (a 6.4 Hz mode growing 0.5 % per tick at 0.25x; likewise a
  position or velocity-integral gain raised against a low velocity gain). That mode is
  real: Coulomb friction hides it after a small move (90 deg at 300 deg/s settles at
  0.25x), but after Fig. 8's moves the plant of ``sim/`` rings in it at 6-6.5 Hz between
  the 5 A clamps at 0.34x and below and holds at 0.37x; over a grid of 63 low-gain sets it
  agreed with that run in 61 and never refused a set the plant held (the two misses, at a
  radius of 0.999, ring and were accepted). Tested on both sides.
"""

from __future__ import annotations

import numpy as np

from firmware_model.params import NOMINAL, FirmwareParams
from firmware_model.units import MOTOR_RAD_S_PER_AXIS_DPS

__all__ = ["current_loop_stable", "spectral_radius", "unstable_reason"]


def current_loop_stable(
    kp_v_per_a: float, ki_v_per_as: float, dt_s: float, delay_ticks: int = 1
) -> bool:
    """Roots of ``z^(d+1) (z - 1) + a (z - 1) + b z`` inside the unit circle (module doc)."""
    r = NOMINAL["resistance_ohm"]
    a = kp_v_per_a / r
    b = ki_v_per_as * dt_s / r
    d = int(delay_ticks)
    poly = np.zeros(d + 3)
    poly[0], poly[1] = 1.0, -1.0  # z^(d+1) (z - 1)
    poly[-2] += a + b
    poly[-1] -= a
    return bool(np.max(np.abs(np.roots(poly))) < 1.0)


def spectral_radius(gains: dict[str, float], params: FirmwareParams) -> float:
    """Largest |eigenvalue| of the whole linear loop at the servo rate (see module doc).

    ``gains``: ``kp_i, ki_i, kp_v, ki_v, kp_p`` (units of ``firmware_model.params``); the
    feed-forward terms are the nominal ones (R and the back-EMF constant).
    """
    servo = params.servo
    dt = servo.dt_s
    d = servo.compute_delay_ticks
    r_ohm = NOMINAL["resistance_ohm"]
    # Axis deg/s^2 per ampere of the nominal rigid motor; V per axis deg/s of back-EMF.
    c = NOMINAL["kt_nm_per_a"] / NOMINAL["inertia_kgm2"] / MOTOR_RAD_S_PER_AXIS_DPS
    k_emf = NOMINAL["kt_nm_per_a"] * MOTOR_RAD_S_PER_AXIS_DPS
    c_obs = params.estimator.accel_per_amp_dps2
    k_pos, k_vel, k_dist = params.estimator.observer_gains(dt)
    # State: true p, v; observer pe, ve, ae; integrators; the current of the last period;
    # the references of the last d + 1 ticks (r0 newest); the voltages not yet applied.
    names = ["p", "v", "pe", "ve", "ae", "iv", "ii", "i_last"]
    names += [f"r{j}" for j in range(d + 1)] + [f"u{j}" for j in range(d)]
    ix = {name: k for k, name in enumerate(names)}
    eye = np.eye(len(names))

    def x(name: str) -> np.ndarray:
        return eye[ix[name]]

    # Observer: the current of the period that just ended is its known acceleration input.
    acc = c_obs * x("i_last") + x("ae")
    pred = x("pe") + dt * x("ve") + 0.5 * dt**2 * acc
    err = x("p") - pred
    ve_new = x("ve") + dt * acc + k_vel / dt * err
    rows = {
        "pe": pred + k_pos * err,
        "ve": ve_new,
        "ae": x("ae") + k_dist / dt**2 * err,
    }
    # Position P and velocity PI on the updated estimate (reference 0).
    ev = -gains["kp_p"] * x("p") - ve_new
    i_ref = gains["kp_v"] * ev + x("iv")
    rows["iv"] = x("iv") + gains["ki_v"] * dt * ev
    # Current PI against the reference of the duty that produced the sample, with
    # resistive and back-EMF (on the estimate) feed-forward.
    e_i = x(f"r{d}") - x("i_last")
    u = r_ohm * i_ref + k_emf * ve_new + gains["kp_i"] * e_i + x("ii")
    rows["ii"] = x("ii") + gains["ki_i"] * dt * e_i
    rows["r0"] = i_ref
    for j in range(1, d + 1):
        rows[f"r{j}"] = x(f"r{j - 1}")
    if d:
        u_applied = x("u0")
        for j in range(d - 1):
            rows[f"u{j}"] = x(f"u{j + 1}")
        rows[f"u{d - 1}"] = u
    else:
        u_applied = u
    # Plant over the tick: static electrical part (L/R << Ts), rigid mechanics.
    i_now = (u_applied - k_emf * x("v")) / r_ohm
    rows["p"] = x("p") + dt * x("v") + 0.5 * c * dt**2 * i_now
    rows["v"] = x("v") + c * dt * i_now
    rows["i_last"] = i_now
    a_mat = np.array([rows[name] for name in names])
    return float(np.max(np.abs(np.linalg.eigvals(a_mat))))


def unstable_reason(params: FirmwareParams, gains: dict[str, float]) -> str | None:
    """None if the gain set passes both checks, else a short reason.

    ``gains`` holds ``kp_i, ki_i, kp_v, ki_v, kp_p`` (units of ``firmware_model.params``).
    """
    servo = params.servo
    dt_c = servo.dt_s / servo.current_loop_multiple
    if not current_loop_stable(gains["kp_i"], gains["ki_i"], dt_c, servo.compute_delay_ticks):
        return "current loop"
    rho = spectral_radius(gains, params)
    if not rho < 1.0:
        return f"servo loops (spectral radius {rho:.4f})"
    return None
