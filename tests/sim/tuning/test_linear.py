"""Linear loop models: margins against a hand-derived case and scipy.signal, the model
against the firmware's own current-loop polynomial, and the stability gate against the
simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from firmware_model.firmware import Firmware
from serial_protocol.exceptions import ConfigError
from serial_protocol.messages import Ack, Loop, Nack, NackCode
from sim.config import Experiment, ScriptedCommand
from sim.loop import apply_overrides, run
from sim.tuning import linear
from sim.tuning.cost import CostWeights
from sim.tuning.evaluate import evaluate
from sim.tuning.gains import GainSet
from sim.tuning.linear import LoopTransfer, loop_transfer, margins

DT_S = 0.002


def _integrator_with_delay(k: float) -> LoopTransfer:
    """L(z) = k / (z (z - 1)): closed loop z^2 - z + k, stable iff k < 1."""
    a, b, c, d = signal.tf2ss([k], [1.0, -1.0, 0.0])
    return LoopTransfer("test", a, b[:, 0], c[0], float(d[0, 0]), DT_S)


@pytest.mark.parametrize("k", [0.1, 0.3, 0.6, 0.9])
def test_margins_of_a_hand_derived_loop(k):
    # |L| = k / (2 sin(theta / 2)), arg L = -pi/2 - 3 theta / 2 at z = exp(j theta):
    # phase crossover at theta = pi / 3 with |L| = k, gain crossover at 2 asin(k / 2).
    m = margins(_integrator_with_delay(k))
    theta_c = 2.0 * math.asin(k / 2.0)
    assert m.gain_margin == pytest.approx(1.0 / k, rel=1e-6)
    assert m.phase_crossover_hz == pytest.approx((math.pi / 3) / (2 * math.pi * DT_S), rel=1e-6)
    assert m.crossover_hz == pytest.approx(theta_c / (2 * math.pi * DT_S), rel=1e-6)
    assert m.phase_margin_deg == pytest.approx(90.0 - math.degrees(1.5 * theta_c), abs=1e-4)
    assert m.stable


def test_unstable_hand_derived_loop_is_flagged():
    m = margins(_integrator_with_delay(1.2))
    assert not m.stable
    assert m.spectral_radius == pytest.approx(math.sqrt(1.2), rel=1e-9)


@pytest.mark.filterwarnings("ignore::scipy.signal.BadCoefficients")
@pytest.mark.parametrize("loop", linear.LOOPS)
def test_response_and_margins_agree_with_scipy_signal(bench, loop):
    gains = GainSet.from_bench(bench)
    lt = loop_transfer(bench, gains, loop)
    num, den = lt.tf()
    system = signal.dlti(num, den, dt=lt.dt_s)
    f_hz = np.geomspace(0.1, lt.nyquist_hz * 0.99, 4000)
    _, resp = signal.dfreqresp(system, w=2 * np.pi * f_hz * lt.dt_s)
    np.testing.assert_allclose(lt.response(f_hz), resp, rtol=1e-6)
    # Independent margins from scipy's response on a dense grid (linear interpolation).
    mag = np.abs(resp)
    k = np.nonzero((mag[:-1] - 1.0) * (mag[1:] - 1.0) < 0)[0][0]
    pm_deg = 180.0 + np.degrees(np.angle(resp[k]))
    m = margins(lt)
    assert m.crossover_hz == pytest.approx(f_hz[k], rel=5e-3)
    assert m.phase_margin_deg == pytest.approx(pm_deg, abs=0.5)
    # The closed-loop poles are the roots of den + num (negative feedback).
    poles = np.roots(np.polyadd(den, num))
    assert np.max(np.abs(poles)) == pytest.approx(m.spectral_radius, rel=1e-6)


@pytest.mark.parametrize("multiple", [1, 2, 4])
def test_current_loop_matches_the_hand_derived_polynomial(bench, multiple):
    # PI Kp + Ki Ts / (z - 1), one period of compute delay, the armature sampled with a
    # hold: i(z) / u(z) = (1 - a) / R / (z - a), a = exp(-R Ts / L). Closed loop:
    # z (z - 1) (z - a) + (1 - a) / R (Kp (z - 1) + Ki Ts) = 0.
    bench = apply_overrides(bench, {"servo.current_loop_multiple": multiple})
    dt_s = DT_S / multiple  # the current loop runs `multiple` times per servo tick
    gains = GainSet.from_bench(bench)
    plant = linear.LinearPlant.from_bench(bench)
    a = math.exp(-plant.r_ohm * dt_s / plant.l_h)
    g = (1.0 - a) / plant.r_ohm
    poly = np.polymul([1.0, 0.0], np.polymul([1.0, -1.0], [1.0, -a]))
    poly = np.polyadd(
        poly, g * np.array([gains.kp_i_v_per_a, gains.ki_i_v_per_as * dt_s - gains.kp_i_v_per_a])
    )
    rho = np.max(np.abs(np.roots(poly)))
    lt = loop_transfer(bench, gains, "current")
    assert lt.dt_s == pytest.approx(dt_s)
    assert lt.spectral_radius() == pytest.approx(rho, rel=1e-9)
    # The servo-rate models run the current loop `multiple` times per tick and stay stable.
    assert all(m.stable for m in linear.analyse(bench, gains).values())


def test_check_gains_refuses_unstable_with_the_source_and_reason(bench):
    gains = GainSet.from_bench(bench)
    linear.check_gains(bench, gains, "paper_bench.toml")  # the defaults pass
    # Kp = 3 R: the proportional path alone returns three times the error a period later.
    bad = gains.replace(kp_i_v_per_a=3.0 * linear.LinearPlant.from_bench(bench).r_ohm)
    with pytest.raises(ConfigError, match=r"the wire: gains refused \(current loop unstable"):
        linear.check_gains(bench, bad, "the wire")


def test_margin_spec_refuses_small_margins(bench):
    gains = GainSet.from_bench(bench)
    m = linear.analyse(bench, gains)["current"]
    tight = linear.MarginSpec(gain_margin=m.gain_margin * 1.01, phase_margin_deg=0.0)
    reasons = linear.rejection_reasons(bench, gains, tight)
    assert reasons == [f"current loop gain margin {m.gain_margin:.2f} < {tight.gain_margin:.2f}"]
    assert linear.rejection_reasons(bench, gains) == []


def _velocity_gain_limit(bench, gains: GainSet) -> float:
    """The smallest velocity Kp (on a 2 % grid) the gate refuses."""
    kp = gains.kp_v_a_per_dps
    while not linear.rejection_reasons(bench, gains.replace(kp_v_a_per_dps=kp)):
        kp *= 1.02
    return kp


def test_gate_agrees_with_the_simulator(bench):
    """A velocity gain half the gate's limit holds still; 15 % past the limit it rings."""
    gains = GainSet.from_bench(bench)
    limit = _velocity_gain_limit(bench, gains)
    ok = gains.replace(kp_v_a_per_dps=limit * 0.5)
    bad = gains.replace(kp_v_a_per_dps=limit * 1.15)
    assert linear.rejection_reasons(bench, ok) == []
    assert "velocity loop unstable" in linear.rejection_reasons(bench, bad)[0]
    # The firmware's back-EMF check trips a loop ringing between its clamps (the current
    # sense is blind half the time, the model disagrees): out of the way, to watch the ring.
    hold = Experiment(
        bench=apply_overrides(bench, {"safety.sensor_mismatch_deg": 1e5}),
        duration_s=0.8,
        commands=(
            ScriptedCommand(
                0.0, "move", (("target_deg", 5.0), ("v_max_dps", 100.0), ("a_max_dps2", 2000.0))
            ),
        ),
    )
    ev = evaluate([hold], [ok, bad], weights=CostWeights(), keep_logs=True)
    current = ev.logs[0].current_a[:, -200:]
    ripple = np.std(np.diff(current, axis=1), axis=1)
    assert ripple[1] > 20 * ripple[0]
    assert ripple[1] > 0.5  # amperes per tick: a sustained oscillation, not noise


