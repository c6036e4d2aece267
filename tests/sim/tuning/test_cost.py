"""Cost terms on synthetic logs with answers worked out by hand, and the weights."""

from __future__ import annotations

import numpy as np
import pytest

from sim.config import Experiment, ScriptedCommand
from sim.loop import LOG_FIELDS, RunLog
from sim.tuning.cost import TERMS, CostWeights, combine, cost_terms

DT_S = 0.01


def _log(n: int, **signals: np.ndarray) -> RunLog:
    cols = {f: np.zeros((2, n)) for f in LOG_FIELDS if f != "t_s"}
    cols["state"] = cols["state"].astype(np.int64)
    cols["fault"] = cols["fault"].astype(np.int64)
    cols.update(signals)
    return RunLog(t_s=np.arange(n) * DT_S, **cols)


def _exp(bench, *times_s: float) -> Experiment:
    cmds = tuple(ScriptedCommand(t, "stop") for t in times_s)
    return Experiment(bench=bench, duration_s=10.0, commands=cmds)


def test_itae_restarts_at_each_command(bench):
    n = 200
    err = np.zeros((2, n))
    err[0] = 0.5  # constant error: sum of age * 0.5 * dt over each window
    sp = np.zeros((2, n))
    log = _log(n, sp_pos_deg=sp, true_pos_deg=-err)
    terms = cost_terms(log, _exp(bench, 0.0, 1.0), current_limit_a=5.0, delay_ticks=1)
    ages = np.arange(100) * DT_S
    expected = 2 * np.sum(ages * 0.5) * DT_S
    assert terms["itae_deg_s2"][0] == pytest.approx(expected)
    assert terms["itae_deg_s2"][1] == 0.0


def test_overshoot_and_settling_after_arrival(bench):
    n = 300
    t = np.arange(n) * DT_S
    sp = np.minimum(t, 1.0)  # ramps to 1 deg, arrives at tick 100
    sp_vel = np.where(t < 1.0, 1.0, 0.0)
    pos = sp.copy()
    pos[110] = 1.3  # 0.3 deg past the target
    pos[150] = 1.005  # inside a 0.01 band
    pos[160] = 0.98  # last excursion outside: settled from tick 161
    log = _log(
        n,
        sp_pos_deg=np.vstack([sp, sp]),
        sp_vel_dps=np.vstack([sp_vel, sp_vel]),
        true_pos_deg=np.vstack([pos, sp]),
    )
    terms = cost_terms(log, _exp(bench, 0.0), current_limit_a=5.0, delay_ticks=1)
    assert terms["overshoot_deg"] == pytest.approx([0.3, 0.0])
    assert terms["settling_s"] == pytest.approx([0.61, 0.0])


def test_limit_chatter_current_error_and_fault(bench):
    n = 100
    i_ref = np.zeros((2, n))
    i_ref[0, 10:30] = 5.0  # 20 ticks at the 5 A limit
    duty = np.zeros((2, n))
    duty[1, ::2] = 0.01  # alternating: |diff| = 0.01 every tick
    i_true = np.zeros((2, n))
    i_true[0, 12:32] = 5.0  # follows the reference two ticks later (delay 1 + 1)
    fault = np.zeros((2, n), dtype=np.int64)
    fault[1, 50] = 2
    log = _log(n, current_ref_a=i_ref, duty=duty, current_a=i_true, fault=fault)
    terms = cost_terms(log, _exp(bench, 0.0), current_limit_a=5.0, delay_ticks=1)
    assert terms["current_limit_s"] == pytest.approx([20 * DT_S, 0.0])
    assert terms["chatter_duty"] == pytest.approx([0.0, 0.01])
    assert terms["current_error_a"] == pytest.approx([0.0, 0.0])
    assert terms["fault"].tolist() == [0.0, 1.0]


def test_combine_and_weights():
    terms = {name: np.array([1.0, np.nan]) for name in TERMS}
    w = CostWeights()
    total = combine(terms, w)
    assert total[0] == pytest.approx(sum(getattr(w, name) for name in TERMS))
    assert total[1] == np.inf
    w2 = w.with_updates(["chatter_duty=0", "settle_band_deg=0.05"])
    assert w2.chatter_duty == 0.0 and w2.settle_band_deg == 0.05
    with pytest.raises(ValueError, match="--weight 'bogus=1'"):
        w.with_updates(["bogus=1"])
    with pytest.raises(ValueError, match="must be a number >= 0"):
        CostWeights(itae_deg_s2=-1.0)


def test_commands_after_the_end_of_the_log_are_ignored(bench):
    n = 50
    sp = np.zeros((2, n))
    log = _log(n, sp_pos_deg=sp, true_pos_deg=sp + 0.1)
    terms = cost_terms(log, _exp(bench, 0.0, 0.2, 5.0), current_limit_a=5.0, delay_ticks=1)
    ages = np.concatenate([np.arange(20), np.arange(30)]) * DT_S
    assert terms["itae_deg_s2"] == pytest.approx([np.sum(ages * 0.1) * DT_S] * 2)
