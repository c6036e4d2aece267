"""Issue 13 §3: the Fig. 6 band and the per-figure effects study (``sim.reproduce.band``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim.loop import apply_overrides, run
from sim.reproduce import band
from sim.reproduce.experiments import load, with_duration
from sim.tuning import linear
from sim.tuning.gains import GainSet


@pytest.fixture(scope="module")
def fig6_short():
    """Fig. 6's step, 4 s (the braking is at ~3.1 s), without encoder noise so that a
    member of a batch and a one-axis run draw the same (no) noise."""
    exp = with_duration(load("fig6"), 4.0)
    return dataclasses.replace(
        exp, bench=apply_overrides(exp.bench, {"encoder.noise_rms_lsb": 0.0})
    )


def test_designs():
    full = band.factorial_design()
    assert len(full) == 27 == len(set(full)) and full[0].nominal
    assert {m.r for m in full} == {m.kt for m in full} == {m.j for m in full} == {0.7, 1.0, 1.3}
    comp = band.composite_design()
    assert len(comp) == 15 == len(set(comp)) and comp[0].nominal
    assert set(comp) < set(full)
    assert set(band.one_at_a_time()) < set(comp)
    # the corners are in both designs (the envelope of a monotone response is there)
    corners = {band.Motor(r, k, j) for r in (0.7, 1.3) for k in (0.7, 1.3) for j in (0.7, 1.3)}
    assert corners < set(comp)


def test_motor_overrides_scale_the_bench_motor_and_keep_kt_equal_ke(fig6_short):
    m = fig6_short.bench.plant.motor
    ov = band.Motor(r=0.7, kt=1.3, j=0.7).overrides(fig6_short.bench)
    assert ov["motor.r_ohm"] == pytest.approx(0.7 * m.r_ohm)
    assert ov["motor.kt_nm_a"] == ov["motor.ke_v_s_rad"] == pytest.approx(1.3 * m.kt_nm_a)
    assert ov["motor.j_kgm2"] == pytest.approx(0.7 * m.j_kgm2)


def test_the_batch_members_equal_one_axis_runs(fig6_short):
    """batch = N x one: every member of a study (its motor, its re-tuned firmware, its
    effect; the bus-model member in its own batch) computes what a one-axis run with the
    same parameters computes."""
    bench = fig6_short.bench
    members = [
        band.Member(band.Motor(kt=0.7), "fixed"),
        band.Member(band.Motor(r=1.3, j=0.7), "classic"),
        band.Member(band.Motor(kt=1.3), "model"),
        band.Member(effect="stiction (motor 5 mN·m, platter 0.45 N·m)"),
        band.Member(effect="bus model + chopper 10 Ω at 26.5 V"),
    ]
    tuned = {(m.motor, m.gains): band.retune(bench, m.motor, m.gains) for m in members}
    logs = band.run_members(fig6_short, members, tuned)
    assert len(logs) == len(members)
    overshoots = []
    for member, log in zip(members, logs, strict=True):
        ov = band.member_overrides(bench, member, tuned)
        single = run(fig6_short, overrides={**ov, "telemetry.decimation": 0}).log
        for col in ("pos_deg", "vel_dps", "current_ref_a", "duty", "fault"):
            np.testing.assert_array_equal(getattr(log, col), getattr(single, col), err_msg=col)
        for col in ("true_pos_deg", "current_a", "bus_v"):
            np.testing.assert_allclose(getattr(log, col), getattr(single, col), atol=1e-9)
        overshoots.append(float(np.max(log.pos_deg)) - 3000.0)
    # the members really differ (the arrays reached them)
    assert len({round(o, 3) for o in overshoots}) == len(members)


def test_retuned_firmware_is_its_motors_and_passes_the_linear_gate():
    bench = load("fig6").bench
    nominal = band.retune(bench, band.Motor(), "model")
    fw = bench.firmware
    # the nominal motor's model is the firmware's default one (to the config's rounding)
    assert nominal["controller.current.resistance_ohm"] == fw.current.resistance_ohm
    assert nominal["controller.current.back_emf_v_per_dps"] == pytest.approx(
        fw.current.back_emf_v_per_dps, rel=1e-5
    )
    assert nominal["controller.velocity.acc_ff_a_per_dps2"] == pytest.approx(
        fw.velocity.acc_ff_a_per_dps2, rel=1e-5
    )
    assert band.retune(bench, band.Motor(kt=0.7), "fixed") == {}
    spec = linear.MarginSpec()
    gains = set()
    for motor in band.factorial_design():
        ov = band.retune(bench, motor, "classic")
        own = apply_overrides(bench, {**motor.overrides(bench), **ov})
        g = GainSet.from_bench(own)
        assert linear.rejection_reasons(own, g, spec) == [], motor.label
        gains.add(g.kp_v_a_per_dps)
        # back-EMF and inertia feed-forward follow Kt and J
        assert ov["controller.current.back_emf_v_per_dps"] == pytest.approx(
            nominal["controller.current.back_emf_v_per_dps"] * motor.kt
        )
    assert len(gains) == 9  # the velocity gain follows J / Kt (9 distinct ratios)


def test_first_fault_and_spread():
    log = run(with_duration(load("fig6"), 0.5), overrides={"current_sense.k_ilis": 3000.0}).log
    f = band.first_fault(log)
    assert f["fault code"] > 0 and 0.0 < f["fault at (s)"] < 0.5
    assert band.first_fault(run(with_duration(load("fig6"), 0.1)).log) == {
        "fault code": 0.0,
        "fault at (s)": pytest.approx(np.nan, nan_ok=True),
    }
    mean, sd, lo, hi = band.spread([1.0, 3.0, float("nan")])
    assert (mean, lo, hi) == (2.0, 1.0, 3.0) and sd == pytest.approx(2**0.5)


def test_bad_member_and_study_arguments_are_refused():
    with pytest.raises(ValueError, match="gains = 'pid'"):
        band.Member(gains="pid")
    with pytest.raises(ValueError, match="effect = 'magic'"):
        band.Member(effect="magic")
    with pytest.raises(ValueError, match="retune = 'model'"):
        band.run_sensitivity(retune_how="model")
    with pytest.raises(ValueError, match="noise copies = 0"):
        band.run_sensitivity(noise_copies=0)


def test_trace_from_log_measures_as_the_decoded_telemetry():
    """The noise copies of REPORT.md section 4 are measured on the log (a batch sends the
    telemetry of member 0 only): on one run, the log and the decoded frames give the same
    metrics up to the wire's rounding."""
    from sim.reproduce.experiments import trace_from_log, trace_from_result
    from sim.reproduce.metrics import measure

    exp = with_duration(load("fig6"), 4.0)
    result = run(exp)
    tel = measure(trace_from_result("step", exp, result), 5.0)
    log = measure(trace_from_log("step", exp, result.log), 5.0)
    assert log.overshoot_deg == pytest.approx(tel.overshoot_deg, abs=1e-3)
    assert log.max_tracking_error_deg == pytest.approx(tel.max_tracking_error_deg, abs=1e-3)
    assert log.max_vel_step_dps == pytest.approx(tel.max_vel_step_dps, abs=1e-3)
    assert log.peak_current_a == pytest.approx(tel.peak_current_a, abs=0.01)
    assert log.peak_true_current_a == tel.peak_true_current_a
    assert log.arrival_t_s == tel.arrival_t_s and log.faults == tel.faults


