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
from typing import TextIO

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
        self._writer.writerow(
            (
                f"{msg.tick / self.tick_hz:.6f}",
                msg.tick,
                repr(msg.sp_pos_deg),
                repr(msg.sp_vel_dps),
                repr(msg.pos_deg),
                repr(msg.vel_dps),
                repr(msg.current_a),
                repr(msg.duty),
                State(msg.state).name,
                Fault(msg.fault).name,
                repr(msg.bus_voltage_v),
            )
        )
        self.rows += 1
