"""Issue 13 §3: Table 1's a_max per move, and the run without feed-forward."""

from __future__ import annotations

import numpy as np
import pytest

from sim.loop import run
from sim.reproduce.experiments import load, move_commands, with_duration
from sim.reproduce.fig8 import PAPER_TABLE1
from sim.reproduce.sensitivity import (
    FF_OFF,
    TABLE1_A_MAX,
    fig8_metrics,
    plan_states_per_move,
    table1_experiment,
)


def test_one_a_max_per_move_reproduces_table_1_and_one_for_all_does_not():
    per_move = plan_states_per_move(TABLE1_A_MAX)
    for (_, state, vel, t_s), (t, v, s) in zip(PAPER_TABLE1, per_move, strict=True):
        assert t == t_s and s == state
        assert v == pytest.approx(vel, abs=1e-6)
    single = plan_states_per_move((148.0,) * 4)
    assert single[2][2] == "accelerating"  # not yet cruising at 10 s
    assert single[2][1] == pytest.approx(-888.0, abs=1e-6)
    assert single[3][1] != pytest.approx(-294.0, abs=1.0)
    # The experiment carries the values to the wire.
    moves = move_commands(table1_experiment())
    assert [dict(c.fields)["a_max_dps2"] for _, c in moves] == list(TABLE1_A_MAX)


def test_without_feed_forward_the_position_loop_lags_by_one_over_its_gain():
    # The first 2.5 s of Fig. 8 (from rest at 148 deg/s^2, then reversing): with only the
    # position command the axis lags by about v / Kp_pos (Kp 13.4 /s: 75 ms).
    exp = with_duration(load("fig8"), 2.5)
    kp = exp.bench.firmware.position.kp_per_s
    on = run(exp).log
    off = run(exp, overrides=FF_OFF).log
    k = int(round(2.0 / exp.bench.dt_s))
    err_off = off.sp_pos_deg[k] - off.true_pos_deg[k]
    assert err_off == pytest.approx(off.sp_vel_dps[k] / kp, rel=0.15)
    assert (
        fig8_metrics(off)["max following error (deg)"]
        > 50 * fig8_metrics(on)["max following error (deg)"]
    )
    assert np.all(off.fault == 0)
    assert fig8_metrics(off)["faults"] == 0
