"""The supply and bus model (issue 13 §2.1, ``sim.supply``): the rail's exact solution
against its closed forms, the supply that cannot sink, the brake chopper, the BTN7971B's
lock-out in the closed loop, the bus step against ``solve_ivp`` (``sim.oracle``), off is
the stiff supply, one implementation for every N."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from recording import recording

from serial_protocol.exceptions import ConfigError
from serial_protocol.messages import Fault
from sim import loop
from sim.config import load_bench
from sim.oracle import replay
from sim.params import SupplyParams
from sim.reproduce import experiments
from sim.supply import SUB_QUIET, rail_advance

C_F = 2200e-6
VS, RS = 24.0, 0.05
BUS = {"supply.bus_model": True}


def _rail(v, i_out, h, rb=0.0, vb=26.5, c=C_F):
    return rail_advance(v, i_out, h, VS, RS, c, rb, vb, 0.0)


def test_returned_charge_lifts_the_blocked_rail_linearly():
    # Above the supply the diode blocks: the returned current only charges C.
    h = 1e-3
    v1 = _rail(VS, -2.5, h)
    assert v1 == pytest.approx(VS + 2.5 * h / C_F, rel=1e-14)
    # The energy balance: 1/2 C (v1^2 - v0^2) is the current times the mean voltage.
    assert 0.5 * C_F * (v1**2 - VS**2) == pytest.approx(2.5 * 0.5 * (VS + v1) * h, rel=1e-12)
    # Nothing drawn: a lifted rail stays lifted (the supply cannot sink it).
    assert _rail(27.0, 0.0, 1.0) == 27.0


def test_issue_13_figures_0_23_j_lift_2200_uf_to_28_v():
    # 0.23 J returned at the braking's 64 W lifts 2,200 uF from 24 V to the 28 V lock-out:
    # integrated through the rail at constant power, it takes E / P = 3.6 ms.
    e_j = 0.5 * C_F * (28.0**2 - 24.0**2)
    assert e_j == pytest.approx(0.2288, abs=1e-4)
    v, t, h = VS, 0.0, 1e-6
    while v < 28.0:
        v = _rail(v, -64.0 / v, h)
        t += h
    assert t == pytest.approx(e_j / 64.0, rel=1e-3)


def test_supply_droops_through_its_source_resistance():
    tau = RS * C_F
    assert _rail(VS, 5.0, 10.0) == pytest.approx(VS - RS * 5.0, abs=1e-12)
    v_eq = VS - RS * 5.0
    assert _rail(VS, 5.0, tau) == pytest.approx(v_eq + (VS - v_eq) * math.exp(-1.0), rel=1e-14)
    # A lifted rail drawn on falls linearly to the supply, then the supply takes over.
    t_fall = C_F * (26.0 - VS) / 2.0
    expect = (VS - RS * 2.0) + RS * 2.0 * math.exp(-(1e-3) / tau)
    assert _rail(26.0, 2.0, t_fall + 1e-3) == pytest.approx(expect, rel=1e-12)


def test_brake_chopper_holds_its_threshold_or_is_overrun():
    rb, vb = 10.0, 26.5
    # 2 A returned < vb / rb = 2.65 A: the chopper holds the rail at vb.
    assert _rail(VS, -2.0, 0.1, rb, vb) == vb
    # 4 A returned: the resistor is on for good, the rail tends to 4 A * rb = 40 V.
    t_reach = C_F * (vb - VS) / 4.0
    tau = rb * C_F
    expect = 40.0 + (vb - 40.0) * math.exp(-(5e-3) / tau)
    assert _rail(VS, -4.0, t_reach + 5e-3, rb, vb) == pytest.approx(expect, rel=1e-12)
    # Above the threshold with nothing returned, the resistor brings it down to vb.
    assert _rail(30.0, 0.0, 1.0, rb, vb) == pytest.approx(vb, abs=1e-12)


def _fig6(duration_s: float = 4.0, **overrides):
    exp = experiments.with_duration(experiments.load("fig6"), duration_s)
    return loop.run(exp, seed=0, overrides=overrides or None).log


def test_fig6_braking_locks_the_bridge_out_and_a_brake_resistor_prevents_it():
    stiff = _fig6()
    bus = _fig6(**BUS)
    braked = _fig6(**BUS, **{"supply.brake_resistor_ohm": 10.0})
    assert np.all(stiff.bus_v == 24.0)  # off: the stiff supply
    # Braking starts near 3.1 s; the bus reaches the 28 V lock-out within 10 ms of it.
    t, v = bus.t_s, bus.bus_v
    first = t[np.argmax(v >= 28.0)]
    start = t[np.argmax(bus.current_a < -0.1)]
    assert 0.0 < first - start < 0.010
    assert v.max() < 28.5  # located to a 125 us sub-step, plus the diodes' return
    # While locked out the bridge applies nothing although the firmware drives a duty.
    out = (t > first) & (t < first + 0.01)
    assert np.all(bus.voltage_v[out] == 0.0) and np.any(bus.duty[out] != 0.0)
    assert bus.true_pos_deg.max() - 3000.0 > 5 * (stiff.true_pos_deg.max() - 3000.0)
    # A 10 ohm chopper at 26.5 V holds the bus there and the step settles as stiff.
    assert braked.bus_v.max() <= 26.5 + 1e-9
    assert braked.bus_v.max() > 26.4
    assert abs(braked.true_pos_deg[-1] - 3000.0) < 0.1
    # Never locked out: the bridge applies every duty the firmware drives (a duty of exactly
    # 0 on the timer's grid, once as the braking duty crosses zero, applies 0 V).
    late = braked.t_s > 0.01
    assert np.all((braked.voltage_v[late] != 0.0) | (braked.duty[late] == 0.0))


def test_a_stiff_bus_is_the_stiff_supply():
    # C -> infinity, R_s -> 0: the bus model tends to the stiff supply of bus_model = false.
    stiff = _fig6()
    big = _fig6(
        **BUS,
        **{
            "supply.bulk_capacitance_uf": 1e6,
            "supply.source_resistance_ohm": 1e-4,
            "supply.logic_load_a": 0.0,
        },
    )
    assert big.bus_v.max() < 24.25  # 5.2 J into 1 F
    assert abs(big.true_pos_deg.max() - stiff.true_pos_deg.max()) < 1.0
    np.testing.assert_allclose(big.true_pos_deg, stiff.true_pos_deg, atol=1.5)


def _replayed(overrides: dict, t_end_s: float, k0: int):
    """``(simulation, log, replay)``: Fig. 6 with ``overrides`` up to ``t_end_s``, and
    ``solve_ivp`` on the continuous model (``sim.oracle.replay``) from the simulation's state
    at tick ``k0`` with its recorded duties: ``replay[i]`` is the state after tick k0 + i."""
    exp = experiments.with_duration(experiments.load("fig6"), t_end_s)
    sim, result = recording(loop.run, exp, seed=0, overrides=overrides)
    log = result.log
    duty, enable = sim.inputs()
    k1 = len(log)
    x0 = np.append(sim.states()[k0, 0], log.bus_v[k0])
    ref = replay(sim.bench.plant, duty[k0 : k1 - 1], enable[k0 : k1 - 1], sim.h_s, x0=x0)
    return sim, log, ref


def test_bus_step_matches_solve_ivp_through_hard_braking():
    # Fig. 6's braking from 3.0 s up to the lock-out (3.106 s): the bus rises 24 -> 28 V in
    # 8 ms. Replayed from the simulation's state with its recorded duties through
    # solve_ivp on the continuous model (the rail and the duty's product exact).
    _, log, ref = _replayed(BUS, 3.106, 1500)
    k0, k1 = 1500, len(log)
    assert log.bus_v[k1 - 1] > 26.0  # the window does reach the hard braking
    assert np.abs(ref[:, 5] - log.bus_v[k0 + 1 : k1]).max() < 3e-3  # V (measured 1.3e-3)
    assert np.abs(ref[:, 0] - log.current_a[k0 + 1 : k1]).max() < 4e-3  # A (1.7e-3)
    rev = np.abs(ref[:, 1] - log.motor_pos_rad[k0 + 1 : k1]).max() / (2 * math.pi)
    assert rev < 5e-6  # (1.9e-6; one encoder count is 6.1e-5 rev)


def test_batch_members_are_the_one_axis_runs():
    # Noise off: a batch draws its encoder noise for all members at once (another stream).
    exp = experiments.with_duration(experiments.load("fig6"), 3.3)
    caps = np.array([2200.0, 10000.0])
    quiet = {**BUS, "encoder.noise_rms_lsb": 0.0}
    both = loop.run(exp, seed=0, batch=2, overrides={**quiet, "supply.bulk_capacitance_uf": caps})
    for j, cap in enumerate(caps):
        one = loop.run(exp, seed=0, overrides={**quiet, "supply.bulk_capacitance_uf": cap}).log
        member = both.log.member(j)
        for name in ("bus_v", "current_a", "true_pos_deg", "voltage_v", "duty"):
            np.testing.assert_array_equal(getattr(member, name), getattr(one, name), name)


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("bus_substeps", 3, "power of two"),
        ("bus_quiet_v", -0.001, ">= 0"),
        ("tvs_breakdown_v", 20.0, "above the supply"),
        ("tvs_resistance_ohm", 0.0, "> 0"),
        ("bulk_capacitance_uf", 0.0, "> 0"),
        ("bus_model", 1, "true or false"),
        ("brake_on_v", 23.0, "above the supply"),
    ],
)
def test_bad_supply_values_are_refused_in_one_line(key, value, words):
    kwargs = {key: value}
    if key == "brake_on_v":
        kwargs["brake_resistor_ohm"] = 10.0
    with pytest.raises(ValueError, match=words) as info:
        SupplyParams(**kwargs)
    assert "\n" not in str(info.value) and key in str(info.value)


def test_firmware_duty_from_the_measured_bus_undoes_a_lifted_bus():
    # The 10 ohm chopper holds the bus at 26.5 V while braking; a firmware that computes
    # its duty for 24 V brakes with less current than it means (its regenerative clamp
    # is in volts), one that divides by the measured bus brakes as on the stiff supply.
    stiff = _fig6().true_pos_deg.max()
    chopper = {**BUS, "supply.brake_resistor_ohm": 10.0}
    plain = _fig6(**chopper).true_pos_deg.max()
    comp = _fig6(**chopper, **{"controller.current.bus_compensation": True}).true_pos_deg.max()
    assert plain - stiff > 10.0  # measured 58.2 against 42.3 deg of overshoot
    assert abs(comp - stiff) < 2.0  # measured 42.9


def test_regenerative_limit_keeps_the_bus_down_and_brakes_on_friction():
    limited = _fig6(**BUS, **{"controller.current.regen_bus_current_limit_a": 0.05})
    # The bus never reaches the lock-out; with only the 40 mA logic load to take the
    # energy, it hardly rises, and the braking is the friction's: a far longer overshoot.
    assert limited.bus_v.max() < 24.1
    assert np.all((limited.voltage_v != 0.0) | (limited.duty == 0.0))  # never locked out
    assert limited.true_pos_deg.max() - 3000.0 > 300.0


def test_lock_out_with_compensation_does_not_wind_the_current_loop_up():
    # Locked out, the IS pin reads nothing; with the duty from the measured bus the duty's
    # sign flips during the lock-out, the missing current becomes "visible" and (before
    # the hold at bus_hold_v) the integrator wound up: 12 A and an over-current trip.
    log = _fig6(**BUS, **{"controller.current.bus_compensation": True})
    assert np.all(log.fault == 0)
    assert np.abs(log.current_a).max() < 6.0  # measured 5.65 A


BUS_CHECK = {**BUS, "safety.bus_voltage_check": True}


def test_fig6_with_the_bus_the_firmware_trips_at_the_lock_out_or_before():
    # At 500 Hz the rail climbs from 26.5 V to 28.1 V within one current-loop period: the
    # default 27 V threshold is crossed in the same period as the chip's 28 V lock-out, and
    # the firmware trips on the reading at its end (measured: both at t = 3.106 s).
    log = _fig6(3.5, **BUS_CHECK)
    t, v = log.t_s, log.bus_v
    trip = int(np.argmax(log.fault != 0))
    assert log.fault[trip] == Fault.BUS_OVER_VOLTAGE
    assert v[trip - 1] <= 27.0 < v[trip]  # the first reading above the threshold trips
    assert t[trip] == t[np.argmax(v >= 28.0)]
    # The fault reaction brakes on the low sides: nothing more returns to the bus (it
    # decays from its peak), and the axis stops within 20 deg of the target.
    assert v.max() < 28.2 and v[-1] < v.max()
    assert abs(log.true_pos_deg.max() - 3000.0) < 25.0  # measured 18.9 (596 without the trip)
    # One period earlier: a 26 V threshold trips before the lock-out; the bus stays below 27 V.
    early = _fig6(3.5, **BUS_CHECK, **{"safety.bus_over_voltage_v": 26.0})
    assert early.fault.max() == Fault.BUS_OVER_VOLTAGE and early.bus_v.max() < 27.0


def test_bad_thresholds_are_one_line(tmp_path):
    bench = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"
    text = bench.read_text().replace("bus_under_voltage_v = 18.0", "bus_under_voltage_v = 28.0")
    f = tmp_path / "b.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_bench(f)
    msg = str(info.value)
    assert "\n" not in msg and "bus_under_voltage_v = 28.0" in msg and "[safety]" in msg


# ------------------------------------------------------------------ the adaptive step


def test_rail_profile_is_the_rails_exact_solution_for_a_ramped_current():
    # A current ramped linearly (r'' = 0: rail_profile's series is then exact) against
    # solve_ivp, the supply conducting and blocked; its mean, by quadrature.
    from scipy.integrate import solve_ivp

    from sim.supply import rail_profile

    h = 0.002
    for v0, r0, r1 in ((23.86, 2.9, 3.1), (23.9, 0.5, 2.5), (24.3, -1.0, -0.4), (24.5, 0.2, 0.6)):
        rate = (r1 - r0) / h
        got_v1, got_mean = rail_profile(v0, r0, r1, 0.5 * (r0 + r1), rate, rate, h, VS, RS, C_F)

        def f(t, v, r0=r0, rate=rate):
            supply = (VS - v[0]) / RS if v[0] < VS else 0.0
            return [(supply - (r0 + rate * t)) / C_F]

        sol = solve_ivp(f, (0.0, h), [v0], rtol=1e-12, atol=1e-14, dense_output=True)
        ts = np.linspace(0.0, h, 40001)
        mean = np.trapezoid(sol.sol(ts)[0], ts) / h
        assert got_v1 == pytest.approx(sol.y[0, -1], abs=1e-9)
        assert got_mean == pytest.approx(mean, abs=1e-9)


def _replay_errors(quiet_v: float, t_end_s: float, k0: int):
    """``(bus V, current A, motor angle rev, periods taken whole)``: the largest differences
    of Fig. 6 with the bus model from ``solve_ivp`` on its recorded inputs from tick ``k0``."""
    sim, log, ref = _replayed({**BUS, "supply.bus_quiet_v": quiet_v}, t_end_s, k0)
    k1 = len(log)
    return (
        np.abs(ref[:, 5] - log.bus_v[k0 + 1 : k1]).max(),
        np.abs(ref[:, 0] - log.current_a[k0 + 1 : k1]).max(),
        np.abs(ref[:, 1] - log.motor_pos_rad[k0 + 1 : k1]).max() / (2 * math.pi),
        int(sim.bus.sub[SUB_QUIET]),
    )


def test_the_adaptive_step_keeps_the_sub_steps_accuracy_where_the_rail_is_quiet():
    # Fig. 6's first 0.5 s (the current at its 5 A limit, the duty rising with the speed:
    # the rail sags 1-2 mV a period): against solve_ivp on the recorded inputs, the
    # adaptive step (whole periods where the rail swings less than bus_quiet_v = 1 mV) and
    # the 16 sub-steps everywhere (bus_quiet_v = 0).
    bus, cur, rev, whole = _replay_errors(1e-3, 0.5, 0)
    bus0, cur0, rev0, whole0 = _replay_errors(0.0, 0.5, 0)
    assert whole0 == 0 and whole > 60  # measured 77 of the 250 periods taken whole
    assert bus < 1e-4 and bus0 < 1e-4  # measured 3.1e-5 and 3.1e-5 V
    assert cur < 5e-4 and cur0 < 1e-4  # 1.1e-4 and 5.1e-5 A
    assert rev < 1e-4 and rev0 < 1e-4  # 4.2e-5 and 3.9e-5 rev


def test_off_the_adaptive_step_is_the_sub_steps_everywhere():
    # bus_quiet_v = 0: every period in sub-steps (the tree before, bit for bit: compared on
    # Fig. 6, 4 s, every column); on, most of Fig. 6's first 3 s are taken whole.
    exp = experiments.with_duration(experiments.load("fig6"), 3.0)
    holder = {}

    class Keep(loop.Simulation):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            holder["sim"] = self

    saved = loop.Simulation
    loop.Simulation = Keep
    try:
        off = loop.run(exp, seed=0, overrides={**BUS, "supply.bus_quiet_v": 0.0}).log
        assert holder["sim"].bus.sub[SUB_QUIET] == 0
        on = loop.run(exp, seed=0, overrides=BUS).log
        assert holder["sim"].bus.sub[SUB_QUIET] > 1000  # of 1,500 periods (measured 1,320)
    finally:
        loop.Simulation = saved
    assert np.abs(on.true_pos_deg - off.true_pos_deg).max() < 5e-3  # deg (measured 3.5e-4)
    assert np.abs(on.bus_v - off.bus_v).max() < 2e-3  # V (4.8e-4)


# ------------------------------------------------------------------ a TVS across the rail


def test_a_tvs_clamps_the_blocked_rail_through_its_dynamic_resistance():
    # 3 A returned into 2,200 uF from 24.5 V: linear up to the breakdown (26.7 V), then
    # first order towards V_br + R_d * 3 A = 28.8 V with tau = R_d C = 1.54 ms.
    vt, rd, i_ret = 26.7, 0.7, 3.0
    t_reach = C_F * (vt - 24.5) / i_ret
    for h in (0.5 * t_reach, t_reach + 1e-3, t_reach + 5e-3):
        got = rail_advance(24.5, -i_ret, h, VS, RS, C_F, rd, vt, vt)
        if h <= t_reach:
            want = 24.5 + i_ret * h / C_F
        else:
            veq = vt + rd * i_ret
            want = veq + (vt - veq) * math.exp(-(h - t_reach) / (rd * C_F))
        assert got == pytest.approx(want, abs=1e-9)
    # Drawn from again, the rail leaves the clamp and falls as the capacitor alone.
    assert rail_advance(28.0, 1.0, 1e-3, VS, RS, C_F, rd, vt, vt) < 28.0


def test_fig6_with_a_tvs_never_locks_out_and_matches_solve_ivp():
    # An SMBJ24A-like TVS (V_BR 26.7 V min, ~0.7 ohm from its clamping voltage): the bus
    # stops below the 28 V lock-out on Fig. 6's braking (measured 27.85 V), the step
    # settles (67.2 deg of overshoot, 595.9 without the TVS). Against solve_ivp through the
    # braking, as the bus test above.
    tvs = {**BUS, "supply.tvs_breakdown_v": 26.7}
    log = _fig6(4.0, **tvs)
    assert 27.5 < log.bus_v.max() < 28.0
    assert np.all((log.voltage_v != 0.0) | (log.duty == 0.0))  # never locked out
    assert log.true_pos_deg.max() - 3000.0 < 100.0
    _, log, ref = _replayed(tvs, 3.2, 1500)
    k0, k1 = 1500, len(log)
    assert log.bus_v[k1 - 1] > 27.0  # the window reaches the clamp
    assert np.abs(ref[:, 5] - log.bus_v[k0 + 1 : k1]).max() < 3e-3  # V (measured 1.3e-3)
    assert np.abs(ref[:, 0] - log.current_a[k0 + 1 : k1]).max() < 4e-3  # A (1.7e-3)
    # The 16 sub-steps' second-order error through the knee (the bus climbing 4 V in 4 ms):
    # measured 7.4e-5 rev by 3.2 s, 4.7e-6 with 64 sub-steps; the same with the adaptive
    # step off (it takes none of the braking).
    rev = np.abs(ref[:, 1] - log.motor_pos_rad[k0 + 1 : k1]).max() / (2 * math.pi)
    assert rev < 1.5e-4
