"""The paper bench and a short move experiment (fast enough for optimiser tests)."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim.config import load_bench, load_experiment

BENCH = Path(__file__).resolve().parents[3] / "bench_configs" / "paper_bench.toml"

SHORT_MOVE = """
title = "short move"
bench = "{bench}"
duration_s = 0.7

[[command]]
t_s = 0.0
type = "move"
target_deg = 30.0
v_max_dps = 300.0
a_max_dps2 = 3000.0
"""


@pytest.fixture(scope="session")
def bench():
    return load_bench(BENCH)


@pytest.fixture(scope="session")
def short_move_path(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("tuning") / "short_move.toml"
    path.write_text(SHORT_MOVE.format(bench=BENCH.as_posix()))
    return path


@pytest.fixture(scope="session")
def short_move(short_move_path):
    return load_experiment(short_move_path)
