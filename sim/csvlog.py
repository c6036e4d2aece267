"""A run log as CSV: one row per servo tick, the columns of ``sim.loop.LOG_FIELDS``.

The header is documented in the README ("CSV columns"). The log's ``current_a`` (the plant's
true armature current) is written as ``true_current_a``, beside ``true_pos_deg``: no CSV the
project writes has a bare ``current_a``, and the measured current is ``current_meas_a`` in
every one (here, and in the telemetry CSVs of ``monitor`` and ``decode``). Floats are
written with 10 significant digits (enough for motor radians over hours of motion to
1e-6 rev), the integer ``state`` and ``fault`` codes as integers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.loop import LOG_FIELDS, RunLog

__all__ = ["read_csv", "write_csv"]

_INT_FIELDS = ("state", "fault")
#: RunLog field -> CSV column, where they differ.
CSV_COLUMN = {"current_a": "true_current_a"}


def write_csv(log: RunLog, path: str | Path) -> Path:
    """Write a single-axis log (use ``log.member(k)`` for a batch) to ``path``."""
    cols = [getattr(log, f) for f in LOG_FIELDS]
    if any(c.ndim != 1 for c in cols):
        raise ValueError("write_csv takes a single-axis log: use log.member(k) for a batch")
    fmt = ["%d" if f in _INT_FIELDS else "%.10g" for f in LOG_FIELDS]
    path = Path(path)
    table = np.column_stack([c.astype(float) for c in cols])
    header = ",".join(CSV_COLUMN.get(f, f) for f in LOG_FIELDS)
    np.savetxt(path, table, fmt=fmt, delimiter=",", header=header, comments="")
    return path


def read_csv(path: str | Path) -> RunLog:
    """Read a CSV written by ``write_csv`` back into a ``RunLog``."""
    data = np.genfromtxt(path, delimiter=",", names=True, ndmin=1)
    names = data.dtype.names or ()
    # a file written before the rename has current_a for the true current
    column = {f: CSV_COLUMN.get(f, f) if CSV_COLUMN.get(f, f) in names else f for f in LOG_FIELDS}
    missing = [column[f] for f in LOG_FIELDS if column[f] not in names]
    if missing:
        raise ValueError(f"{path}: missing columns {missing}")
    cols = {
        f: data[column[f]].astype(np.int64) if f in _INT_FIELDS else data[column[f]].astype(float)
        for f in LOG_FIELDS
    }
    return RunLog(**cols)
