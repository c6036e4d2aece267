"""The firmware's thermal protection (issue 13 §2.6, ``firmware_model.thermal``): derating
then the ``THERMAL`` trip on a stalled motor held at its current limit, never on the
paper's experiments, one law for every N and both arithmetics, and its config checks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from firmware_model.params import SafetyParams
from serial_protocol.messages import Fault, FaultFlag, FaultReport, Limits
from sim import cli, loop
from sim.reproduce import experiments

# A stall: a platter that will not turn (the motor winds up the belt, then stands), driven
# by a STEP move (no following-error trip) at the 5 A limit. Quick thresholds: derate from
# 50 degC, trip at 60 degC (the firmware assumes 40 degC at power-up).
STALL = {"platter.coulomb_nm": 1e4, "platter.stiction_nm": 0.0}
QUICK = {"safety.thermal_derate_c": 50.0, "safety.thermal_trip_c": 60.0}


def _fig6(duration_s: float, batch: int | None = None, **overrides) -> loop.RunResult:
    exp = experiments.with_duration(experiments.load("fig6"), duration_s)
    return loop.run(exp, seed=0, batch=batch, overrides=overrides or None)


@pytest.mark.parametrize("arithmetic", ["float", "fixed"])
def test_a_stalled_motor_is_derated_then_tripped(arithmetic):
    result = _fig6(40.0, **{**STALL, **QUICK, "servo.arithmetic": arithmetic})
    log = result.log
    hot = np.flatnonzero(log.fault == int(Fault.THERMAL))
    assert hot.size, "no THERMAL trip"
    k_trip = hot[0]
    t_trip = log.t_s[k_trip]
    # Before the derating the loop holds the 5 A limit; derated, the reference falls
    # towards half of it before the trip.
    i_ref = np.abs(log.current_ref_a[:k_trip])
    assert i_ref[100:600].min() == pytest.approx(5.0, abs=1e-3)
    assert 2.4 < i_ref[-20:].max() < 4.0
    assert 5.0 < t_trip < 40.0
    # The fault is reported on the wire with its own flag, the estimate and the threshold.
    reports = [m for m in result.replies if isinstance(m, FaultReport) and m.fault == Fault.THERMAL]
    assert len(reports) == 1
    assert reports[0].fault_flags & int(FaultFlag.THERMAL)
    assert reports[0].threshold == 60.0 and reports[0].value >= 60.0
    # The plant's winding (its own model, with the model's own constants) is hot too.
    assert not np.isnan(log.winding_c).any()


def test_the_plant_heats_where_the_firmware_estimates():
    # The plant's heat model and the firmware's estimate have the same constants here
    # (the plant at the firmware's 40 degC ambient, no friction heat at a stall): they
    # agree within the effect of R(T) the firmware takes at its own estimate.
    over = {
        **STALL, "thermal.model": True, "thermal.ambient_c": 40.0,
        "safety.thermal_trip_c": 200.0, "safety.thermal_derate_c": 190.0,
    }  # fmt: skip
    exp = experiments.with_duration(experiments.load("fig6"), 20.0)
    holder = {}
    saved = loop.Simulation

    class Keep(saved):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            holder["sim"] = self

    loop.Simulation = Keep
    try:
        result = loop.run(exp, seed=0, overrides=over)
    finally:
        loop.Simulation = saved
    plant_c = result.log.winding_c[-1]
    firmware_c = holder["sim"].fw.thermal_estimate_c
    assert plant_c > 70.0  # 20 s at 5 A
    assert abs(firmware_c - plant_c) < 0.01 * (plant_c - 40.0)  # measured: 83.260 vs 83.254


def test_never_trips_nor_derates_in_the_paper_experiments():
    # Fig. 6 (10 s), Fig. 7 and Fig. 8 (30 s) with the protection on (its feed-forward R
    # and k_emf aside) are the runs without it: it never derates there.
    ff_off = {"safety.thermal_ff_resistance": False, "safety.thermal_ff_back_emf": False}
    for name in ("fig6", "fig7", "fig8"):
        exp = experiments.load(name)
        on = loop.run(exp, seed=0, overrides=ff_off)
        off = loop.run(exp, seed=0, overrides={"safety.thermal_protection": False})
        for field, column in on.log.items():
            np.testing.assert_array_equal(column, getattr(off.log, field), f"{name} {field}")
        assert Fault.THERMAL not in set(on.log.fault.tolist())
        assert Fault.THERMAL not in set(loop.run(exp, seed=0).log.fault.tolist())


def test_a_batch_member_trips_alone_and_the_others_are_single_runs():
    coulomb = np.array([0.3, 1e4])  # member 0 turns, member 1 is stalled
    # Without encoder noise a stalled motor trips the stuck-encoder check first: off here.
    quiet = {**QUICK, "encoder.noise_rms_lsb": 0.0, "safety.encoder_stuck_ticks": 100_000}
    both = _fig6(40.0, batch=2, **{**quiet, "platter.coulomb_nm": coulomb}).log
    assert both.fault[1].max() == int(Fault.THERMAL)
    assert both.fault[0].max() == 0
    for j, c in enumerate(coulomb):
        one = _fig6(40.0, **{**quiet, "platter.coulomb_nm": float(c)}).log
        member = both.member(j)
        k = np.flatnonzero(one.fault)[0] if one.fault.any() else len(one)
        for name in ("current_ref_a", "duty", "true_pos_deg", "fault"):
            np.testing.assert_array_equal(getattr(member, name)[:k], getattr(one, name)[:k], name)


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"thermal_derate_c": 130.0}, "below thermal_trip_c"),
        ({"thermal_derate_min_ratio": 1.5}, "thermal_derate_min_ratio"),
        ({"thermal_tau_winding_s": 0.0}, "thermal_tau_winding_s"),
        ({"thermal_protection": 1}, "true or false"),
    ],
)
def test_bad_protection_values_are_refused_in_one_line(changes, words):
    with pytest.raises(ValueError, match=words) as info:
        dataclasses.replace(SafetyParams(), **changes)
    assert "\n" not in str(info.value)


def test_a_bad_protection_value_in_a_bench_file_is_exit_status_2(tmp_path, capsys):
    bench = tmp_path / "bench.toml"
    bench.write_text("[safety]\nthermal_derate_c = 150.0\n")
    exp = tmp_path / "exp.toml"
    exp.write_text(f'bench = "{bench}"\nduration_s = 0.1\n')
    status = cli.main(["run", str(exp), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "thermal_derate_c = 150.0" in lines[0] and "[safety]" in lines[0]


def test_the_threshold_and_the_estimate_are_read_with_get_limits():
    # Limits' appended read-only fields, through the wire: the trip and the estimate
    # (0, 0 with the protection off); 30 s into the stall the estimate is past 40 degC.
    from sim.config import ScriptedCommand

    base = experiments.with_duration(experiments.load("fig6"), 30.5)
    exp = dataclasses.replace(
        base, commands=(*base.commands, ScriptedCommand(30.0, "get_limits", ()))
    )
    for on in (True, False):
        over = {**STALL, "safety.thermal_protection": on}
        result = loop.run(exp, seed=0, overrides=over)
        (reply,) = [m for m in result.replies if isinstance(m, Limits)]
        if on:
            assert reply.thermal_trip_c == 120.0
            assert 60.0 < reply.winding_estimate_c < 120.0
        else:
            assert (reply.thermal_trip_c, reply.winding_estimate_c) == (0.0, 0.0)
