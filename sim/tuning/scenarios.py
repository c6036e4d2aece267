"""The scenarios the tuner judges gains on: built-in experiment names or experiment files,
run on the bench being tuned, optionally time-compressed, with a settling tail.

``fig8`` is ``bench_configs/fig8.toml`` (seed 000 Fig. 8 / Table 1: four moves, replanned
while accelerating, cruising and decelerating). The optimiser runs it compressed by
``time_scale`` (``sim.reproduce.experiments.scale_quick``: times / k, positions / k^2,
velocities / k, the accelerations of the paper kept, so every replan happens in the same
state of its move) and with ``tail_s`` more seconds after the last command so that the final
stop's overshoot and settling are seen. ``time_scale = 1`` is the paper's 30 s scenario.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import bench_configs
from serial_protocol.exceptions import ConfigError
from sim.config import BenchConfig, Experiment, load_experiment
from sim.reproduce.experiments import scale_quick

__all__ = ["DEFAULT_SCENARIO", "scenario"]

DEFAULT_SCENARIO = "fig8"


def _load(name: str) -> Experiment:
    path = Path(name)
    if path.suffix == ".toml" and path.is_file():
        return load_experiment(path)
    try:
        return load_experiment(
            bench_configs.path(name if name.endswith(".toml") else name + ".toml")
        )
    except FileNotFoundError:
        raise ConfigError(f"--scenario {name!r}: no such experiment file or built-in") from None


def scenario(
    name: str, bench: BenchConfig, *, time_scale: float = 1.0, tail_s: float = 0.0
) -> Experiment:
    """Experiment ``name`` on ``bench``, compressed by ``time_scale``, ``tail_s`` longer."""
    if not time_scale >= 1.0:
        raise ConfigError(f"--time-scale {time_scale!r}: must be >= 1")
    if not tail_s >= 0.0:
        raise ConfigError(f"tail_s = {tail_s!r}: must be >= 0")
    exp = dataclasses.replace(_load(name), bench=bench)
    if time_scale != 1.0:
        exp = scale_quick(exp, time_scale)
    last_s = max((c.t_s for c in exp.commands), default=0.0)
    duration_s = max(exp.duration_s, last_s) + tail_s
    return dataclasses.replace(exp, duration_s=duration_s, title=exp.title or name)
