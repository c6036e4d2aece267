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
    n_eff = len(band.EFFECTS)
    full = band.fig6_band_members(design="factorial", noise_copies=5, effects_everywhere=True)
    # every motor with three kinds of gains, every effect on every motor fixed and re-tuned:
    # each member in 5 noise realisations
    assert len(full) == 5 * (27 * 3 + 27 * 2 * n_eff)
    assert len(set(full)) == len(full)
    cheap = band.fig6_band_members()
    assert len(cheap) == 3 * (15 * 3 + n_eff)
    assert {m.motor for m in cheap if m.effect} == {band.Motor()}
    for members, n in ((full, 5), (cheap, 3)):
        copies: dict = {}
        for m in members:
            copies.setdefault((m.motor, m.gains, m.effect), []).append(m.copy)
        assert all(c == list(range(n)) for c in copies.values())
    # every variant of the one-at-a-time tables in 3 noise realisations, as the nominal
    variants = [m for m in cheap if band.is_variant(m)]
    assert len(variants) == 3 * (6 * 2 + n_eff)
    assert {m.copy for m in variants} == {0, 1, 2}
    # Fig. 7 / 8's studies: the nominal and the variants only
    eff = band.effects_members(noise_copies=3)
    assert len(eff) == 3 * (2 + 6 * 2 + n_eff) == len(set(eff))


def _synthetic_band(rows: dict, effect=None, retune="classic"):
    """A BandResult whose members are ``rows``' motors (with ``retune`` gains: fixed, model
    and re-tuned), copies 0..n-1, and whose metrics are the values given: ``rows[(motor,
    gains)] = [(overshoot, fault code), ...]`` per copy."""
    members, metrics = [], []
    for (motor, gains), copies in rows.items():
        for c, (value, code) in enumerate(copies):
            members.append(band.Member(motor, gains, effect, copy=c))
            metrics.append({"overshoot (deg)": value, "fault code": float(code),
                            "fault at (s)": 3.25 if code else float("nan")})  # fmt: skip
    st = band.Study("synthetic", tuple(members), tuple(metrics), np.zeros(1))
    return band.BandResult(st, 3000.0, retune, "composite", effect is not None)


def test_the_band_table_separates_the_spread_over_motors_from_the_noise():
    """Section 8's band table: per gains, the motors that tripped in any realisation, then
    the median (min–max) of the per-motor means and the median (largest) of the per-motor
    standard deviations (recomputed here by hand)."""
    from serial_protocol.messages import Fault

    oc = int(Fault.OVER_CURRENT)
    a, b, c, d = (band.Motor(r=0.7), band.Motor(kt=1.3), band.Motor(j=0.7), band.Motor())
    rows = {
        (a, "fixed"): [(10.0, 0), (12.0, 0), (14.0, 0)],  # mean 12, sd 2
        (b, "fixed"): [(100.0, 0), (101.0, 0), (102.0, 0)],  # mean 101, sd 1
        (c, "fixed"): [(1.0, 0), (1.0, 0), (1.0, 0)],  # mean 1, sd 0
        (d, "fixed"): [(50.0, 0), (0.0, oc), (50.0, 0)],  # tripped in 1 of 3: left out
        (a, "model"): [(5.0, 0), (float("nan"), 0), (7.0, 0)],  # mean 6, sd 1.414
        (b, "model"): [(8.0, 0), (8.0, 0), (8.0, 0)],
        (a, "classic"): [(3.0, 0), (3.0, 0), (3.0, 0)],
    }
    lines = band._band_table(_synthetic_band(rows), ["overshoot (deg)"])
    table = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines if ln]
    assert table[0] == ["gains", "tripped", "spread", "overshoot (deg)"]
    got = {(r[0], r[2]): (r[1], r[3]) for r in table[2:]}
    assert got[("fixed", "motors")] == (
        "1 of 4 (nominal motor: OVER_CURRENT at 3.250 s (in 1 of 3))",
        "12 (1–101)",
    )
    assert got[("fixed", "noise")] == ("", "1 (2)")
    assert got[("model", "motors")] == (
        "0 of 2",
        "7 (6–8) [undefined in 1 of 6 realisations]",
    )
    assert got[("model", "noise")][1] == "0.71 (1.4)"
    assert got[("classic", "motors")][1] == "3 (3–3)" and got[("classic", "noise")][1] == "0 (0)"
    # one realisation per motor: no spread over the noise to show (not "0")
    single = {k: v[:1] for k, v in rows.items()}
    lines = band._band_table(_synthetic_band(single), ["overshoot (deg)"])
    noise = [ln for ln in lines if "| noise |" in ln]
    assert len(noise) == 3 and all(ln.endswith("| - |") for ln in noise)
    # the effects table (full study): the same numbers per effect
    eff = "gearbox drag off"
    rows_e = {k: v for k, v in rows.items() if k[1] != "model"}
    b_none = _synthetic_band(rows_e)
    b_eff = _synthetic_band(rows_e, effect=eff)
    st = band.Study(
        "both", b_none.study.members + b_eff.study.members,
        b_none.study.metrics + b_eff.study.metrics, np.zeros(1),
    )  # fmt: skip
    lines = band._effects_everywhere_table(dataclasses.replace(b_eff, study=st))
    cells = {ln.split(" | ")[0].strip("| "): ln.split(" | ")[1:] for ln in lines[2:] if ln}
    for name in ("none (the bench)", eff):
        assert cells[name][0] == "1 of 4 (OVER_CURRENT 1); 12 (1–101); noise sd 1 (2)"
        assert cells[name][1].rstrip(" |") == "0 of 1; 3 (3–3); noise sd 0 (0)"