def test_noise_spread_is_the_spread_of_the_copies():
    from sim.reproduce.sensitivity import noise_spread

    exp = with_duration(load("fig6"), 4.0)
    spread3 = noise_spread("step", exp, 3, 5.0)
    mean, sd = spread3["overshoot_deg"]
    assert 40.0 < mean < 45.0 and 0.0 < sd < 0.5  # the copies drew different noise
    assert spread3["max_sp_vel_step_dps"][1] == 0.0  # the setpoint has no noise
    quiet = dataclasses.replace(
        exp, bench=apply_overrides(exp.bench, {"encoder.noise_rms_lsb": 0.0})
    )
    assert noise_spread("step", quiet, 2, 5.0)["overshoot_deg"][1] == 0.0
    with pytest.raises(ValueError, match="copies = 1"):
        noise_spread("step", exp, 1, 5.0)


@pytest.mark.parametrize("seeds", ["1", "65", "x"])
def test_the_sensitivity_module_refuses_bad_seeds_in_one_line(seeds, capsys):
    from sim.reproduce import sensitivity

    with pytest.raises(SystemExit) as exc:
        sensitivity.main(["--seeds", seeds])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--seeds: '{seeds}'" in err[0]


def test_the_de_retune_is_the_tuners_and_passes_its_gate():
    """``--retune de``: the tuner's differential evolution on the member's own bench (its
    default scenario), from the classic gains: its result passes the optimiser's gate and
    costs no more than the classic start on that scenario."""
    from sim.tuning.cost import CostWeights
    from sim.tuning.evaluate import evaluate
    from sim.tuning.scenarios import DEFAULT_SCENARIO, scenario

    bench = load("fig6").bench
    motor = band.Motor(kt=0.7)
    classic = band.retune(bench, motor, "classic")
    de = band.retune(bench, motor, "de")
    model = {k: v for k, v in classic.items() if k not in GainSet.from_bench(bench).overrides()}
    assert {k: de[k] for k in model} == model  # the same feed-forward model
    own = apply_overrides(bench, {**motor.overrides(bench), **model})
    g_classic = GainSet.from_bench(apply_overrides(own, classic))
    g_de = GainSet.from_bench(apply_overrides(own, de))
    assert g_de != g_classic
    assert linear.rejection_reasons(own, g_de, linear.MarginSpec()) == []
    scen = [scenario(DEFAULT_SCENARIO, own, time_scale=4.0, tail_s=1.0)]
    ev = evaluate(scen, [g_classic, g_de], weights=CostWeights())
    assert ev.cost[1] <= ev.cost[0]


