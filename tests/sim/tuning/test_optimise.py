"""The optimiser: it beats the config's gains on an independent re-run, refuses unstable
candidates without simulating them, and a fixed seed reproduces the result."""

from __future__ import annotations

import pytest

from serial_protocol.exceptions import ConfigError
from sim.tuning import linear
from sim.tuning.cost import CostWeights
from sim.tuning.evaluate import evaluate
from sim.tuning.gains import GainSet
from sim.tuning.optimise import TuneSettings, tune

# Wide bounds so that the population straddles the stability boundary of every loop.
SETTINGS = TuneSettings(seed=3, popsize=4, maxiter=2, bound_factor=12.0)


@pytest.fixture(scope="module")
def tuned(bench, short_move):
    return tune([short_move], GainSet.from_bench(bench), SETTINGS)


def test_tuned_gains_beat_the_defaults(bench, short_move, tuned):
    start = GainSet.from_bench(bench)
    # A fresh batch (other members, other noise draws than during the search).
    ev = evaluate([short_move], [tuned.gains, start], weights=CostWeights(), seed=11)
    assert ev.cost[0] < 0.8 * ev.cost[1]
    assert tuned.gains != start


def test_unstable_candidates_are_refused_and_never_kept(bench, tuned):
    assert sum(s.refused for s in tuned.stages) > 0
    assert all(s.simulated > 0 for s in tuned.stages)
    assert linear.rejection_reasons(bench, tuned.gains, SETTINGS.margins) == []
    for stage in tuned.stages:
        assert list(stage.best_per_generation) == sorted(stage.best_per_generation, reverse=True)


def test_a_fixed_seed_reproduces_the_result(bench, short_move, tuned):
    again = tune([short_move], GainSet.from_bench(bench), SETTINGS)
    assert again.gains == tuned.gains
    assert [s.cost for s in again.stages] == [s.cost for s in tuned.stages]


def test_unstable_start_is_refused(bench, short_move):
    start = GainSet.from_bench(bench)
    bad = start.replace(kp_p_per_s=start.kp_p_per_s * 20)
    with pytest.raises(ConfigError, match="position loop unstable"):
        tune([short_move], bad, SETTINGS)


def test_joint_mode_tunes_all_gains_in_one_stage(bench, short_move):
    settings = TuneSettings(seed=1, mode="joint", popsize=2, maxiter=1)
    result = tune([short_move], GainSet.from_bench(bench), settings)
    assert [s.loops for s in result.stages] == [("current", "velocity", "position")]
    assert result.stages[0].cost <= result.stages[0].start_cost


def test_start_cost_is_the_config_gains_cost(bench, short_move, tuned):
    """The start gains are the first member of the initial population; its cost is the
    stage's start cost (penalised when the gate refuses it, as the margin spec may)."""
    start = GainSet.from_bench(bench)
    stage = tuned.stages[0]
    if linear.rejection_reasons(bench, start, SETTINGS.margins):
        assert stage.start_cost >= 1e6
    else:
        ev = evaluate([short_move], [start], weights=CostWeights(), seed=SETTINGS.seed)
        # Same gains, same seed, another batch size: the noise draws differ.
        assert stage.start_cost == pytest.approx(float(ev.cost[0]), rel=0.5)
    assert stage.cost <= stage.start_cost


def test_extra_starts_join_the_initial_population(bench, short_move, tuned):
    """With no generation after the initial one, a tune seeded with good gains ends at
    least about as good as them: they were in its population."""
    start = GainSet.from_bench(bench)
    settings = TuneSettings(seed=5, popsize=2, maxiter=0, bound_factor=12.0)
    seeded = tune([short_move], start, settings, extra_starts=[tuned.gains])
    ev = evaluate([short_move], [seeded.gains, tuned.gains, start], weights=CostWeights(), seed=7)
    assert ev.cost[0] < 0.8 * ev.cost[2]
    assert ev.cost[0] < 1.25 * ev.cost[1]


def test_scenarios_add_up(bench, short_move):
    """Two scenarios: each term is the sum over them (here the same run twice)."""
    gains = [GainSet.from_bench(bench)]
    one = evaluate([short_move], gains, weights=CostWeights(), seed=4)
    two = evaluate([short_move, short_move], gains, weights=CostWeights(), seed=4)
    for name, value in one.terms.items():
        assert two.terms[name] == pytest.approx(2 * value, rel=1e-12, abs=1e-15)
    assert two.cost == pytest.approx(2 * one.cost)
