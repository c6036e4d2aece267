"""A run log as CSV: one row per servo tick, the columns of ``sim.loop.LOG_FIELDS``.

The header is documented in the README ("CSV columns"). Floats are written with 10
significant digits (enough for motor radians over hours of motion to 1e-6 rev), the integer
``state`` and ``fault`` codes as integers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.loop import LOG_FIELDS, RunLog

__all__ = ["read_csv", "write_csv"]

_INT_FIELDS = ("state", "fault")


def write_csv(log: RunLog, path: str | Path) -> Path:
    """Write a single-axis log (use ``log.member(k)`` for a batch) to ``path``."""
    cols = [getattr(log, f) for f in LOG_FIELDS]
    if any(c.ndim != 1 for c in cols):
        raise ValueError("write_csv takes a single-axis log: use log.member(k) for a batch")
    fmt = ["%d" if f in _INT_FIELDS else "%.10g" for f in LOG_FIELDS]
    path = Path(path)
    table = np.column_stack([c.astype(float) for c in cols])
    np.savetxt(path, table, fmt=fmt, delimiter=",", header=",".join(LOG_FIELDS), comments="")
    return path


def read_csv(path: str | Path) -> RunLog:
    """Read a CSV written by ``write_csv`` back into a ``RunLog``."""
    data = np.genfromtxt(path, delimiter=",", names=True, ndmin=1)
    missing = [f for f in LOG_FIELDS if f not in (data.dtype.names or ())]
    if missing:
        raise ValueError(f"{path}: missing columns {missing}")
    cols = {
        f: data[f].astype(np.int64) if f in _INT_FIELDS else data[f].astype(float)
        for f in LOG_FIELDS
    }
    return RunLog(**cols)