def test_the_effects_table_names_the_faults_the_motors_tripped_with():
    """Section 8's effects table says which first fault tripped the motors it counts (the
    counts alone could not tell an over-current from a sensor or thermal trip)."""
    from types import SimpleNamespace

    from serial_protocol.messages import Fault

    codes = [0, int(Fault.OVER_CURRENT), int(Fault.THERMAL), int(Fault.OVER_CURRENT)]
    st = SimpleNamespace(metrics=[{"fault code": float(c)} for c in codes])
    assert band._faults_by_name(st, [0, 1, 2, 3]) == " (OVER_CURRENT 2, THERMAL 1)"
    assert band._faults_by_name(st, [0]) == ""


def test_the_band_figure_uses_the_per_motor_means_and_any_realisations_trip():
    """fig6_band.png: the legend's overshoot range is over the per-motor means (as the
    table's), and a motor that tripped in one realisation only is drawn apart (dotted)."""
    from matplotlib.lines import Line2D

    from serial_protocol.messages import Fault

    oc = int(Fault.OVER_CURRENT)
    a, b, d = band.Motor(r=0.7), band.Motor(kt=1.3), band.Motor()
    rows = {
        (d, "fixed"): [(40.0, 0), (44.0, 0)],  # mean 42
        (a, "fixed"): [(10.0, 0), (14.0, 0)],  # mean 12
        (b, "fixed"): [(100.0, 0), (0.0, oc)],  # tripped in copy 1 only
        (d, "classic"): [(30.0, 0), (30.0, 0)],
    }
    res = _synthetic_band(rows)
    st = res.study
    t = np.linspace(0.0, 4.0, 9)
    kept = tuple(k for k, m in enumerate(st.members) if m.copy == 0)
    cols = {c: np.stack([t * (j + 1) for j in range(len(kept))]) for c in ("pos_deg", "vel_dps")}
    st = dataclasses.replace(st, t_s=t, columns=cols, kept=kept)
    fig = band.plot(dataclasses.replace(res, study=st), None)
    labels = [ln.get_label() for ln in fig.get_axes()[1].get_lines()]
    assert "fixed gains (firmware as configured): 2 motors, overshoot 12–42° (median 27°)" in labels
    assert "1 motors that tripped (in some realisation)" in labels
    # the tripped motor's own curve (realisation 0), dotted, outside the envelope
    (line,) = [ln for ln in fig.get_axes()[1].get_lines() if "tripped" in ln.get_label()]
    assert isinstance(line, Line2D) and line.get_linestyle() == ":"
    assert np.array_equal(line.get_ydata(), cols["pos_deg"][kept.index(4)] - 3000.0)
    with pytest.raises(KeyError, match="was not kept"):
        st.column("pos_deg", [len(st.members) - 1])
