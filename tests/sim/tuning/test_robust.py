"""The plant spread: its members, and the worst case over it in one batch."""

from __future__ import annotations

import pytest

from sim.tuning.cost import TERMS, CostWeights
from sim.tuning.evaluate import evaluate
from sim.tuning.gains import GainSet
from sim.tuning.robust import SPREAD, plant_spread, robust_table, spread_evaluate


def test_spread_covers_the_corners(short_move):
    plants = plant_spread(short_move)
    p = short_move.bench.plant
    assert len(plants) == 2 ** len(SPREAD) + 1
    assert plants[0]["platter.j_kgm2"] == p.platter.j_kgm2
    js = sorted({q["platter.j_kgm2"] for q in plants[1:]})
    assert js == pytest.approx([0.7 * p.platter.j_kgm2, 1.3 * p.platter.j_kgm2])
    assert sorted({q["supply.voltage_v"] for q in plants[1:]}) == [20.0, 26.0]
    assert sorted({q["encoder.noise_rms_lsb"] for q in plants[1:]}) == [0.0, 1.0]
    friction = sorted({q["motor.coulomb_nm"] / p.motor.coulomb_nm for q in plants[1:]})
    assert friction == pytest.approx([0.5, 2.0])


def test_worst_case_is_at_least_the_nominal(bench, short_move):
    gains = {"config": GainSet.from_bench(bench)}
    worst = spread_evaluate([short_move], gains, weights=CostWeights())
    nominal = evaluate([short_move], [gains["config"]], weights=CostWeights())
    w = worst["config"]
    assert w["cost"] >= nominal.cost[0] * 0.999
    assert 0 <= w["worst_plant"] <= 2 ** len(SPREAD)
    assert set(TERMS) <= set(w)
    assert robust_table(worst).splitlines()[2].startswith("| config | ")
