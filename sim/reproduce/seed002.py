"""Seed 002 (Zhang et al. 2013), Tables 1 and 2: the printed rows next to the planner's
fixed-period samples, and next to the board's setpoint and encoder position decoded from
the telemetry of ``bench_configs/seed002_tables.toml`` every 75 ticks (150 ms).

The paper's move is L = 120 mm at 50 mm/s; on the turntable it is 120 axis degrees at
50 deg/s (the planner is unit-free, so the samples are the same numbers).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner import sample_fixed_period, scurve_from_periods, trapezoid_from_periods
from sim.reproduce.experiments import Runner, Trace, load

__all__ = [
    "PAPER_TABLE1",
    "PAPER_TABLE2",
    "Seed002Result",
    "TableComparison",
    "bench_samples",
    "run",
]

# Seed 002, Table 1 (trapezoid): position, velocity, acceleration per 150 ms period, as
# printed (mm, mm/s, mm/s^2).
PAPER_TABLE1 = (
    (0, 0, 0), (0.93, 12.5, 83.3), (3.75, 25.0, 83.3), (8.43, 37.5, 83.3), (15.00, 50.0, 83.3),
    (22.50, 50.0, 0), (30.00, 50.0, 0), (37.50, 50.0, 0), (45.00, 50.0, 0), (52.50, 50.0, 0),
    (60.00, 50.0, 0), (67.50, 50.0, 0), (75.00, 50.0, 0), (82.50, 50.0, 0), (90.00, 50.0, 0),
    (97.50, 50.0, 0), (105.00, 50.0, 0), (111.56, 37.5, -83.3), (116.25, 25.0, -83.3),
    (119.07, 12.5, -83.3), (120.00, 0, -83.3),
)  # fmt: skip
# Seed 002, Table 2 (S-curve): position, velocity, acceleration, jerk (mm/s^3), as printed.
PAPER_TABLE2 = (
    (0, 0, 0, 0), (0.070, 1.39, 18.52, 123.456790), (0.560, 5.56, 37.04, 123.456790),
    (1.875, 12.50, 55.56, 123.456790), (4.375, 20.83, 55.56, 0), (8.125, 29.17, 55.56, 0),
    (13.125, 37.50, 55.56, 0), (19.310, 44.44, 37.04, -123.456790),
    (26.820, 48.61, 18.52, -123.456790), (33.750, 50.00, 0, -123.456790),
    (41.250, 50.00, 0, 0), (48.750, 50.00, 0, 0), (56.250, 50.00, 0, 0), (63.750, 50.00, 0, 0),
    (71.250, 50.00, 0, 0), (78.750, 50.00, 0, 0), (86.250, 50.00, 0, 0),
    (93.680, 48.61, -18.52, -123.456790), (100.69, 44.44, -37.04, -123.456790),
    (106.875, 37.50, -55.56, -123.456790), (111.875, 29.17, -55.56, 0),
    (115.625, 20.83, -55.56, 0), (118.125, 12.50, -55.56, 0), (119.440, 5.56, -37.04, 123.456790),
    (119.930, 1.39, -18.52, 123.456790), (120.000, 0, 0, 123.456790),
)  # fmt: skip

PERIOD_S = 0.15


@dataclass(frozen=True)
class TableComparison:
    """One table: the paper's rows, the planner's samples and the bench's, shape ``(rows,)``
    each, and where the largest differences are."""

    name: str
    columns: tuple[str, ...]
    paper: np.ndarray  # (rows, columns)
    planner: np.ndarray  # (rows, columns)
    bench_sp_pos: np.ndarray  # (rows,) the board's setpoint, relative to the move's start
    bench_pos: np.ndarray  # (rows,) the encoder position, relative to the move's start

    def max_diff(self, column: int) -> tuple[float, int]:
        """Largest |planner - paper| in ``column`` and its row."""
        d = np.abs(self.planner[:, column] - self.paper[:, column])
        k = int(np.argmax(d))
        return float(d[k]), k

    def max_bench_diff(self) -> tuple[float, int, float, int]:
        """Largest |board setpoint - planner position| (row) and |encoder - planner| (row)."""
        d_sp = np.abs(self.bench_sp_pos - self.planner[:, 0])
        d_pos = np.abs(self.bench_pos - self.planner[:, 0])
        return float(d_sp.max()), int(d_sp.argmax()), float(d_pos.max()), int(d_pos.argmax())


@dataclass(frozen=True)
class Seed002Result:
    tables: tuple[TableComparison, TableComparison]
    trace: Trace


def bench_samples(trace: Trace, move: int, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """The board's setpoint and encoder position every 150 ms from the start of ``move``
    (an index into the trace's moves), ``rows`` of each, relative to the start."""
    t0 = trace.command_t_s[move]
    i0 = trace.index_at(t0)
    start = trace.sp_pos_deg[i0]
    ticks = int(round(PERIOD_S / trace.dt_s))
    idx = i0 + ticks * np.arange(rows)
    idx = np.minimum(idx, len(trace.t_s) - 1)
    return trace.sp_pos_deg[idx] - start, trace.pos_deg[idx] - start


def run(runner: Runner) -> Seed002Result:
    """Sample the planner as the paper did and run the two moves on the bench.

    Runs as written also under ``--quick`` (the run is 8.5 s of simulated time and the
    paper's 150 ms grid does not survive a time scaling)."""
    exp = load("seed002_tables")
    trace = runner.run("seed 002 tables", exp)
    trap = sample_fixed_period(trapezoid_from_periods(120.0, 50.0, PERIOD_S, n_acc=4), PERIOD_S)
    scurve_prof = scurve_from_periods(120.0, 50.0, PERIOD_S, n_jerk=3, n_const=3)
    sc = sample_fixed_period(scurve_prof, PERIOD_S)
    t1 = np.array(PAPER_TABLE1, dtype=float)
    t2 = np.array(PAPER_TABLE2, dtype=float)
    sp1, pos1 = bench_samples(trace, 0, len(t1))
    sp2, pos2 = bench_samples(trace, 1, len(t2))
    table1 = TableComparison(
        "Table 1 (trapezoid)",
        ("position", "velocity", "acceleration"),
        t1,
        np.column_stack([trap.p, trap.v, trap.a_held]),
        sp1,
        pos1,
    )
    table2 = TableComparison(
        "Table 2 (S-curve)",
        ("position", "velocity", "acceleration", "jerk"),
        t2,
        np.column_stack([sc.p, sc.v, sc.a, sc.j_held]),
        sp2,
        pos2,
    )
    return Seed002Result((table1, table2), trace)
