"""The back-EMF check's allowance for what the firmware does not know of R and the IS offset,
as decided in issue 13 §2.3 (docs/model.md "Safety", "The R spread and a warm restart";
figures from benchmarks/sensor_spread.py): no false trip on a grid of healthy boards up to
a restart at the thermal trip, and how fast real faults are still caught."""

from __future__ import annotations

import numpy as np
import pytest
from test_safety import R_NOMINAL_OHM, _spread_run
from uart_fuzz import paper_bench

from serial_protocol import frame
from serial_protocol.messages import Fault, FaultReport, Hello, Move, Profile
from sim.loop import Simulation

CAL = {"controller.current.sense_calibration": True}
# What the calibration leaves of the offset and the check's allowance for it by default.
CAL_DEFAULT_COUNTS = 2
# A restart the firmware's estimate cannot see: the heat model on, the plant's winding and
# housing above the lab's 25 degC at power-up (warm: +55 / +30 K; hot: the winding at the
# firmware's 120 degC trip, +95 / +70 K).
HEAT = {"thermal.model": True}
HOT_GRID = [
    {"current_sense.k_ilis": k, "motor.r_ohm": R_NOMINAL_OHM * r,
     "thermal.initial_winding_rise_k": w, "thermal.initial_housing_rise_k": h}
    for k, r in ((8500.0, 1.0), (8500.0, 1.3), (12000.0, 1.3), (14000.0, 1.0), (14000.0, 1.3))
    for w, h in ((55.0, 30.0), (95.0, 70.0))
]  # fmt: skip
NO_RESTART = {"safety.sensor_mismatch_restart_rise_k": 0.0}


@pytest.mark.parametrize("calibrated", [False, True])
def test_no_healthy_board_trips_up_to_a_restart_at_the_thermal_trip(calibrated):
    over = {**HEAT, **(CAL if calibrated else {})}
    first, peak = _spread_run("fig6", HOT_GRID, **over)
    assert first == [0] * len(HOT_GRID)
    assert np.all(peak < 0.75 / 2)  # at most half the threshold (measured 0.25: the start)
    # Without the restart's allowance the hottest corner trips: k_ILIS 14k, R x1.3 at 120
    # degC is R x1.81 of the firmware's, beyond the +-30 % spread (measured at 3.57-3.60 s;
    # with the calibrated allowance of 2 counts the warm restarts at 14k R x1.3 and the hot
    # one at 12k R x1.3 too).
    before, _ = _spread_run("fig6", HOT_GRID, **over, **NO_RESTART)
    assert before[-1] == Fault.SENSOR_MISMATCH
    if calibrated:
        assert before[-2] == before[5] == Fault.SENSOR_MISMATCH


def test_no_healthy_board_trips_while_warming_up_by_running():
    # Boards warmed by running (the heat duty: Fig. 6's move back and forth): the firmware
    # estimates that heat, but from the current it reads, 0.61 of the true one at k_ILIS
    # 14k: without the restart's allowance (which covers it while it decays) R x1.3 tripped
    # after 7.4 min with the calibrated allowance.
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "docs"))
    from heat_duty import back_and_forth

    import sim.loop as loop_module

    rows = [{"current_sense.k_ilis": 14000.0, "motor.r_ohm": R_NOMINAL_OHM * 1.3}]
    ov = {key: [row[key] for row in rows] for key in rows[0]}
    exp = back_and_forth(9.0, 4.0)
    log = loop_module.run(exp, batch=1, overrides={**ov, **HEAT, **CAL}).log
    assert not np.any(np.atleast_2d(log.fault) == Fault.SENSOR_MISMATCH)
    log = loop_module.run(exp, batch=1, overrides={
        **ov, **HEAT, **CAL, **NO_RESTART}).log  # fmt: skip
    assert np.any(np.atleast_2d(log.fault) == Fault.SENSOR_MISMATCH)


def _first_report(sim):
    reports = [m for m in frame.Decoder().feed(sim.pc_read()) if isinstance(m, FaultReport)]
    return reports[0] if reports else None


def _freeze_ticks(overrides, *, idle_s=0.0, v_dps=100.0):
    """Ticks from a noisy encoder freeze, cruising at ``v_dps`` 3 s into a move that starts
    ``idle_s`` after power-up, to the first trip (and which)."""
    sim = Simulation(paper_bench(**overrides), seed=3)
    sim.pc_write(frame.encode(Hello(0, session=1), 0))
    sim.step(round(idle_s * 500) + 1)
    sim.pc_write(frame.encode(Move(1, 30000.0, v_dps, 2000.0, 0.0, Profile.TRAPEZOID, 1), 1))
    sim.step(1500)
    k0 = sim.tick
    sim.encoder.inject("freeze", x=sim.plant_state)
    sim.step(600)
    rep = _first_report(sim)
    return rep.fault, rep.tick - k0


@pytest.mark.parametrize("calibrated", [False, True])
def test_a_frozen_encoder_is_caught_and_faster_as_a_restart_s_heat_decays(calibrated):
    over = CAL if calibrated else {}
    fault, at_power_up = _freeze_ticks(over)
    assert fault is Fault.SENSOR_MISMATCH
    # measured 126 (uncalibrated) / 112 (calibrated) ticks; 85 / 74 without the restart
    assert at_power_up <= (130 if not calibrated else 115)
    fault, later = _freeze_ticks(over, idle_s=1800.0)
    assert fault is Fault.SENSOR_MISMATCH
    assert later <= at_power_up - 20


@pytest.mark.parametrize("kind", ["short", "stuck"])
def test_a_shorted_or_stuck_is_pin_is_caught_at_the_next_move(kind):
    # The pin fails at rest; the next move (Fig. 6's step at the 5 A clamp) drives the
    # current the loop cannot see: measured 4 ticks, 0.1 deg, with every setting.
    sim = Simulation(paper_bench(**CAL), seed=3)
    sim.pc_write(frame.encode(Hello(0, session=1), 0))
    sim.step(1498)
    sim.inject_sense(kind)
    sim.pc_write(frame.encode(Move(1, 3000.0, 990.0, 2000.0, 0.0, Profile.STEP, 1), 1))
    sim.step(100)
    rep = _first_report(sim)
    assert rep.fault is Fault.SENSOR_MISMATCH and rep.tick - 1500 <= 10


def test_a_stuck_is_pin_while_cruising_and_an_open_winding_are_caught():
    sim = Simulation(paper_bench(**CAL), seed=3)
    sim.pc_write(frame.encode(Hello(0, session=1), 0))
    sim.pc_write(frame.encode(Move(1, 450.05, 100.0, 2000.0, 0.0, Profile.TRAPEZOID, 1), 1))
    sim.step(1500)
    sim.inject_sense("stuck")
    sim.step(1500)
    rep = _first_report(sim)
    assert rep.fault is Fault.SENSOR_MISMATCH and rep.tick - 1500 <= 160  # measured 146
    # An open winding (R 1 kOhm): no current, the back-EMF speed is the duty's.
    sim = Simulation(paper_bench(**CAL, **{"motor.r_ohm": 1000.0}), seed=3)
    sim.pc_write(frame.encode(Hello(0, session=1), 0))
    sim.pc_write(frame.encode(Move(1, 450.0, 100.0, 2000.0, 0.0, Profile.TRAPEZOID, 1), 1))
    sim.step(200)
    rep = _first_report(sim)
    # measured 20 ticks (17 of them the calibration)
    assert rep.fault is Fault.SENSOR_MISMATCH and rep.tick <= 30