def test_gains_from_the_wire_are_refused_by_the_firmware_with_this_gate(bench):
    """SetGains over the emulated UART: the board built with ``firmware_gain_check`` NACKs
    a velocity gain the simulator shows ringing (test above) and accepts a safe one."""
    gains = GainSet.from_bench(bench)
    ki = gains.ki_v_a_per_deg

    def set_gains(t_s: float, kp: float) -> ScriptedCommand:
        return ScriptedCommand(t_s, "set_gains", (("loop", Loop.VELOCITY), ("kp", kp), ("ki", ki)))

    exp = Experiment(
        bench=bench,
        duration_s=0.1,
        commands=(
            set_gains(0.01, _velocity_gain_limit(bench, gains) * 1.15),
            set_gains(0.05, 0.1),
        ),
    )
    board = Firmware(bench.firmware, gain_check=linear.firmware_gain_check(bench))
    replies = run(exp, firmware=board).replies
    nacks = [m for m in replies if isinstance(m, Nack)]
    acks = [m for m in replies if isinstance(m, Ack)]
    assert [n.code for n in nacks] == [NackCode.UNSTABLE_GAINS]
    assert len(acks) == 1 and acks[0].cmd_id == nacks[0].cmd_id + 1
    assert board.law.gains["kp_v"] == pytest.approx(0.1)
