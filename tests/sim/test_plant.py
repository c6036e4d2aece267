"""Plant: exact discretisation against solve_ivp, analytic steady states, modes."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from sim import drivetrain, plant_kernel
from sim.motor import no_load_speed_rad_s, steady_speed_rad_s
from sim.params import BridgeParams, GearboxParams, MotorParams, PlantParams
from sim.plant import (
    B_DIODE_POS,
    B_LIMIT_POS,
    B_OPEN,
    MECH_MODES,
    N_MODES,
    Coefficients,
    Plant,
    affine,
    augmented,
    derivative,
    expm_small,
    zoh_ladder,
)

DT_S = 0.002


class ScalarPlant(Plant):
    """A ``Plant`` of one member."""

    def __init__(self, params: PlantParams, h_s: float, event_levels: int = 20) -> None:
        super().__init__(params, 1, h_s, event_levels)

    def update(self, t_s, x, u):
        """``x`` (5,) or (1, 5) -> (1, 5) (``_run`` chains the arrays as a run does)."""
        if not (isinstance(x, np.ndarray) and x.shape == (1, 5)):
            x = np.asarray(x, dtype=float).reshape(1, 5)
        return super().update(t_s, x, u)


def _run(plant: Plant, x0: list[float], duties: list[float], enable: bool = True):
    xs = []
    x = np.array([x0], dtype=float)
    for k, d in enumerate(duties):
        x = plant.update(k * DT_S, x, (d, enable))
        xs.append(x[0])
    return np.array(xs)


def _oracle(params: PlantParams, x0, duties, enable=True) -> np.ndarray:
    """solve_ivp (rtol 1e-10) of the continuous model, one call per held duty."""
    y = np.array(x0, dtype=float)
    out = []
    for k, d in enumerate(duties):
        sol = solve_ivp(
            lambda t, s, d=d: derivative(t, s, (d, enable), params),
            (k * DT_S, (k + 1) * DT_S),
            y,
            method="DOP853",
            rtol=1e-10,
            atol=1e-12,
        )
        y = sol.y[:, -1]
        out.append(y)
    return np.array(out)


def test_zoh_matches_solve_ivp_through_mode_switches():
    # Accelerate, reverse (friction bands, backlash crossing, power-flow reversal), coast.
    params = PlantParams()
    duties = [0.6] * 150 + [-0.7] * 150 + [0.05] * 100 + [0.0] * 100
    xs = _run(ScalarPlant(params, DT_S), [0.0] * 5, duties)
    ref = _oracle(params, [0.0] * 5, duties)
    err_rev = np.max(np.abs(xs[:, 1] - ref[:, 1])) / (2 * math.pi)
    assert err_rev < 1e-6
    np.testing.assert_allclose(xs[:, 2], ref[:, 2], atol=1e-4)


def test_expm_small_matches_scipy_for_every_kind_of_mode():
    co = Coefficients.from_params(PlantParams())
    for key in range(0, N_MODES, 7):
        a, b, e = affine(key, co)
        m = np.zeros((7, 7))
        m[:5, :5], m[:5, 5], m[:5, 6] = a, b, e
        for h, rtol in ((2e-3, 1e-10), (2e-3 / 2**10, 1e-10), (2e-3 / 2**20, 1e-10), (0.1, 1e-8)):
            ref = scipy.linalg.expm(m * h)
            np.testing.assert_allclose(expm_small(m * h), ref, rtol=rtol, atol=1e-12)


def test_zoh_ladder_matches_scipy_at_every_level():
    co = Coefficients.from_params(PlantParams())
    for key in range(1, N_MODES, 11):
        ladder = zoh_ladder(key, co, 2e-3, 20)
        for level in (0, 1, 7, 20):
            m = augmented(key, co) * (2e-3 / 2**level)
            ref = scipy.linalg.expm(m)[:5, :]
            np.testing.assert_allclose(ladder[level], ref, rtol=1e-10, atol=1e-12)


def test_steady_speed_matches_analytic():
    params = PlantParams()
    xs = _run(ScalarPlant(params, DT_S), [0.0] * 5, [0.5] * 1500)
    assert xs[-1][2] == pytest.approx(steady_speed_rad_s(params, 0.5), rel=1e-6)


def test_bare_motor_no_load_speed():
    # With the load made negligible the drive train runs at the bare motor's no-load speed.
    light = PlantParams(
        platter=dataclasses.replace(
            PlantParams().platter, j_kgm2=1e-4, coulomb_nm=0.0, viscous_nm_s_rad=0.0
        ),
    )
    xs = _run(ScalarPlant(light, DT_S), [0.0] * 5, [1.0] * 1500)
    expected = no_load_speed_rad_s(light.motor, 24.0, light.bridge.r_on_path_ohm)
    assert xs[-1][2] == pytest.approx(expected, rel=1e-4)
    # ~15,800 rpm: the assumed motor's no-load speed at 24 V.
    assert expected * 60 / (2 * math.pi) == pytest.approx(15_600, rel=0.03)


def test_belt_resonance_from_eigenvalues():
    params = PlantParams()
    co = Coefficients.from_params(params)
    key = ((0 * 3 + 2) * 3 + 2) * 3 * 2 + 2 * 2  # bridge on, both sliding +, contact +
    a, _, _ = affine(key, co)
    eig = np.linalg.eigvals(a)
    osc = eig[np.abs(eig.imag) > 1.0]
    f_hz = np.abs(osc[0]) / (2 * math.pi)
    assert 25.0 < f_hz < 32.0
    assert f_hz == pytest.approx(drivetrain.resonance_hz(params), rel=0.05)


def test_belt_resonance_in_time_domain():
    # Hold the motor still (huge inertia) and ring the platter: the twist oscillates at
    # sqrt(k / J_p) (the motor side does not move); measure the period from zero crossings.
    params = PlantParams(
        motor=dataclasses.replace(MotorParams(), j_kgm2=1e3),
        platter=dataclasses.replace(PlantParams().platter, coulomb_nm=0.0, viscous_nm_s_rad=0.0),
        gearbox=dataclasses.replace(GearboxParams(), backlash_deg=0.0),
    )
    params = dataclasses.replace(
        params, belt=dataclasses.replace(params.belt, damping_nm_s_rad=0.0)
    )
    plant = ScalarPlant(params, DT_S / 20)
    x = [0.0, 0.0, 0.0, 1e-3, 0.0]
    tw = []
    for _ in range(4000):
        x = plant.update(0.0, x, (0.0, False))
        tw.append(x[0, 3])
    tw = np.array(tw)
    crossings = np.nonzero(np.diff(np.sign(tw)) != 0)[0]
    period_s = 2 * np.mean(np.diff(crossings)) * DT_S / 20
    expected = 2 * math.pi * math.sqrt(params.platter.j_kgm2 / params.belt.stiffness_nm_rad)
    assert period_s == pytest.approx(expected, rel=0.01)


def test_bridge_current_limitation_pins_current():
    params = PlantParams(bridge=BridgeParams(current_limit_a=10.0))
    plant = ScalarPlant(params, DT_S)
    xs = _run(plant, [0.0] * 5, [1.0] * 50)
    assert np.max(xs[:, 0]) <= 10.0 + 1e-9
    assert np.max(xs[:, 0]) > 9.99
    assert plant.key(list(xs[0]), 1.0, True) // MECH_MODES == B_LIMIT_POS
    # The oracle agrees.
    ref = _oracle(params, [0.0] * 5, [1.0] * 50)
    np.testing.assert_allclose(xs[:, 2], ref[:, 2], rtol=1e-6)


def test_disabled_bridge_current_decays_to_zero_and_stays():
    params = PlantParams()
    plant = ScalarPlant(params, DT_S)
    x = _run(plant, [0.0] * 5, [0.8] * 200)[-1].tolist()
    assert x[0] > 0.1
    assert plant.key(x, 0.0, False) // MECH_MODES == B_DIODE_POS
    xs = _run(plant, x, [0.0] * 50, enable=False)
    assert np.all(xs[:, 0] >= 0.0)
    assert xs[-1][0] == 0.0
    assert plant.key(list(xs[-1]), 0.0, False) // MECH_MODES == B_OPEN
    assert xs[-1][2] < x[2]  # coasting down


def test_batch_members_with_their_own_parameters_step_as_one_axis_each():
    base = PlantParams()
    r = np.array([1.0, 1.2, 1.5, 2.0])
    params = dataclasses.replace(base, motor=dataclasses.replace(base.motor, r_ohm=r))
    batch = Plant(params, 4, DT_S)
    x = np.zeros((4, 5))
    duty = np.array([0.5, 0.5, -0.3, 0.9])
    for k in range(300):
        sign = 1.0 if (k // 100) % 2 == 0 else -1.0  # reversals: bands, gap, power flow
        x = batch.update(k * DT_S, x, (sign * duty, True))
    assert batch.n_events > 4
    for j in range(4):
        signs = [1.0 if (k // 100) % 2 == 0 else -1.0 for k in range(300)]
        xs = _run(ScalarPlant(params.member(j), DT_S), [0.0] * 5, [s * duty[j] for s in signs])
        np.testing.assert_array_equal(x[j], xs[-1])


def test_power_flow_direction_changes_reflected_torque():
    params = PlantParams()
    tb = np.array([1.0, 1.0])
    w = np.array([10.0, -10.0])
    g = drivetrain.load_factor(tb, w, params)
    assert g[0] == pytest.approx(1 / (400 * 0.8))
    assert g[1] == pytest.approx(0.8 / 400)


def test_derivative_is_batched_and_pure():
    params = PlantParams()
    x = np.array([[1.0, 2.0, 30.0, 1e-3, 0.05], [-1.0, 0.0, -3.0, -2e-3, 0.0]])
    x_copy = x.copy()
    d = derivative(0.0, x, (np.array([0.2, -0.1]), np.array([True, True])), params)
    assert d.shape == (2, 5)
    np.testing.assert_array_equal(x, x_copy)
    for j, dj in enumerate([0.2, -0.1]):
        np.testing.assert_allclose(d[j], derivative(0.0, x[j], (dj, True), params))


def test_diode_mode_key_when_current_positive():
    plant = ScalarPlant(PlantParams(), DT_S)
    assert plant.key([1.0, 0.0, 0.0, 0.0, 0.0], 0.0, False) // MECH_MODES == B_DIODE_POS


def test_hidden_excursion_into_a_band_is_detected():
    from sim.plant_kernel import hermite_leaves as _hermite_leaves

    # Ends at -0.3 (outside the +-0.1 band), slopes towards it and back: the cubic peaks at
    # -0.3 + (m0 - m1) / 8 at mid-step.
    assert _hermite_leaves(-0.3, -0.3, 1.2, -1.2, 0.1)  # peaks at 0.0: inside the band
    assert not _hermite_leaves(-0.3, -0.3, 0.4, -0.4, 0.1)  # peaks at -0.2: stays out
    assert not _hermite_leaves(-30.0, -29.0, 1.0, 1.0, 0.1)  # far away: gate
    assert _hermite_leaves(0.5, 0.5, -4.0, 4.0, 0.1)  # dips through the band to the other side


def test_gearbox_drag_lowers_the_steady_speed_by_drag_over_slope():
    base = PlantParams()
    drag = dataclasses.replace(
        base, gearbox=dataclasses.replace(base.gearbox, drag_nm=0.002, drag_viscous_nm_s_rad=1e-6)
    )
    xs = _run(ScalarPlant(drag, DT_S), [0.0] * 5, [0.5] * 1500)
    w = steady_speed_rad_s(drag, 0.5)
    assert xs[-1][2] == pytest.approx(w, rel=1e-6)
    # Analytic: the motor torque balance at w, drag included.
    m, n, eta = base.motor, base.total_ratio, base.gearbox.efficiency
    r = m.r_ohm + base.bridge.r_on_path_ohm
    i = (0.5 * 24.0 - m.ke_v_s_rad * w) / r
    load = base.platter.coulomb_nm + base.platter.viscous_nm_s_rad * w / n
    balance = m.kt_nm_a * i - (m.coulomb_nm + 0.002) - (m.viscous_nm_s_rad + 1e-6) * w
    assert balance == pytest.approx(load / (n * eta), rel=1e-9)
    assert w < steady_speed_rad_s(base, 0.5)
    # Drag off is the model without it, bit for bit.
    off = dataclasses.replace(base, gearbox=dataclasses.replace(base.gearbox, drag_nm=0.0))
    np.testing.assert_array_equal(
        _run(ScalarPlant(off, DT_S), [0.0] * 5, [0.5] * 50),
        _run(ScalarPlant(base, DT_S), [0.0] * 5, [0.5] * 50),
    )


def test_gearbox_efficiency_is_load_dependent_with_drag():
    # Measured in the simulated steady state: the power the belt delivers over the power
    # the motor puts into the gearbox. With the drag it is low at light load and tends to
    # eta at heavy load: eta_eff = (T/N) / (T/(N eta) + drag + drag_visc w).
    base = PlantParams()
    gb = dataclasses.replace(base.gearbox, drag_nm=0.002, drag_viscous_nm_s_rad=1e-6)
    m, n, eta = base.motor, base.total_ratio, gb.efficiency
    measured = []
    for load_nm in (0.3, 1.5, 4.0):
        pl = dataclasses.replace(base.platter, coulomb_nm=load_nm)
        params = dataclasses.replace(base, gearbox=gb, platter=pl)
        x = _run(ScalarPlant(params, DT_S), [0.0] * 5, [0.6] * 1500)[-1]
        i, w, tw, wp = x[0], x[2], x[3], x[4]
        tb = float(drivetrain.belt_torque_nm(tw, w / n - wp, params))
        into_gearbox = (m.kt_nm_a * i - m.coulomb_nm - m.viscous_nm_s_rad * w) * w
        eff = tb * wp / into_gearbox
        t_out = load_nm + base.platter.viscous_nm_s_rad * wp
        expected = (t_out / n) / (t_out / (n * eta) + gb.drag_nm + gb.drag_viscous_nm_s_rad * w)
        assert eff == pytest.approx(expected, rel=1e-6)
        measured.append(eff)
    assert measured[0] < measured[1] < measured[2] < eta


def _with_stiction(params: PlantParams, motor_ts: float, motor_ws: float, plat_ts=0.0, plat_ws=0.0):
    return dataclasses.replace(
        params,
        motor=dataclasses.replace(params.motor, stiction_nm=motor_ts, stribeck_rad_s=motor_ws),
        platter=dataclasses.replace(params.platter, stiction_nm=plat_ts, stribeck_rad_s=plat_ws),
    )


def test_stiction_holds_below_breakaway_and_slips_above():
    # Motor at rest, belt slack (in the backlash gap): a stall torque K_t V d / R below the
    # breakaway torque T_s only creeps inside the band, at the analytic speed
    # w = (K_t V d / R) / (T_s / w_b + b + K_t K_e / R); above T_s the motor breaks away.
    base = PlantParams()
    m = base.motor
    params = _with_stiction(base, motor_ts=0.008, motor_ws=2.0)
    r = m.r_ohm + base.bridge.r_on_path_ohm
    ts = params.motor_breakaway_nm
    for frac in (0.9, 1.1):
        duty = frac * ts * r / (m.kt_nm_a * 24.0)
        xs = _run(ScalarPlant(params, DT_S), [0.0] * 5, [duty] * 100)
        if frac < 1:
            creep = (m.kt_nm_a * 24.0 * duty / r) / (
                ts / m.coulomb_band_rad_s + m.viscous_nm_s_rad + m.kt_nm_a * m.ke_v_s_rad / r
            )
            assert xs[-1][2] == pytest.approx(creep, rel=1e-6)
            assert xs[-1][2] < m.coulomb_band_rad_s
        else:
            assert xs[-1][2] > 50 * m.coulomb_band_rad_s
    # Without stiction the same 0.9 T_s (above Coulomb) turns the motor.
    duty = 0.9 * ts * r / (m.kt_nm_a * 24.0)
    xs = _run(ScalarPlant(base, DT_S), [0.0] * 5, [duty] * 100)
    assert xs[-1][2] > 50 * m.coulomb_band_rad_s


def test_stiction_and_stribeck_drop_match_solve_ivp():
    # Break away, run, reverse and stop through the Stribeck regions of motor and platter
    # (negative friction slopes: stick-slip), against the oracle.
    params = _with_stiction(PlantParams(), 0.008, 2.0, plat_ts=0.45, plat_ws=0.01)
    duties = [0.02] * 60 + [0.3] * 60 + [-0.25] * 100 + [0.0] * 80
    xs = _run(ScalarPlant(params, DT_S), [0.0] * 5, duties)
    ref = _oracle(params, [0.0] * 5, duties)
    assert np.max(np.abs(xs[:, 1] - ref[:, 1])) / (2 * math.pi) < 1e-7
    np.testing.assert_allclose(xs[:, 4], ref[:, 4], atol=1e-7)


def test_friction_law_pieces_are_the_physics_function():
    # affine's piecewise-linear friction equals sim.motor.friction_torque_nm in every region.
    params = _with_stiction(PlantParams(), 0.008, 2.0, plat_ts=0.45, plat_ws=0.01)
    co = Coefficients.from_params(params)
    from sim.motor import friction_torque_nm
    from sim.plant import _friction_piece
    from sim.plant_kernel import _friction_region

    for w in (-5.0, -1.0, -0.05, 0.0, 0.03, 0.5, 1.99, 3.0):
        region = _friction_region(w, co.wbm, co.wsm)
        slope, offset = _friction_piece(region, co.tcm, co.wbm, co.tsm, co.wsm)
        expected = friction_torque_nm(w, co.tcm, co.wbm, 0.0, co.tsm, co.wsm)
        assert slope * w + offset == pytest.approx(float(expected), abs=1e-15)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_a_batch_s_coefficients_are_each_member_s_bit_for_bit(seed, stiction):
    # Plant takes a Monte-Carlo batch's parameter sets from the batch's coefficient arrays
    # (Coefficients.members) instead of from each member's parameters: the same floats.
    rng = np.random.default_rng(seed)
    n = 7

    def spread(v: float) -> np.ndarray:
        return v * rng.uniform(0.7, 1.3, n)

    base = PlantParams()
    coulomb, band = spread(0.004), spread(0.1)
    motor = dataclasses.replace(
        base.motor, r_ohm=spread(1.2), l_h=spread(0.6e-3), kt_nm_a=spread(0.0145),
        ke_v_s_rad=spread(0.0145), j_kgm2=spread(1.2e-5), viscous_nm_s_rad=spread(2e-6),
        coulomb_nm=coulomb, coulomb_band_rad_s=band,
        # stiction on for some members (at least Coulomb, its Stribeck speed above the band)
        stiction_nm=np.where(rng.random(n) < 0.5, coulomb * rng.uniform(1.2, 2.0, n), 0.0)
        if stiction else 0.0,
        stribeck_rad_s=band * rng.uniform(3.0, 8.0, n) if stiction else 0.0,
    )  # fmt: skip
    params = dataclasses.replace(
        base, motor=motor,
        supply=dataclasses.replace(base.supply, voltage_v=24.0 * rng.uniform(0.8, 1.15, n)),
        belt=dataclasses.replace(base.belt, stiffness_nm_rad=spread(base.belt.stiffness_nm_rad),
                                 damping_nm_s_rad=spread(base.belt.damping_nm_s_rad)),
        gearbox=dataclasses.replace(base.gearbox, backlash_deg=spread(base.gearbox.backlash_deg),
                                    efficiency=rng.uniform(0.6, 0.9, n)),
        platter=dataclasses.replace(base.platter, j_kgm2=spread(base.platter.j_kgm2)),
        bridge=dataclasses.replace(
            base.bridge, current_limit_a=spread(base.bridge.current_limit_a)
        ),
    )  # fmt: skip
    batch = Coefficients.from_params(params).members(n)
    alone = [Coefficients.from_params(params.member(k)) for k in range(n)]
    for a, b in zip(batch, alone, strict=True):
        for f in dataclasses.fields(a):
            x, y = getattr(a, f.name), getattr(b, f.name)
            assert type(x) is type(y) and (x == y), (f.name, x, y)
        assert a == b and hash(a) == hash(b)  # the key of the shared mode tables
    # and the step's coefficients (Plant packs the batch's arrays at once): each member's
    consts = Plant(params, n, 2e-3)._consts
    for k, co in enumerate(alone):
        one = plant_kernel.pack_consts(co, 2e-3)
        assert one.shape == (plant_kernel.N_CONSTS,)
        assert np.array_equal(consts[k].view(np.int64), one.view(np.int64)), k
    # A batch whose arrays no coefficient takes (a brake resistor per member): n the same.
    brakes = dataclasses.replace(
        base, supply=dataclasses.replace(base.supply, brake_resistor_ohm=spread(4.0))
    )
    assert Coefficients.from_params(brakes).members(n) == [Coefficients.from_params(base)] * n
