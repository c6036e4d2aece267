"""Differential evolution over the loop gains, the whole population run as one lock-step
batch of the simulator per generation.

``scipy.optimize.differential_evolution(vectorized=True, updating="deferred")`` hands the
objective a whole generation, ``(n_params, S)``; the objective first drops every candidate
the linear gate refuses (an unstable loop, or margins below ``MarginSpec``: those get a
penalty and are never simulated), then runs the rest as one batch (``sim.tuning.evaluate``).
The search is over log10 of each gain, within ``/bound_factor`` .. ``*bound_factor`` of
the starting gains. Staged (default): current, then velocity, then position, each stage
starting from the previous stage's best; joint: all five gains at once.

Reproducible: the seed drives scipy's generator and the simulator's noise (the same noise
for every candidate and every generation: common random numbers, so that differences in cost
come from the gains).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import differential_evolution
from scipy.stats import qmc

from sim.config import Experiment
from sim.tuning import linear
from sim.tuning.cost import CostWeights
from sim.tuning.evaluate import evaluate
from sim.tuning.gains import LOOP_FIELDS, GainSet

__all__ = ["PENALTY", "StageResult", "TuneResult", "TuneSettings", "generations", "tune"]

#: Cost given to a refused candidate (plus one per reason), far above any simulated cost.
PENALTY = 1.0e6


@dataclass(frozen=True)
class TuneSettings:
    """How the optimiser runs.

    Attributes:
        seed: drives differential evolution and the simulator's noise.
        mode: ``"staged"`` (current, velocity, position in turn) or ``"joint"``.
        popsize: scipy's population multiplier (members = popsize * gains of the stage).
        maxiter: generations after the initial one, per stage.
        bound_factor: search each gain within [start / f, start * f].
        weights: the cost weights.
        margins: least margins a candidate must keep (None: only stability).
    """

    seed: int = 0
    mode: str = "staged"
    popsize: int = 10
    maxiter: int = 4
    bound_factor: float = 4.0
    weights: CostWeights = field(default_factory=CostWeights)
    margins: linear.MarginSpec | None = field(default_factory=linear.MarginSpec)

    def __post_init__(self) -> None:
        if self.mode not in ("staged", "joint"):
            raise ValueError(f"mode = {self.mode!r}: must be 'staged' or 'joint'")
        if self.popsize < 2 or self.maxiter < 0:
            raise ValueError(f"popsize = {self.popsize}, maxiter = {self.maxiter}: too small")
        if not self.bound_factor > 1.0:
            raise ValueError(f"bound_factor = {self.bound_factor!r}: must be > 1")

    def stages(self) -> list[tuple[str, ...]]:
        if self.mode == "joint":
            return [("current", "velocity", "position")]
        return [("current",), ("velocity",), ("position",)]


@dataclass(frozen=True)
class StageResult:
    """One stage: the loops tuned, the best gains and cost, and the search record."""

    loops: tuple[str, ...]
    gains: GainSet
    cost: float
    start_cost: float
    generations: int
    simulated: int
    refused: int
    best_per_generation: tuple[float, ...]


@dataclass(frozen=True)
class TuneResult:
    start: GainSet
    gains: GainSet
    stages: tuple[StageResult, ...]


def _stage(
    scenarios: Sequence[Experiment],
    start: GainSet,
    loops: tuple[str, ...],
    settings: TuneSettings,
    seed: int,
    on_generation: Callable[[], None] | None,
    extra_starts: Sequence[GainSet] = (),
) -> StageResult:
    names = [f for loop in loops for f in LOOP_FIELDS[loop]]

    def log_gains(g: GainSet) -> np.ndarray:
        return np.array([math.log10(max(getattr(g, n), 1e-12)) for n in names])

    centre = log_gains(start)
    half = math.log10(settings.bound_factor)
    lo, hi = centre - half, centre + half
    # The initial population: a Latin hypercube over the box, its first member the start
    # gains, the next ones the extra starts (baselines) clipped into the box.
    size = max(5, settings.popsize * len(names))  # scipy needs more than 4 members
    unit = qmc.LatinHypercube(d=len(names), seed=seed).random(size)
    init = lo + unit * (hi - lo)
    init[0] = centre
    for k, g in enumerate(extra_starts[: size - 1], start=1):
        init[k] = np.clip(log_gains(g), lo, hi)
    bench = scenarios[0].bench
    record: dict = {"simulated": 0, "refused": 0, "best": [], "best_x": None}
    record.update(best_cost=math.inf, start_cost=math.nan)

    def candidate(x: np.ndarray) -> GainSet:
        return start.replace(**{n: float(10.0**v) for n, v in zip(names, x, strict=True)})

    def objective(xs: np.ndarray) -> np.ndarray:
        xs = np.atleast_2d(xs.T).T  # (n_params, S)
        sets = [candidate(xs[:, k]) for k in range(xs.shape[1])]
        cost = np.empty(len(sets))
        ok = []
        for k, g in enumerate(sets):
            reasons = linear.rejection_reasons(bench, g, settings.margins)
            if reasons:
                cost[k] = PENALTY * (1 + len(reasons))
            else:
                ok.append(k)
        record["refused"] += len(sets) - len(ok)
        if ok:
            ev = evaluate(scenarios, [sets[k] for k in ok], weights=settings.weights, seed=seed)
            cost[ok] = np.minimum(ev.cost, PENALTY)
            record["simulated"] += len(ok)
        for k in range(xs.shape[1]):
            if np.allclose(xs[:, k], centre, rtol=0.0, atol=1e-12):
                record["start_cost"] = float(cost[k])  # the first member of generation 0
        k_best = int(np.argmin(cost))
        if cost[k_best] < record["best_cost"]:
            record["best_cost"] = float(cost[k_best])
            record["best_x"] = xs[:, k_best].copy()
        record["best"].append(record["best_cost"])
        if on_generation is not None:
            on_generation()
        return cost

    differential_evolution(
        objective,
        bounds=list(zip(lo, hi, strict=True)),
        popsize=settings.popsize,
        maxiter=settings.maxiter,
        tol=0.0,
        seed=seed,
        init=init,
        polish=False,
        vectorized=True,
        updating="deferred",
    )
    if math.isnan(record["start_cost"]):  # not met exactly in generation 0
        objective(centre[:, None])
    start_cost = record["start_cost"]
    best = candidate(record["best_x"]) if record["best_cost"] < start_cost else start
    return StageResult(
        loops=loops,
        gains=best,
        cost=min(record["best_cost"], start_cost),
        start_cost=start_cost,
        generations=len(record["best"]),
        simulated=record["simulated"],
        refused=record["refused"],
        best_per_generation=tuple(record["best"]),
    )


def generations(settings: TuneSettings) -> int:
    """Objective calls of a whole tune (for a progress bar): per stage the initial
    population (the start gains are its first member) and ``maxiter`` generations."""
    return len(settings.stages()) * (settings.maxiter + 1)


def tune(
    scenarios: Sequence[Experiment],
    start: GainSet,
    settings: TuneSettings,
    *,
    on_generation: Callable[[], None] | None = None,
    extra_starts: Sequence[GainSet] = (),
) -> TuneResult:
    """Tune ``start`` on ``scenarios``; the start gains must pass the linear gate's
    stability check (``linear.check_gains``). ``extra_starts`` (e.g. the baselines) join
    each stage's initial population, their gains of that stage clipped into the box."""
    linear.check_gains(scenarios[0].bench, start, "tune start gains")
    gains = start
    stages = []
    for loops in settings.stages():
        result = _stage(
            scenarios, gains, loops, settings, settings.seed, on_generation, extra_starts
        )
        stages.append(result)
        gains = result.gains
    return TuneResult(start=start, gains=gains, stages=tuple(stages))
