"""Telemetry to CSV, as the PC side records it (``monitor --csv``, ``decode``).

Columns: ``t_s`` (tick / tick_hz, the board's clock) then the ``Telemetry`` fields with their
unit suffixes; ``state`` and ``fault`` are written by name. The message's ``current_a`` (the
board's reading of the IS pin) is the column ``current_meas_a``, the name the simulator's
``log.csv`` gives the same reading (its ``true_current_a`` is the plant's true current, which
no board can send). ``bus_voltage_v``, the bus voltage the board measured (0 from an older
board that does not send it), is the last column: a reader that looks columns up by name
reads older files without it (``sim.runfile``).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from typing import Any, TextIO

from serial_protocol.messages import Fault, State, Telemetry

__all__ = ["TELEMETRY_CSV_COLUMNS", "TelemetryCsvWriter"]

TELEMETRY_CSV_COLUMNS = (
    "t_s",
    "tick",
    "sp_pos_deg",
    "sp_vel_dps",
    "pos_deg",
    "vel_dps",
    "current_meas_a",
    "duty",
    "state",
    "fault",
    "bus_voltage_v",
)

_STATE_NAMES = {int(s): s.name for s in State}
_FAULT_NAMES = {int(f): f.name for f in Fault}


def _list(values: Any) -> list[Any]:
    """A column as a list of Python scalars (numpy's ``tolist``: the same values as
    ``float()`` / ``int()`` of each element)."""
    return values.tolist() if hasattr(values, "tolist") else list(values)


def _names(codes: Any, names: dict[int, str], enum: Any) -> list[str]:
    # an unknown code raises the ValueError naming it that enum(code) raises
    return [names[c] if c in names else enum(c).name for c in _list(codes)]


class TelemetryCsvWriter:
    """Write ``Telemetry`` rows to an open text file (header first)."""

    def __init__(self, out: TextIO, tick_hz: float = 500.0) -> None:
        if not tick_hz > 0:
            raise ValueError(f"tick_hz = {tick_hz!r}: must be > 0")
        self.tick_hz = tick_hz
        self.rows = 0
        self._writer = csv.writer(out, lineterminator="\n")
        self._writer.writerow(TELEMETRY_CSV_COLUMNS)

    def write(self, msg: Telemetry) -> None:
        """Append one row."""
        self.write_columns(
            [msg.tick], [msg.sp_pos_deg], [msg.sp_vel_dps], [msg.pos_deg], [msg.vel_dps],
            [msg.current_a], [msg.duty], [msg.state], [msg.fault], [msg.bus_voltage_v],
        )  # fmt: skip

    def write_columns(
        self,
        tick: Sequence[int] | Any,
        sp_pos_deg: Sequence[float] | Any,
        sp_vel_dps: Sequence[float] | Any,
        pos_deg: Sequence[float] | Any,
        vel_dps: Sequence[float] | Any,
        current_a: Sequence[float] | Any,
        duty: Sequence[float] | Any,
        state: Sequence[int] | Any,
        fault: Sequence[int] | Any,
        bus_voltage_v: Sequence[float] | Any,
    ) -> None:
        """Append one row per element of the columns (sequences or numpy arrays of the
        ``Telemetry`` fields, all of one length): the rows :meth:`write` would write for
        the messages, without building one per row."""
        ticks = _list(tick)
        floats = (sp_pos_deg, sp_vel_dps, pos_deg, vel_dps, current_a, duty)
        cols = [
            [f"{t / self.tick_hz:.6f}" for t in ticks],
            ticks,
            *(list(map(repr, _list(c))) for c in floats),
            _names(state, _STATE_NAMES, State),
            _names(fault, _FAULT_NAMES, Fault),
            list(map(repr, _list(bus_voltage_v))),
        ]
        n = len(ticks)
        if any(len(c) != n for c in cols):
            raise ValueError(f"columns of {sorted({len(c) for c in cols})} rows: need one length")
        self._writer.writerows(zip(*cols, strict=True))
        self.rows += n
