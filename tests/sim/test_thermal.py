"""The motor's heat (issue 13 §2.6, ``sim.thermal``): the lumped network against its closed
forms, R(T) and Kt(T) in the plant, the off switch, one implementation for every N and for
both loop paths, the oracle, and the ``[thermal]`` table's checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from recording import recording

from firmware_model.thermal import network_step, network_zoh, steady_rise_k
from sim import cli, loop
from sim.oracle import replay
from sim.params import MotorParams, PlantParams, ThermalParams
from sim.reproduce import experiments
from sim.thermal import Heat, heat_advance

HEAT = {"thermal.model": True}
QUIET = {"encoder.noise_rms_lsb": 0.0}


def _fig6(duration_s: float = 1.5, seed: int = 0, batch: int | None = None, **overrides):
    exp = experiments.with_duration(experiments.load("fig6"), duration_s)
    return loop.run(exp, seed=seed, batch=batch, overrides=overrides or None)


def _run_inputs(duration_s: float, **overrides):
    """Fig. 6 through the tick-by-tick loop, recording the plant's inputs: (duty, enable,
    plant params, result)."""
    sim, result = recording(_fig6, duration_s, **overrides)
    duty, enable = sim.inputs()
    return duty, enable, sim.bench.plant, result


def _network(p_w: float, p_h: float, h_s: float, steps: int, **kw) -> np.ndarray:
    th = ThermalParams(**kw)
    net = network_zoh(
        th.r_winding_housing_k_w, th.r_housing_ambient_k_w, th.tau_winding_s, th.tau_housing_s,
        h_s,
    )  # fmt: skip
    temps = np.array([[th.ambient_c, th.ambient_c]])
    out = np.empty((steps, 2))
    for k in range(steps):
        network_step(temps, 0, p_w, p_h, th.ambient_c, net)
        out[k] = temps[0]
    return out


def test_network_is_the_two_node_closed_form():
    # 10 W into the winding from ambient: the two-exponential solution of the network,
    # rising to P (R_wh + R_ha) with the network's two time constants.
    r_wh, r_ha, tau_w, tau_h, amb = 2.5, 6.0, 30.0, 900.0, 25.0
    h, steps, p = 5.0, 2000, 10.0
    out = _network(p, 0.0, h, steps)
    c_w, c_h = tau_w / r_wh, tau_h / r_ha
    a = np.array([[-1 / (r_wh * c_w), 1 / (r_wh * c_w)],
                  [1 / (r_wh * c_h), -(1 / r_wh + 1 / r_ha) / c_h]])  # fmt: skip
    lam, vec = np.linalg.eig(a)
    steady = np.array(steady_rise_k(p, 0.0, r_wh, r_ha))
    coef = np.linalg.solve(vec, -steady)  # rise(0) = 0
    t = h * np.arange(1, steps + 1)
    rise = steady[:, None] + (vec * coef) @ np.exp(np.outer(lam, t))
    np.testing.assert_allclose(out - amb, rise.T, rtol=0, atol=1e-9)
    assert out[-1, 0] - amb == pytest.approx(p * (r_wh + r_ha), rel=2e-3)  # 3 tau_h: ~steady
    # The two time constants, the roots of s^2 + b s + c: 27.7 s (the winding against its
    # housing) and 974 s (the whole motor), where the catalogue's tau_w, tau_h are 30, 900 s.
    b = 1 / (r_wh * c_w) + (1 / r_wh + 1 / r_ha) / c_h
    c = 1 / (r_wh * c_w * r_ha * c_h)
    roots = [(-b + math.sqrt(b * b - 4 * c)) / 2, (-b - math.sqrt(b * b - 4 * c)) / 2]
    assert sorted(-1 / lam) == pytest.approx(sorted(-1 / r for r in roots), rel=1e-12)
    assert sorted(-1 / lam) == pytest.approx([27.71, 974.29], abs=0.01)


def test_a_winding_on_a_held_housing_is_first_order():
    # A housing of enormous capacity stays at ambient: the winding rises as P R_wh with tau_w.
    out = _network(8.0, 0.0, 0.5, 400, tau_housing_s=1e12)
    t = 0.5 * np.arange(1, 401)
    np.testing.assert_allclose(out[:, 0] - 25.0, 8.0 * 2.5 * (1 - np.exp(-t / 30.0)), atol=1e-9)


def test_a_held_current_heats_the_winding_to_the_fixed_point_of_r_of_t():
    # 3 A held at rest, R(T) rising with the winding: T = T_a + i^2 R(T) R_th solved for T.
    params = PlantParams(thermal=ThermalParams(model=True))
    heat = Heat(params, 1, 10.0)
    x = np.array([[3.0, 0.0, 0.0, 0.0, 0.0]])
    for _ in range(4000):  # 40,000 s: 34 housing time constants
        heat_advance(x, x, heat.kernel_args())
    th, r20 = params.thermal, params.motor.r_ohm
    k = 9.0 * r20 * (th.r_winding_housing_k_w + th.r_housing_ambient_k_w)
    a = th.alpha_cu_per_k
    t_ss = (th.ambient_c + k * (1 - a * th.reference_c)) / (1 - k * a)
    assert heat.temps[0, 0] == pytest.approx(t_ss, rel=1e-9)
    assert t_ss > 150.0  # 3 A continuous is far beyond this motor's rating (docs/model.md)


def test_off_is_the_model_without_heat():
    base = _fig6()
    changed = _fig6(
        **{"thermal.ambient_c": 80.0, "thermal.alpha_cu_per_k": 0.005,
           "thermal.initial_winding_rise_k": 30.0},
    )  # fmt: skip
    for name, column in base.log.items():
        np.testing.assert_array_equal(column, getattr(changed.log, name), name)
    assert base.pc_bytes == changed.pc_bytes
    assert np.all(base.log.winding_c == 20.0)


def test_a_held_temperature_is_the_plant_built_with_that_r_and_kt():
    # A winding held at 70 degC (capacities so large that it does not move; the 10 K table
    # step puts a table exactly at 70 degC) runs as the plant whose [motor] says R(70),
    # Kt(70), Ke(70): every column, bit for bit.
    dt = 70.0 - 20.0
    held = _fig6(
        **HEAT,
        **{"thermal.ambient_c": 70.0, "thermal.matrix_step_k": 10.0,
           "thermal.tau_winding_s": 1e12, "thermal.tau_housing_s": 1e12},
    )  # fmt: skip
    m = MotorParams()
    mag = 1.0 + ThermalParams().magnet_tc_per_k * dt
    built = _fig6(
        **{"motor.r_ohm": m.r_ohm * (1.0 + ThermalParams().alpha_cu_per_k * dt),
           "motor.kt_nm_a": m.kt_nm_a * mag, "motor.ke_v_s_rad": m.ke_v_s_rad * mag},
    )  # fmt: skip
    for name, column in built.log.items():
        if name != "winding_c":
            np.testing.assert_array_equal(column, getattr(held.log, name), name)
    assert np.abs(held.log.winding_c - 70.0).max() < 1e-6
    # ... and it is not the cold motor's run.
    assert np.abs(held.log.true_pos_deg - _fig6().log.true_pos_deg).max() > 1.0


def test_batch_members_with_their_own_thermal_parameters_are_single_runs():
    amb = np.array([10.0, 25.0, 60.0])
    tau = np.array([30.0, 10.0, 60.0])
    over = {**HEAT, **QUIET, "thermal.ambient_c": amb, "thermal.tau_winding_s": tau}
    both = _fig6(1.2, batch=3, **over)
    for j in range(3):
        one = _fig6(
            1.2, **{**HEAT, **QUIET, "thermal.ambient_c": amb[j], "thermal.tau_winding_s": tau[j]}
        ).log
        member = both.log.member(j)
        for name in ("winding_c", "current_a", "true_pos_deg", "voltage_v", "duty"):
            np.testing.assert_array_equal(getattr(member, name), getattr(one, name), name)
    assert both.log.winding_c[2, -1] > both.log.winding_c[0, -1] + 40.0


def test_compiled_tick_and_tick_by_tick_loop_agree():
    over = {**HEAT, "thermal.initial_winding_rise_k": 40.0, "thermal.matrix_step_k": 0.1}
    fast = _fig6(0.8, **over)
    slow = _run_inputs(0.8, **over)[3]  # recording the inputs: the Python tick
    for name, column in fast.log.items():
        np.testing.assert_array_equal(column, getattr(slow.log, name), name)
    assert fast.pc_bytes == slow.pc_bytes


def test_replay_against_solve_ivp_with_the_temperatures():
    # Fig. 6's first 0.8 s at 5 A from a warm winding, replayed by solve_ivp with R, Kt, Ke
    # at the winding's temperature as it is at every instant (sim.oracle.derivative_heat).
    over = {
        **HEAT,
        "thermal.matrix_step_k": 0.05,
        "thermal.initial_winding_rise_k": 20.0,
        "thermal.initial_housing_rise_k": 20.0,
    }
    duty, enable, params, result = _run_inputs(0.8, **over)
    ref = replay(params, duty, enable, 0.002)
    log = result.log
    n = len(ref) - 1
    rise = log.winding_c[n] - log.winding_c[0]
    assert rise > 0.4  # the winding heats by ~0.5 K meanwhile
    assert np.abs(ref[:n, 5] - log.winding_c[1 : n + 1]).max() < 0.02 * rise
    assert np.abs(ref[:n, 1] - log.motor_pos_rad[1 : n + 1]).max() / (2 * math.pi) < 2e-3
    assert np.abs(ref[:n, 0] - log.current_a[1 : n + 1]).max() < 2e-3


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("model", 1, "true or false"),
        ("tau_winding_s", 0.0, "> 0"),
        ("r_housing_ambient_k_w", -1.0, "> 0"),
        ("ambient_c", 400.0, "[-60, 250]"),
        ("initial_winding_rise_k", 300.0, "[-60, 250]"),
        ("friction_heat_fraction", 1.5, "[0, 1]"),
        ("alpha_cu_per_k", 0.1, "<= 0"),
        ("matrix_step_k", 20.0, "at most 10"),
        ("reference_c", math.inf, "finite"),
    ],
)
def test_bad_thermal_values_are_refused_in_one_line(key, value, words):
    with pytest.raises(ValueError, match=words) as info:
        ThermalParams(**{key: value})
    assert "\n" not in str(info.value) and key in str(info.value)


def test_a_bad_thermal_value_in_a_bench_file_is_exit_status_2(tmp_path, capsys):
    bench = tmp_path / "bench.toml"
    bench.write_text("[thermal]\nmodel = true\ntau_housing_s = -5.0\n")
    exp = tmp_path / "exp.toml"
    exp.write_text(f'bench = "{bench}"\nduration_s = 0.1\n')
    status = cli.main(["run", str(exp), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "[thermal]" in lines[0] and "tau_housing_s = -5.0" in lines[0]
    assert "Traceback" not in err and not (tmp_path / "out").exists()
