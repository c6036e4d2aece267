"""Fast checks of the reproduction's building blocks: experiment variants, the quick
scaling, strategy and state classification, Table 1's arithmetic, the waypoint schedule."""

from __future__ import annotations

import numpy as np
import pytest

from planner import plan_trapezoid
from serial_protocol.messages import Profile
from sim.reproduce import fig7, fig8, lookahead_demo
from sim.reproduce.experiments import (
    Trace,
    load,
    move_commands,
    replace_move,
    scale_quick,
    to_scurve,
    with_duration,
)
from sim.reproduce.metrics import measure

DT = 0.002


def synthetic_trace(sp_vel, *, command_t_s=(0.0,), target=100.0, pos=None):
    sp_vel = np.asarray(sp_vel, dtype=float)
    n = len(sp_vel)
    sp_pos = np.cumsum(sp_vel) * DT
    pos = sp_pos if pos is None else np.asarray(pos, dtype=float)
    zeros = np.zeros(n)
    return Trace(
        name="synthetic",
        dt_s=DT,
        t_s=np.arange(n) * DT,
        sp_pos_deg=sp_pos,
        sp_vel_dps=sp_vel,
        pos_deg=pos,
        vel_dps=sp_vel.copy(),
        current_a=zeros,
        duty=zeros,
        state=zeros.astype(np.int64),
        fault=zeros.astype(np.int64),
        command_t_s=tuple(command_t_s),
        command_target_deg=(target,) * len(command_t_s),
        command_a_max_dps2=(148.0,) * len(command_t_s),
        replies=(),
    )


def test_every_experiment_file_loads_with_the_paper_numbers():
    f6 = load("fig6")
    ((_, step),) = move_commands(f6)
    assert step.get("profile") is Profile.STEP and step.get("target_mdeg") == 3e6
    f8 = load("fig8")
    assert [c.t_s for _, c in move_commands(f8)] == [0.0, 2.0, 10.0, 16.0]
    assert [c.get("target_mdeg") for _, c in move_commands(f8)] == [3e6, -8e6, -6e6, -1e6]
    assert {c.get("a_max_dps2") for _, c in move_commands(f8)} == {148.0}
    f7 = load("fig7")
    assert move_commands(f7)[-1][1].get("target_mdeg") == 1e7
    assert load("seed002_tables").commands[1].get("profile") is Profile.SCURVE
    assert len(move_commands(load("lookahead_program"))) == 7


def test_fig7_run_up_reaches_400_at_zero_by_the_planner():
    """The run-up in fig7.toml, replayed through the planner, cruises through 0 deg at
    400 deg/s at the interrupt (each command applied one tick after it is sent)."""
    from planner import OnlinePlanner

    planner = OnlinePlanner("trapezoid")
    planner.reset(0.0)
    moves = [c for _, c in move_commands(load("fig7"))]
    for cmd in moves[:-1]:
        planner.command(
            cmd.t_s + DT, cmd.get("target_deg"), v_max=cmd.get("v_max_dps"),
            a_max=cmd.get("a_max_dps2"),
        )  # fmt: skip
    p, v, a = planner.sample(moves[-1].t_s + DT)
    assert v == pytest.approx(400.0) and a == 0.0
    assert p == pytest.approx(0.0, abs=1e-9)


def test_replace_move_and_to_scurve_change_only_what_they_say():
    f8 = load("fig8")
    changed = replace_move(f8, 1, target_mdeg=-7e6)
    assert move_commands(changed)[1][1].get("target_mdeg") == -7e6
    assert move_commands(changed)[2][1] == move_commands(f8)[2][1]
    sc = to_scurve(f8, 0.25)
    for _, c in move_commands(sc):
        assert c.get("profile") is Profile.SCURVE
        assert c.get("j_max_dps3") == pytest.approx(148.0 / 0.25)
    sc7 = to_scurve(load("fig7"), 0.25, run_up_j_max_dps3=1e6)
    assert [c.get("j_max_dps3") for _, c in move_commands(sc7)] == [1e6, 1e6, 592.0]
    assert with_duration(f8, 3.0).duration_s == 3.0


def test_scale_quick_keeps_every_strategy():
    f7 = load("fig7")
    quick = scale_quick(f7, 4.0)
    assert quick.duration_s == pytest.approx(f7.duration_s / 4)
    (_, last) = move_commands(quick)[-1]
    assert last.t_s == pytest.approx(1.7 / 4)
    assert last.get("v_max_dps") == pytest.approx(990.0 / 4)
    assert last.get("a_max_dps2") == 148.0
    for _, target_mdeg, case, _ in fig7.PAPER_TARGETS:
        full = plan_trapezoid(0.0, target_mdeg / 1000, v_max=990.0, a_max=148.0, v0=400.0)
        small = plan_trapezoid(0.0, target_mdeg / 16000, v_max=247.5, a_max=148.0, v0=100.0)
        assert full.case == small.case == case
        assert small.duration == pytest.approx(full.duration / 4)


