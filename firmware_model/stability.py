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
* Position and velocity loops: a rigid motor (``Kt/J``), the commanded current effective
  after ``delay_ticks`` ticks (compute delay + current loop), the third-order velocity
  observer, the velocity PI and the position P, as one discrete state-space matrix whose
  spectral radius must be below 1.
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


def spectral_radius(
    kp_per_s: float,
    kp_a_per_dps: float,
    ki_a_per_deg: float,
    *,
    dt_s: float,
    observer: tuple[float, float, float],
    accel_per_amp_dps2: float,
    delay_ticks: int = 2,
) -> float:
    """Largest |eigenvalue| of the linear position/velocity loop model (see module doc)."""
    # Axis deg/s^2 per ampere of the nominal rigid motor.
    c = NOMINAL["kt_nm_per_a"] / NOMINAL["inertia_kgm2"] / MOTOR_RAD_S_PER_AXIS_DPS
    d = max(int(delay_ticks), 1)
    k_pos, k_vel, k_dist = observer
    # State: p, v (true), pe, ve, ae (observer), I_v, pipe[0..d-1] (currents not yet acting).
    n = 6 + d
    a_mat = np.zeros((n, n))
    p_, v_, pe_, ve_, iv_, ae_ = 0, 1, 2, 3, 4, 5
    pipe = list(range(6, 6 + d))
    eye = np.eye(n)
    # Plant: the oldest commanded current acts during this tick.
    a_mat[p_, p_] = 1.0
    a_mat[p_, v_] = dt_s
    a_mat[p_, pipe[0]] = 0.5 * c * dt_s**2
    a_mat[v_, v_] = 1.0
    a_mat[v_, pipe[0]] = c * dt_s
    # Observer (measures p; the current acting this tick is its known input):
    # acc = c_est i + ae; pred = pe + ve dt + acc dt^2 / 2; err = p - pred.
    acc = eye[ae_] + accel_per_amp_dps2 * eye[pipe[0]]
    pred = eye[pe_] + dt_s * eye[ve_] + 0.5 * dt_s**2 * acc
    err = eye[p_] - pred
    a_mat[pe_] = pred + k_pos * err
    a_mat[ve_] = eye[ve_] + dt_s * acc + k_vel / dt_s * err
    a_mat[ae_] = eye[ae_] + k_dist / dt_s**2 * err
    # Control law on the *updated* observer (as the firmware runs it), reference 0.
    ve_new = a_mat[ve_]
    vref = -kp_per_s * eye[p_]
    ev = vref - ve_new
    a_mat[iv_] = eye[iv_] + ki_a_per_deg * dt_s * ev
    iref = kp_a_per_dps * ev + eye[iv_]
    for j in range(d - 1):
        a_mat[pipe[j]] = eye[pipe[j + 1]]
    a_mat[pipe[-1]] = iref
    return float(np.max(np.abs(np.linalg.eigvals(a_mat))))


def unstable_reason(params: FirmwareParams, gains: dict[str, float]) -> str | None:
    """None if the gain set passes both checks, else a short reason.

    ``gains`` holds ``kp_i, ki_i, kp_v, ki_v, kp_p`` (units of ``firmware_model.params``).
    """
    servo = params.servo
    dt_c = servo.dt_s / servo.current_loop_multiple
    if not current_loop_stable(gains["kp_i"], gains["ki_i"], dt_c, servo.compute_delay_ticks):
        return "current loop"
    rho = spectral_radius(
        gains["kp_p"],
        gains["kp_v"],
        gains["ki_v"],
        dt_s=servo.dt_s,
        observer=params.estimator.observer_gains(servo.dt_s),
        accel_per_amp_dps2=params.estimator.accel_per_amp_dps2,
        delay_ticks=servo.compute_delay_ticks + 1,
    )
    if not rho < 1.0:
        return f"position/velocity loop (spectral radius {rho:.3f})"
    return None
