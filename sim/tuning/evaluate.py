"""Run gain sets (and plant variants) as one lock-step batch of the simulator; cost them.

Every member of the batch follows the same scripted commands through ``sim.loop.run``
(the simulated PC, the emulated UART, the firmware, the plant); member ``k`` gets the gains
``sets[k]`` and, optionally, its own plant parameters. Several scenarios are run one after
the other and their terms added.

Two settings of the runs differ from the config, both for speed and neither changing what
is judged: telemetry is off (``[telemetry] decimation = 0``: nothing reads it here) and
``[loop] event_levels`` is capped at :data:`EVENT_LEVELS` (a mode switch of the plant is
located within 2 ms / 2^8 = 8 us instead of 2 ns). When this was written the plant's event
halving could recurse ~10^5 times in one step when the speed crossed zero in belt contact
(seconds per tick); the plant no longer does, and the cap still halves the time of a batch
on Fig. 8 (measured: 3.2 s -> 1.6 s for 6 s of Fig. 8 with 30 members).

A third works around the batch firmware taking member 0's boot reading as everybody's
start: with the encoder zeroed at the start position, noise makes some members read
16383 (one count below zero, wrapped) at boot and believe they stand 4.5 deg away. The
encoder is offset by :data:`BOOT_OFFSET_COUNTS` counts so that no boot reading wraps, and
the cost compares the setpoint with the true position in the firmware's frame.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from firmware_model.units import AXIS_DEG_PER_COUNT
from sim.config import Experiment
from sim.loop import RunLog, run
from sim.tuning.cost import TERMS, CostWeights, combine, cost_terms
from sim.tuning.gains import GainSet, batch_overrides

__all__ = ["BOOT_OFFSET_COUNTS", "EVENT_LEVELS", "Evaluation", "evaluate"]

EVENT_LEVELS = 8
BOOT_OFFSET_COUNTS = 16


@dataclass(frozen=True)
class Evaluation:
    """Terms ``{name: (N,)}``, total ``cost (N,)`` and, if kept, the logs per scenario."""

    terms: dict[str, np.ndarray]
    cost: np.ndarray
    logs: tuple[RunLog, ...] = ()

    def member_terms(self, k: int) -> dict[str, float]:
        return {name: float(self.terms[name][k]) for name in TERMS}


def evaluate(
    scenarios: Sequence[Experiment],
    sets: Sequence[GainSet],
    *,
    weights: CostWeights,
    seed: int = 0,
    plant_overrides: Mapping[str, Any] | None = None,
    keep_logs: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> Evaluation:
    """Cost of each gain set (member ``k`` = ``sets[k]``) over ``scenarios``.

    ``plant_overrides``: ``{"table.key": (N,) list or scalar}`` for plant spreads
    (``sim.tuning.robust``). ``progress(done, total)`` counts ticks over all scenarios.
    """
    n = len(sets)
    if n < 1:
        raise ValueError("sets: need at least one gain set")
    overrides: dict[str, Any] = batch_overrides(list(sets))
    overrides["telemetry.decimation"] = 0
    overrides.update(plant_overrides or {})
    totals = {name: np.zeros(n) for name in TERMS}
    logs = []
    n_ticks = [int(round(e.duration_s / e.bench.dt_s)) for e in scenarios]
    done = 0
    for exp, ticks in zip(scenarios, n_ticks, strict=True):
        ov = dict(overrides)
        ov["loop.event_levels"] = min(EVENT_LEVELS, exp.bench.loop.event_levels)
        offset_counts = exp.bench.plant.encoder.offset_counts + BOOT_OFFSET_COUNTS
        ov.setdefault("encoder.offset_counts", offset_counts)

        def step(tick: int, _total: int, base: int = done) -> None:
            if progress is not None:
                progress(base + tick, sum(n_ticks))

        result = run(exp, batch=n, seed=seed, overrides=ov, progress=step)
        fw = exp.bench.firmware
        terms = cost_terms(
            result.log,
            exp,
            current_limit_a=fw.limits.current_limit_a,
            delay_ticks=fw.servo.compute_delay_ticks,
            settle_band_deg=weights.settle_band_deg,
            pos_offset_deg=BOOT_OFFSET_COUNTS * AXIS_DEG_PER_COUNT,
        )
        for name in TERMS:
            totals[name] = totals[name] + terms[name]
        if keep_logs:
            logs.append(result.log)
        done += ticks
    return Evaluation(totals, combine(totals, weights), tuple(logs))