def test_observed_strategy_reads_reversal_and_cruise():
    v_max = 10.0
    ramp = np.linspace(4.0, 10.0, 50)
    cruise = np.full(100, 10.0)  # 0.2 s at v_max
    down = np.linspace(10.0, 0.0, 50)
    assert fig7.observed_strategy(synthetic_trace(np.r_[ramp, cruise, down]), 0.0, v_max)[0] == "a"
    assert fig7.observed_strategy(synthetic_trace(np.r_[ramp, down]), 0.0, v_max)[0] == "b"
    rev = np.r_[np.linspace(4.0, -6.0, 60), np.linspace(-6.0, 0.0, 40)]
    assert fig7.observed_strategy(synthetic_trace(rev), 0.0, v_max)[0] == "c"
    rev_cruise = np.r_[np.linspace(4.0, -10.0, 60), -cruise, np.linspace(-10.0, 0.0, 40)]
    assert fig7.observed_strategy(synthetic_trace(rev_cruise), 0.0, v_max)[0] == "d"
    short = np.r_[ramp, np.full(10, 10.0), down]  # 20 ms at v_max is not a cruise
    assert fig7.observed_strategy(synthetic_trace(short), 0.0, v_max)[0] == "b"


def test_classify_state():
    assert fig8.classify_state(0.0, 0.0) == "at rest"
    assert fig8.classify_state(296.0, 148.0) == "accelerating"
    assert fig8.classify_state(-296.0, -148.0) == "accelerating"
    assert fig8.classify_state(-990.0, 0.0) == "cruising"
    assert fig8.classify_state(-294.0, 148.0) == "decelerating"
    assert fig8.classify_state(0.0, -148.0) == "accelerating"


def test_table1_implied_a_max_arithmetic():
    imp = fig8.implied_a_max()
    assert imp["row2"] == pytest.approx(148.0)
    assert imp["row3_min"] == pytest.approx(160.75)
    # The bisection's answer does give -294 deg/s at 16 s.
    assert fig8.plan_states(imp["row4"])[3][2] == pytest.approx(-294.0, abs=1e-6)
    # With 148, the axis is not yet at -990 deg/s at 10 s: it gets there at 10.69 s.
    states = fig8.plan_states(148.0)
    assert states[2][2] == pytest.approx(-888.0)
    assert states[2][3].startswith("accelerating")


def test_measure_overshoot_and_tracking_error():
    sp = np.r_[np.linspace(0, 50, 100), np.full(100, 50.0), np.linspace(50, 0, 100), np.zeros(50)]
    trace = synthetic_trace(sp, target=float(np.sum(sp) * DT))
    pos = trace.sp_pos_deg.copy()
    pos[-30:] += 0.7  # beyond the target at the end
    with_overshoot = synthetic_trace(sp, target=trace.command_target_deg[0], pos=pos)
    m = measure(with_overshoot, current_limit_a=5.0)
    assert m.overshoot_deg == pytest.approx(0.7)
    assert m.max_tracking_error_deg == pytest.approx(0.7)
    assert m.max_sp_vel_step_dps == pytest.approx(50.0 / 99)
    assert measure(trace, 5.0).overshoot_deg == 0.0


def test_lookahead_schedule_follows_the_toml():
    moves = [c for _, c in move_commands(load("lookahead_program"))]
    targets = [c.get("target_deg") for c in moves]
    times = lookahead_demo.schedule(targets, 990.0, 500.0)
    assert times == pytest.approx([c.t_s for c in moves])
    # Each move starts at least DWELL_S after the previous one ends by its plan.
    prev = 0.0
    for t0, t1, target in zip(times, times[1:], targets, strict=False):
        end = t0 + plan_trapezoid(prev, target, v_max=990.0, a_max=500.0).duration
        assert t1 - end >= lookahead_demo.DWELL_S - 1e-9
        prev = target


def test_lookahead_queue_experiment_sends_the_waypoints_as_blocks():
    """The board's-queue form of the waypoint program: SetLimits with the program's limits,
    then one QueueSegment per waypoint, a dwell on each reversal but not at the end; under
    --quick the dwells scale like every other time."""
    exp = load("lookahead_program")
    waypoints = [0.0] + [c.get("target_deg") for _, c in move_commands(exp)]
    assert lookahead_demo.reversals(waypoints) == [False, False, True, False, True, True, True]
    q = lookahead_demo.queue_experiment(exp, waypoints, 990.0, 500.0)
    assert [c.type for c in q.commands] == ["set_limits"] + ["queue_segment"] * 7
    assert q.commands[0].get("a_max_dps2") == 500.0
    blocks = [(c.get("target_deg"), c.get("v_max_dps"), c.get("dwell_s")) for c in q.commands[1:]]
    assert [b[0] for b in blocks] == waypoints[1:]
    assert [b[2] for b in blocks] == [0.0, 0.0, 0.2, 0.0, 0.2, 0.2, 0.0]
    quick = scale_quick(q)
    assert [c.get("dwell_s") for c in quick.commands[1:]] == pytest.approx(
        [0.0, 0.0, 0.05, 0.0, 0.05, 0.05, 0.0]
    )
    assert quick.commands[1].get("target_deg") == pytest.approx(1000.0 / 16)