def test_the_full_study_members():
    full = band.fig6_band_members(design="factorial", noise_copies=5, effects_everywhere=True)
    n_eff = len(band.EFFECTS)
    # + 4 more noise copies of each one-at-a-time variant: 6 motors and the effects on the
    # nominal motor, fixed and re-tuned
    assert len(full) == 27 * 3 + 4 * 2 + 27 * 2 * n_eff + 4 * (6 + n_eff) * 2
    assert len(set(full)) == len(full)
    cheap = band.fig6_band_members()
    assert len(cheap) == 15 * 3 + 2 * 2 + n_eff + 2 * (6 * 2 + n_eff)
    assert {m.motor for m in cheap if m.effect} == {band.Motor()}
    # every variant of the one-at-a-time tables in 3 noise realisations, as the nominal
    variants = [m for m in cheap if band.is_variant(m)]
    assert len(variants) == 3 * (6 * 2 + n_eff)
    assert {m.copy for m in variants} == {0, 1, 2}


def test_the_effects_table_names_the_faults_the_motors_tripped_with():
    """Section 8's effects table says which first fault tripped the motors it counts (the
    counts alone could not tell an over-current from a sensor or thermal trip)."""
    from types import SimpleNamespace

    from serial_protocol.messages import Fault

    codes = [0, int(Fault.OVER_CURRENT), int(Fault.THERMAL), int(Fault.OVER_CURRENT)]
    st = SimpleNamespace(metrics=[{"fault code": float(c)} for c in codes])
    assert band._faults_by_name(st, [0, 1, 2, 3]) == " (OVER_CURRENT 2, THERMAL 1)"
    assert band._faults_by_name(st, [0]) == ""
